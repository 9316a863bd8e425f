"""Fixed-point values for Amaranth (hw/rtl_fixed.py) equal the bit-true arithmetic (hw/fixed.py)."""
from __future__ import annotations

import re

import numpy as np
import pytest
from amaranth.back import rtlil
from amaranth.hdl import Module, Signal, Value, signed, unsigned
from amaranth.lib import wiring
from amaranth.lib.wiring import In, Out
from amaranth.sim import Simulator

from hw.fixed import SQ, UQ, Saturations, add, mul
from hw.rtl_fixed import (CSD_ADDERS_PER_MULTIPLIER, DSP_BITS, DSP_REGS, Const, FixedValue, as_shape, constant_product,
                          csd_digits, multipliers, pipelined_product, product_latency, registered_product,
                          shift_add_choice)

CASES = 400


def _run_comb(inputs, outputs, vectors):
    """Drive combinational logic with each input vector; return the outputs' values."""
    m = Module()
    m.d.comb += [o.eq(e) for o, e in outputs]
    sim = Simulator(m)
    got = []

    async def tb(ctx):
        for vec in vectors:
            for sig, v in zip(inputs, vec):
                ctx.set(sig, int(v))
            got.append([ctx.get(o) for o, _ in outputs])
    sim.add_testbench(tb)
    sim.run()
    return np.array(got, dtype=object)


@pytest.mark.parametrize("fa,fb,dst", [(SQ(4, 12), SQ(3, 13), SQ(5, 9)), (SQ(8, 24), SQ(2, 30), SQ(4, 28)),
                                       (UQ(6, 10), SQ(4, 12), SQ(3, 5))])
def test_product_rounds_and_saturates_as_the_bit_true_model(fa, fb, dst):
    rng = np.random.default_rng(1)
    a = rng.integers(fa.min_raw, fa.max_raw + 1, CASES)
    b = rng.integers(fb.min_raw, fb.max_raw + 1, CASES)
    a[:4] = [fa.min_raw, fa.max_raw, 0, 1]
    b[:4] = [fb.min_raw, fb.max_raw, -1 if fb.signed else 1, 1]
    sat = Saturations()
    expected = [int(mul(np.array([x]), fa, np.array([y]), fb, dst, sat, "p")[0]) for x, y in zip(a, b)]
    flags = []
    for x, y in zip(a, b):
        s = Saturations()
        mul(np.array([x]), fa, np.array([y]), fb, dst, s, "p")
        flags.append(s.total)
    sa, sb = Signal(as_shape(fa)), Signal(as_shape(fb))
    val, flag = (FixedValue.of(fa, sa) * FixedValue.of(fb, sb)).round(dst)
    out, fl = Signal(as_shape(dst)), Signal()
    got = _run_comb([sa, sb], [(out, val.raw), (fl, flag)], zip(a, b))
    assert [int(v) for v in got[:, 0]] == expected
    assert [int(v) for v in got[:, 1]] == flags
    assert sum(flags) > 0 and sum(flags) < CASES           # both kinds of case were exercised


@pytest.mark.parametrize("subtract", [False, True])
def test_sum_aligns_rounds_and_saturates_as_the_bit_true_model(subtract):
    fa, fb, dst = SQ(4, 20), SQ(9, 7), SQ(6, 12)
    rng = np.random.default_rng(2)
    a = rng.integers(fa.min_raw, fa.max_raw + 1, CASES)
    b = rng.integers(fb.min_raw, fb.max_raw + 1, CASES)
    expected, flags = [], []
    for x, y in zip(a, b):
        s = Saturations()
        expected.append(int(add(np.array([x]), fa, np.array([y]), fb, dst, s, "s", subtract=subtract)[0]))
        flags.append(s.total)
    sa, sb = Signal(as_shape(fa)), Signal(as_shape(fb))
    A, B = FixedValue.of(fa, sa), FixedValue.of(fb, sb)
    val, flag = ((A - B) if subtract else (A + B)).round(dst)
    out, fl = Signal(as_shape(dst)), Signal()
    got = _run_comb([sa, sb], [(out, val.raw), (fl, flag)], zip(a, b))
    assert [int(v) for v in got[:, 0]] == expected
    assert [int(v) for v in got[:, 1]] == flags
    assert 0 < sum(flags) < CASES


