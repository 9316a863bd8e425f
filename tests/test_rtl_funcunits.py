"""Gateware function units (hw/rtl_funcunits.py) against their NumPy models (hw/funcunits.py), bit for bit.

Every case runs the unit in Amaranth's simulator, one input per clock (some cases with random idle
cycles), and compares each output with the model called on the same raw inputs: the values exactly,
the model's saturation total with the sum of the hardware's per-output saturation fields, and the
per-element saturation counts (the model's count is additive over elements; it is split down to single
elements by calling the model on sub-arrays). Every output must appear exactly `latency` cycles after its
input, and only then. The expected results always come from the model, never from the gateware.

Cases: exhaustive over every input of small formats chosen to reach every path (x <= 0, mantissa
rounding, left and right output shifts, saturating outputs, odd and negative fraction bits; inverse
tables (the damper's Phi with its companion w', and Psi): every non-negative magnitude, position shifts
> 0, = 0 and < 0, the position limited to the end point, clipped table entries in one or both tables,
y1 = 0, unreachable y2 or interpolated piece), and the configurations press-2d-rheological uses under
the narrow, medium and wide presets with a few thousand dense and random inputs each (random idle
cycles between them). The inverse table's `below` / `above` fields are checked against the model's
thresholds (hw/arith.py FixedArith.inverse: y <= Y1, y >= Y2), and PipeArith.inverse (hw/pipeline.py)
is checked in a small lane. Simulator throughput is roughly 3-10k cycles/s.
"""
from __future__ import annotations

import gc

import numpy as np
import pytest
from amaranth.back import rtlil
from amaranth.hdl import Module, Signal, signed, unsigned
from amaranth.sim import Simulator

from golden.elements import DamperLaw
from hw.datapath import phi_curve, psi_curve
from hw.fixed import SQ, UQ, Saturations, shift_round
from hw.funcunits import InverseTable, Rsqrt, RsqrtTable
from hw.rtl_funcunits import InverseTableUnit, RsqrtTableUnit, RsqrtUnit

pytestmark = pytest.mark.hdl      # `make test-fast` leaves these out


# ================================================================================================ harness

def _simulate(dut, xs, fields, idle=0.0, seed=0):
    """Feed xs one per cycle (an idle cycle, valid = 0, with probability `idle` before each input) and
    return the output fields as int64 arrays, in input order; checks that each output appears exactly
    dut.latency cycles after its input and that o.valid is low otherwise."""
    xs = [int(v) for v in xs]
    rng = np.random.default_rng(seed)
    gaps = rng.random(len(xs)) < idle if idle else np.zeros(len(xs), bool)
    feed = []                                     # per simulated cycle: input index or None
    for j in range(len(xs)):
        if gaps[j]:
            feed.append(None)
        feed.append(j)
    feed += [None] * (dut.latency + 2)
    got, seen = [], []

    async def testbench(ctx):
        for c, j in enumerate(feed):
            if j is None:
                ctx.set(dut.i.valid, 0)
            else:
                ctx.set(dut.i.valid, 1)
                ctx.set(dut.i.payload, xs[j])
            await ctx.tick()
            # after the edge that ends cycle c: the output of the input presented in cycle c - latency + 1
            if ctx.get(dut.o.valid):
                p = ctx.get(dut.o.payload)
                got.append(tuple(int(getattr(p, f)) for f in fields))
                seen.append(c)

    sim = Simulator(dut)
    sim.add_clock(1e-8)
    sim.add_testbench(testbench)
    sim.run()
    expect_cycles = [c + dut.latency - 1 for c, j in enumerate(feed) if j is not None]
    assert seen == expect_cycles, "outputs do not appear exactly `latency` cycles after their inputs"
    arr = np.array(got, dtype=np.int64).reshape(len(got), len(fields))
    return {f: arr[:, k] for k, f in enumerate(fields)}


def _per_element_counts(count, x, max_per):
    """Per-element saturation counts of a model, from its totals over sub-arrays (count(xs) -> total).

    The total over an array is the sum over its elements (each element counts independently), so an
    array whose total is 0 (or max_per per element) is settled; otherwise it is halved."""
    out = np.zeros(len(x), np.int64)

    def rec(lo, hi, total):
        if total == 0:
            return
        if total == max_per * (hi - lo):
            out[lo:hi] = max_per
            return
        if hi - lo == 1:
            assert 0 < total <= max_per, f"one element counts {total} saturations (at most {max_per})"
            out[lo] = total
            return
        mid = (lo + hi) // 2
        t1, t2 = count(x[lo:mid]), count(x[mid:hi])
        assert t1 + t2 == total, "the model's saturation count is not additive over elements"
        rec(lo, mid, t1)
        rec(mid, hi, t2)

    rec(0, len(x), count(x))
    return out


