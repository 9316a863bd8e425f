"""The arithmetic the datapath is written against, and its two array implementations.

The kernels of hw/datapath.py are written once against `Arith` (the operations below) and `Gate` (a
condition that selects items). Three arithmetics run them:

- `FloatArith` computes in float64 and records the largest magnitude of every quantity (range analysis);
- `FixedArith` computes on raw int64 integers with the formats of a `FormatSet`, rounding to nearest
  (ties up) and saturating with a count per quantity (hw/fixed.py): the bit-true model;
- `hw.pipeline.PipeArith` emits an Amaranth pipeline stage per operation: the hardware.

Every value names the quantity it holds; every operation names the quantity of its result, and in fixed
point that name selects the result's format (hw/formats.py), so rounding and saturation happen exactly
where the hardware rounds and saturates. The two array arithmetics hold values as `V` (an array and its
quantity) and also gather and scatter whole arrays (`ArrayArith`: the step of hw/datapath.py).
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from collections import defaultdict
from dataclasses import dataclass

import numpy as np

from .fixed import Saturations, Shape, _round_owned_into, _shift_left, add, mul, round_into


class Gate(ABC):
    """The items for which a condition holds: values taken into a gate are its items' only; operations on
    them act for those items only (in hardware: a flag that travels with the item and enables its
    saturation counts). `lift` puts a gate's values back among the enclosing gate's items (zero where the
    condition does not hold), `expand` all the way out, `gate` nests a further condition, `zeros(q)` is
    zero for the gate's items."""

    @property
    @abstractmethod
    def empty(self) -> bool:
        """No item passes: the array code skips what follows (a hardware gate never is empty)."""

    @abstractmethod
    def take(self, v): ...

    @abstractmethod
    def gate(self, cond) -> "Gate": ...

    @abstractmethod
    def lift(self, v): ...

    @abstractmethod
    def expand(self, v): ...

    @abstractmethod
    def zeros(self, q): ...


class Arith(ABC):
    """The operations a kernel may use. `q` names the quantity of a result; values are the arithmetic's own
    (arrays, raw integers, pipelined Amaranth values); conditions are its booleans."""

    @abstractmethod
    def const(self, q, value):
        """A scalar constant."""

    @abstractmethod
    def param(self, q, value):
        """A per-item parameter (array) or a scalar; in hardware a ROM field or a constant."""

    @abstractmethod
    def flag(self, name, values):
        """A per-item boolean (per node: free, member of a load)."""

    @abstractmethod
    def window(self, step_no, first, end):
        """first <= step_no < end (a load's time window)."""

    @abstractmethod
    def zeros(self, q, n):
        """Zero in q's format (n items; a hardware zero is one constant)."""

    @abstractmethod
    def gate(self, cond) -> Gate:
        """The items where cond holds."""

    @abstractmethod
    def mul(self, a, b, q): ...

    @abstractmethod
    def add(self, a, b, q): ...

    @abstractmethod
    def sub(self, a, b, q): ...

    @abstractmethod
    def sum(self, terms, q):
        """The sum of several terms, rounded once."""

    @abstractmethod
    def neg(self, a):
        """-a in a's quantity."""

    @abstractmethod
    def convert(self, a, q):
        """a rounded (and saturated) into q's format."""

    @abstractmethod
    def rsqrt(self, a, q):
        """1 / sqrt(a), the function unit of quantity q."""

    @abstractmethod
    def inverse(self, mag, curve):
        """(below, above, outputs) of the inverse table of `curve` (hw/funcunits.py InverseTable)."""

    @abstractmethod
    def le(self, a, b): ...

    @abstractmethod
    def lt(self, a, b): ...

    @abstractmethod
    def select(self, cond, a, b):
        """cond ? a : b, in a's quantity (b converted first when its quantity differs)."""


@dataclass
class V:
    """A value of the array arithmetics: an array (float values, or raw integers in the format of
    quantity q) and its quantity."""
    x: np.ndarray
    q: str


class ArrayGate(Gate):
    """A gate of the array arithmetics: the indices of the active items (`take` keeps them)."""

    def __init__(self, ar, cond, parent=None, n=None):
        self.ar, self.parent = ar, parent
        self.idx = np.flatnonzero(cond)
        self.n = len(cond) if n is None else n
        self.size = self.idx.size

    @property
    def empty(self) -> bool:
        return self.size == 0

    def take(self, v):
        return self.ar.take(v, self.idx)

    def gate(self, cond):
        if getattr(self.ar, "open_gates", False):      # the range probe opens nested gates too
            cond = np.ones(np.shape(cond), bool)
        return ArrayGate(self.ar, cond, self)

    def lift(self, v):
        out = np.zeros(self.n, v.x.dtype)
        out[self.idx] = v.x
        return V(out, v.q)

    def expand(self, v):
        full = self.lift(v)
        return self.parent.expand(full) if self.parent is not None else full

    def zeros(self, q):
        return self.ar.zeros(q, self.size)

    @property
    def full_idx(self):
        return self.idx if self.parent is None else self.parent.full_idx[self.idx]