def test_ties_round_up_and_constants_round_to_nearest():
    fmt = SQ(4, 2)
    s = Signal(as_shape(SQ(4, 4)))
    val, _ = FixedValue.of(SQ(4, 4), s).round(fmt)
    out = Signal(as_shape(fmt))
    ties = [-6, -2, 2, 6]                           # -0.375, -0.125, 0.125, 0.375: exactly half an output LSB
    got = _run_comb([s], [(out, val.raw)], [[t] for t in ties])
    assert [int(v) for v in got[:, 0]] == [int(np.floor(t / 4 + 0.5)) for t in ties] == [-1, 0, 1, 2]
    c, n_sat = Const(1.3, SQ(2, 4))
    assert c.raw.value == 21 and n_sat == 0          # 1.3 * 16 = 20.8 -> 21
    c, n_sat = Const(9.0, SQ(2, 4))
    assert n_sat == 1 and c.raw.value == SQ(2, 4).max_raw


def test_reshape_refuses_to_drop_bits():
    v = FixedValue.of(SQ(2, 8), Signal(10))
    assert v.reshape(12).f == 12
    with pytest.raises(ValueError, match="drop bits"):
        v.reshape(4)
    with pytest.raises(TypeError, match="fixed-point Shape"):
        FixedValue.of("SQ(2, 8)", Signal(10))


# (a shape, b shape, latency, multipliers): one 18x18 multiplier (signed, unsigned, mixed with a 17-bit
# unsigned operand), or DSP-sized partial products, those with a limb of at most 4 bits formed in logic
# (an 18-bit unsigned operand in a signed product is 19 bits: limbs of 17 and 2 bits; the 1/sqrt unit's
# 22 x 22 and 20 x 23 unsigned products, 18-bit limbs and short top limbs; its 36 x 36 and 34 x 37 of the
# wide preset; 36-bit signed operands: 17-bit limbs and a signed 2-bit one)
PRODUCTS = [(signed(18), signed(18), 1, 1), (unsigned(18), unsigned(18), 1, 1),
            (unsigned(17), signed(18), 1, 1), (unsigned(18), signed(18), 2, 1),
            (unsigned(22), unsigned(22), 2, 1), (unsigned(20), unsigned(23), 2, 2),
            (unsigned(36), unsigned(36), 2, 4), (unsigned(34), unsigned(37), 2, 4),
            (signed(25), signed(9), 2, 2), (signed(36), signed(36), 2, 4), (unsigned(40), signed(18), 2, 3),
            # narrow operands: rows in logic, no multiplier
            (signed(18), signed(4), 1, 0), (unsigned(3), unsigned(18), 1, 0), (signed(1), signed(18), 1, 0),
            (signed(22), signed(4), 2, 0),
            # constant operands (int): 2^8 * 78125 (the damper's scale in press-2d) fits as 78125, 17 bits;
            # an odd 25-bit constant does not; -3 * 2^20 is a signed 3-bit -3, so rows
            (signed(18), 20000000, 1, 1), (signed(18), 20000001, 2, 2), (signed(18), -3 << 20, 1, 0)]


@pytest.mark.parametrize("sa, sb, latency, mults", PRODUCTS, ids=[f"{a}x{b}" for a, b, _, _ in PRODUCTS])
def test_multipliers_counts_what_pipelined_product_builds(sa, sb, latency, mults):
    """multipliers() (the shift-add products' budget) equals the $mul cells of the products above; a
    constant counts by its odd part."""
    from hw.rtl_fixed import _odd_part
    b = _odd_part(Value.cast(sb)).shape() if isinstance(sb, int) else sb
    assert multipliers(sa, b) == mults


