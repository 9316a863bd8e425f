"""Turns a datapath kernel (hw/datapath.py) into a fully pipelined Amaranth datapath, one item per clock.

`PipeArith` implements the arithmetic interface of hw/arith.py, but each operation emits hardware: the
kernel code that the bit-true model runs on NumPy arrays is run once more here on Amaranth values, so
the pipeline performs exactly the bit-true model's operations, in its formats, with its rounding and
saturation (hw/rtl_fixed.py). There is one description of the physics, and the two cannot drift apart.

Schedule (as soon as possible, no stalls; II = 1):
- every value carries the pipeline stage at which it is valid; an operation waits for its latest
  operand, earlier operands are delayed (shared between users): by a chain of registers over fewer than
  `LINE_MIN` stages, else by a delay line in a 16-word LUT RAM (`_line`: the ECP5's distributed RAM,
  TRELLIS_DPR16X4, with a registered output) that spans up to `LINE_MAX` stages, chained for longer
  delays; nearly all of a lane's delay flip-flops were in such long chains (the 1e3 poke core at P = 2,
  Pp = 3 had 43k of its 68k flip-flops in them, and nextpnr could not place it on an LFE5U-85F);
- multiply: 1 + DSP_REGS + `product_latency` stages (hw/rtl_fixed.py): 4 when both operands fit one
  18x18 multiplier (operand registers, exact product register, its copy, then round/saturate register),
  5 when one is wider (registered DSP-sized partial products, their exact sum); the operand registers and
  the product's copy serve the multiplier alone, so that the placer can put them beside its DSP block
  (nextpnr on the 1e3 square, medium: a multiplier between two far flip-flops took 3.9 ns of logic and
  8.8 ns of routing, 75.7 MHz); a product by a constant built from
  shifts and adds (`constant_product`) takes 1 + its stated latency (the same, or 3 for a constant of 5 or
  more signed digits by an operand that fits one multiplier); add, subtract, sum of terms, negate,
  convert, select: 1 stage; comparisons and boolean logic: 0 stages (combinational, folded into the select
  that uses them); constants and per-phase values (step counter): no stage at all;
- `clamp_stage` (the streaming core's lanes): an operation whose result can saturate takes one stage more,
  its exact rounded value registered before the clamp; a comparison of values takes one stage,
  registered. In one stage, the carry chain's top bits decided the clamp, whose select fanned out to
  every bit of the result (nextpnr on the 1e4 square: a product's rounding into its register, 11.3 ns,
  4.1 of them on that fan-out; a window word's saturating difference into a multiplier's operand
  register, 11.6 ns);
- function units (hw/rtl_funcunits.py) stream their operand in and their result out after their latency.
A valid bit travels with every item; only it has a reset: a value's registers have none (read only
where its valid bit says so), since a reset on every register was a net of 21,900 flip-flops across
the die of the 1e4 square (and a slice's two flip-flops share their reset line). Each saturating operation yields a flag at its stage; it counts
when the item is valid and, inside a gate (a condition such as "the node is below the floor"), when the
gate is open: exactly the items the bit-true model evaluates after `np.flatnonzero`. Flags count one
stage late (their gates registered first) and a lane's counts are summed per quantity into a register
(`saturation_events`), two cycles after the stage of the flag (or of its gate, if later).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from amaranth.hdl import Cat, Const, Elaboratable, Module, Mux, Signal, Value, unsigned
from amaranth.lib.memory import Memory

from .arith import Arith, Gate
from .fixed import Saturations, Shape
from .rtl_fixed import KEEP_APART_TAG, FixedValue, as_shape, constant_product, registered_product, tree_sum

OP_LATENCY = 1
LINE_WORDS = 16          # a delay line's memory: one TRELLIS_DPR16X4 deep
LINE_MIN = 4             # delays of this many stages or more go through delay lines
LINE_MAX = LINE_WORDS    # the longest one line spans (its read never meets the write of its cycle)
LINE_GROUP = 32          # delay lines made one after another that share their address counters


@dataclass
class PV:
    """A pipelined fixed-point value: Amaranth value `sig` (raw, in the format of quantity q), valid at
    `stage` (None: a constant or a value that holds still during a phase), inside `gate` (or None)."""
    sig: Value
    q: str
    stage: int | None
    gate: "PBool | None" = None


@dataclass
class PBool:
    sig: Value
    stage: int | None
    gate: "PBool | None" = None

    def _op(self, other, fn):
        ar = _CURRENT[-1]
        return ar._bool(fn, self, other)

    def __and__(self, other):
        return self._op(other, lambda a, b: a & b)

    def __rand__(self, other):
        return self._op(other, lambda a, b: a & b)

    def __or__(self, other):
        return self._op(other, lambda a, b: a | b)

    def __invert__(self):
        ar = _CURRENT[-1]
        return ar._bool(lambda a: ~a, self)


_CURRENT: list = []


class RtlGate(Gate):
    """The hardware form of hw.arith.Gate: the condition travels with the values instead of subsetting, so a
    hardware gate is never empty and its zeros are one constant."""

    def __init__(self, ar: "PipeArith", cond: PBool, parent: "RtlGate | None" = None):
        self.ar, self.cond, self.parent = ar, cond, parent

    def take(self, v: PV) -> PV:
        return PV(v.sig, v.q, v.stage, self.cond)

    def gate(self, cond: PBool) -> "RtlGate":
        return RtlGate(self.ar, self.ar._bool(lambda a, b: a & b, self.cond, cond), self)

    def lift(self, v: PV) -> PV:
        """Zero where this gate is closed; the result lives in the enclosing gate (as Gate.lift)."""
        zero = self.ar.zeros(v.q, 1)
        out = self.ar.select(self.cond, PV(v.sig, v.q, v.stage, None), zero)
        return PV(out.sig, out.q, out.stage, self.parent.cond if self.parent is not None else None)

    def expand(self, v: PV) -> PV:
        zero = self.ar.zeros(v.q, 1)
        out = self.ar.select(self.cond, PV(v.sig, v.q, v.stage, None), zero)
        return PV(out.sig, out.q, out.stage, None)

    @property
    def empty(self) -> bool:
        return False

    def zeros(self, q) -> PV:
        return self.ar.zeros(q, 1)


@dataclass
class SatSource:
    quantity: str
    flag: Value       # 1 bit, or a small count
    stage: int
    gate: PBool | None


class PackedLines(Elaboratable):
    """The delay lines of one group and span side by side in one 16-word LUT RAM: a value of w bits in a
    line of its own takes ceil(w / 4) TRELLIS_DPR16X4, so flags and narrow values wasted most of theirs
    (an element lane of press-2d-rheological, medium: 315 DPR16X4 alone, 257 packed). Built when the
    design is elaborated, after the kernel and its users (scatter, state write) have asked for every line:
    each line's value is written at `w_addr` every cycle, the word read at `r_addr` combinationally, and
    its slice registered into the line's output (`add`'s `out`)."""

    def __init__(self, w_addr: Signal, r_addr: Signal):
        self.w_addr, self.r_addr = w_addr, r_addr
        self.lines: list[tuple[Value, Signal]] = []

    def add(self, value: Value, out: Signal):
        self.lines.append((value, out))

    def elaborate(self, platform):
        m = Module()
        word = Cat(*(value for value, _ in self.lines))
        m.submodules.mem = mem = Memory(shape=unsigned(len(word)), depth=LINE_WORDS, init=[])
        wr, rd = mem.write_port(), mem.read_port(domain="comb")
        m.d.comb += [wr.addr.eq(self.w_addr), wr.data.eq(word), wr.en.eq(1), rd.addr.eq(self.r_addr)]
        at = 0
        for value, out in self.lines:
            m.d.sync += out.eq(rd.data[at:at + len(value)])
            at += len(value)
        return m


class PipeArith(Arith):
    """Builds one pipeline lane in module `m`.

    `fmt`: quantity -> Shape (hw/formats.py FormatSet); `units`: the bit-true function unit models by
    name ("inv_l", ..., "phi", "psi"); `valid`: the stage-0 valid bit; `param_source(q, array)` returns the
    Amaranth value (valid at stage `param_stage`) of a per-item parameter, or of a per-item flag;
    `tables`: where the function units' ROMs come from (None: each unit its own; hw/stream/tables.py);
    `dsp`: the multipliers' variant (hw/rtl_fixed.py DSP_VARIANTS: "ecp5" instantiates MULT18X18Ds);
    `clamp_stage`: results that can saturate take a stage more, their exact value registered before the
    clamp (see the module docstring).
    """

    def __init__(self, m: Module, fmt, units: dict, valid: Value, name: str, param_source=None,
                 param_stage: int = 1, tables=None, dsp: str = "sim", clamp_stage: bool = False):
        self.m, self.fmt, self.units, self.name, self.tables, self.dsp = m, fmt, units, name, tables, dsp
        self.clamp_stage = clamp_stage
        self.param_source, self.param_stage = param_source, param_stage
        self._valid = {0: valid}
        self._delays = {}
        self._taps = {}                        # id(sig) -> {stage: the value at that stage}
        self._n = 0
        self.sat_sources: list[SatSource] = []
        self.const_sat = Saturations()
        self.memories: list[dict] = []         # the function units' memories, named by their place
        self.depth = 0
        self._lines = 0                        # delay lines made so far
        self._counters: dict = {}              # (line group, span; 0: write) -> its address counter
        self._packs: dict = {}                 # (line group, span) -> its PackedLines

    def __enter__(self):
        _CURRENT.append(self)
        return self

    def __exit__(self, *exc):
        _CURRENT.pop()

    # ---- plumbing
    def shape(self, q) -> Shape:
        return self.fmt[q]

    def _name(self, what):
        self._n += 1
        return f"{self.name}_{what}_{self._n}"

    def _reg(self, expr, shape, what):
        r = Signal(shape, name=self._name(what), reset_less=True)       # a value: no reset (see above)
        self.m.d.sync += r.eq(expr)
        return r

    def valid_at(self, stage: int) -> Value:
        if stage not in self._valid:
            prev = self.valid_at(stage - 1)
            r = Signal(name=f"{self.name}_valid_{stage}")
            self.m.d.sync += r.eq(prev)
            self._valid[stage] = r
        self.depth = max(self.depth, stage)
        return self._valid[stage]

    def delay(self, sig: Value, src: int | None, dst: int) -> Value:
        """sig (valid at stage src) as seen at stage dst >= src: from the nearest stage at or before dst
        at which it is already available (a tap), by registers when that is fewer than LINE_MIN stages
        back, else by delay lines."""
        if src is None or src == dst:
            return sig
        if dst < src:
            raise AssertionError(f"value of stage {src} wanted at earlier stage {dst}")
        key = (id(sig), dst)
        if key not in self._delays:
            taps = self._taps.setdefault(id(sig), {src: sig})
            base = max(st for st in taps if st <= dst)
            if dst - base < LINE_MIN:
                prev = self.delay(sig, src, dst - 1)
                out = self._reg(prev, sig.shape(), "dly")
            else:
                span = min(dst - base, LINE_MAX)
                if dst - base - span and dst - base - span < LINE_MIN:
                    span = dst - base - LINE_MIN        # leave the last piece long enough for a line
                out = self._line(taps[base], span)
                if base + span < dst:
                    self._delays[(id(sig), base + span)] = (out, sig)
                    taps[base + span] = out
                    out = self.delay(sig, src, dst)
            self._delays[key] = (out, sig)     # keep sig alive for id()
            taps[dst] = out
        self.depth = max(self.depth, dst)
        return self._delays[key][0]

    def _line(self, value: Value, span: int) -> Value:
        """`value` `span` cycles later (LINE_MIN <= span <= LINE_MAX) through a delay line: written every
        cycle at word t mod 16 (t: a free-running cycle count), read combinationally span - 1 words back, the word
        registered. Lines made one after another share address counters in groups of LINE_GROUP
        (`_line_address`); the lines of one group and span also share their LUT RAM (`PackedLines`)."""
        assert LINE_MIN <= span <= LINE_MAX, span
        group = self._lines // LINE_GROUP
        self._lines += 1
        key = (group, span)
        if key not in self._packs:
            pack = PackedLines(self._line_address(group, 0), self._line_address(group, span))
            self.m.submodules[f"{self.name}_lines{group}_s{span}"] = pack
            self._packs[key] = pack
        out = Signal(value.shape(), name=self._name("line"), reset_less=True)
        self._packs[key].add(value, out)
        return out

    def _line_address(self, group: int, span: int) -> Signal:
        """Line group `group`'s counter of write addresses (span 0) or of read addresses for `span`:
        counting from -(span - 1) mod 16, one a cycle. One counter for all of a lane's lines was a
        route across the die (12.3 ns of routing on the 1e3 poke, 61 MHz); a counter a line cost the
        1e4 square 5,300 LUT4 and 6,200 flip-flops more, and its route stalled; so did groups of 8
        (1,000 LUT4 more than groups of 32, with which it routed: docs/streaming-core.md)."""
        key = (group, span)
        if key not in self._counters:
            what = "w" if span == 0 else f"r{span}"
            # no reset: the counters only ever step together, so a reset would not change their distance
            counter = Signal(range(LINE_WORDS), init=-(span - 1) % LINE_WORDS if span else 0,
                             name=f"{self.name}_lines{group}_{what}{KEEP_APART_TAG}", reset_less=True)
            self.m.d.sync += counter.eq(counter + 1)
            self._counters[key] = counter
        return self._counters[key]

    @staticmethod
    def _stage(*vals):
        st = [v.stage for v in vals if v is not None and v.stage is not None]
        return max(st) if st else None

    @staticmethod
    def _gate(*vals):
        g = [v.gate for v in vals if v is not None and v.gate is not None]
        return g[0] if g else None          # kernels only combine values of one gate (or nested ones)

    def input(self, sig: Value, q: str, stage: int) -> PV:
        return PV(sig, q, stage)

    def at(self, v, stage):
        return self.delay(v.sig, v.stage, stage)

    def fx(self, v: PV, stage) -> FixedValue:
        return FixedValue.of(self.shape(v.q), self.at(v, stage))

    def _result(self, exact: FixedValue, q, stage, gate, what):
        """Saturate `exact` (rounded to q's binary point, valid at `stage`) into q, register it and record
        its saturation flag: both valid at stage + 1, or at stage + 2 with `clamp_stage` when it can
        saturate (`exact` registered first, then clamped)."""
        if self.clamp_stage and not exact.fits(self.shape(q)):
            exact = FixedValue(self._reg(exact.raw, exact.raw.shape(), what + "_exact"), exact.f)
            stage += 1
        return self._registered(*exact.saturate(self.shape(q)), q, stage, gate, what)

    def _registered(self, val: FixedValue, flag, q, stage, gate, what):
        """Register `val` (in q's format, valid at `stage`) and its saturation flag: both valid at stage + 1."""
        r = self._reg(val.raw, as_shape(self.shape(q)), what)
        if not (isinstance(flag, Const) or (isinstance(flag, bool) and not flag)):
            f = self._reg(flag, 1, what + "_sat")
            self.sat_sources.append(SatSource(q, f, stage + 1, gate))
        self.valid_at(stage + 1)
        return PV(r, q, stage + 1, gate)

    def _s(self, *vals):
        s = self._stage(*vals)
        return 0 if s is None else s

    # ---- the arithmetic interface (hw/arith.py Arith)
    def const(self, q, value) -> PV:
        if isinstance(value, np.ndarray) and value.ndim > 0:
            raise ValueError(f"constant '{q}' is an array: per-item values come through param()")
        sat = Saturations()
        raw = int(self.shape(q).from_float(float(value), sat, q))
        for k, n in sat.items():
            self.const_sat[k] += n
        return PV(Const(raw, as_shape(self.shape(q))), q, None)

    def param(self, q, value) -> PV:
        arr = np.asarray(value)
        if arr.ndim == 0 or np.all(arr == arr.flat[0]):
            return self.const(q, float(arr.flat[0]))
        if self.param_source is None:
            raise ValueError(f"per-item parameter '{q}' but this lane has no parameter memory")
        sat = Saturations()
        raw = self.shape(q).from_float(arr, sat, q)
        for k, n in sat.items():
            self.const_sat[k] += n
        sig = self.param_source(q, raw, as_shape(self.shape(q)))
        return PV(sig, q, self.param_stage)

    def flag(self, name, values) -> PBool:
        arr = np.asarray(values, bool)
        if np.all(arr == arr.flat[0]):
            return PBool(Const(int(arr.flat[0]), 1), None)
        return PBool(self.param_source(name, arr.astype(np.int64), 1), self.param_stage)

    def window(self, step_no, first, end) -> PBool:
        """first <= step < end for the phase's step counter `step_no` (an Amaranth value)."""
        return PBool((step_no >= first) & (step_no < min(end, (1 << 32) - 1)), None)

    def zeros(self, q, n) -> PV:
        return PV(Const(0, as_shape(self.shape(q))), q, None)

    def mul(self, a, b, q) -> PV:
        """a * b rounded into q. A product by a constant (a Const operand: one material's k1 or c1, the
        penalty constants, the damper's linear-piece slopes...) is built from shifts and adds when that
        takes few adders (hw/rtl_fixed.py constant_product), otherwise, and for two variable operands, by
        multipliers (pipelined_product); either is exact, and the stage of the result follows the latency
        of the form built."""
        s = self._s(a, b)
        fa, fb = self.fx(a, s), self.fx(b, s)
        name = self._name("prod")
        built = None
        if isinstance(a.sig, Const) != isinstance(b.sig, Const):
            (cv, fc), x = ((a, fa), fb) if isinstance(a.sig, Const) else ((b, fb), fa)
            # the constant from the operand's own Const (fx may hand a delay register of it, or a sign
            # reinterpretation: an Operator), its bits read as the operand's format reads them
            c = Const(cv.sig.value, fc.raw.shape())
            built = constant_product(self.m, x.raw, c, name)
        p, lat = built or registered_product(self.m, fa.raw, fb.raw, name, self.dsp)
        return self._result(FixedValue(p, fa.f + fb.f).rounded(self.shape(q)), q, s + lat, self._gate(a, b), "mul")

    def add(self, a, b, q) -> PV:
        s = self._s(a, b)
        return self._result((self.fx(a, s) + self.fx(b, s)).rounded(self.shape(q)), q, s, self._gate(a, b), "add")

    def sub(self, a, b, q) -> PV:
        s = self._s(a, b)
        return self._result((self.fx(a, s) - self.fx(b, s)).rounded(self.shape(q)), q, s, self._gate(a, b), "sub")

    def sum(self, terms, q) -> PV:
        s = self._s(*terms)
        acc = None
        for t in terms:
            acc = self.fx(t, s) if acc is None else acc + self.fx(t, s)
        return self._result(acc.rounded(self.shape(q)), q, s, self._gate(*terms), "sum")

    def neg(self, a) -> PV:
        s = self._s(a)
        x, dst = self.fx(a, s), self.shape(a.q)
        if dst.signed:
            # -x leaves a signed format only at x = min_raw: decided from x, beside the negation's carry
            # chain, so that it takes one stage with `clamp_stage` too
            low = x.raw == dst.min_raw
            return self._registered(FixedValue.of(dst, Mux(low, dst.max_raw, (-x).raw)[:dst.width]), low,
                                    a.q, s, a.gate, "neg")
        return self._result((-x).rounded(dst), a.q, s, a.gate, "neg")

    def convert(self, a, q) -> PV:
        s = self._s(a)
        return self._result(self.fx(a, s).rounded(self.shape(q)), q, s, a.gate, "cvt")

    def le(self, a, b) -> PBool:
        return self._compare(a, b, lambda x, y: x <= y)

    def lt(self, a, b) -> PBool:
        return self._compare(a, b, lambda x, y: x < y)

    def _compare(self, a, b, fn) -> PBool:
        """A comparison: combinational at its operands' stage, or with `clamp_stage` registered (a stage
        later), so that no carry chain drives a select's fan-out in the same cycle."""
        s = self._stage(a, b)
        ss = 0 if s is None else s
        out = fn(self.fx(a, ss), self.fx(b, ss))
        if self.clamp_stage and s is not None:
            out, s = self._reg(out, 1, "cmp"), s + 1
            self.valid_at(s)
        return PBool(out, s, self._gate(a, b))

    def _bool(self, fn, *args) -> PBool:
        args = [a if isinstance(a, PBool) else PBool(Const(int(bool(a)), 1), None) for a in args]
        s = self._stage(*args)
        ss = 0 if s is None else s
        return PBool(fn(*[self.delay(a.sig, a.stage, ss) for a in args]), s, self._gate(*args))

    def select(self, cond, a, b) -> PV:
        """cond ? a : b in a's quantity (b converted first when its quantity differs, as hw/arith.py)."""
        if b.q != a.q:
            b = self.convert(b, a.q)
        s = self._s(cond, a, b)
        expr = Mux(self.delay(cond.sig, cond.stage, s), self.at(a, s), self.at(b, s))
        r = self._reg(expr, as_shape(self.shape(a.q)), "sel")
        self.valid_at(s + 1)
        return PV(r, a.q, s + 1, self._gate(a, b, cond))

    def gate(self, cond: PBool) -> RtlGate:
        return RtlGate(self, cond)

    def rsqrt(self, a, q) -> PV:
        """1/sqrt by the unit that implements the bit-true model self.units[q]: RsqrtUnit for an Rsqrt
        (Newton), RsqrtTableUnit for an RsqrtTable (table and interpolation)."""
        from .funcunits import RsqrtTable
        from .rtl_funcunits import RsqrtTableUnit, RsqrtUnit
        s = self._s(a)
        model = self.units[q]
        unit = (RsqrtTableUnit if isinstance(model, RsqrtTable) else RsqrtUnit)(model, self.tables, self.dsp)
        self._add_unit(self._name("rsqrt_" + q), unit)
        self.m.d.comb += [unit.i.payload.eq(self.at(a, s)), unit.i.valid.eq(self.valid_at(s))]
        out = s + unit.latency
        self.valid_at(out)
        self.sat_sources.append(SatSource(q, unit.o.payload.saturated, out, a.gate))
        return PV(unit.o.payload.value, q, out, a.gate)

    def inverse(self, mag, curve):
        """(below, above, [outputs]) of the inverse table unit of `curve` (hw/rtl_funcunits.py
        InverseTableUnit, model self.units[curve.name]) at the magnitude `mag`, as hw/arith.py
        FixedArith.inverse: below = mag <= Y1, above = mag >= Y2, the outputs in the quantities
        curve.outputs; all valid at the unit's latency after mag, in mag's gate. The unit's saturations
        count under the model's name (curve.name, as the bit-true model counts them)."""
        from .rtl_funcunits import InverseTableUnit
        model = self.units[curve.name]
        if self.shape(mag.q) != model.in_shape:
            raise ValueError(f"inverse table '{curve.name}': operand '{mag.q}' is {self.shape(mag.q)}, the "
                             f"unit takes {model.in_shape}")
        if len(curve.outputs) != len(model.out_shapes):
            raise ValueError(f"inverse table '{curve.name}': {len(curve.outputs)} outputs named, the unit "
                             f"has {len(model.out_shapes)}")
        s = self._s(mag)
        unit = InverseTableUnit(model, self.tables, self.dsp)
        self._add_unit(self._name("inverse_" + curve.name), unit)
        self.m.d.comb += [unit.i.payload.eq(self.at(mag, s)), unit.i.valid.eq(self.valid_at(s))]
        out = s + unit.latency
        self.valid_at(out)
        o = unit.o.payload
        self.sat_sources.append(SatSource(model.name, o.saturations, out, mag.gate))
        outs = [PV(getattr(o, f), q, out, mag.gate) for f, q in zip(unit.output_fields, curve.outputs)]
        return PBool(o.below, out, mag.gate), PBool(o.above, out, mag.gate), outs

    def _add_unit(self, name, unit):
        self.m.submodules[name] = unit
        self.memories += [{**mem, "name": f"{name}.{mem['name']}"} for mem in unit.memories]

    # ---- saturation accounting
    def saturation_events(self) -> list[tuple[str, Value]]:
        """(quantity, count) per quantity of this lane, in a register: each source's flag counts one
        stage after the later of its own stage and its gate's (the gate, often a comparison that is
        combinational at its stage, is registered first), when the item is valid and the gate open; the
        counts are summed per quantity into a register, so that the core's sum over lanes and quantities
        starts from flip-flops. An item's saturation at stage s (the later of flag and gate) is in this
        register two cycles after the item was at stage s."""
        per_q: dict[str, list[Value]] = {}
        for src in self.sat_sources:
            st = src.stage
            if src.gate is not None and src.gate.stage is not None and src.gate.stage > st:
                st = src.gate.stage            # the gate is known later: count the flag then
            st += 1
            flag = self.delay(src.flag, src.stage, st)
            en = self.valid_at(st)
            if src.gate is not None:
                en = en & self.delay(src.gate.sig, src.gate.stage, st)
            w = flag.shape().width
            per_q.setdefault(src.quantity, []).append(Mux(en, flag, Const(0, w)))
        out = []
        for q, terms in per_q.items():
            total = tree_sum(terms)
            r = Signal(total.shape(), name=f"{self.name}_sats_{q}")     # reset: 0 when nothing is valid
            self.m.d.sync += r.eq(total)
            out.append((q, r))
        return out