def _inputs(shape, values):
    """Distinct raw values clipped into the format, as int64."""
    v = np.unique(np.asarray(values, dtype=np.int64))
    return v[(v >= shape.min_raw) & (v <= shape.max_raw)]


def _shuffle(x, seed):
    x = np.array(x, np.int64)
    np.random.default_rng(seed).shuffle(x)
    return x


# ================================================================================================ Rsqrt

def _rsqrt_count(model):
    def count(xs):
        sat = Saturations()
        model(xs, sat)
        return sat.total
    return count


def _check_rsqrt(model: Rsqrt, x, idle=0.0, seed=0, expect_sat=None):
    dut = RsqrtUnit(model)
    assert dut.latency == 7 + 15 * model.newton_steps     # 3 products of 4 cycles, 3 roundings a step
    sat = Saturations()
    ref = model(x, sat)
    hw = _simulate(dut, x, ("value", "saturated"), idle=idle, seed=seed)
    bad = np.nonzero(hw["value"] != ref)[0]
    assert bad.size == 0, (f"{bad.size} outputs differ, first x = {x[bad[:5]].tolist()}: "
                           f"hw {hw['value'][bad[:5]].tolist()} model {ref[bad[:5]].tolist()}")
    assert int(hw["saturated"].sum()) == sat.total
    per = _per_element_counts(_rsqrt_count(model), x, 1)
    bad = np.nonzero(hw["saturated"] != per)[0]
    assert bad.size == 0, f"saturation flags differ at x = {x[bad[:5]].tolist()}"
    if expect_sat is not None:                   # coverage: both saturated and unsaturated outputs
        assert (0 < sat.total < len(x)) == expect_sat
    return hw


# exhaustive cases: (in_shape, out_shape, seed_bits, newton_steps, guard_bits); inputs = 2^in.width
RSQRT_EXHAUSTIVE = [
    # 16384 inputs each: negative inputs and 0, saturating small inputs, seed-only/1/2 Newton steps
    (SQ(6, 8), SQ(4, 10), 6, 0, 2),
    (SQ(6, 8), SQ(4, 10), 6, 1, 2),
    (SQ(6, 8), SQ(4, 10), 6, 2, 2),
    # 4096 inputs: unsigned; M = 10 < 13 = k_max (mantissa rounding and its clamp), left output shifts
    (UQ(4, 8), UQ(2, 8), 4, 1, 0),
    # 4096 inputs: odd input fraction bits, seed of 3 bits, 3 Newton steps, 1 guard bit
    (SQ(3, 9), SQ(6, 6), 3, 3, 1),
    # 256 inputs: negative input fraction bits (the raw LSB is 4)
    (SQ(10, -2), UQ(1, 9), 5, 1, 2),
    # 4 inputs each: 2-bit inputs (bit length 1 or 2; 1 for the signed one)
    (UQ(2, 0), UQ(1, 7), 3, 1, 2),
    (SQ(2, 0), SQ(2, 6), 3, 1, 2),
]


@pytest.mark.parametrize("ins, outs, sb, steps, guard", RSQRT_EXHAUSTIVE,
                         ids=[f"{a}-{b}-seed{c}-newton{d}-guard{e}" for a, b, c, d, e in RSQRT_EXHAUSTIVE])
def test_rsqrt_exhaustive(ins, outs, sb, steps, guard):
    model = Rsqrt(ins, outs, seed_bits=sb, newton_steps=steps, guard_bits=guard)
    x = np.arange(ins.min_raw, ins.max_raw + 1, dtype=np.int64)
    _check_rsqrt(model, x, expect_sat=True)


def test_rsqrt_exhaustive_case_reaches_every_path():
    """The UQ(4, 8) -> UQ(2, 8) case rounds the mantissa (k > M) and shifts left (Y + e - fo < 0)."""
    model = Rsqrt(UQ(4, 8), UQ(2, 8), seed_bits=4, newton_steps=1, guard_bits=0)
    assert model.k_max > model.M
    n = np.arange(1, 13)
    k = n + ((n - 8) & 1)
    assert (model.Y + ((k - 8) >> 1) - 8 < 0).any()


# ================================================================================================ RsqrtTable

def _check_rsqrt_table(model: RsqrtTable, x, idle=0.0, seed=0, expect_sat=None):
    """RsqrtTableUnit against its model at the inputs x: values, saturation flags (total and per element)."""
    dut = RsqrtTableUnit(model)
    assert dut.latency == 12
    sat = Saturations()
    ref = model(x, sat)
    hw = _simulate(dut, x, ("value", "saturated"), idle=idle, seed=seed)
    bad = np.nonzero(hw["value"] != ref)[0]
    assert bad.size == 0, (f"{bad.size} outputs differ, first x = {x[bad[:5]].tolist()}: "
                           f"hw {hw['value'][bad[:5]].tolist()} model {ref[bad[:5]].tolist()}")
    assert int(hw["saturated"].sum()) == sat.total
    per = _per_element_counts(_rsqrt_count(model), x, 1)
    bad = np.nonzero(hw["saturated"] != per)[0]
    assert bad.size == 0, f"saturation flags differ at x = {x[bad[:5]].tolist()}"
    if expect_sat is not None:                   # coverage: both saturated and unsaturated outputs
        assert (0 < sat.total < len(x)) == expect_sat
    return hw