@pytest.mark.parametrize("sa, sb, latency, mults", PRODUCTS, ids=[f"{a}x{b}" for a, b, _, _ in PRODUCTS])
def test_pipelined_product_is_exact_with_its_latency(sa, sb, latency, mults):
    """Every product equals a * b, `latency` cycles after its operands; every multiplier of the RTLIL
    has operands of at most 18 bits, and there are as many as the limbs make."""
    a = Signal(sa)
    const = isinstance(sb, int)
    b = sb if const else Signal(sb)
    m = Module()
    p, lat = pipelined_product(m, a, b, "p")
    assert lat == latency
    if not const:
        assert lat == product_latency(sa, sb)
    assert p.shape() == (a * b).shape()
    pv = Signal(p.shape())
    m.d.comb += pv.eq(p)
    p = pv
    text = rtlil.convert(m, ports=[a, p] if const else [a, b, p])
    cells = text.split("cell $mul")[1:]
    assert len(cells) == mults
    for cell in cells:
        for w in re.findall(r"parameter \\[AB]_WIDTH (\d+)", cell.split("end", 1)[0]):
            assert int(w) <= DSP_BITS

    def lim(s):
        return (-(1 << (s.width - 1)), (1 << (s.width - 1)) - 1) if s.signed else (0, (1 << s.width) - 1)
    rng = np.random.default_rng(3)
    (alo, ahi) = lim(sa)
    av = [alo, ahi, alo, ahi, 0, 1] + [int(v) for v in rng.integers(alo, ahi, CASES, endpoint=True)]
    if const:
        bv = [sb] * len(av)
    else:
        blo, bhi = lim(sb)
        bv = [blo, bhi, bhi, blo, 1, 0] + [int(v) for v in rng.integers(blo, bhi, CASES, endpoint=True)]
    got = []

    async def tb(ctx):
        for c in range(len(av) + latency):
            if c < len(av):
                ctx.set(a, av[c])
                if not const:
                    ctx.set(b, bv[c])
            await ctx.tick()
            if c + 1 >= latency:
                got.append(ctx.get(p))
    sim = Simulator(m)
    sim.add_clock(1e-8)
    sim.add_testbench(tb)
    sim.run()
    assert got[:len(av)] == [x * y for x, y in zip(av, bv)]


@pytest.mark.parametrize("raw_shape", [signed(3), signed(4), signed(7), unsigned(3), unsigned(4), unsigned(7)])
@pytest.mark.parametrize("dst", [SQ(2, 2), UQ(2, 2)], ids=str)
def test_saturate_clamps_every_raw_value(raw_shape, dst):
    """saturate (range tests on raw's high bits) equals a clamp to [min_raw, max_raw], exhaustively, for
    raw values narrower than, as wide as and wider than the format, signed and unsigned."""
    s = Signal(raw_shape)
    val, flag = FixedValue(s, dst.f).saturate(dst)
    out, fl = Signal(as_shape(dst)), Signal()
    lo, hi = ((-(1 << (raw_shape.width - 1)), 1 << (raw_shape.width - 1)) if raw_shape.signed
              else (0, 1 << raw_shape.width))
    xs = list(range(lo, hi))
    got = _run_comb([s], [(out, val.raw), (fl, flag)], [[x] for x in xs])
    assert [int(v) for v in got[:, 0]] == [min(max(x, dst.min_raw), dst.max_raw) for x in xs]
    assert [int(v) for v in got[:, 1]] == [int(not dst.min_raw <= x <= dst.max_raw) for x in xs]


# ------------------------------------------------------------------------------------- constant products

# constants: zero, +/- 1, powers of two, negative ones, sparse and dense signed-digit patterns (9 digits,
# the most an 18-bit word has; 7 digits ending in a negation), the narrow square's element constants
# (k1 = 85899, c1 = 83886, 130941, 25 * 4096, 104753), press-2d's c1 (104858, 9 digits), 78125, the damper
# tables' 25-bit scales (2 multipliers: up to 16 adders); and dense ones that keep their multiplier (a
# 9-digit 18-bit constant whose sum needs a negation: 9 adders; 17 digits, or 13 and a negation: more than
# 2 adder levels in a cycle)
SHIFT_ADD_CONSTANTS = [0, 1, -1, 2, -2, 1 << 17, -(1 << 17), 3, -3, 5, -5, 7, -7, 25, -17, 0b1010101010101,
                       -0b1010101010101, 0b101010101010101, 87381, 85899, 83886, -83886, 130941, 25 * 4096,
                       104753, -104753, 104858, 78125, (1 << 17) - 1, -(1 << 17) + 1]
WIDE_CONSTANTS = [27780865, 32006401, 17779753, 0x2AAAAAA, -0x2AAAAA7, -27780865]
DENSE_CONSTANTS = [-87381, 0x2AAAAAAAA, -0x2AAAAAA]


