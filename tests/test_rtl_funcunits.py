"""Gateware function units (hw/rtl_funcunits.py) against their NumPy models (hw/funcunits.py), bit for bit.

Every case runs the unit in Amaranth's simulator, one input per clock (some cases with random idle
cycles), and compares each output with the model called on the same raw inputs: the values exactly,
the model's saturation total with the sum of the hardware's per-output saturation fields, and the
per-element saturation counts (the model's count is additive over elements; it is split down to single
elements by calling the model on sub-arrays). Every output must appear exactly `latency` cycles after its
input, and only then. The expected results always come from the model, never from the gateware.

Cases: exhaustive over every input of small formats chosen to reach every path (x <= 0, mantissa
rounding, left and right output shifts, saturating outputs, odd and negative fraction bits; damper
position shifts > 0, = 0 and < 0, clipped table entries, c12 saturation, unreachable f2 or interpolated
piece), and the configurations press-2d-rheological uses under the narrow, medium and wide presets with
a few thousand dense and random inputs each. Simulator throughput is roughly 5-10k cycles/s.
"""
from __future__ import annotations

import gc

import numpy as np
import pytest
from amaranth.back import rtlil
from amaranth.hdl import signed, unsigned
from amaranth.sim import Simulator

from hw.fixed import SQ, UQ, Saturations, shift_round
from hw.funcunits import DamperTable, Rsqrt
from hw.rtl_funcunits import DamperUnit, RsqrtUnit


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
    assert dut.latency == 7 + 9 * model.newton_steps
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


# ================================================================================================ damper

def _damper_count(model):
    def count(xs):
        sat = Saturations()
        model(xs, sat)
        return sat.total
    return count


def _check_damper(model: DamperTable, x, idle=0.0, seed=0):
    dut = DamperUnit(model)
    assert dut.latency == 9
    sat = Saturations()
    c2, c12, inv = model(x, sat)
    hw = _simulate(dut, x, ("c2", "c12", "inv", "saturations"), idle=idle, seed=seed)
    for name, ref in (("c2", c2), ("c12", c12), ("inv", inv)):
        bad = np.nonzero(hw[name] != ref)[0]
        assert bad.size == 0, (f"{name}: {bad.size} outputs differ, first f = {x[bad[:5]].tolist()}: "
                               f"hw {hw[name][bad[:5]].tolist()} model {ref[bad[:5]].tolist()}")
    assert int(hw["saturations"].sum()) == sat.total
    per = _per_element_counts(_damper_count(model), x, 3)
    bad = np.nonzero(hw["saturations"] != per)[0]
    assert bad.size == 0, f"saturation counts differ at f = {x[bad[:5]].tolist()}"
    return hw, sat.total


# (f_shape, c2_shape, inv_shape, c1, c_min, c_max, f1, f2, segments_log2, frac_bits, scale_bits)
DAMPER_EXHAUSTIVE = {
    # 8192 inputs, signed f (negative forces too), pos_shift 22 > 0; c2 entries above SQ(5, 7) and inv
    # entries above SQ(1, 11) are clipped; c12 saturates
    "signed-clipped": (SQ(4, 9), SQ(5, 7), SQ(1, 11), 0.25, 0.5, 20.0, 1.0, 5.0, 5, 8, 25),
    # 8192 inputs, 8-bit scale rounded up (K_q > K): just below f2 the position passes the end point and
    # is limited to it (visibly: the inv table's last step is ~250 LSBs)
    "position-limit": (UQ(5, 8), UQ(6, 6), UQ(0, 12), 1.0, 1.0, 50.0, 3.0, 13.0, 4, 6, 8),
    # 4096 inputs, unsigned f, pos_shift -8 < 0 (a left shift of D), 8-bit scale, position limit reached
    "left-shift": (UQ(12, 0), UQ(4, 8), UQ(1, 11), 0.5, 1.0, 10.0, 100.3, 3000.7, 3, 24, 8),
    # 4096 inputs, pos_shift = 0
    "no-shift": (UQ(8, 4), UQ(6, 6), UQ(0, 12), 1.0, 2.0, 60.0, 20.0, 36.0, 4, 16, 13),
    # 8192 inputs, f2 beyond the format (F2 = max_raw + 1: the c_min piece is unreachable)
    "f2-unreachable": (SQ(6, 7), SQ(8, 6), UQ(0, 14), 2.0, 1.0, 50.0, 40.0, 100.0, 4, 12, 25),
    # 256 inputs, f1 beyond the format (F1 = max_raw, OFF = 0: only the c_max piece)
    "f1-unreachable": (UQ(4, 4), SQ(7, 5), SQ(2, 10), 1.0, 2.0, 30.0, 20.0, 40.0, 4, 16, 25),
}


def _position_limit_reached(model: DamperTable) -> bool:
    """Whether some f strictly between F1 and F2 has a position past the end point 2^(S+P) (step 2)."""
    f = np.arange(model.F1 + 1, model.F2, dtype=np.int64)
    pos = shift_round(f * model.K_raw - model.OFF, model.pos_shift)
    return bool((pos > 1 << (model.S + model.P)).any())