# exhaustive cases: (in_shape, out_shape, segments_log2, guard_bits); inputs = 2^in.width
RSQRT_TABLE_EXHAUSTIVE = [
    # 16384 inputs each: negative inputs and 0, saturating small inputs; 16 segments, and the presets'
    # 1,024 (the first word's offset clamped to 2^(Y+1) - 1)
    (SQ(6, 8), SQ(4, 10), 4, 2),
    (SQ(6, 8), SQ(4, 10), 10, 4),
    # 4096 inputs: unsigned; M = 10 < 13 = k_max (mantissa rounding and its clamp), left output shifts
    (UQ(4, 8), UQ(2, 8), 3, 0),
    # 4096 inputs: odd input fraction bits, one segment per octave (S = 2), 1 guard bit
    (SQ(3, 9), SQ(6, 6), 2, 1),
    # 256 inputs: negative input fraction bits (the raw LSB is 4)
    (SQ(10, -2), UQ(1, 9), 5, 2),
    # 256 inputs: M = S + 1, a 1-bit fraction (always 0 in the lower octave)
    (UQ(4, 4), UQ(2, 4), 5, 0),
    # 4 inputs each: 2-bit inputs
    (UQ(2, 0), UQ(1, 7), 3, 2),
    (SQ(2, 0), SQ(2, 6), 3, 2),
]


@pytest.mark.parametrize("ins, outs, S, guard", RSQRT_TABLE_EXHAUSTIVE,
                         ids=[f"{a}-{b}-S{c}-guard{d}" for a, b, c, d in RSQRT_TABLE_EXHAUSTIVE])
def test_rsqrt_table_exhaustive(ins, outs, S, guard):
    model = RsqrtTable(ins, outs, segments_log2=S, guard_bits=guard)
    x = np.arange(ins.min_raw, ins.max_raw + 1, dtype=np.int64)
    _check_rsqrt_table(model, x, expect_sat=True)


def test_rsqrt_table_exhaustive_cases_reach_every_path():
    """Mantissa rounding and left output shifts (UQ(4, 8) -> UQ(2, 8)), F = 1 (UQ(4, 4) -> UQ(2, 4)), the
    first word's offset at 2^(Y+1) - 1, the largest c0 - 2^Y the ROM holds."""
    model = RsqrtTable(UQ(4, 8), UQ(2, 8), segments_log2=3, guard_bits=0)
    assert model.k_max > model.M
    n = np.arange(1, 13)
    k = n + ((n - 8) & 1)
    assert (model.Y + ((k - 8) >> 1) - 8 < 0).any()
    assert RsqrtTable(UQ(4, 4), UQ(2, 4), segments_log2=5, guard_bits=0).F == 1
    top = RsqrtTable(SQ(6, 8), SQ(4, 10), segments_log2=10, guard_bits=4)
    assert top.c0[0] == (1 << (top.Y + 1)) - 1