def test_csd_digits_are_canonical_and_exact():
    """csd_digits: sum d 2^k = c, digits +/- 1, no two adjacent, no more than the binary digits of |c|; over
    every c in [-4096, 4096] and the constants above."""
    for c in [*range(-4096, 4097), *SHIFT_ADD_CONSTANTS, *DENSE_CONSTANTS]:
        d = csd_digits(c)
        assert sum(s << k for k, s in d) == c
        assert all(s in (1, -1) for _, s in d)
        ks = [k for k, _ in d]
        assert ks == sorted(ks) and all(b - a >= 2 for a, b in zip(ks, ks[1:]))
        assert len(d) <= bin(abs(c)).count("1")
    assert [len(csd_digits(c)) for c in (7, 85899, 104753, 0b1010101010101, 87381)] == [2, 7, 8, 7, 9]


def _check_constant_products(x_shape, constants, values):
    """Every constant_product of x by the constants equals x * c exactly, `latency` cycles after x, from
    adders only (no $mul cell); the latency is the stated one (`shift_add_choice`), no less than the
    multiplier's."""
    x = Signal(x_shape)
    m = Module()
    outs = []
    for j, c in enumerate(constants):
        p, lat = constant_product(m, x, c, f"p{j}")
        assert lat == shift_add_choice(x_shape, c)[0] in (1, 2)
        assert lat >= product_latency(x_shape, Value.cast(c).shape()) or c % 2 == 0
        assert p.shape() == (x * c).shape()
        pv = Signal(p.shape(), name=f"o{j}")
        m.d.comb += pv.eq(p)
        outs.append((pv, lat, c))
    assert "cell $mul" not in rtlil.convert(m, ports=[x, *(o for o, _, _ in outs)])
    got = {j: [] for j in range(len(outs))}

    async def tb(ctx):
        for cyc in range(len(values) + 2):
            ctx.set(x, int(values[cyc]) if cyc < len(values) else 0)
            await ctx.tick()
            for j, (o, lat, _) in enumerate(outs):
                if cyc + 1 >= lat and cyc + 1 - lat < len(values):
                    got[j].append(ctx.get(o))
    sim = Simulator(m)
    sim.add_clock(1e-8)
    sim.add_testbench(tb)
    sim.run()
    for j, (_, _, c) in enumerate(outs):
        assert got[j] == [int(v) * c for v in values], f"x * {c} differs"


@pytest.mark.hdl
@pytest.mark.parametrize("x_shape", [signed(18), unsigned(18), signed(10), unsigned(4), signed(1), signed(36)],
                         ids=str)
def test_constant_product_is_exact(x_shape):
    """x * c by shifts and adds against the exact integer product: every x of a 10-, 4- or 1-bit operand,
    the extremes and random values of 18- and 36-bit ones, for every constant above."""
    lo, hi = ((-(1 << (x_shape.width - 1)), (1 << (x_shape.width - 1)) - 1) if x_shape.signed
              else (0, (1 << x_shape.width) - 1))
    if x_shape.width <= 10:
        values = list(range(lo, hi + 1))
    else:
        rng = np.random.default_rng(x_shape.width)
        values = [lo, hi, lo + 1, hi - 1, 0, 1, -1 if x_shape.signed else 2]
        values += [int(v) for v in rng.integers(lo, hi, 1500, endpoint=True)]
    consts = SHIFT_ADD_CONSTANTS + (WIDE_CONSTANTS if x_shape.width > 4 else [])
    assert all(shift_add_choice(x_shape, c) is not None for c in consts)
    _check_constant_products(x_shape, consts, values)


