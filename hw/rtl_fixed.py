"""Fixed-point values for Amaranth: a raw Amaranth value plus its format, with exact arithmetic.

Names follow Amaranth's proposed `lib.fixed` (RFC 41): formats are the `SQ(i, f)` / `UQ(i, f)` shapes of
hw/fixed.py (one definition for the bit-true model and the hardware), `Const` makes a constant, `reshape`
moves the binary point exactly, `round` rounds to nearest (ties up) into a format and `saturate` clamps
into it, returning the flag the saturation counters count; `as_float` reads a raw value back.

Arithmetic is exact: a product has i1 + i2 integer and f1 + f2 fraction bits, a sum aligns both operands
to the finer binary point and grows by one bit. Rounding and saturation happen only where asked, which is
where the bit-true model (hw/fixed.py) rounds and saturates, so the two agree bit for bit.

`pipelined_product` registers an exact product of two raw values the way an ECP5 maps it best: one
18x18 multiplier (MULT18X18D) and a product register when both operands fit one, otherwise registered
DSP-sized partial products and their sum one cycle later (`product_latency` gives its latency).
"""
from __future__ import annotations

from amaranth.hdl import Cat, Module, Mux, Signal, Value, signed, unsigned
from amaranth.hdl import Const as _AConst

from .fixed import SQ, UQ, Shape

__all__ = ["SQ", "UQ", "Shape", "FixedValue", "Const", "as_shape", "as_float", "DSP_BITS", "LIMB_BITS",
           "product_latency", "pipelined_product", "tree_sum"]

DSP_BITS = 18     # operand width of one MULT18X18D (18 x 18 bits, signed or unsigned)
LIMB_BITS = 17    # low limbs of a split operand in a signed product: unsigned, so 18-bit signed values
ROW_BITS = 4      # a (partial) product with an operand this narrow is a sum of shifted rows, not a DSP


def as_shape(fmt: Shape):
    """The Amaranth shape holding the raw integers of `fmt`."""
    return signed(fmt.width) if fmt.signed else unsigned(fmt.width)


def as_float(fmt: Shape, raw: int) -> float:
    return float(raw) * fmt.lsb


class FixedValue:
    """An Amaranth value `raw` holding a fixed-point number with `f` fraction bits (value = raw 2^-f).

    Intermediate results keep whatever width their exact arithmetic needs; `round` and `saturate` bring
    them into a format (a `Shape`) again.
    """

    def __init__(self, raw, f: int):
        self.raw = Value.cast(raw)
        self.f = int(f)

    @classmethod
    def of(cls, shape: Shape, raw) -> "FixedValue":
        if not isinstance(shape, Shape):
            raise TypeError(f"FixedValue needs a fixed-point Shape (SQ/UQ), got {shape!r}")
        raw = Value.cast(raw)
        if raw.shape().signed != shape.signed:
            raw = raw.as_signed() if shape.signed else raw.as_unsigned()
        return cls(raw, shape.f)

    def __repr__(self):
        return f"FixedValue({self.raw!r}, f={self.f})"

    # ---- exact arithmetic (Amaranth widens the raw values as needed)
    def __mul__(self, other: "FixedValue") -> "FixedValue":
        return FixedValue(self.raw * other.raw, self.f + other.f)

    def _aligned(self, other):
        f = max(self.f, other.f)
        return self.reshape(f).raw, other.reshape(f).raw, f

    def __add__(self, other: "FixedValue") -> "FixedValue":
        a, b, f = self._aligned(other)
        return FixedValue(a + b, f)

    def __sub__(self, other: "FixedValue") -> "FixedValue":
        a, b, f = self._aligned(other)
        return FixedValue(_signed(a) - _signed(b), f)

    def __neg__(self) -> "FixedValue":
        return FixedValue(-_signed(self.raw), self.f)

    def __lt__(self, other: "FixedValue") -> Value:
        a, b, _ = self._aligned(other)
        return a < b

    def __le__(self, other: "FixedValue") -> Value:
        a, b, _ = self._aligned(other)
        return a <= b

    # ---- format changes
    def reshape(self, f: int) -> "FixedValue":
        """The same value with f fraction bits; only exact moves (f >= self.f) are allowed."""
        if f < self.f:
            raise ValueError(f"reshape from {self.f} to {f} fraction bits would drop bits: use round()")
        return FixedValue(self.raw.shift_left(f - self.f), f)

    def round(self, dst: Shape) -> tuple["FixedValue", Value]:
        """Round to nearest (ties up) to dst's binary point, then saturate into dst: (value, saturated)."""
        s = self.f - dst.f
        raw = self.raw
        if s > 0:
            raw = (raw + (1 << (s - 1))) >> s
        elif s < 0:
            raw = raw.shift_left(-s)
        return FixedValue(raw, dst.f).saturate(dst)

    def saturate(self, dst: Shape) -> tuple["FixedValue", Value]:
        """Clamp into dst (same binary point required): (value, saturated flag).

        The range tests look at raw's bits above dst's width (raw > max_raw: raw non-negative with one of
        them set; raw < min_raw: raw negative with one of them clear, or any negative raw for an unsigned
        dst), which are the comparisons with max_raw and min_raw without a carry chain after the one
        that computed raw.
        """
        if dst.f != self.f:
            raise ValueError(f"saturate needs the same binary point ({self.f} -> {dst}): use round()")
        raw = self.raw
        over, under = _out_of_range(raw, dst)
        clamped = Mux(over, dst.max_raw, Mux(under, dst.min_raw, raw))
        return FixedValue.of(dst, clamped[:dst.width]), over | under