class ArrayArith(Arith):
    """What both array arithmetics share: per-item parameters, flags, gates, step windows; and the array
    operations of a whole step: `state` (a state array as a value), `take` (gather items), `scatter`
    (exact per-node sums), `value` (a value as floats)."""

    def param(self, q, value):
        return self.const(q, value)

    def flag(self, name, values):
        return np.asarray(values, bool)

    def window(self, step_no, first, end):
        return first <= step_no < end

    def gate(self, cond):
        return ArrayGate(self, cond)

    @abstractmethod
    def state(self, q, x): ...

    @abstractmethod
    def host_value(self, q, x):
        """A value a host writes at run time (the probe's position, SI converted to hardware units) in q's
        format: rounded, its saturations counted as the run's."""

    @abstractmethod
    def initial_value(self, q, x):
        """A value of the initial state (the probe's initial position) in q's format, converted like the
        initial state (saturations counted as the constants')."""

    @abstractmethod
    def take(self, v, idx): ...

    @abstractmethod
    def scatter(self, parts, n, q): ...

    @abstractmethod
    def value(self, v) -> np.ndarray: ...


class FloatArith(ArrayArith):
    """float64 arithmetic; `peak[q]` is the largest |value| seen for quantity q.

    With `open_gates` every gate lets every item through (a probe that reaches every quantity, even
    ones a run never uses, such as contact forces of a scene that never touches the floor).
    """

    def __init__(self, open_gates: bool = False):
        self.peak = defaultdict(float)
        self.open_gates = open_gates

    def gate(self, cond):
        return ArrayGate(self, np.ones(np.shape(cond), bool) if self.open_gates else cond)

    def _rec(self, q, x):
        x = np.asarray(x, float)
        if x.size:
            m = float(np.abs(x).max())          # the method: np.max's Python wrapper cost a third more
            if m > self.peak[q]:
                self.peak[q] = m
        return V(x, q)

    def const(self, q, value):
        return self._rec(q, value)

    def state(self, q, x):
        return self._rec(q, x)

    def host_value(self, q, x):
        return self._rec(q, x)

    def initial_value(self, q, x):
        return self._rec(q, x)

    def value(self, v: V) -> np.ndarray:
        return v.x

    def take(self, v, idx):
        return V(v.x[idx], v.q)

    def mul(self, a, b, q):
        return self._rec(q, a.x * b.x)

    def add(self, a, b, q):
        return self._rec(q, a.x + b.x)

    def sub(self, a, b, q):
        return self._rec(q, a.x - b.x)

    def sum(self, terms, q):
        s = terms[0].x
        for t in terms[1:]:
            s = s + t.x
        return self._rec(q, s)

    def neg(self, a):
        return V(-a.x, a.q)

    def convert(self, a, q):
        return self._rec(q, a.x)

    def rsqrt(self, a, q):
        return self._rec(q, 1.0 / np.sqrt(a.x))

    def inverse(self, mag, curve):
        """(below, above, outputs) of an inverse table (hw/funcunits.py InverseTable), exactly: the
        magnitude's piece, and the inverse and companions at the magnitude clamped into the table."""
        from golden.elements import solve_convex
        y1, y2 = float(curve.g(np.float64(curve.t_lo))), float(curve.g(np.float64(curve.t_hi)))
        y = np.clip(mag.x, y1, y2)
        t = solve_convex(lambda t, k: curve.g(t), lambda t, k: curve.dg(t), y, curve.t_lo, curve.t_hi)
        outs = [t] + [c(t) for c, _, _ in curve.companions]
        return mag.x <= y1, mag.x >= y2, [self._rec(q, v) for q, v in zip(curve.outputs, outs)]

    def le(self, a, b):
        return a.x <= b.x

    def lt(self, a, b):
        return a.x < b.x

    def select(self, cond, a, b):
        """cond ? a : b, in a's quantity."""
        return V(np.where(cond, a.x, b.x), a.q)

    def zeros(self, q, n):
        return V(np.zeros(n), q)

    def scatter(self, parts, n, q):
        """Exact per-node sums of (values, node indices) contributions in q's binary point (not rounded,
        not range-recorded: the node kernel rounds them)."""
        out = np.zeros(n)
        for v, idx in parts:
            out += np.bincount(idx, weights=v.x, minlength=n)
        return V(out, q)


