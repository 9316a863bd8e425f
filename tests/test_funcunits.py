"""Function units (hw/funcunits.py) against float64 references: exhaustive over every input of 16- to
20-bit formats, dense random for 32-bit formats, and edge cases.

Every check compares the unit's output with 1/sqrt(v) or the damper's exact formulas in float64 (never
with the unit itself) under the bounds the units state. `pytest -s` prints a table per configuration:
max relative error, max |error| in output LSBs, bias (mean error in LSBs) and the stated bounds.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from hw.fixed import SQ, UQ, Saturations
from hw.funcunits import DamperTable, Rsqrt, _bit_length, _mul_shift_round

# float64 evaluation of measured errors and bounds: a relative slack far below every bound's size
SLACK = 1e-9


def _row(*cells):
    print(" | ".join(str(c) for c in cells))


# ================================================================================================ helpers

def test_bit_length_at_powers_of_two():
    j = np.arange(0, 53)
    p = np.int64(1) << j
    assert np.array_equal(_bit_length(p), j + 1)
    assert np.array_equal(_bit_length(p[1:] - 1), j[1:])
    assert np.array_equal(_bit_length(p + 1)[1:], j[1:] + 1)


@pytest.mark.parametrize("s", [0, 1, 7, 23, 24, 25, 40, 47, 48, 49, 55, 70, 85])
def test_wide_product_rounding_is_exact(s):
    rng = np.random.default_rng(s)
    a = rng.integers(0, 1 << 47, 5000)
    b = rng.integers(0, 1 << 47, 5000)
    a[:3], b[:3] = (1 << 47) - 1, [(1 << 47) - 1, 0, 1]      # extremes
    b[3:6] = (1 << 47) - 1
    got = _mul_shift_round(a, b, s, 94)
    A, Bo = a.astype(object), b.astype(object)
    ref = (A * Bo + ((1 << (s - 1)) if s else 0)) >> s        # Python integers: exact
    fits = ref < (1 << 62)
    assert fits.any()
    assert np.array_equal(got[fits].astype(object), ref[fits])
    # the direct int64 path agrees where the product fits
    small_a, small_b = a >> 17, b >> 17
    if s <= 60:
        assert np.array_equal(_mul_shift_round(small_a, small_b, s, 60), _mul_shift_round(small_a, small_b, s, 94))


# ================================================================================================ Rsqrt

def _rsqrt_a_priori_bound(unit: Rsqrt) -> float:
    """The internal bound recomputed from the class docstring, from the formats alone (not the unit's ROM)."""
    sb, Y, M = unit.seed_bits, unit.M, unit.M
    w = 2.0 ** -sb
    a = np.arange(1 << (sb - 2), 1 << sb) * w
    c = a + w / 2                                               # the interval midpoints
    E = float(np.max(np.maximum(1 - np.sqrt(a / c), np.sqrt((a + w) / c) - 1))) + 2.0 ** -(Y + 1)
    rho = 2.0 ** -(Y + 1)
    for _ in range(unit.newton_steps):
        E = E * E * (3 + E) / 2 + (2 + E) * rho
    k_max = int(unit.in_shape.max_raw).bit_length() + 1
    eps_m = 1 / math.sqrt(1 - 2.0 ** (1 - M)) - 1 if k_max > M else 0.0
    return (1 + E) * (1 + eps_m) - 1


def _rsqrt_check(unit: Rsqrt, x: np.ndarray, label: str):
    """Check every output in x against 1/sqrt(v); returns the measured statistics."""
    # the unit's stated bound is no looser than the a-priori one (so a wrong ROM cannot hide in it)
    assert unit.internal_relative_error_bound() <= _rsqrt_a_priori_bound(unit) * (1 + SLACK)
    sat = Saturations()
    out = unit(x, sat)
    assert out.dtype == np.int64
    o = unit.out_shape
    v = unit.in_shape.to_float(x)
    r = Rsqrt.reference(v)
    E = unit.internal_relative_error_bound()
    # saturation: certain where even the lowest possible output exceeds the format, impossible where the
    # highest possible output fits
    must_sat = r * (1 - E) - 0.5 * o.lsb > o.max_value
    cannot_sat = r * (1 + E) + 0.5 * o.lsb <= o.max_value
    assert np.all(out[must_sat] == o.max_raw), f"{label}: overflowing outputs must saturate to the maximum"
    assert int(np.count_nonzero(must_sat)) <= sat.total <= int(np.count_nonzero(~cannot_sat))
    assert set(sat) <= {unit.name}
    checked = cannot_sat | (out < o.max_raw)
    assert checked.sum() > 0.5 * len(x)
    err = o.to_float(out[checked]) - r[checked]
    bound = unit.error_bound(v[checked])
    worst = float(np.max(np.abs(err) / bound))
    assert worst <= 1 + SLACK, f"{label}: |out - 1/sqrt(v)| exceeds the stated bound (ratio {worst:.4f})"
    rel = np.abs(err) / r[checked]
    assert rel.max() <= unit.max_relative_error_bound() * (1 + SLACK)
    # the internal result (before the output rounding) against the internal bound
    internal = unit.internal(x[checked])
    irel = np.abs(internal / r[checked] - 1)
    assert irel.max() <= E * (1 + SLACK) + 1e-15, f"{label}: internal error {irel.max():.3e} > bound {E:.3e}"
    lsb_err = np.abs(err) / o.lsb
    bias = float(np.mean(err) / o.lsb)
    # bias: where the output rounding dominates (internal error below half an LSB) the mean error is a
    # few hundredths of an LSB (ties-up rounding of few dropped bits); where the seed or Newton error
    # dominates, its mean is a small part of the bound (Newton approaches from below: eps' <= 0)
    ibias = float(np.mean(internal / r[checked] - 1))
    if E * r[checked].max() <= 0.5 * o.lsb:
        assert abs(bias) <= 0.05, f"{label}: bias {bias:.4f} LSB"
    else:
        assert abs(ibias) <= 0.2 * E, f"{label}: mean relative error {ibias:.3e} vs bound {E:.3e}"
    _row(f"{label:<34}", f"sb={unit.seed_bits:2d} N={unit.newton_steps}", f"n={len(x):8d}",
         f"int.rel max {irel.max():.2e} <= {E:.2e}",
         f"rel max {rel.max():.2e} <= {unit.max_relative_error_bound():.2e}",
         f"max |err| {lsb_err.max():9.3f} LSB (err/bound {worst:.3f})", f"bias {bias:+.4f} LSB",
         f"mean rel {ibias:+.1e}", f"sat {sat.total}")
    return {"irel": float(irel.max()), "E": E, "lsb": float(lsb_err.max()), "bias": bias, "sat": sat.total}


RSQRT_EXHAUSTIVE = [
    # in, out, seed_bits, newton_steps
    (UQ(4, 16), SQ(6, 12), 9, 1),         # 20-bit input, 18-bit output (the narrow preset's unit)
    (UQ(4, 16), SQ(6, 12), 6, 2),
    (UQ(4, 16), SQ(6, 12), 12, 0),
    (UQ(4, 16), SQ(6, 12), 3, 3),
    (SQ(8, 12), UQ(2, 22), 9, 1),         # 24-bit output: one Newton step from 9 seed bits is ~17 bits
    (SQ(8, 12), UQ(2, 22), 10, 2),
    (SQ(8, 12), UQ(2, 22), 4, 0),         # seed only: ~2^-4 relative error
    (UQ(8, 8), SQ(6, 12), 9, 1),          # 16-bit input
    (SQ(-3, 19), UQ(8, 10), 7, 1),        # 16-bit input with negative integer bits: values < 1/16
    (UQ(6, 10), SQ(-1, 19), 9, 2),        # 16-bit input, output with negative integer bits (< 1/4)
]


@pytest.mark.parametrize("ins,outs,sb,nw", RSQRT_EXHAUSTIVE,
                         ids=[f"{i}->{o}-sb{s}-N{n}" for i, o, s, n in RSQRT_EXHAUSTIVE])
def test_rsqrt_exhaustive(ins, outs, sb, nw):
    unit = Rsqrt(ins, outs, seed_bits=sb, newton_steps=nw)
    x = np.arange(1, ins.max_raw + 1, dtype=np.int64)
    stats = _rsqrt_check(unit, x, f"rsqrt {ins}->{outs}")
    # the analysis is not vacuous: the measured internal error reaches a fair part of the bound
    assert stats["irel"] >= stats["E"] / 8


def test_rsqrt_bound_follows_newton_convergence():
    """Each Newton step roughly squares the seed's relative error (E -> 3/2 E^2) until rounding dominates."""
    ins, outs = UQ(4, 16), UQ(2, 30)
    E0 = Rsqrt(ins, outs, seed_bits=6, newton_steps=0).internal_relative_error_bound()
    E1 = Rsqrt(ins, outs, seed_bits=6, newton_steps=1).internal_relative_error_bound()
    assert 2 ** -7 < E0 < 2 ** -5
    assert E1 == pytest.approx(1.5 * E0 ** 2, rel=0.1)
    x = np.arange(1, ins.max_raw + 1, 7, dtype=np.int64)
    for nw in range(4):
        u = Rsqrt(ins, outs, seed_bits=6, newton_steps=nw)
        measured = float(np.max(np.abs(u.internal(x) * np.sqrt(ins.to_float(x)) - 1)))
        assert measured <= u.internal_relative_error_bound() * (1 + SLACK)
        if nw:
            assert measured >= u.internal_relative_error_bound() / 8


def _random_inputs(shape, n, seed):
    """Half uniform over the raw range, half log-uniform (uniform bit length, then uniform)."""
    rng = np.random.default_rng(seed)
    top = shape.max_raw
    uni = rng.integers(1, top, n // 2, endpoint=True)
    bits = rng.integers(1, top.bit_length() + 1, n - n // 2)
    lo = np.int64(1) << (bits - 1)
    logu = np.minimum(lo + rng.integers(0, lo, endpoint=False), top)
    return np.concatenate([uni, logu, [1, 2, 3, top - 1, top]]).astype(np.int64)


RSQRT_RANDOM_32 = [
    (UQ(16, 16), UQ(9, 23), 10, 2),        # no output saturation: 1/sqrt(v) in [2^-8, 2^8]
    (UQ(16, 16), UQ(9, 23), 9, 1),
    (SQ(12, 20), SQ(4, 28), 10, 2),        # saturates for v < 1/64
    (SQ(-3, 35), UQ(12, 20), 12, 1),       # a squared-length-like input format
]


@pytest.mark.parametrize("ins,outs,sb,nw", RSQRT_RANDOM_32, ids=[f"{i}->{o}-sb{s}-N{n}" for i, o, s, n in RSQRT_RANDOM_32])
def test_rsqrt_random_32bit(ins, outs, sb, nw):
    unit = Rsqrt(ins, outs, seed_bits=sb, newton_steps=nw)
    assert unit.M == 34 and unit.Y == 34     # 36-bit iterates: the Newton products are wider than int64
    x = _random_inputs(ins, 1_000_000, seed=sb * 10 + nw)
    _rsqrt_check(unit, x, f"rsqrt {ins}->{outs} random")


def test_rsqrt_edge_cases():
    ins, outs = UQ(4, 16), SQ(6, 12)
    unit = Rsqrt(ins, outs, seed_bits=9, newton_steps=1)
    E = unit.internal_relative_error_bound()
    # x = 1: v = 2^-16, 1/sqrt(v) = 256 does not fit SQ(6, 12) (max 32): saturates, counted
    sat = Saturations()
    assert unit(np.array([1]), sat)[0] == outs.max_raw and sat == {"rsqrt": 1}
    # powers of two: where 1/sqrt(v) is representable and the internal error is below half an LSB,
    # the output is exact
    j = np.arange(0, 20)
    x = np.int64(1) << j
    sat = Saturations()
    out = unit(x, sat)
    r = Rsqrt.reference(ins.to_float(x))
    must = r * (1 - E) - 0.5 * outs.lsb > outs.max_value
    fits = r * (1 + E) + 0.5 * outs.lsb <= outs.max_value
    assert must.sum() >= 6 and np.all(out[must] == outs.max_raw)
    assert must.sum() <= sat.total <= (~fits).sum()
    exact = fits & ((16 - j) % 2 == 0) & (E * r < 0.5 * outs.lsb)
    assert exact.sum() >= 6
    assert np.array_equal(outs.to_float(out[exact]), r[exact])
    assert np.all(np.abs(outs.to_float(out[fits]) - r[fits]) <= unit.error_bound(ins.to_float(x[fits])))
    # the largest input: v = 16 - 2^-16, 1/sqrt(v) just above 1/4
    top = np.array([ins.max_raw])
    got = outs.to_float(unit(top))[0]
    assert abs(got - Rsqrt.reference(ins.max_value)) <= unit.error_bound(ins.max_value)
    # zero and negative inputs (a signed input format): the maximum, one saturation each
    sunit = Rsqrt(SQ(8, 12), SQ(6, 12), name="inv_l")
    sat = Saturations()
    out = sunit(np.array([0, -1, SQ(8, 12).min_raw, 4096]), sat)
    assert list(out[:3]) == [SQ(6, 12).max_raw] * 3 and out[3] == 1 << 12
    assert sat == {"inv_l": 3}
    # no counting object: same outputs
    assert np.array_equal(sunit(np.array([0, -1, 4096])), out[[0, 1, 3]])
    # shapes are preserved
    assert unit(np.full((3, 2), 1 << 16)).shape == (3, 2)
    # inputs outside the input format are a usage error
    with pytest.raises(ValueError, match="outside"):
        unit(np.array([1 << 20]))
    with pytest.raises(ValueError, match="integers"):
        unit(np.array([1.0]))


def test_rsqrt_output_overflow_saturates_and_counts():
    """Every input whose 1/sqrt exceeds the output range by more than the error saturates, counted once."""
    ins, outs = UQ(8, 8), UQ(2, 14)             # 1/sqrt(v) >= 4 for v <= 1/16 (raw <= 16)
    unit = Rsqrt(ins, outs, seed_bits=8, newton_steps=1, name="finv")
    x = np.arange(1, 64, dtype=np.int64)
    sat = Saturations()
    out = unit(x, sat)
    r = Rsqrt.reference(ins.to_float(x))
    bound = unit.error_bound(ins.to_float(x))
    over = r - bound > outs.max_value
    fits = r + bound <= outs.max_value
    assert over.sum() == 15 and fits.sum() == 63 - 16               # raw 16: 1/sqrt(v) = 4, either
    assert np.all(out[over] == outs.max_raw)
    assert over.sum() <= sat["finv"] <= (~fits).sum() and set(sat) == {"finv"}
    # left shifts at the output (needed only by outputs that overflow when guard_bits >= 1): inputs
    # below 1 and an output format below 2^-8; shifts of up to 41 bits, no int64 overflow
    tiny = Rsqrt(UQ(0, 32), UQ(-8, 40), seed_bits=9, newton_steps=1)
    x = np.array([1, 2, 3, 1 << 20, (1 << 32) - 1])
    sat = Saturations()
    assert np.all(tiny(x, sat) == UQ(-8, 40).max_raw) and sat.total == len(x)


def test_rsqrt_without_guard_bits():
    for ins, outs in ((UQ(4, 16), SQ(6, 12)), (UQ(6, 10), SQ(-1, 19))):
        unit = Rsqrt(ins, outs, seed_bits=9, newton_steps=2, guard_bits=0)
        assert unit.M == outs.width
        _rsqrt_check(unit, np.arange(1, ins.max_raw + 1, dtype=np.int64), f"rsqrt {ins}->{outs} guard 0")


@pytest.mark.parametrize("kwargs,match", [
    (dict(seed_bits=2), "seed_bits"), (dict(seed_bits=13), "seed_bits"), (dict(seed_bits=9.0), "seed_bits"),
    (dict(newton_steps=4), "newton_steps"), (dict(newton_steps=-1), "newton_steps"),
    (dict(guard_bits=-1), "guard_bits"), (dict(guard_bits=9), "guard_bits"),
])
def test_rsqrt_rejects_bad_arguments(kwargs, match):
    with pytest.raises(ValueError, match=match):
        Rsqrt(UQ(4, 16), SQ(6, 12), **kwargs)


def test_rsqrt_rejects_bad_shapes():
    with pytest.raises(ValueError, match="at most 32"):
        Rsqrt(UQ(4, 30), SQ(6, 12))
    with pytest.raises(ValueError, match="at most 32"):
        Rsqrt(UQ(4, 16), SQ(6, 27))
    with pytest.raises(ValueError, match="Shape"):
        Rsqrt("UQ(4, 16)", SQ(6, 12))
    with pytest.raises(ValueError, match="narrower than seed_bits"):
        Rsqrt(UQ(4, 16), SQ(2, 4), seed_bits=12, guard_bits=2)


# ================================================================================================ damper

def _damper_a_priori(unit: DamperTable) -> dict:
    """The class docstring's bounds from the parameters and formats alone (not the unit's constants):
    |K_q/K - 1| <= 2^-scale_bits, the offset's rounding <= 2^-scale_bits input LSBs, the position's
    rounding <= 2^-(P+1) segments."""
    h = (unit.f2 - unit.f1) / (1 << unit.S)
    sb = unit.scale_bits
    df = (unit.f2 - unit.f1) * 2.0 ** -sb + unit.f_shape.lsb * 2.0 ** -sb + h * 2.0 ** -(unit.P + 1)
    B, c1 = math.log(unit.c_max / unit.c_min) / (unit.f2 - unit.f1), unit.c1
    u = np.linspace(unit.c_min, unit.c_max, 200001)            # dense: max|g'|, max|g''| of 1/(c1 + c2)
    d1 = float(np.max(B * u / (c1 + u) ** 2)) * 1.001
    d2 = float(np.max(np.abs(B * B * u * (u - c1) / (c1 + u) ** 3))) * 1.001
    c2 = h * h / 8 * B * B * unit.c_max + B * unit.c_max * df + unit.c2_shape.lsb
    return {"position": df, "c2": c2, "c12": c2 + 0.5 * unit.c2_shape.lsb,
            "inv": h * h / 8 * d2 + d1 * df + unit.inv_shape.lsb}


def _damper_check(unit: DamperTable, label: str, valid_from: float = -1.0):
    """Exhaustive over every non-negative input; elements with f < valid_from may use clamped entries."""
    stated, prior = unit.error_bounds(), _damper_a_priori(unit)
    for q in ("position", "c2", "c12", "inv"):
        assert stated[q] <= prior[q] * (1 + SLACK), f"{label}: stated {q} bound {stated[q]:.3e} > {prior[q]:.3e}"
    fs = unit.f_shape
    f_raw = np.arange(0, fs.max_raw + 1, dtype=np.int64)
    sat = Saturations()
    c2, c12, inv = unit(f_raw, sat)
    for a in (c2, c12, inv):
        assert a.dtype == np.int64 and a.shape == f_raw.shape
    f = fs.to_float(f_raw)
    rc2, rc12, rinv = unit.reference(f)
    b = unit.error_bounds()
    cs, ish = unit.c2_shape, unit.inv_shape
    # monotone: c2 and c1 + c2 non-increasing, 1/(c1 + c2) non-decreasing in f
    assert np.all(np.diff(c2) <= 0) and np.all(np.diff(c12) <= 0) and np.all(np.diff(inv) >= 0)
    # the flat pieces are exact
    lo, hi = f <= unit.f1, f >= unit.f2
    c_max_raw = cs.from_float(unit.c_max)
    c_min_raw = cs.from_float(unit.c_min)
    assert lo.any()
    assert np.all(c2[lo] == c_max_raw)
    assert np.all(c2[hi] == c_min_raw)
    assert np.all(inv[lo] == ish.from_float(1 / (unit.c1 + unit.c_max)))
    assert np.all(inv[hi] == ish.from_float(1 / (unit.c1 + unit.c_min)))
    # errors against the exact formulas, where no clamped table entry can be involved
    ok = f >= valid_from
    rows = {}
    for q, out, ref, shape in (("c2", c2, rc2, cs), ("c12", c12, rc12, cs), ("inv", inv, rinv, ish)):
        fits = ok & (ref + b[q] <= shape.max_value)         # c12 may saturate where c1 + c2 is too big
        err = shape.to_float(out[fits]) - ref[fits]
        worst = float(np.max(np.abs(err))) if fits.any() else 0.0
        assert worst <= b[q] * (1 + SLACK), f"{label} {q}: max error {worst:.3e} > bound {b[q]:.3e}"
        mid = fits & (f > unit.f1) & (f < unit.f2)
        bias = float(np.mean(shape.to_float(out[mid]) - ref[mid]) / shape.lsb) if mid.any() else 0.0
        assert abs(bias) <= b[q] / shape.lsb
        rows[q] = (worst, worst / shape.lsb, b[q], b[q] / shape.lsb, bias, int(fits.sum()))
    # c12 is c1 + c2: exactly c1 (rounded) + c2 where it does not saturate, within 1/2 LSB of c1 + c2
    unsat = c12 < cs.max_raw
    assert np.all(c12[unsat] - c2[unsat] == cs.from_float(unit.c1))
    assert np.all(np.abs(cs.to_float(c12[unsat]) - (unit.c1 + cs.to_float(c2[unsat]))) <= 0.5 * cs.lsb)
    for q, (worst, wl, bq, bl, bias, n) in rows.items():
        _row(f"{label:<40}", f"S={unit.S:2d}", f"{q:<4}", f"n={n:7d}", f"max |err| {worst:.3e} = {wl:7.3f} LSB",
             f"bound {bq:.3e} = {bl:7.3f} LSB", f"bias {bias:+.4f} LSB", f"sat {sat.total}")
    return sat, (c2, c12, inv), f


DAMPER_CASES = {
    # label: (f, c2, inv, c1, c_min, c_max, f1, f2, S, extra kwargs)
    "scene-like c_max/c_min=10": (UQ(-3, 21), SQ(5, 13), SQ(2, 16), 2.0, 0.5, 5.0, 0.01, 0.05, 6, {}),
    "series c1=0 ratio 1000 wide": (SQ(-2, 20), SQ(11, 16), SQ(3, 24), 0.0, 0.5, 500.0, 0.01, 0.05, 10, {}),
    "ratio 1000 S=8 narrow": (SQ(-2, 20), SQ(11, 7), SQ(3, 15), 0.0, 0.5, 500.0, 0.01, 0.05, 8, {}),
    "16-bit f, c1 inside [cmin, cmax]": (SQ(4, 12), SQ(6, 12), SQ(0, 18), 3.0, 1.0, 12.0, 0.5, 3.0, 8, {}),
    "constant c_min=c_max": (SQ(4, 12), SQ(8, 10), SQ(1, 17), 1.5, 3.0, 3.0, 0.0, 1.0, 6, {}),
    "left-shifted position, f1=0": (UQ(12, 4), SQ(7, 11), SQ(0, 18), 1.0, 2.0, 20.0, 0.0, 100.0, 8,
                                    dict(frac_bits=24, scale_bits=16)),
    "f2 beyond the f range": (UQ(2, 16), SQ(4, 14), SQ(1, 17), 0.5, 1.0, 4.0, 1.0, 9.0, 8, {}),
}


@pytest.mark.parametrize("label", list(DAMPER_CASES))
def test_damper_exhaustive(label):
    fsh, c2s, invs, c1, cmin, cmax, f1, f2, S, kw = DAMPER_CASES[label]
    unit = DamperTable(fsh, c2s, invs, c1, cmin, cmax, f1, f2, segments_log2=S, **kw)
    if label == "left-shifted position, f1=0":
        assert unit.pos_shift < 0
    sat, _, _ = _damper_check(unit, label)
    assert sat.total == 0


def test_damper_interpolation_error_dominates_and_shrinks_with_segments():
    """The bound's interpolation term is h^2/8 max|g''|; the measured error follows it (4x per segment doubling)."""
    args = (UQ(-3, 21), SQ(11, 16), SQ(3, 24), 0.0, 0.5, 500.0, 0.01, 0.05)
    f_raw = np.arange(0, UQ(-3, 21).max_raw + 1, dtype=np.int64)
    f = UQ(-3, 21).to_float(f_raw)
    errs = []
    for S in (4, 5, 6):
        unit = DamperTable(*args, segments_log2=S)
        c2, _, _ = unit(f_raw)
        err = float(np.max(np.abs(SQ(11, 16).to_float(c2) - unit.reference(f)[0])))
        b = unit.error_bounds()
        assert b["interp_c2"] > 0.5 * b["c2"]
        assert 0.5 * b["interp_c2"] <= err <= b["c2"]
        errs.append(err)
    assert errs[0] / errs[1] == pytest.approx(4, rel=0.15) and errs[1] / errs[2] == pytest.approx(4, rel=0.15)


def test_damper_c12_saturates_and_counts():
    """c1 + c2 beyond the c2 format saturates (counted); c2 itself and the inverse do not."""
    fsh, cs = UQ(2, 16), SQ(4, 14)                  # c2 format max ~8
    unit = DamperTable(fsh, cs, SQ(1, 17), 4.0, 1.0, 6.0, 0.5, 2.5, segments_log2=8)
    sat, (c2, c12, inv), f = _damper_check(unit, "c12 saturates (c1 + c_max = 10 > 8)")
    _, rc12, _ = unit.reference(f)
    b = unit.error_bounds()["c12"]
    must = rc12 - b > cs.max_value
    cannot = rc12 + b <= cs.max_value
    assert must.sum() > 1000
    assert np.all(c12[must] == cs.max_raw)
    assert must.sum() <= sat["damper"] <= (~cannot).sum()
    assert set(sat) == {"damper"}


def test_damper_clamped_table_entries_are_counted():
    """c_max beyond the c2 format (and 1/c_min beyond the inverse's): clamped ROM words, counted when used."""
    fsh, cs, ish = UQ(2, 16), SQ(3, 15), SQ(1, 17)   # c2 max ~4, inverse max ~1
    c1, cmin, cmax, f1, f2 = 0.0, 1.0, 6.0, 0.25, 1.25
    unit = DamperTable(fsh, cs, ish, c1, cmin, cmax, f1, f2, segments_log2=8, name="damper0")
    S = 8
    h = (f2 - f1) / (1 << S)
    fj = f1 + np.arange((1 << S) + 1) * h
    c2j = cmax * np.exp(-math.log(cmax / cmin) * (fj - f1) / (f2 - f1))
    clipped_c2 = np.floor(c2j * 2 ** cs.f + 0.5) > cs.max_raw
    clipped_inv = np.floor(1 / (c1 + c2j) * 2 ** ish.f + 0.5) > ish.max_raw
    assert clipped_c2[0] and not clipped_c2[-1] and clipped_inv[-1] and not clipped_inv[0]
    df = unit.position_error_bound()
    last_c2 = fj[np.flatnonzero(clipped_c2)[-1]]
    first_inv = fj[np.flatnonzero(clipped_inv)[0]]
    fraw = np.arange(0, fsh.max_raw + 1, dtype=np.int64)
    sat = Saturations()
    c2, c12, inv = unit(fraw, sat)
    f = fsh.to_float(fraw)
    rc2, rc12, rinv = unit.reference(f)
    b = unit.error_bounds()
    # certain: the exact interpolant would leave the format; possible: an element near a clamped entry
    must = (rc2 - b["c2"] > cs.max_value).sum() + (rinv - b["inv"] > ish.max_value).sum()
    can = (f < last_c2 + h + df).sum() + (f > first_inv - h - df).sum()
    assert must > 1000
    assert must <= sat["damper0"] <= can
    assert np.all(c2 <= cs.max_raw) and np.all(inv <= ish.max_raw)
    assert np.all(c2[f <= f1] == cs.max_raw) and np.all(inv[f >= f2] == ish.max_raw)
    # away from clamped entries the bounds hold
    away = (f >= last_c2 + h + df) & (f <= first_inv - h - df)
    assert away.sum() > 1000
    assert np.all(np.abs(cs.to_float(c2[away]) - rc2[away]) <= b["c2"] * (1 + SLACK))
    assert np.all(np.abs(ish.to_float(inv[away]) - rinv[away]) <= b["inv"] * (1 + SLACK))
    # monotone even where clamped
    assert np.all(np.diff(c2) <= 0) and np.all(np.diff(inv) >= 0)


def test_damper_f1_beyond_input_range_is_constant():
    unit = DamperTable(UQ(2, 14), SQ(4, 14), SQ(1, 17), 1.0, 0.5, 5.0, 10.0, 20.0, segments_log2=4)
    c2, c12, inv = unit(np.arange(0, UQ(2, 14).max_raw + 1))
    assert np.all(c2 == SQ(4, 14).from_float(5.0))
    assert np.all(c12 == SQ(4, 14).from_float(6.0))
    assert np.all(inv == SQ(1, 17).from_float(1 / 6))


def test_damper_reference_pieces():
    unit = DamperTable(UQ(2, 16), SQ(5, 13), SQ(2, 16), 2.0, 0.5, 5.0, 0.5, 1.5)
    c2, c12, inv = unit.reference(np.array([0.0, 0.5, 1.0, 1.5, 3.0]))
    assert c2[0] == c2[1] == 5.0 and c2[3] == c2[4] == 0.5
    assert c2[2] == pytest.approx(math.sqrt(5.0 * 0.5))                 # geometric mean at the middle
    assert c2[2] == pytest.approx(unit.A * math.exp(-unit.B * 1.0))
    assert np.allclose(c12, 2.0 + c2) and np.allclose(inv, 1 / (2.0 + c2))


@pytest.mark.parametrize("kwargs,match", [
    (dict(f1=0.05, f2=0.01), "f1 < f2"), (dict(f1=-0.1), "0 <= f1"), (dict(c_min=0.0), "c_min"),
    (dict(c_min=6.0), "c_min <= c_max"), (dict(c1=-1.0), "c1 >= 0"), (dict(c1=float("nan")), "finite"),
    (dict(c_max="big"), "real number"), (dict(f2=0.01 + 1e-9), "below one LSB"),
    (dict(segments_log2=0), "segments_log2"), (dict(segments_log2=13), "segments_log2"),
    (dict(frac_bits=0), "frac_bits"), (dict(scale_bits=30), "scale_bits"),
    (dict(f_shape=UQ(4, 29)), "at most 32"), (dict(inv_shape=1.0), "Shape"),
])
def test_damper_rejects_bad_arguments(kwargs, match):
    args = dict(f_shape=UQ(-3, 21), c2_shape=SQ(5, 13), inv_shape=SQ(2, 16), c1=2.0, c_min=0.5, c_max=5.0,
                f1=0.01, f2=0.05)
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        DamperTable(**args)