def _rsqrt_table_inputs(model: RsqrtTable, seed: int, n_random=3000):
    """Extremes, powers of two and neighbours, the inputs around the output's saturation threshold, one
    input in every table segment (at a random exponent), uniform and log-uniform random inputs."""
    s = model.in_shape
    S = model.S
    rng = np.random.default_rng(seed)
    Wn = s.max_raw.bit_length()
    pw = np.int64(1) << np.arange(Wn, dtype=np.int64)
    edge = int(round(2.0 ** s.f / model.out_shape.max_value ** 2))
    # x with bit length b, k = b (b - fi even), has the mantissa x 2^-b: in segment [a, a + h) of octave o
    # when x is in [a 2^b, (a + h) 2^b), which holds an integer when b >= S + 1
    bs = [b for b in range(S + 1, Wn + 1) if (b - s.f) % 2 == 0]
    segs = []
    for addr in range(1 << S):
        o, j = addr >> (S - 1), addr & ((1 << (S - 1)) - 1)
        q = S + 1 - o                                   # a = n 2^-q, h = 2^-q
        b = int(rng.choice(bs))
        segs.append((((1 << (S - 1)) + j) << (b - q)) + int(rng.integers(0, 1 << (b - q))))
    vals = [s.min_raw, s.min_raw + 1, -2, -1, 0, 1, 2, 3, s.max_raw - 1, s.max_raw,
            *pw, *(pw + 1), *(pw - 1), *range(edge - 16, edge + 17), *segs,
            *rng.integers(s.min_raw, s.max_raw, n_random // 3, endpoint=True),
            *np.exp2(rng.uniform(0, Wn, n_random)).astype(np.int64)]          # log-uniform positive
    return _shuffle(_inputs(s, vals), seed)


# the formats of other scenes' 1/sqrt units under the narrow and medium presets (press-2d-rheological's
# are in test_scene_units): dense inputs, every table word read
RSQRT_TABLE_SCENES = [
    (SQ(0, 18), SQ(7, 11)),        # press-3d-rheological inv_l
    (SQ(-6, 24), SQ(9, 9)),        # press-3d-rheological tinv2
    (SQ(-7, 25), SQ(11, 7)),       # friction-3d-mu03 cinv2
    (SQ(-33, 51), SQ(32, -14)),    # friction-3d-mu03 finv
]


@pytest.mark.parametrize("ins, outs", RSQRT_TABLE_SCENES, ids=[f"{a}-{b}" for a, b in RSQRT_TABLE_SCENES])
def test_rsqrt_table_scene_formats(ins, outs):
    from hw.formats import FORMAT_PRESETS
    S = FORMAT_PRESETS["narrow"].rsqrt_table_segments_log2
    assert S == FORMAT_PRESETS["medium"].rsqrt_table_segments_log2 == 10
    model = RsqrtTable(ins, outs, segments_log2=S)
    x = _rsqrt_table_inputs(model, seed=ins.f)
    assert len(x) > 3000
    _check_rsqrt_table(model, x, idle=0.1, seed=ins.f)


# ================================================================================================ inverse tables

def _inverse_count(model):
    def count(xs):
        sat = Saturations()
        model(xs, sat)
        return sat.total
    return count


def _check_inverse(model: InverseTable, x, idle=0.0, seed=0):
    """Every output field of an InverseTableUnit against the model at the magnitudes x."""
    dut = InverseTableUnit(model)
    assert dut.latency == 12
    n = len(model.out_shapes)
    assert dut.output_fields == tuple(f"out{k}" for k in range(n))
    sat = Saturations()
    refs = model(x, sat)
    hw = _simulate(dut, x, (*dut.output_fields, "below", "above", "saturations"), idle=idle, seed=seed)
    for name, ref in zip(dut.output_fields, refs):
        bad = np.nonzero(hw[name] != ref)[0]
        assert bad.size == 0, (f"{name}: {bad.size} outputs differ, first y = {x[bad[:5]].tolist()}: "
                               f"hw {hw[name][bad[:5]].tolist()} model {ref[bad[:5]].tolist()}")
    # the pieces as hw/arith.py FixedArith.inverse reports them
    assert np.array_equal(hw["below"], (x <= model.Y1).astype(np.int64)), "below differs"
    assert np.array_equal(hw["above"], (x >= model.Y2).astype(np.int64)), "above differs"
    assert int(hw["saturations"].sum()) == sat.total
    per = _per_element_counts(_inverse_count(model), x, n)
    bad = np.nonzero(hw["saturations"] != per)[0]
    assert bad.size == 0, f"saturation counts differ at y = {x[bad[:5]].tolist()}"
    return hw, sat.total


def _curve(kind, law):
    return phi_curve(DamperLaw(*law)) if kind == "phi" else psi_curve(DamperLaw(*law))


# (curve, (c1, c_min, c_max, f1, f2), in_shape, out_shapes, segments_log2, frac_bits, scale_bits)
INVERSE_EXHAUSTIVE = {
    # 4096 magnitudes of a signed input, pos_shift 23 > 0; the top entries of both tables are clipped
    # (T above SQ(3, 7), w' above SQ(2, 11)): up to 2 saturations per item
    "signed-clipped": ("phi", (0.25, 0.5, 20.0, 1.0, 5.0), SQ(5, 9), (SQ(3, 7), SQ(2, 11)), 5, 8, 25),
    # 8192 inputs, 8-bit scale rounded up (K_q > K): just below y2 the position passes the end point and
    # is limited to it
    "position-limit": ("phi", (0.0, 1.0, 50.0, 3.0, 13.0), UQ(5, 8), (UQ(5, 7), UQ(4, 8)), 4, 6, 8),
    # 4096 inputs, pos_shift -8 < 0 (a left shift of D), 8-bit scale, position limit reached
    "left-shift": ("phi", (0.0, 1.0, 10.0, 100.3, 3000.7), UQ(12, 0), (UQ(12, 0), UQ(12, 0)), 3, 24, 8),
    # 4096 inputs, pos_shift = 0
    "no-shift": ("phi", (0.0, 2.0, 60.0, 20.0, 36.0), UQ(8, 4), (UQ(6, 6), UQ(5, 7)), 4, 16, 13),
    # 4096 magnitudes, y2 beyond the format (Y2 = max_raw + 1: `above` never set); w' entries clipped
    "y2-unreachable": ("phi", (2.0, 1.0, 50.0, 40.0, 100.0), SQ(8, 6), (SQ(8, 6), UQ(3, 11)), 4, 12, 25),
    # 256 inputs, y1 beyond the format (Y1 = max_raw, OFF = 0: only the first entries)
    "y1-unreachable": ("phi", (1.0, 2.0, 30.0, 20.0, 40.0), UQ(4, 4), (SQ(7, 5), SQ(6, 6)), 4, 16, 25),
    # 8192 inputs, Psi (one output, a 1-bit saturation count), f1 = 0 so y1 = 0 and Y1 = 0
    "psi-y1-zero": ("psi", (0.0, 1.0, 100.0, 0.0, 2.0), UQ(2, 11), (SQ(3, 9),), 6, 16, 25),
    # 8192 magnitudes, Psi with clipped entries (T above SQ(2, 12)), 2 idle cycles in 10
    "psi-clipped": ("psi", (0.5, 0.5, 50.0, 1.0, 3.0), SQ(4, 10), (SQ(2, 12),), 7, 16, 25),
}


def _position_limit_reached(model: InverseTable) -> bool:
    """Whether some y strictly between Y1 and Y2 has a position past the end point 2^(S+P) (step 2)."""
    y = np.arange(model.Y1 + 1, model.Y2, dtype=np.int64)
    pos = shift_round(y * model.K_raw - model.OFF, model.pos_shift)
    return bool((pos > 1 << (model.S + model.P)).any())


@pytest.mark.parametrize("case", list(INVERSE_EXHAUSTIVE))
def test_inverse_exhaustive(case):
    kind, law, ins, outs, S, P, sb = INVERSE_EXHAUSTIVE[case]
    model = InverseTable(ins, outs, _curve(kind, law), segments_log2=S, frac_bits=P, scale_bits=sb)
    x = np.arange(0, ins.max_raw + 1, dtype=np.int64)
    _, total = _check_inverse(model, x, idle=0.2 if case == "psi-clipped" else 0.0, seed=len(case))
    # the case reaches what it is there for
    clipped = [bool(c.any()) for c in model.clips]
    if case == "signed-clipped":
        assert model.pos_shift > 0 and all(clipped) and total > 0
    elif case == "position-limit":
        assert model.pos_shift > 0 and _position_limit_reached(model)
    elif case == "left-shift":
        assert model.pos_shift < 0 and _position_limit_reached(model)
    elif case == "no-shift":
        assert model.pos_shift == 0
    elif case == "y2-unreachable":
        assert model.Y2 == ins.max_raw + 1 and clipped == [False, True] and total > 0
    elif case == "y1-unreachable":
        assert model.Y1 == ins.max_raw and model.OFF == 0
    elif case == "psi-y1-zero":
        assert model.Y1 == 0 and len(outs) == 1
    elif case == "psi-clipped":
        assert clipped == [True] and total > 0


# ================================================================================================ the project's units

SCENE = "press-2d-rheological"


@pytest.fixture(scope="module")
def scene_units():
    """{preset: {name: model}} for press-2d-rheological: the function units `hw.bittrue.BitTrue(system,
    preset)` builds (formats from a full range analysis, as `rheo simulate --backend fixed`; cached per
    session in tests/conftest.py), identical configurations (inv_l and tinv) kept once."""
    from conftest import bittrue

    result = {}
    for preset in ("narrow", "medium", "wide"):
        units, seen = {}, set()
        for name, u in bittrue(SCENE, preset).ar.units.items():
            key = repr({k: v for k, v in u.to_dict().items() if k != "name"})
            if key not in seen:
                seen.add(key)
                units[name] = u
        result[preset] = units
    return result


def _rsqrt_inputs(model: Rsqrt, seed: int, n_random=3000):
    """Extremes, powers of two and neighbours, the inputs around the output's saturation threshold, one
    input in every seed ROM interval (at a random exponent), uniform and log-uniform random inputs."""
    s = model.in_shape
    rng = np.random.default_rng(seed)
    Wn = s.max_raw.bit_length()
    pw = np.int64(1) << np.arange(Wn, dtype=np.int64)
    # the input at which the output reaches out.max_value: 1/sqrt(v) = max_value, v = 1/max_value^2
    edge = int(round(2.0 ** s.f / model.out_shape.max_value ** 2))
    # x in [idx 2^(b - sb), (idx + 1) 2^(b - sb)) with k = b (b - fi even) has its mantissa in seed
    # interval idx
    sb = model.seed_bits
    bs = [b for b in range(sb, Wn + 1) if (b - s.f) % 2 == 0]
    seeds = []
    for idx in range(model.idx_lo, 1 << sb):
        b = int(rng.choice(bs))
        seeds.append((idx << (b - sb)) + int(rng.integers(0, 1 << (b - sb))))
    vals = [s.min_raw, s.min_raw + 1, -2, -1, 0, 1, 2, 3, s.max_raw - 1, s.max_raw,
            *pw, *(pw + 1), *(pw - 1), *range(edge - 16, edge + 17), *seeds,
            *rng.integers(s.min_raw, s.max_raw, n_random // 3, endpoint=True),
            *np.exp2(rng.uniform(0, Wn, n_random)).astype(np.int64)]          # log-uniform positive
    return _shuffle(_inputs(s, vals), seed)


def _inverse_inputs(model: InverseTable, seed: int, n_random=10000):
    """Extremes, Y1 and Y2 and neighbours, every table breakpoint and neighbours (so every ROM word is
    read), random magnitudes around the interpolated piece and over the whole format."""
    s = model.in_shape
    rng = np.random.default_rng(seed)
    bp = np.floor(model.breakpoints * 2.0 ** s.f).astype(np.int64)
    lo, hi = max(model.Y1 - 20, 0), min(model.Y2 + 20, s.max_raw)
    vals = [0, 1, 2, s.max_raw - 1, s.max_raw,
            *range(model.Y1 - 3, model.Y1 + 4), *range(model.Y2 - 3, model.Y2 + 4),
            *(bp - 1), *bp, *(bp + 1),
            *rng.integers(lo, hi, n_random, endpoint=True),
            *rng.integers(0, s.max_raw, n_random // 4, endpoint=True)]
    x = _inputs(s, vals)
    return _shuffle(x[x >= 0], seed)


@pytest.mark.parametrize("preset", ["narrow", "medium", "wide"])
def test_scene_units(scene_units, preset):
    units = scene_units[preset]
    # 1/sqrt by table (RsqrtTable) under narrow and medium, by Newton (Rsqrt) under wide (hw/formats.py
    # rsqrt_table_segments_log2, hw/bittrue.py function_units)
    rsqrt, other = (Rsqrt, RsqrtTable) if preset == "wide" else (RsqrtTable, Rsqrt)
    assert any(isinstance(u, rsqrt) for u in units.values())
    assert not any(isinstance(u, other) for u in units.values())
    tables = {name: u for name, u in units.items() if isinstance(u, InverseTable)}
    assert set(tables) == {"phi", "psi"}
    assert len(tables["phi"].out_shapes) == 2 and len(tables["psi"].out_shapes) == 1
    for k, (name, model) in enumerate(units.items()):
        if isinstance(model, Rsqrt):
            x = _rsqrt_inputs(model, seed=100 + k)
            _check_rsqrt(model, x, idle=0.1, seed=k)
        elif isinstance(model, RsqrtTable):
            x = _rsqrt_table_inputs(model, seed=100 + k)
            _check_rsqrt_table(model, x, idle=0.1, seed=k)
        else:
            x = _inverse_inputs(model, seed=200 + k)
            assert len(x) > 10000
            _check_inverse(model, x, idle=0.1, seed=k)


# ================================================================================================ the pipeline

def _run_lane(m, x_sig, valid, xs, probes, gate_sig=None, gates=None):
    """Feed xs one per cycle into a PipeArith lane and sample `probes` ({name: (signal, stage)}) at the
    stage at which each is valid; returns {name: values in input order}."""
    horizon = max(st for _, st in probes.values()) + 2
    got = {k: {} for k in probes}

    async def testbench(ctx):
        for c in range(len(xs) + horizon):
            ctx.set(valid, int(c < len(xs)))
            ctx.set(x_sig, int(xs[c]) if c < len(xs) else 0)
            if gate_sig is not None:
                ctx.set(gate_sig, int(gates[c]) if c < len(xs) else 0)
            await ctx.tick()
            # after this edge, a value valid at stage st holds the item presented in cycle c - st + 1
            for k, (sig, st) in probes.items():
                j = c - st + 1
                if 0 <= j < len(xs):
                    got[k][j] = int(ctx.get(sig))

    sim = Simulator(m)
    sim.add_clock(1e-8)
    sim.add_testbench(testbench)
    sim.run()
    return {k: np.array([v[j] for j in range(len(xs))], np.int64) for k, v in got.items()}


def test_pipeline_inverse():
    """PipeArith.inverse: below, above and the outputs valid at the operand's stage + latency, in its gate;
    the unit's saturations counted under the curve's name, only where the gate is open."""
    from hw.pipeline import PBool, PipeArith
    kind, law, ins, outs, S, P, sb = INVERSE_EXHAUSTIVE["signed-clipped"]
    curve = _curve(kind, law)
    model = InverseTable(ins, outs, curve, segments_log2=S, frac_bits=P, scale_bits=sb)
    fmt = {"drive": ins, "force": outs[0], "wdot": outs[1], "other": SQ(6, 8)}
    m = Module()
    valid, x, g = Signal(), Signal(signed(ins.width)), Signal()
    ar = PipeArith(m, fmt, {"phi": model}, valid, "lane")
    with ar:
        gate = ar.gate(PBool(g, 0))
        mag = gate.take(ar.input(x, "drive", 0))
        below, above, vals = ar.inverse(mag, curve)
        events = dict(ar.saturation_events())
        with pytest.raises(ValueError, match="operand 'other' is SQ"):
            ar.inverse(ar.input(x, "other", 0), curve)
    L = 12                                       # InverseTableUnit.latency (checked in _check_inverse)
    assert [v.q for v in vals] == ["force", "wdot"]
    for v in (below, above, *vals):
        assert v.stage == L and v.gate is mag.gate
    assert set(events) == {"phi"}
    rng = np.random.default_rng(5)
    xs = _shuffle(np.arange(0, ins.max_raw + 1, 3), 5)
    gates = rng.random(len(xs)) < 0.7
    probes = {"below": (below.sig, L), "above": (above.sig, L), "out0": (vals[0].sig, L),
              "out1": (vals[1].sig, L), "sat": (events["phi"], L + 2)}
    got = _run_lane(m, x, valid, xs, probes, g, gates)
    refs = model(xs)
    assert np.array_equal(got["out0"], refs[0]) and np.array_equal(got["out1"], refs[1])
    assert np.array_equal(got["below"], (xs <= model.Y1).astype(np.int64))
    assert np.array_equal(got["above"], (xs >= model.Y2).astype(np.int64))
    per = _per_element_counts(_inverse_count(model), xs, 2)
    assert per.sum() > 100
    assert np.array_equal(got["sat"], np.where(gates, per, 0))


# ================================================================================================ interface

# the rejected objects were created (Elaboratable.__new__) but never elaborated
@pytest.mark.filterwarnings("ignore::amaranth.hdl.UnusedElaboratable")
def test_constructor_rejects_wrong_models():
    rs = Rsqrt(SQ(6, 8), SQ(4, 10), seed_bits=6)
    it = InverseTable(UQ(8, 4), (UQ(6, 6), UQ(5, 7)), _curve("phi", (0.0, 2.0, 60.0, 20.0, 36.0)), segments_log2=4)
    for bad in (it, None, SQ(6, 8), "rsqrt"):
        with pytest.raises(TypeError, match="RsqrtUnit needs a hw.funcunits.Rsqrt model"):
            RsqrtUnit(bad)
    for bad in (rs, None, 3.0, it.curve):
        with pytest.raises(TypeError, match="InverseTableUnit needs a hw.funcunits.InverseTable model"):
            InverseTableUnit(bad)
    gc.collect()          # the rejected objects' warnings fire here, under this test's filter


def test_signatures_and_conversion():
    rs = Rsqrt(SQ(6, 8), UQ(4, 10), seed_bits=6, newton_steps=2)
    u = RsqrtUnit(rs)
    assert u.latency == 37                 # 7 + 15 * 2 Newton steps
    assert u.i.payload.shape() == signed(14)
    assert u.o.payload.value.shape() == unsigned(14)
    assert u.o.payload.saturated.shape() == unsigned(1)
    phi = InverseTable(UQ(8, 4), (SQ(6, 6), UQ(5, 7)), _curve("phi", (0.0, 2.0, 60.0, 20.0, 36.0)), segments_log2=4)
    d = InverseTableUnit(phi)
    assert d.latency == 12
    assert d.i.payload.shape() == unsigned(12)
    assert d.o.payload.out0.shape() == signed(12) and d.o.payload.out1.shape() == unsigned(12)
    assert d.o.payload.below.shape() == unsigned(1) and d.o.payload.above.shape() == unsigned(1)
    assert d.o.payload.saturations.shape() == unsigned(2)
    psi = InverseTable(SQ(4, 10), (SQ(2, 12),), _curve("psi", (0.5, 0.5, 50.0, 1.0, 3.0)), segments_log2=7)
    q = InverseTableUnit(psi)
    assert q.output_fields == ("out0",) and q.i.payload.shape() == signed(14)
    assert q.o.payload.saturations.shape() == unsigned(1)
    # all convert to RTLIL (what Yosys reads), ROMs included. The ports are listed explicitly: Amaranth
    # 0.5 cannot infer them from a Component whose always_ready streams hold ready = Const(1)
    # (amaranth-lang/amaranth#1574)
    for dut in (u, d, q):
        ports = [dut.i.valid, dut.i.payload, dut.o.valid, dut.o.payload.as_value()]
        text = rtlil.convert(dut, ports=ports)
        assert "$mem" in text


@pytest.mark.filterwarnings("ignore::amaranth.hdl.UnusedElaboratable")
def test_rsqrt_table_unit_interface():
    """RsqrtTableUnit: RsqrtUnit's stream signature, latency 10, its own model type only; converts to
    RTLIL with its ROM."""
    md = RsqrtTable(SQ(6, 8), UQ(4, 10), segments_log2=6)
    u = RsqrtTableUnit(md)
    assert u.latency == 12
    assert u.i.payload.shape() == signed(14)
    assert u.o.payload.value.shape() == unsigned(14) and u.o.payload.saturated.shape() == unsigned(1)
    assert u.signature.members["i"].signature == RsqrtUnit(Rsqrt(SQ(6, 8), UQ(4, 10), seed_bits=6)).signature.members["i"].signature
    text = rtlil.convert(u, ports=[u.i.valid, u.i.payload, u.o.valid, u.o.payload.as_value()])
    assert "$mem" in text and text.count("cell $mul") == 1
    for bad in (Rsqrt(SQ(6, 8), UQ(4, 10), seed_bits=6), None, "rsqrt"):
        with pytest.raises(TypeError, match="RsqrtTableUnit needs a hw.funcunits.RsqrtTable model"):
            RsqrtTableUnit(bad)
    with pytest.raises(TypeError, match="RsqrtUnit needs a hw.funcunits.Rsqrt model"):
        RsqrtUnit(md)
    gc.collect()


@pytest.mark.filterwarnings("ignore::amaranth.hdl.UnusedElaboratable")
def test_units_declare_their_memories():
    """Every unit's `memories` (known at construction, before elaboration: what the core's schedule facts
    and the manifest list) are the Memory submodules it elaborates, by name, depth and width."""
    from amaranth.hdl import Shape as AShape
    from amaranth.lib.memory import Memory
    phi = InverseTable(UQ(8, 4), (SQ(6, 6), UQ(5, 7)), _curve("phi", (0.0, 2.0, 60.0, 20.0, 36.0)), segments_log2=4)
    for dut in (RsqrtUnit(Rsqrt(SQ(6, 8), UQ(4, 10), seed_bits=6)),
                RsqrtTableUnit(RsqrtTable(SQ(6, 8), UQ(4, 10), segments_log2=6)),
                RsqrtTableUnit(RsqrtTable(SQ(10, 8), SQ(4, 14), segments_log2=10)),
                InverseTableUnit(phi)):
        declared = [dict(mem) for mem in dut.memories]
        m = dut.elaborate(None)
        built = [{"name": name, "depth": sub.depth, "width": AShape.cast(sub.shape).width}
                 for name, (sub, _) in m._named_submodules.items() if isinstance(sub, Memory)]
        assert declared == built and built, type(dut).__name__
    del dut, m
    gc.collect()          # the units elaborated by hand warn here, under this test's filter


@pytest.mark.parametrize("kind", ["table", "newton"])
def test_pipeline_rsqrt_picks_the_unit_of_its_model(kind):
    """PipeArith.rsqrt builds the unit that implements the bit-true model it is given (RsqrtTableUnit for
    an RsqrtTable, RsqrtUnit for an Rsqrt): result valid at the operand's stage + that unit's latency,
    bit for bit the model's, saturations counted under the quantity."""
    from hw.pipeline import PipeArith
    ins, outs = SQ(6, 8), SQ(4, 10)
    model = (RsqrtTable(ins, outs, segments_log2=6, name="inv_l") if kind == "table"
             else Rsqrt(ins, outs, seed_bits=6, name="inv_l"))
    L = 12 if kind == "table" else 22                # the units' latencies: 8 + 4, 7 + 15 (one Newton step)
    m = Module()
    valid, x = Signal(), Signal(signed(ins.width))
    ar = PipeArith(m, {"l2": ins, "inv_l": outs}, {"inv_l": model}, valid, "lane")
    with ar:
        r = ar.rsqrt(ar.input(x, "l2", 0), "inv_l")
        events = dict(ar.saturation_events())
    assert r.stage == L and r.q == "inv_l" and set(events) == {"inv_l"}
    rom = ("table_rom", 1 << 6) if kind == "table" else ("seed_rom", len(model.seed_table))
    assert [(mem["name"].split(".")[-1], mem["depth"]) for mem in ar.memories] == [rom]   # the lane reports it
    xs = _shuffle(np.arange(ins.min_raw, ins.max_raw + 1, 5), 7)
    got = _run_lane(m, x, valid, xs, {"v": (r.sig, L), "sat": (events["inv_l"], L + 2)})
    assert np.array_equal(got["v"], model(xs))
    assert np.array_equal(got["sat"], _per_element_counts(_rsqrt_count(model), xs, 1))