def _out_of_range(raw: Value, dst: Shape) -> tuple[Value, Value]:
    """(raw > dst.max_raw, raw < dst.min_raw) from raw's high bits. dst holds the raw integers of
    [-2^(w-1), 2^(w-1)) (signed, w bits: raw fits when its bits w-1 and up are all equal) or [0, 2^w)
    (unsigned: raw fits when it is non-negative and its bits w and up are clear)."""
    n, signed_raw = len(raw), raw.shape().signed
    w = dst.width - 1 if dst.signed else dst.width        # raw's bits from w up must be copies of its sign
    if dst.signed:
        assert dst.max_raw == (1 << w) - 1 and dst.min_raw == -(1 << w), dst
    else:
        assert dst.max_raw == (1 << w) - 1 and dst.min_raw == 0, dst
    if not signed_raw:
        return (raw[w:].any() if n > w else _AConst(0, 1)), _AConst(0, 1)
    neg = raw[n - 1]
    if n - 1 <= w:                                        # no bits between dst's top bit and raw's sign
        return _AConst(0, 1), (neg if not dst.signed else _AConst(0, 1))
    high = raw[w:n - 1]
    return ~neg & high.any(), neg & (~high.all() if dst.signed else _AConst(1, 1))


def _signed(v: Value) -> Value:
    """v as a signed value of the same numeric value (unsigned values gain a zero sign bit)."""
    return v if v.shape().signed else Cat(v, _AConst(0, 1)).as_signed()


def Const(value: float, shape: Shape) -> tuple[FixedValue, int]:
    """A constant: value rounded to nearest into `shape` and saturated; returns (value, saturations)."""
    from .fixed import Saturations
    sat = Saturations()
    raw = int(shape.from_float(value, sat, "const"))
    return FixedValue.of(shape, _AConst(raw, as_shape(shape))), sat.total



# ---------------------------------------------------------------------------------------------- products

def _operand_width(shape, signed_product: bool) -> int:
    """Bits of an operand in the product's arithmetic: Amaranth multiplies an unsigned operand by a signed
    one as a signed value with a zero sign bit (one bit more); two unsigned operands stay unsigned."""
    return shape.width + int(signed_product and not shape.signed)


def product_latency(a_shape, b_shape) -> int:
    """Cycles `pipelined_product` takes for operands of these Amaranth shapes: 1 when both fit one 18x18
    multiplier (at most DSP_BITS bits each in the product's arithmetic, as above), else 2."""
    sp = a_shape.signed or b_shape.signed
    fits = _operand_width(a_shape, sp) <= DSP_BITS and _operand_width(b_shape, sp) <= DSP_BITS
    return 1 if fits else 2