def test_constant_product_threshold():
    """At most CSD_ADDERS_PER_MULTIPLIER = 8 adders per multiplier saved (every 18-bit constant, at most 9
    signed digits, but one needing a negation), at most 2 adder levels a cycle over 2 cycles; denser
    constants are left to the multiplier (None). Up to 4 digits take one cycle, like the 18x18 multiplier
    they replace; a 25-bit constant replaces 2 multipliers and keeps their 2 cycles."""
    assert CSD_ADDERS_PER_MULTIPLIER == 8
    m = Module()
    x = Signal(signed(18))
    for c in DENSE_CONSTANTS:
        assert shift_add_choice(x.shape(), c) is None and constant_product(m, x, c, "p") is None
    assert ([shift_add_choice(x.shape(), c) for c in (0, 1, -1, 25, 130941, 85899, 104753, 104858, 17779753)]
            == [(1, 0), (1, 0), (1, 1), (1, 2), (1, 3), (2, 6), (2, 7), (2, 8), (2, 8)])
    # a wide operand keeps the multiplier's 2 cycles even for a 1-digit constant
    _, lat = constant_product(m, Signal(signed(36)), 4, "q")
    assert lat == 2
    assert "cell $mul" not in rtlil.convert(m, ports=[x])


@pytest.mark.hdl
@pytest.mark.parametrize("value", [1.5, -0.3125, 0.6, -1.2345678, 0.0, 1.3333333, -1.3333333], ids=str)
def test_pipeline_product_by_a_constant_equals_the_bit_true_model(value):
    """PipeArith.mul by a constant (hw/pipeline.py): shift-add or multiplier as the constant's digits decide,
    the result at the stage the form built states, rounded and saturated exactly as hw/fixed.py mul, with
    its saturation flags. Raw constants: 98304 and -20480 (2 digits: one cycle), 39322 and -80909 (8 and 6:
    two cycles), 0, 87381 (9 digits: 8 adders, two cycles) and -87381 (9 digits and a negation: a
    multiplier)."""
    from hw.pipeline import PipeArith
    from hw.rtl_fixed import DSP_REGS
    fx, fk, fq = SQ(3, 15), SQ(2, 16), SQ(2, 10)
    k_raw = int(fk.from_float(value))
    choice = shift_add_choice(signed(18), k_raw)
    sparse = choice is not None
    m = Module()
    valid, x = Signal(), Signal(signed(18))
    ar = PipeArith(m, {"x": fx, "k": fk, "q": fq}, {}, valid, "lane")
    with ar:
        r = ar.mul(ar.const("k", value), ar.input(x, "x", 0), "q")
        events = dict(ar.saturation_events())
    text = rtlil.convert(m, ports=[valid, x, r.sig])
    assert ("cell $mul" in text) == (not sparse)
    assert r.stage == 1 + (choice[0] if sparse else 1 + DSP_REGS)    # a multiplier: its registers beside it
    rng = np.random.default_rng(abs(k_raw))
    xs = [fx.min_raw, fx.max_raw, 0, 1, -1] + [int(v) for v in rng.integers(fx.min_raw, fx.max_raw, 600, endpoint=True)]
    expected, flags = [], []
    for v in xs:
        s = Saturations()
        expected.append(int(mul(np.array([v]), fx, np.array([k_raw]), fk, fq, s, "q")[0]))
        flags.append(s.total)
    got, sats = [], []
    L = r.stage

    async def tb(ctx):
        for c in range(len(xs) + L + 3):
            ctx.set(valid, int(c < len(xs)))
            ctx.set(x, xs[c] if c < len(xs) else 0)
            await ctx.tick()
            if 0 <= c - L + 1 < len(xs):
                got.append(ctx.get(r.sig))
            if "q" in events and 0 <= c - L - 1 < len(xs):
                sats.append(ctx.get(events["q"]))
    sim = Simulator(m)
    sim.add_clock(1e-8)
    sim.add_testbench(tb)
    sim.run()
    assert got == expected
    if "q" in events:
        assert sats == flags
    else:
        assert not any(flags)