@pytest.mark.parametrize("case", list(DAMPER_EXHAUSTIVE))
def test_damper_exhaustive(case):
    fs, c2s, invs, c1, cmin, cmax, f1, f2, S, P, sb = DAMPER_EXHAUSTIVE[case]
    model = DamperTable(fs, c2s, invs, c1, cmin, cmax, f1, f2, segments_log2=S, frac_bits=P, scale_bits=sb)
    x = np.arange(fs.min_raw, fs.max_raw + 1, dtype=np.int64)
    _, total = _check_damper(model, x)
    # the case reaches what it is there for
    if case == "signed-clipped":
        assert model.pos_shift > 0 and model.clip_c2.any() and model.clip_inv.any() and total > 0
    elif case == "position-limit":
        assert model.pos_shift > 0 and _position_limit_reached(model)
    elif case == "left-shift":
        assert model.pos_shift < 0 and _position_limit_reached(model)
    elif case == "no-shift":
        assert model.pos_shift == 0
    elif case == "f2-unreachable":
        assert model.F2 == fs.max_raw + 1
    elif case == "f1-unreachable":
        assert model.F1 == fs.max_raw and model.OFF == 0


# ================================================================================================ the project's units

SCENE = "press-2d-rheological"


@pytest.fixture(scope="module")
def scene_units():
    """{preset: {name: model}} for press-2d-rheological, formats from a full range analysis (as
    simulate_fixed does; the analysis is preset-independent, so it runs once, about 9 s), identical
    configurations (inv_l and tinv) kept once."""
    from golden.scene import compile_scene, load_scene
    from hw.bittrue import BitTrue, range_analysis
    from hw.formats import PRESETS, derive
    from hw.datapath import Params
    from hw.units import HardwareUnits

    sys = compile_scene(load_scene(SCENE))
    hu = HardwareUnits.of(sys)
    peaks = range_analysis(sys, Params.of(sys, hu), hu, sys.n_steps)
    result = {}
    for preset in ("narrow", "medium", "wide"):
        bt = BitTrue(sys, preset, formats=derive(peaks, PRESETS[preset], dict(sys.formats)))
        units, seen = {}, set()
        for name, u in bt.ar.units.items():
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


def _damper_inputs(model: DamperTable, seed: int, n_random=1500):
    """Extremes, F1 and F2 and neighbours, every table breakpoint and neighbours (so every ROM word is
    read), random inputs around the interpolated piece and over the whole format."""
    s = model.f_shape
    rng = np.random.default_rng(seed)
    bp = np.floor(model.breakpoints * 2.0 ** s.f).astype(np.int64)
    lo, hi = max(model.F1 - 20, s.min_raw), min(model.F2 + 20, s.max_raw)
    vals = [s.min_raw, s.min_raw + 1, -1, 0, 1, s.max_raw - 1, s.max_raw,
            *range(model.F1 - 3, model.F1 + 4), *range(model.F2 - 3, model.F2 + 4),
            *(bp - 1), *bp, *(bp + 1),
            *rng.integers(lo, hi, n_random, endpoint=True),
            *rng.integers(s.min_raw, s.max_raw, n_random // 5, endpoint=True)]
    return _shuffle(_inputs(s, vals), seed)


@pytest.mark.parametrize("preset", ["narrow", "medium", "wide"])
def test_scene_units(scene_units, preset):
    units = scene_units[preset]
    assert any(isinstance(u, Rsqrt) for u in units.values())
    assert any(isinstance(u, DamperTable) for u in units.values())
    for k, (name, model) in enumerate(units.items()):
        if isinstance(model, Rsqrt):
            x = _rsqrt_inputs(model, seed=100 + k)
            _check_rsqrt(model, x, idle=0.1, seed=k)
        elif isinstance(model, DamperTable):
            x = _damper_inputs(model, seed=200 + k)
            _check_damper(model, x, idle=0.1, seed=k)


# ================================================================================================ interface

# the rejected objects were created (Elaboratable.__new__) but never elaborated
@pytest.mark.filterwarnings("ignore::amaranth.hdl.UnusedElaboratable")
def test_constructor_rejects_wrong_models():
    rs = Rsqrt(SQ(6, 8), SQ(4, 10), seed_bits=6)
    dp = DamperTable(UQ(8, 4), UQ(6, 6), UQ(0, 12), 1.0, 2.0, 60.0, 20.0, 36.0, segments_log2=4)
    for bad in (dp, None, SQ(6, 8), "rsqrt"):
        with pytest.raises(TypeError, match="RsqrtUnit needs a hw.funcunits.Rsqrt model"):
            RsqrtUnit(bad)
    for bad in (rs, None, 3.0):
        with pytest.raises(TypeError, match="DamperUnit needs a hw.funcunits.DamperTable model"):
            DamperUnit(bad)
    gc.collect()          # the rejected objects' warnings fire here, under this test's filter


def test_signatures_and_conversion():
    rs = Rsqrt(SQ(6, 8), UQ(4, 10), seed_bits=6, newton_steps=2)
    u = RsqrtUnit(rs)
    assert u.latency == 25                 # 7 + 9 * 2 Newton steps
    assert u.i.payload.shape() == signed(14)
    assert u.o.payload.value.shape() == unsigned(14)
    assert u.o.payload.saturated.shape() == unsigned(1)
    dp = DamperTable(UQ(8, 4), SQ(6, 6), UQ(0, 12), 1.0, 2.0, 60.0, 20.0, 36.0, segments_log2=4)
    d = DamperUnit(dp)
    assert d.i.payload.shape() == unsigned(12)
    assert d.o.payload.c2.shape() == signed(12) and d.o.payload.c12.shape() == signed(12)
    assert d.o.payload.inv.shape() == unsigned(12) and d.o.payload.saturations.shape() == unsigned(2)
    # both convert to RTLIL (what Yosys reads), ROMs included. The ports are listed explicitly: Amaranth
    # 0.5 cannot infer them from a Component whose always_ready streams hold ready = Const(1)
    # (amaranth-lang/amaranth#1574)
    for dut in (u, d):
        ports = [dut.i.valid, dut.i.payload, dut.o.valid, dut.o.payload.as_value()]
        text = rtlil.convert(dut, ports=ports)
        assert "$mem" in text