def _limbs(v: Value, limb: int) -> list[tuple[int, Value]]:
    """(bit offset, limb) of an operand already in the product's arithmetic: v itself when it has at most
    DSP_BITS bits, else unsigned `limb`-bit limbs from the LSB and a top limb of the remaining bits
    (at most DSP_BITS) with v's signedness, so that v = sum of limb 2^offset."""
    w = len(v)
    if w <= DSP_BITS:
        return [(0, v)]
    out, off = [], 0
    while w - off > DSP_BITS:
        out.append((off, v[off:off + limb]))
        off += limb
    top = v[off:]
    out.append((off, top.as_signed() if v.shape().signed else top))
    return out


def tree_sum(values):
    """A balanced adder tree (exact: Amaranth widens every sum)."""
    values = list(values)
    while len(values) > 1:
        values = [values[i] + values[i + 1] if i + 1 < len(values) else values[i]
                  for i in range(0, len(values), 2)]
    return values[0]


def _mul(x: Value, y: Value) -> Value:
    """x * y: a multiplier, or for an operand of at most ROW_BITS bits the sum of the other operand's
    copies selected by its bits (the top bit of a signed one weighs -2^(n-1)), a few LUTs and adders
    instead of a MULT18X18D (which, used for a 4-bit operand, costs a DSP block and long routes to it)."""
    if min(len(x), len(y)) > ROW_BITS:
        return x * y
    s, l = (x, y) if len(x) <= len(y) else (y, x)
    n = len(s)
    rows = [Mux(s[i], l, 0).shift_left(i) for i in range(n)]
    if s.shape().signed:
        rows[-1] = -rows[-1]
    return tree_sum(rows)


def pipelined_product(m: Module, a, b, name: str) -> tuple[Value, int]:
    """The exact product a * b (Amaranth values or integers) from a register: (value, latency).

    When both operands fit one 18x18 multiplier (`product_latency` = 1) the product is registered
    directly: one multiplier, then the register. Otherwise each operand wider than DSP_BITS is split into
    limbs from the LSB, unsigned ones of LIMB_BITS = 17 bits in a signed product (DSP_BITS = 18 when both
    operands are unsigned) and a top limb of at most 18 bits, signed when the operand is, so that every
    pair of limbs fits one multiplier; every partial product is registered (cycle 1), and the partial products,
    shifted to their weights, are summed exactly into the product register (cycle 2): latency 2, and no
    cycle holds both a multiplier and a wide adder. A (partial) product with an operand of at most
    ROW_BITS = 4 bits (a limb counted in the product's arithmetic: a split's short top limb, say) is
    formed in logic, in the same cycle, as a sum of at most 4 shifted rows instead of a multiplier. A
    constant operand 2^z c (c odd) is multiplied as c, and the registered product shifted left by z. The
    result has the shape of a * b; registers are reset-less (their contents matter only alongside a valid
    bit).
    """
    a, b = Value.cast(a), Value.cast(b)
    shape = (a * b).shape()
    # a constant operand with trailing zero bits: multiply by its odd part, shift the product (exact)
    tz = 0
    if isinstance(b, _AConst) and not isinstance(a, _AConst):
        a, b = b, a
    if isinstance(a, _AConst) and a.value != 0:
        tz = (a.value & -a.value).bit_length() - 1
        if tz:
            a = _AConst(a.value >> tz, signed(len(a) - tz) if a.shape().signed else unsigned(len(a) - tz))

    def reg(value, shp, nm):
        r = Signal(shp, name=nm, reset_less=True)
        m.d.sync += r.eq(value)
        return r

    def result(value, latency):
        if not tz:
            return reg(value, shape, name), latency
        return reg(value, (a * b).shape(), name).shift_left(tz), latency

    if product_latency(a.shape(), b.shape()) == 1:
        return result(_mul(a, b), 1)
    # operands in the product's arithmetic (a zero sign bit on an unsigned one in a signed product)
    a_, b_ = (_signed(v) if shape.signed else v for v in (a, b))
    limb = LIMB_BITS if shape.signed else DSP_BITS
    parts = []
    for i, (oa, la) in enumerate(_limbs(a_, limb)):
        for j, (ob, lb) in enumerate(_limbs(b_, limb)):
            pp = reg(_mul(la, lb), (la * lb).shape(), f"{name}_pp{i}{j}")
            parts.append(pp.shift_left(oa + ob))
    return result(tree_sum(parts), 2)