@pytest.mark.hdl
@pytest.mark.parametrize("form", ["delayed", "other_signedness"])
def test_pipeline_product_by_a_constant_operand_reads_it_as_its_format(form):
    """PipeArith.mul takes the constant from the operand's own Const, read as the operand's format reads it:
    a Const fed in at an earlier stage than the other operand (fx hands a delay register of it) and a Const
    of unsigned bits in a signed format (fx hands a sign reinterpretation) both give the bit-true product,
    by shifts and adds (raw k = -20480: 2 signed digits, one cycle)."""
    from amaranth.hdl import Const as AConst

    from hw.pipeline import PipeArith
    fx, fk, fq = SQ(3, 15), SQ(2, 16), SQ(2, 10)
    k_raw = -20480
    m = Module()
    valid, x = Signal(), Signal(signed(18))
    ar = PipeArith(m, {"x": fx, "k": fk, "q": fq}, {}, valid, "lane")
    with ar:
        if form == "delayed":
            k, xin, x_stage = ar.input(AConst(k_raw, signed(18)), "k", 0), ar.input(x, "x", 1), 1
        else:
            k, xin, x_stage = ar.input(AConst(k_raw & 0x3FFFF, unsigned(18)), "k", None), ar.input(x, "x", 0), 0
        r = ar.mul(xin, k, "q")
    assert "cell $mul" not in rtlil.convert(m, ports=[valid, x, r.sig])
    assert r.stage == x_stage + 2
    rng = np.random.default_rng(5)
    xs = [fx.min_raw, fx.max_raw, 0, 1, -1] + [int(v) for v in rng.integers(fx.min_raw, fx.max_raw, 300, endpoint=True)]
    expected = [int(mul(np.array([v]), fx, np.array([k_raw]), fk, fq, Saturations(), "q")[0]) for v in xs]
    got, L = [], r.stage - x_stage

    async def tb(ctx):
        for c in range(len(xs) + L + 3):
            ctx.set(valid, 1)
            ctx.set(x, xs[c] if c < len(xs) else 0)
            await ctx.tick()
            if 0 <= c - L + 1 < len(xs):
                got.append(ctx.get(r.sig))
    sim = Simulator(m)
    sim.add_clock(1e-8)
    sim.add_testbench(tb)
    sim.run()
    assert got == expected


class _Products(wiring.Component):
    """Every case of PRODUCTS through `registered_product` of one variant: inputs a<k>,
    b<k> (b<k> absent for a constant), outputs p<k>_0, p<k>_1 (the product's bits, 48 a port: the vectors
    are int64)."""

    def __init__(self, dsp: str):
        self.dsp, self.latencies = dsp, []
        members = {}
        for k, (sa, sb, _, _) in enumerate(PRODUCTS):
            members[f"a{k}"] = In(sa)
            if not isinstance(sb, int):
                members[f"b{k}"] = In(sb)
            width = (Signal(sa) * (sb if isinstance(sb, int) else Signal(sb))).shape().width
            members[f"p{k}_0"], members[f"p{k}_1"] = Out(min(width, 48)), Out(max(width - 48, 1))
        super().__init__(members)

    def elaborate(self, platform):
        m = Module()
        for k, (_, sb, _, _) in enumerate(PRODUCTS):
            b = sb if isinstance(sb, int) else getattr(self, f"b{k}")
            p, lat = registered_product(m, getattr(self, f"a{k}"), b, f"prod{k}", dsp=self.dsp)
            self.latencies.append(lat)
            m.d.comb += [getattr(self, f"p{k}_0").eq(p[:48]), getattr(self, f"p{k}_1").eq(p[48:])]
        return m


