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
`constant_product` forms a product by a constant from shifts and adds of its canonical signed digits
instead, when that takes few adders (CSD_ADDERS_PER_MULTIPLIER per multiplier saved), with its latency
stated (never below the multiplier's).
"""
from __future__ import annotations

from amaranth.hdl import Cat, Module, Mux, Signal, Value, signed, unsigned
from amaranth.hdl import Const as _AConst

from .fixed import SQ, UQ, Shape
from .mult18x18d import mult18x18d

__all__ = ["SQ", "UQ", "Shape", "FixedValue", "Const", "as_shape", "as_float", "DSP_BITS", "LIMB_BITS",
           "product_latency", "pipelined_product", "registered_product", "DSP_REGS", "DSP_VARIANTS", "KEEP_APART_TAG", "tree_sum", "multipliers", "csd_digits", "shift_add_choice",
           "constant_product", "CSD_ADDERS_PER_MULTIPLIER"]

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

    def rounded(self, dst: Shape) -> "FixedValue":
        """Round to nearest (ties up) to dst's binary point, exactly (as wide as that needs): the value
        `round` saturates."""
        s = self.f - dst.f
        raw = self.raw
        if s > 0:
            raw = (raw + (1 << (s - 1))) >> s
        elif s < 0:
            raw = raw.shift_left(-s)
        return FixedValue(raw, dst.f)

    def round(self, dst: Shape) -> tuple["FixedValue", Value]:
        """Round to nearest (ties up) to dst's binary point, then saturate into dst: (value, saturated)."""
        return self.rounded(dst).saturate(dst)

    def fits(self, dst: Shape) -> bool:
        """Whether every value raw's shape holds lies in dst's range, so that `saturate` never clamps
        (the flags of `_out_of_range` are constants)."""
        n, w = len(self.raw), dst.width - 1 if dst.signed else dst.width
        return n <= w if not self.raw.shape().signed else (dst.signed and n - 1 <= w)

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


DSP_REGS = 2     # a multiplier's own registers (`registered_product`): its operands before it, its
                 # product after it, so that the placer can put them beside its DSP block
DSP_VARIANTS = ("sim", "ecp5")   # `registered_product`: multipliers as Amaranth products, or MULT18X18D instances
KEEP_APART_TAG = "_keep_apart"   # in the names of registers Yosys must not merge (the multipliers' operand
                                 # registers, hw/stream/bram.py's LUT RAM write registers): it would make one
                                 # flip-flop of two that hold the same value, feeding blocks far apart (nextpnr:
                                 # 2.9 ns to the farther), so sim/synth.py marks them `keep`


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


def _constant_first(a: Value, b: Value) -> tuple[Value, Value, int]:
    """(a, b, z): a constant operand 2^z c (c odd) moved first and replaced by c, so that the product is
    (a b) 2^z, exactly; z = 0 without a constant operand."""
    if isinstance(b, _AConst) and not isinstance(a, _AConst):
        a, b = b, a
    if not isinstance(a, _AConst) or a.value == 0:
        return a, b, 0
    c = _odd_part(a)
    return c, b, len(a) - len(c)


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
    a, b, tz = _constant_first(a, b)

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


def registered_product(m: Module, a, b, name: str, dsp: str = "sim") -> tuple[Value, int]:
    """`pipelined_product` with its non-constant operands registered before it and its product after it
    (DSP_REGS cycles more): those registers serve the multipliers alone, so that the placer can put them
    beside the DSP blocks (nextpnr had a multiplier between two far flip-flops: 8.8 ns of routing).

    `dsp` (DSP_VARIANTS): "sim", those registers in logic, the multipliers Amaranth products (for every
    simulator, and Yosys maps them); "ecp5", the multipliers instantiated with those registers inside them
    (`_ecp5_product`). The latency and the value are the same."""
    if dsp not in DSP_VARIANTS:
        raise ValueError(f"unknown multiplier variant {dsp!r} (known: {', '.join(DSP_VARIANTS)})")
    if dsp == "ecp5":
        built = _ecp5_product(m, a, b, name)
        if built is not None:
            return built

    def reg(v, nm):
        r = Signal(v.shape(), name=nm, reset_less=True)
        m.d.sync += r.eq(v)
        return r
    a, b = (v if isinstance(v, (int, _AConst)) else reg(Value.cast(v), f"{name}{KEEP_APART_TAG}") for v in (a, b))
    p, lat = pipelined_product(m, a, b, name)
    return reg(p, f"{name}_dsp_out"), lat + DSP_REGS


def _ecp5_product(m: Module, a, b, name: str) -> tuple[Value, int] | None:
    """`registered_product` with MULT18X18D instances (hw/mult18x18d.py) holding its registers, cycle for
    cycle: one multiplier's operand, product and output registers become its input, pipeline and output
    registers; a split product's multipliers hold the operand and partial-product registers (input and
    output), and the sum and output registers stay in logic, as do the rows of a partial product with a
    narrow operand (`_mul`) and the registers of its operands. None when no multiplier is built (a product
    in rows alone): the caller's logic form is the same."""
    a, b = Value.cast(a), Value.cast(b)
    shape = (a * b).shape()
    a, b, tz = _constant_first(a, b)
    if multipliers(a.shape(), b.shape()) == 0:
        return None

    def reg(value, shp, nm):
        r = Signal(shp, name=nm, reset_less=True)
        m.d.sync += r.eq(value)
        return r

    def dsp(x, y, pipeline, nm):
        """x * y (operands of at most DSP_BITS bits in their product's arithmetic) from a MULT18X18D."""
        xy = (x * y).shape()
        x_, y_ = (_signed(v) if xy.signed else v for v in (x, y))
        p = mult18x18d(m, x_, y_, xy.signed, pipeline, nm)[:xy.width]
        return p.as_signed() if xy.signed else p

    def shifted(p):
        return p.shift_left(tz) if tz else p

    if product_latency(a.shape(), b.shape()) == 1:             # one multiplier: 3 registers inside it
        return shifted(dsp(a, b, True, name)), 1 + DSP_REGS
    a_, b_ = (_signed(v) if shape.signed else v for v in (a, b))
    limb = LIMB_BITS if shape.signed else DSP_BITS
    operands = {}                                                # logic's operand registers, when rows need them

    def registered(v, nm):
        if nm not in operands:
            operands[nm] = v if isinstance(v, _AConst) else reg(v, v.shape(), f"{name}_{nm}{KEEP_APART_TAG}")
        return operands[nm]
    parts = []
    for i, (oa, la) in enumerate(_limbs(a_, limb)):
        for j, (ob, lb) in enumerate(_limbs(b_, limb)):
            if min(len(la), len(lb)) > ROW_BITS:                 # partial product registered in the block
                pp = dsp(la, lb, False, f"{name}_pp{i}{j}")
            else:
                ra, rb = registered(a_, "a"), registered(b_, "b")
                la_r, lb_r = dict(_limbs(ra, limb))[oa], dict(_limbs(rb, limb))[ob]
                pp = reg(_mul(la_r, lb_r), (la_r * lb_r).shape(), f"{name}_pp{i}{j}")
            parts.append(pp.shift_left(oa + ob))
    total = reg(tree_sum(parts), (a * b).shape(), name)
    return reg(shifted(total), shape, f"{name}_dsp_out"), 2 + DSP_REGS


# ------------------------------------------------------------------------------------- constant products

CSD_ADDERS_PER_MULTIPLIER = 8    # shift-add products of a constant: at most this many adders per multiplier saved
ADDER_LEVELS_PER_CYCLE = 2


def _odd_part(c: _AConst) -> _AConst:
    """The constant operand `pipelined_product` multiplies by: c without its trailing zero bits."""
    if c.value == 0:
        return c
    tz = (c.value & -c.value).bit_length() - 1
    return _AConst(c.value >> tz, signed(len(c) - tz) if c.shape().signed else unsigned(len(c) - tz))


def multipliers(a_shape, b_shape) -> int:
    """MULT18X18D that `pipelined_product` builds for operands of these Amaranth shapes (of a constant
    operand, its odd part's shape): one per pair of DSP-sized limbs (one for operands that fit one), none for
    a (partial) product with an operand of at most ROW_BITS bits (rows in logic)."""
    if product_latency(a_shape, b_shape) == 1:
        return int(min(a_shape.width, b_shape.width) > ROW_BITS)
    sp = a_shape.signed or b_shape.signed
    limb = LIMB_BITS if sp else DSP_BITS

    def widths(shape):
        w = _operand_width(shape, sp)
        if w <= DSP_BITS:
            return [w]
        n = -(-(w - DSP_BITS) // limb)              # limbs of `limb` bits below a top limb of <= DSP_BITS
        return [limb] * n + [w - n * limb]
    return sum(1 for wa in widths(a_shape) for wb in widths(b_shape) if min(wa, wb) > ROW_BITS)


def csd_digits(c: int) -> list[tuple[int, int]]:
    """The canonical signed digits of the integer c (its non-adjacent form): [(shift, +1 or -1)] by rising
    shift, sum d 2^shift = c, no two digits at adjacent shifts; the fewest non-zero signed digits of any
    representation (about a third of c's bits on average)."""
    c, k, out = int(c), 0, []
    while c:
        if c & 1:
            d = 2 - (c & 3)            # +1 when c = 1 mod 4, -1 when c = 3 mod 4: leaves c = 0 mod 4
            out.append((k, d))
            c -= d
        c >>= 1
        k += 1
    return out


def _shift_add(a: Value, b: Value, d: int, sub: bool) -> Value:
    """a + b 2^d (a - b 2^d when sub), exact, with an adder only as wide as b and a's bits from d up: the
    low d bits of the sum are a's (b 2^d has none), a = (a >> d) 2^d + (a mod 2^d)."""
    if d == 0:
        return a - b if sub else a + b
    if len(a) <= d:                    # widen a (sign or zeros) so that a >> d keeps its sign
        fill = d + 1 - len(a)
        a = (Cat(a, a[-1].replicate(fill)).as_signed() if a.shape().signed else Cat(a, _AConst(0, fill)))
    hi = a.shift_right(d)
    hi = hi - b if sub else hi + b
    v = Cat(a[:d], hi)
    return v.as_signed() if hi.shape().signed else v


class _ShiftAddPlan:
    """The adder tree of x * c from c's canonical signed digits, as terms (shift, sign, value) summed
    pairwise by rising shift, one adder per pair: a + b 2^d keeps the lower term's sign s_a (b's sign
    s_b != s_a: a - b 2^d), except the last adder, which makes a positive result from a negative lower term
    and a positive upper one (b 2^d - a). A result still negative at the end is negated (one more adder).
    With `emit` False only the adders and adder levels are counted (the same decisions, no hardware)."""

    def __init__(self, c: int):
        self.digits = csd_digits(c)

    @staticmethod
    def _level(terms, last, emit):
        out = []
        for i in range(0, len(terms) - 1, 2):
            (ka, sa, va), (kb, sb, vb) = terms[i], terms[i + 1]
            d = kb - ka
            if last and len(terms) == 2 and sa < 0 < sb:
                out.append((ka, 1, emit and (vb.shift_left(d) - va)))
            else:
                out.append((ka, sa, emit and _shift_add(va, vb, d, sub=sa != sb)))
        if len(terms) % 2:
            out.append(terms[-1])
        return out

    def reduce(self, terms, last, emit):
        """Sum the terms into one (levels of pairwise adders); returns (term, levels)."""
        levels = 0
        while len(terms) > 1:
            terms = self._level(terms, last, emit)
            levels += 1
        return terms[0], levels

    def groups(self, cycles: int) -> list[int]:
        """Group sizes summed in the first of two cycles (partial sums registered; one group: its sum holds
        the last adder), or [n] for one cycle."""
        n = len(self.digits)
        if cycles == 1 or n <= 1:
            return [n]
        g = 2 if n <= 4 else 4
        return [min(g, n - i) for i in range(0, n, g)]

    def cost(self, cycles: int) -> tuple[int, list[int]]:
        """(adders, adder levels per cycle) of the tree built over `cycles` cycles."""
        terms = [(k, d, None) for k, d in self.digits]
        if not terms:
            return 0, [0] * cycles
        if cycles == 1:
            (_, s, _), lv = self.reduce(terms, True, False)
            neg = int(s < 0)
            return len(terms) - 1 + neg, [lv + neg]
        parts, lv1, i = [], 0, 0
        gs = self.groups(2)
        for g in gs:
            t, lv = self.reduce(terms[i:i + g], len(gs) == 1, False)
            parts.append(t)
            lv1, i = max(lv1, lv), i + g
        (_, s, _), lv2 = self.reduce(parts, True, False)
        neg = int(s < 0)
        return len(terms) - 1 + neg, [lv1, lv2 + neg]


def shift_add_choice(x_shape, c) -> tuple[int, int] | None:
    """(latency, adders) of the shift-and-add product of a value of Amaranth shape `x_shape` by the constant
    c (an int or Const), or None when the multiplier is kept: when it would take more than
    CSD_ADDERS_PER_MULTIPLIER adders per multiplier it replaces (`multipliers`, counted as at least one), or
    more than ADDER_LEVELS_PER_CYCLE adder levels a cycle over 2 cycles. The latency is the cycles the tree
    needs (1 or 2), and never less than the multiplier's (`product_latency`)."""
    c = c if isinstance(c, _AConst) else Value.cast(int(c))
    odd = _odd_part(c)
    budget = CSD_ADDERS_PER_MULTIPLIER * max(1, multipliers(x_shape, odd.shape()))
    plan = _ShiftAddPlan(c.value)
    floor = product_latency(x_shape, odd.shape())
    for cycles in (floor, 2) if floor == 1 else (2,):
        adders, levels = plan.cost(cycles)
        if adders <= budget and max(levels) <= ADDER_LEVELS_PER_CYCLE:
            return cycles, adders
    return None


def constant_product(m: Module, x, c, name: str) -> tuple[Value, int] | None:
    """The exact product x * c of a value x and a constant c (an Amaranth Const, or an int) by shifts and
    adds, from a register: (value, latency); None when the multiplier is kept (`shift_add_choice`), for
    which the caller builds one (`pipelined_product`).

    c's canonical signed digits (`csd_digits`: n non-zero ones) give x c = sum of +/- x 2^k, n - 1 adders
    in a tree of pairwise sums (`_ShiftAddPlan`; one more to negate a result whose terms all stay negative),
    each only as wide as x and the sum's growth (the low bits of x 2^k need no adder). At most
    ADDER_LEVELS_PER_CYCLE = 2 adder levels per cycle, as much logic as an 18x18 multiplier's own cycle: up
    to 4 digits in one cycle (the tree, then the product register), up to 16 in two (sums of groups of 2 or 4
    digits registered, then their sum into the product register). The latency is that, and never less than
    the multiplier's for the same operands (`product_latency`; the tree is then spread over its 2 cycles):
    the schedule is the multiplier's wherever that fits, and one cycle longer for 5 or more digits (or 4
    with a final negation) on operands that fit one multiplier. The result has the shape of x * c, like
    `pipelined_product`'s; registers are reset-less.

    Threshold: at most CSD_ADDERS_PER_MULTIPLIER = 8 adders per multiplier saved. An ECP5-85k has 156
    MULT18X18D and 83,640 LUT4s, 536 LUTs per multiplier, and the element lanes run out of multipliers
    first (a narrow 2D lane takes about 3,500 LUTs). An adder of an 18-bit operand is about 20 bits wide (10
    CCU2C carry cells, 20 LUTs' worth): 8 of them cost about 160 LUTs, under a third of a multiplier's share
    of the chip. 8 adders take every constant of an 18-bit word (at most 9 signed digits: k1, c1, penalty
    constants, the damper's slopes) but a 9-digit one whose result needs a negation; the damper table's
    25-bit scale replaces 2 multipliers (16 adders, up to the 2-cycle limit of 16 digits).
    """
    x = Value.cast(x)
    c = c if isinstance(c, _AConst) else Value.cast(int(c))
    choice = shift_add_choice(x.shape(), c)
    if choice is None:
        return None
    latency, _ = choice
    shape = (x * c).shape()
    plan = _ShiftAddPlan(c.value)

    def reg(value, shp, nm):
        r = Signal(shp, name=nm, reset_less=True)
        m.d.sync += r.eq(value)
        return r

    def finish(term):
        k, s, v = term
        v = v.shift_left(k)
        return -v if s < 0 else v

    terms = [(k, d, x) for k, d in plan.digits]
    if not terms:                                                    # c = 0
        p = reg(_AConst(0, shape), shape, name)
        return (p if latency == 1 else reg(p, shape, f"{name}_d")), latency
    if latency == 1:
        return reg(finish(plan.reduce(terms, True, True)[0]), shape, name), 1
    parts, i = [], 0                                                 # 2 cycles: partial sums, then their sum
    gs = plan.groups(2)
    for j, g in enumerate(gs):
        k, s, v = plan.reduce(terms[i:i + g], len(gs) == 1, True)[0]
        parts.append((k, s, reg(v, v.shape(), f"{name}_ps{j}")))
        i += g
    return reg(finish(plan.reduce(parts, True, True)[0]), shape, name), 2