class FixedArith(ArrayArith):
    """Bit-true fixed-point arithmetic with the formats of `fmt` (quantity -> Shape)."""

    def __init__(self, fmt: dict, units: dict | None = None, sat: Saturations | None = None,
                 const_sat: Saturations | None = None, lost: Saturations | None = None):
        self.fmt = fmt
        self.units = units or {}          # function units by name: the rsqrt quantities, "phi", "psi"
        self.sat = sat if sat is not None else Saturations()                 # run time (the hardware counts)
        self.const_sat = const_sat if const_sat is not None else Saturations()   # constants (compile time)
        self.lost = lost if lost is not None else Saturations()     # constants that round to zero
        self._magnitude = {}      # quantity -> [sum |value| converted, sum |value| rounded to zero]
        self._consts = {}

    def shape(self, q) -> Shape:
        try:
            return self.fmt[q]
        except KeyError:
            raise KeyError(f"no number format for quantity '{q}'") from None

    def const(self, q, value):
        key = (q, id(value)) if isinstance(value, np.ndarray) else (q, float(value))
        if key not in self._consts:
            self._consts[key] = V(self.convert_constant(q, value), q)
        return self._consts[key]

    LOST_FRACTION = 0.01      # a quantity whose values lose this much of their magnitude to zero is lost

    def convert_constant(self, q, value) -> np.ndarray:
        """A constant or initial state in q's format. Saturations count in const_sat; values that round to
        zero count in `lost` once they carry more than LOST_FRACTION of the magnitude of everything
        converted into q (an object's coordinates all at the origin, a load that vanishes; a few tiny
        values below half an LSB are ordinary rounding)."""
        raw = self.shape(q).from_float(value, self.const_sat, q)
        v = np.abs(np.asarray(value, float))
        tot = self._magnitude.setdefault(q, [0.0, 0.0])
        tot[0] += float(v.sum())
        tot[1] += float(v[np.asarray(raw == 0)].sum()) if v.ndim else (float(v) if raw == 0 else 0.0)
        if tot[1] > self.LOST_FRACTION * tot[0]:
            self.lost[q] = max(self.lost[q], int(np.count_nonzero((raw == 0) & (v > 0))))
        elif q in self.lost:
            del self.lost[q]
        return raw

    def state(self, q, raw):
        return V(np.asarray(raw, np.int64), q)

    def host_value(self, q, x):
        return V(self.shape(q).from_float(x, self.sat, q), q)

    def initial_value(self, q, x):
        return V(self.convert_constant(q, x), q)

    def value(self, v: V) -> np.ndarray:
        return self.shape(v.q).to_float(v.x)

    def take(self, v, idx):
        return V(v.x[idx], v.q)

    def mul(self, a, b, q):
        return V(mul(a.x, self.shape(a.q), b.x, self.shape(b.q), self.shape(q), self.sat, q), q)

    def add(self, a, b, q):
        return V(add(a.x, self.shape(a.q), b.x, self.shape(b.q), self.shape(q), self.sat, q), q)

    def sub(self, a, b, q):
        return V(add(a.x, self.shape(a.q), b.x, self.shape(b.q), self.shape(q), self.sat, q, subtract=True), q)

    def sum(self, terms, q):
        f = max(self.shape(t.q).f for t in terms)
        parts = [_shift_left(t.x, f - self.shape(t.q).f) for t in terms]
        if len(parts) == 1:
            return V(round_into(parts[0], f, self.shape(q), self.sat, q), q)
        s = parts[0] + parts[1]                  # a fresh array: the rest is added in place
        for x in parts[2:]:
            if np.shape(s) == np.broadcast_shapes(np.shape(s), np.shape(x)):
                s += x
            else:                                # x is the larger: broadcasting needs a new array
                s = s + x
        return V(_round_owned_into(s, f, self.shape(q), self.sat, q), q)

    def neg(self, a):
        return V(self.shape(a.q).saturate(-a.x, self.sat, a.q), a.q)

    def convert(self, a, q):
        return V(round_into(a.x, self.shape(a.q).f, self.shape(q), self.sat, q), q)

    def rsqrt(self, a, q):
        unit = self.units[q]
        return V(unit(a.x, self.sat), q)

    def inverse(self, mag, curve):
        unit = self.units[curve.name]
        outs = unit(mag.x, self.sat)
        return mag.x <= unit.Y1, mag.x >= unit.Y2, [V(v, q) for v, q in zip(outs, curve.outputs)]

    def _aligned(self, a, b):
        fa, fb = self.shape(a.q).f, self.shape(b.q).f
        f = max(fa, fb)
        return _shift_left(a.x, f - fa), _shift_left(b.x, f - fb)

    def le(self, a, b):
        x, y = self._aligned(a, b)
        return x <= y

    def lt(self, a, b):
        x, y = self._aligned(a, b)
        return x < y

    def select(self, cond, a, b):
        if b.q != a.q:
            b = self.convert(b, a.q)
        return V(np.where(cond, a.x, b.x), a.q)

    def zeros(self, q, n):
        return V(np.zeros(n, np.int64), q)

    def scatter(self, parts, n, q):
        """Exact per-node sums of (values, node indices) contributions at q's binary point, not rounded.

        Integer sums are order independent, so any hardware accumulation order gives these bits; the
        node kernel rounds them once (with the floor and load forces) into the node force format.
        """
        f = self.shape(q).f
        for v, _ in parts:
            if self.shape(v.q).f > f:
                raise ValueError(f"scatter into '{q}': '{v.q}' has a finer binary point")
        out = np.zeros(n, np.int64)
        for v, i in parts:       # unbuffered int64 adds (np.add.at): exact, repeated indices included
            np.add.at(out, i, np.broadcast_to(_shift_left(v.x, f - self.shape(v.q).f), np.shape(i)))
        return V(out, q)