@pytest.mark.hdl
def test_products_on_instantiated_multipliers_equal_the_logic_form_cycle_for_cycle():
    """registered_product's "ecp5" variant (MULT18X18D instances holding its registers, hw/mult18x18d.py, on
    Icarus with the model hw/mult18x18d.v) gives a * b with the latency of the "sim" variant, for every
    shape of PRODUCTS, and instantiates as many multipliers as `multipliers` counts."""
    from amaranth.back import verilog
    from stream_helpers import run_verilog
    sim_form, dsp_form = _Products("sim"), _Products("ecp5")
    text = verilog.convert(dsp_form, name="top", emit_src=False)
    verilog.convert(sim_form, name="top", emit_src=False)
    assert dsp_form.latencies == sim_form.latencies == [lat + DSP_REGS for _, _, lat, _ in PRODUCTS]
    assert len(re.findall(r"^\s*MULT18X18D\b", text, re.M)) == sum(n for *_, n in PRODUCTS)
    assert "$mul" not in rtlil.convert(dsp_form) or sum(n for *_, n in PRODUCTS) == 0
    rng = np.random.default_rng(18)
    inputs, draws, widths = [], [], []
    for k, (sa, sb, _, _) in enumerate(PRODUCTS):
        for nm, s in [("a", sa)] + ([] if isinstance(sb, int) else [("b", sb)]):
            lo, hi = (-(1 << (s.width - 1)), (1 << (s.width - 1)) - 1) if s.signed else (0, (1 << s.width) - 1)
            v = [lo, hi, hi, lo, 0, min(1, hi), max(-1, lo)] + [int(x) for x in rng.integers(lo, hi, 200, endpoint=True)]
            inputs.append(f"{nm}{k}")
            draws.append(v[:200])
            widths.append(s.width)
    values = [[v[t] % (1 << w) for v, w in zip(draws, widths)] for t in range(200)]   # the ports' bits
    outputs = [f"p{k}_{h}" for k in range(len(PRODUCTS)) for h in (0, 1)]
    got = run_verilog(dsp_form, inputs, values, outputs, tag="mult18x18d")
    col = {nm: draws[i] for i, nm in enumerate(inputs)}
    for k, (sa, sb, _, _) in enumerate(PRODUCTS):
        lat = dsp_form.latencies[k]
        bv = [sb] * 200 if isinstance(sb, int) else col[f"b{k}"]
        width = len(getattr(dsp_form, f"p{k}_0")) + (len(getattr(dsp_form, f"p{k}_1")) if len(getattr(dsp_form, f"p{k}_0")) == 48 else 0)
        want = [(x * y) % (1 << width) for x, y in zip(col[f"a{k}"], bv)]
        bits = [int(lo) + (int(hi) << 48 if width > 48 else 0) for lo, hi in got[:, 2 * k:2 * k + 2]]
        # operands of cycle t reach the output after edge t + lat - 1 (row t + lat - 1)
        assert bits[lat - 1:] == want[:200 - lat + 1], f"product {k}: {sa} x {sb}"


@pytest.mark.parametrize("delay", [3, 4, 10, 16, 17, 20, 35])
def test_delay_lines_give_each_value_its_delay_later(delay):
    """PipeArith.delay (hw/pipeline.py) by registers (under LINE_MIN stages) or by delay lines packed side
    by side in one LUT RAM per group and span, chained past LINE_MAX: a flag, a signed 6-bit and an
    unsigned 13-bit value, fed random items, each comes out `delay` cycles later, bit for bit, beside
    delays of 5 stages made in between (another span in the same group)."""
    from hw.pipeline import PipeArith
    m = Module()
    flag, small, wide = Signal(), Signal(signed(6)), Signal(13)
    ar = PipeArith(m, {}, {}, Signal(), "lane")
    outs, near = [], []
    for v in (flag, small, wide):
        outs.append(ar.delay(v, 0, delay))
        near.append(ar.delay(v, 0, 5))
    rng = np.random.default_rng(delay)
    n = 80
    items = [(int(rng.integers(0, 2)), int(rng.integers(-32, 32)), int(rng.integers(0, 1 << 13))) for _ in range(n)]
    got, got_near = [], []

    async def tb(ctx):
        for c in range(n + max(delay, 5) + 1):
            for sig, val in zip((flag, small, wide), items[c] if c < n else (0, 0, 0)):
                ctx.set(sig, val)
            if delay <= c < n + delay:
                got.append(tuple(ctx.get(o) for o in outs))
            if 5 <= c < n + 5:
                got_near.append(tuple(ctx.get(o) for o in near))
            await ctx.tick()
    sim = Simulator(m)
    sim.add_clock(1e-8)
    sim.add_testbench(tb)
    sim.run()
    assert got == items
    assert got_near == items


@pytest.mark.hdl
@pytest.mark.parametrize("clamp_stage", [False, True], ids=["one_stage", "clamp_stage"])
def test_pipeline_operations_equal_the_bit_true_model_with_or_without_a_clamp_stage(clamp_stage):
    """PipeArith (hw/pipeline.py) add, sub, sum, neg (into a signed and an unsigned format), convert, mul
    of two variables and selects by comparisons, at the formats' extremes and at random: results and
    saturation flags equal hw/arith.py FixedArith item for item. With `clamp_stage` an operation that can
    saturate takes two stages (its exact value registered, then clamped), except a signed negation, which
    knows its only overflow (x = min) from x; one that cannot saturate (a convert into a wider format)
    takes one; a comparison takes one (registered) instead of none."""
    from hw.arith import FixedArith, V
    from hw.pipeline import PipeArith
    fmt = {"x": SQ(3, 12), "y": SQ(2, 13), "s": SQ(2, 10), "n": UQ(3, 12), "w": SQ(6, 14), "p": SQ(1, 14)}
    ops = {                                   # name -> (kernel on either arithmetic, its stages without / with)
        "add": (lambda ar, x, y, n: ar.add(x, y, "s"), 1, 2),
        "sub": (lambda ar, x, y, n: ar.sub(x, y, "s"), 1, 2),
        "sum": (lambda ar, x, y, n: ar.sum([x, y, x], "s"), 1, 2),
        "neg": (lambda ar, x, y, n: ar.neg(x), 1, 1),
        "neg_unsigned": (lambda ar, x, y, n: ar.neg(n), 1, 2),
        "narrow": (lambda ar, x, y, n: ar.convert(x, "s"), 1, 2),
        "widen": (lambda ar, x, y, n: ar.convert(x, "w"), 1, 1),
        "mul": (lambda ar, x, y, n: ar.mul(x, y, "p"), 1 + 1 + DSP_REGS, 2 + 1 + DSP_REGS),
        "min": (lambda ar, x, y, n: ar.select(ar.lt(x, y), x, y), 2, 3),     # y converted (1 or 2 stages)
        "le_or": (lambda ar, x, y, n: ar.select(ar.le(x, y) | ar.lt(ar.neg(x), y), x, ar.neg(x)), 2, 3),
    }
    rng = np.random.default_rng(7)
    ext = lambda f: [f.min_raw, f.max_raw, f.min_raw + 1, 0, 1, f.max_raw - 1]
    cols = [[int(a), int(b), int(c)] for a in ext(fmt["x"]) for b in ext(fmt["y"]) for c in ext(fmt["n"])[:3]]
    cols += [[int(rng.integers(f.min_raw, f.max_raw, endpoint=True)) for f in (fmt["x"], fmt["y"], fmt["n"])]
             for _ in range(300)]
    xs, ys, ns = (np.array(c, np.int64) for c in zip(*cols))
    m = Module()
    valid = Signal()
    x, y, n = Signal(signed(15)), Signal(signed(15)), Signal(unsigned(15))
    ar = PipeArith(m, fmt, {}, valid, "lane", clamp_stage=clamp_stage)
    with ar:
        ins = ar.input(x, "x", 0), ar.input(y, "y", 0), ar.input(n, "n", 0)
        outs, sources = {}, {}
        for name, (fn, _, _) in ops.items():
            before = len(ar.sat_sources)
            outs[name] = fn(ar, *ins)
            sources[name] = ar.sat_sources[before:]         # its saturation flag (none: it cannot saturate)
    for name, (_, one, two) in ops.items():
        assert outs[name].stage == (two if clamp_stage else one), (name, outs[name].stage)
    expected, flags = {}, {}
    for name, (fn, _, _) in ops.items():
        fa = FixedArith(fmt)
        out = fn(fa, V(xs, "x"), V(ys, "y"), V(ns, "n"))
        expected[name] = [int(v) for v in out.x]
        flags[name] = fa.sat.total
    assert flags["add"] and flags["neg"] and flags["neg_unsigned"] and flags["mul"] and not flags["widen"]
    got, counted = {name: [] for name in ops}, {name: 0 for name in ops}
    L = max(v.stage for v in outs.values())

    async def tb(ctx):
        for c in range(len(cols) + L + 1):
            if c < len(cols):
                for sig, v in zip((x, y, n), cols[c]):
                    ctx.set(sig, v)
            ctx.set(valid, int(c < len(cols)))
            await ctx.tick()
            for name, v in outs.items():
                k = c - v.stage + 1
                if 0 <= k < len(cols):
                    got[name].append(ctx.get(v.sig))
                for src in sources[name]:
                    if 0 <= c - src.stage + 1 < len(cols):
                        counted[name] += ctx.get(src.flag)
    sim = Simulator(m)
    sim.add_clock(1e-8)
    sim.add_testbench(tb)
    sim.run()
    for name in ops:
        assert got[name] == expected[name], name
        assert counted[name] == flags[name], (name, counted[name], flags[name])
