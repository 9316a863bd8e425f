"""Function units (hw/funcunits.py) against float64 references: exhaustive over every input of 16- to
20-bit formats, dense random (3 million inputs) for 24- to 32-bit formats, and edge cases.

Every check compares the unit's output with 1/sqrt(v), or with the damper's curves written out here
independently (Phi = G^-1 with its companion w' = H(T), Psi = H^-1; MODEL.md section 2 v2; inverted by
the test's own Newton solve), never with the unit itself, under the bounds the units state. The golden
element's exact solves (golden.elements.ElementParams.phi / psi) are checked against the same curves
with hypothesis (seeded) over random materials. `pytest -s` prints a table per configuration: max
|error| (relative for rsqrt) and in output LSBs, bias (mean error in LSBs) and the stated bounds.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from golden.elements import DamperLaw
from hw.datapath import phi_curve, psi_curve
from hw.fixed import SQ, UQ, Saturations
from hw.funcunits import InverseTable, OddCurve, Rsqrt, RsqrtTable, _bit_length, _mul_shift_round

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
    a_priori = _rsqrt_table_a_priori_bound(unit) if isinstance(unit, RsqrtTable) else _rsqrt_a_priori_bound(unit)
    assert unit.internal_relative_error_bound() <= a_priori * (1 + SLACK)
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
    elif isinstance(unit, RsqrtTable):
        # the centred line's error spans [-G/2, G/2] over a segment (G the chord's gap) with mean +G/6: at
        # most a third of the bound where the line dominates, less where the roundings do
        assert abs(ibias) <= E / 3, f"{label}: mean relative error {ibias:.3e} vs bound {E:.3e}"
    else:
        assert abs(ibias) <= 0.2 * E, f"{label}: mean relative error {ibias:.3e} vs bound {E:.3e}"
    config = f"S={unit.S:2d} g={unit.guard_bits}" if isinstance(unit, RsqrtTable) else \
        f"sb={unit.seed_bits:2d} N={unit.newton_steps}"
    _row(f"{label:<34}", config, f"n={len(x):8d}",
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


# ============================================================================================ RsqrtTable

def _rsqrt_table_a_priori_bound(unit: RsqrtTable) -> float:
    """The RsqrtTable docstring's bound from S, Y and the formats alone (not the unit's table):
    h^2/16 max|f''| relative, (3/16) 2^-2S (1 + 2^(1-S))^(1/2), plus 5/4 2^-Y of roundings."""
    S, Y, M = unit.S, unit.Y, unit.M
    E = 3 / 16 * 2.0 ** (-2 * S) * math.sqrt(1 + 2.0 ** (1 - S)) + 1.25 * 2.0 ** -Y
    k_max = int(unit.in_shape.max_raw).bit_length() + 1
    eps_m = 1 / math.sqrt(1 - 2.0 ** (1 - M)) - 1 if k_max > M else 0.0
    return (1 + E) * (1 + eps_m) - 1


RSQRT_TABLE_EXHAUSTIVE = [
    # in, out, segments_log2, guard_bits
    (UQ(4, 16), SQ(6, 12), 10, 4),        # 20-bit input, 18-bit output, the presets' table
    (UQ(4, 16), SQ(6, 12), 6, 2),         # few segments: the interpolation error dominates
    (SQ(8, 12), UQ(2, 22), 10, 2),        # 24-bit output
    (UQ(8, 8), SQ(6, 12), 8, 4),          # 16-bit input
    (SQ(-3, 19), UQ(8, 10), 7, 1),        # input values < 1/16
    (UQ(6, 10), SQ(-1, 19), 9, 2),        # output values < 1/4
    (UQ(4, 8), UQ(2, 8), 4, 0),           # M = 10 < 13 = k_max: mantissa rounding
    (UQ(4, 4), UQ(2, 4), 5, 0),           # M = S + 1: F = 1, the lower octave's fraction is always 0
    (UQ(8, 8), UQ(2, 12), 2, 2),          # one segment per octave
    # the formats of the scenes' 1/sqrt units under the narrow and medium presets (S = 10, 4 guard bits):
    # every positive input
    (SQ(-3, 21), SQ(8, 10), 10, 4),       # press-2d-rheological inv_l and tinv
    (SQ(0, 18), SQ(7, 11), 10, 4),        # press-3d-rheological inv_l
    (SQ(-6, 24), SQ(9, 9), 10, 4),        # press-3d-rheological tinv2
    (SQ(-2, 20), SQ(8, 10), 10, 4),       # friction-3d-mu03 inv_l
    (SQ(-10, 28), SQ(12, 6), 10, 4),      # friction-3d-mu03 tinv2
    (SQ(-7, 25), SQ(11, 7), 10, 4),       # friction-3d-mu03 cinv2
    (SQ(-33, 51), SQ(32, -14), 10, 4),    # friction-3d-mu03 finv
]


@pytest.mark.parametrize("ins,outs,S,g", RSQRT_TABLE_EXHAUSTIVE,
                         ids=[f"{i}->{o}-S{s}-g{g}" for i, o, s, g in RSQRT_TABLE_EXHAUSTIVE])
def test_rsqrt_table_exhaustive(ins, outs, S, g):
    unit = RsqrtTable(ins, outs, segments_log2=S, guard_bits=g)
    x = np.arange(1, ins.max_raw + 1, dtype=np.int64)
    stats = _rsqrt_check(unit, x, f"rsqrt table {ins}->{outs}")
    # the analysis is not vacuous: the measured internal error reaches a fair part of the bound
    assert stats["irel"] >= stats["E"] / 2


def test_rsqrt_table_preset_configuration():
    """The narrow and medium presets' table (S = 10, 4 guard bits) on an 18-bit output: 1,024 words of
    35 bits (c0 - 2^Y in 22 bits and a 13-bit slope: two 1024 x 18 block RAMs), a 12 x 13-bit product,
    a bound below 2^-21 relative (the h^2/16 max|f''| term 1.8e-7), far below the Newton step's."""
    unit = RsqrtTable(UQ(4, 16), SQ(6, 12))
    assert (unit.S, unit.guard_bits, unit.M, unit.Y, unit.F) == (10, 4, 22, 22, 12)
    assert len(unit.c0) == 1024 and unit.to_dict()["rom_word_bits"] == 35 <= 36
    assert np.all((unit.c0 >= 1 << unit.Y) & (unit.c0 < 1 << (unit.Y + 1)))
    assert int(unit.slope.min()) > 0 and int(unit.slope.max()).bit_length() == 13
    E = unit.internal_relative_error_bound()
    assert E <= 2.0 ** -21 and E <= _rsqrt_table_a_priori_bound(unit)
    assert 3 / 16 * 2.0 ** -20 == pytest.approx(1.79e-7, rel=1e-2)
    assert Rsqrt(UQ(4, 16), SQ(6, 12), seed_bits=9, newton_steps=1).internal_relative_error_bound() > 10 * E


def test_rsqrt_table_error_shrinks_4x_per_segment_bit():
    """With the roundings made negligible (Y = 30), the error is the centred line's h^2/16 max|f''|:
    a quarter for every bit of S, close to the a-priori (3/16) 2^-2S."""
    ins, outs = UQ(4, 16), UQ(2, 24)
    x = np.arange(1, ins.max_raw + 1, 3, dtype=np.int64)
    r = Rsqrt.reference(ins.to_float(x))
    errs = []
    for S in (5, 6, 7, 8):
        unit = RsqrtTable(ins, outs, segments_log2=S, guard_bits=6)
        errs.append(float(np.max(np.abs(unit.internal(x) / r - 1))))
        assert errs[-1] <= unit.internal_relative_error_bound() * (1 + SLACK)
        assert errs[-1] == pytest.approx(3 / 16 * 2.0 ** (-2 * S), rel=0.1)
    assert np.allclose(np.array(errs[:-1]) / np.array(errs[1:]), 4.0, rtol=0.05)


def test_rsqrt_table_edge_cases():
    ins, outs = UQ(4, 16), SQ(6, 12)
    unit = RsqrtTable(ins, outs, name="inv_l")
    E = unit.internal_relative_error_bound()
    # x = 1: v = 2^-16, 1/sqrt(v) = 256 does not fit SQ(6, 12) (max 32): saturates, counted
    sat = Saturations()
    assert unit(np.array([1]), sat)[0] == outs.max_raw and sat == {"inv_l": 1}
    # powers of four have the mantissa 1/4 (the first segment's start, the clamped word) or 1/2: the
    # output is exact where 1/sqrt(v) is representable and the internal error below half an LSB
    j = np.arange(0, 20)
    x = np.int64(1) << j
    out = unit(x)
    r = Rsqrt.reference(ins.to_float(x))
    fits = r * (1 + E) + 0.5 * outs.lsb <= outs.max_value
    exact = fits & ((16 - j) % 2 == 0) & (E * r < 0.5 * outs.lsb)
    assert exact.sum() >= 6
    assert np.array_equal(outs.to_float(out[exact]), r[exact])
    # zero and negative inputs (a signed input format): the maximum, one saturation each
    sunit = RsqrtTable(SQ(8, 12), SQ(6, 12), name="inv_l")
    sat = Saturations()
    out = sunit(np.array([0, -1, SQ(8, 12).min_raw, 4096]), sat)
    assert list(out[:3]) == [SQ(6, 12).max_raw] * 3 and out[3] == 1 << 12
    assert sat == {"inv_l": 3}
    assert np.array_equal(sunit(np.array([0, -1, 4096])), out[[0, 1, 3]])
    # shapes are preserved; inputs outside the format are a usage error
    assert unit(np.full((3, 2), 1 << 16)).shape == (3, 2)
    with pytest.raises(ValueError, match="outside"):
        unit(np.array([1 << 20]))
    with pytest.raises(ValueError, match="integers"):
        unit(np.array([1.0]))
    # left output shifts (outputs that overflow) and int64 safety, as Rsqrt
    tiny = RsqrtTable(UQ(0, 32), UQ(-8, 40), segments_log2=9)
    x = np.array([1, 2, 3, 1 << 20, (1 << 32) - 1])
    sat = Saturations()
    assert np.all(tiny(x, sat) == UQ(-8, 40).max_raw) and sat.total == len(x)


@pytest.mark.parametrize("kwargs,match", [
    (dict(segments_log2=1), "segments_log2"), (dict(segments_log2=13), "segments_log2"),
    (dict(segments_log2=10.0), "segments_log2"), (dict(guard_bits=-1), "guard_bits"),
    (dict(guard_bits=9), "guard_bits"),
])
def test_rsqrt_table_rejects_bad_arguments(kwargs, match):
    with pytest.raises(ValueError, match=match):
        RsqrtTable(UQ(4, 16), SQ(6, 12), **kwargs)


def test_rsqrt_table_rejects_bad_shapes():
    with pytest.raises(ValueError, match="at most 32"):
        RsqrtTable(UQ(4, 30), SQ(6, 12))
    with pytest.raises(ValueError, match="Shape"):
        RsqrtTable("UQ(4, 16)", SQ(6, 12))
    with pytest.raises(ValueError, match="segments_log2 \\+ 1"):
        RsqrtTable(UQ(4, 16), SQ(2, 4), segments_log2=10, guard_bits=0)
    with pytest.raises(ValueError, match="no positive values"):
        RsqrtTable(SQ(1, 0), SQ(6, 12))


# ========================================================================================= inverse tables
#
# The damper's curves (MODEL.md section 2 v2) are written out here once more, independently of golden/ and
# hw/: c2 as the power c_max (c_min / c_max)^x (not A exp(-B f)), the inverse by Newton's method from the
# right end of the bracket (a convex g: the iterates descend monotonically), not by the model's bisection.
# The units under test are built from the project's curves (hw/datapath.py phi_curve / psi_curve).

@dataclass(frozen=True)
class Mat:
    """A damper beside its c1 (MODEL.md 2): G(T) = T + c1 H(T), H(T) = T / c2(|T|), the test's own code."""
    c1: float
    c_min: float
    c_max: float
    f1: float
    f2: float

    def law(self) -> DamperLaw:
        return DamperLaw(self.c1, self.c_min, self.c_max, self.f1, self.f2)

    def curve(self, kind: str) -> OddCurve:
        return phi_curve(self.law()) if kind == "phi" else psi_curve(self.law())

    @property
    def B(self) -> float:
        return math.log(self.c_max / self.c_min) / (self.f2 - self.f1)

    def c2(self, t):
        x = np.clip((np.abs(t) - self.f1) / (self.f2 - self.f1), 0.0, 1.0)
        return self.c_max * (self.c_min / self.c_max) ** x

    def H(self, t):
        return t / self.c2(t)

    def G(self, t):
        return t + self.c1 * self.H(t)

    # on [f1, f2]: 1 / c2 = e^(B (t - f1)) / c_max, so H' = (1 + B t) / c2 and H'' = B (2 + B t) / c2
    def dH(self, t):
        return (1.0 + self.B * t) / self.c2(t)

    def d2H(self, t):
        return self.B * (2.0 + self.B * t) / self.c2(t)

    def g(self, kind):
        return self.G if kind == "phi" else self.H

    def dg(self, kind):
        return (lambda t: 1.0 + self.c1 * self.dH(t)) if kind == "phi" else self.dH

    def outputs(self, kind, t):
        """The table's outputs at t: (T, w' = H(T)) for Phi, (T,) for Psi."""
        return [t, self.H(t)] if kind == "phi" else [t]

    def derivatives(self, kind, t):
        """(o', o'') of every output with respect to the input y, at t = g^-1(y) in [f1, f2]."""
        h1, h2 = self.dH(t), self.d2H(t)
        if kind == "psi":
            return [(1.0 / h1, -h2 / h1 ** 3)]
        g1 = 1.0 + self.c1 * h1                  # G' ; G'' = c1 H'', so (H'' G' - H' G'') = H''
        return [(1.0 / g1, -self.c1 * h2 / g1 ** 3), (h1 / g1, h2 / g1 ** 3)]

    def solve(self, kind, y):
        """t in [f1, f2] with g(t) = y (y in [g(f1), g(f2)]): Newton from t = f2, to float64 precision."""
        g, dg = self.g(kind), self.dg(kind)
        y = np.asarray(y, np.float64)
        t = np.full(y.shape, float(self.f2))
        act = np.arange(y.size)
        for _ in range(200):
            step = (g(t[act]) - y[act]) / dg(t[act])
            new = np.clip(t[act] - step, self.f1, self.f2)
            moved = np.abs(new - t[act]) > 4 * np.spacing(np.maximum(np.abs(new), 1e-300))
            t[act] = new
            act = act[moved]
            if act.size == 0:
                break
        assert act.size == 0, "the test's reference solve did not converge"
        return t


RHEO = Mat(0.5, 0.5, 500.0, 0.01, 0.05)          # the rheological preset, hardware-unit-like magnitudes
SERIES = Mat(0.0, 1.0, 1000.0, 0.0, 0.04)        # c1 = 0: Phi is the identity (only w' is curved); f1 = 0
INSIDE = Mat(3.0, 1.0, 12.0, 0.5, 3.0)           # c1 inside [c_min, c_max]
MILD = Mat(2.0, 0.5, 5.0, 0.01, 0.05)            # c_max / c_min = 10
STEEP = Mat(1.0, 2.0, 20.0, 0.0, 100.0)          # large inputs: the position is a left shift


def _fmt_round(value, shape):
    """The raw value nearest to a real value (ties up), clamped into the format (written out here)."""
    raw = np.floor(np.asarray(value, np.float64) * 2.0 ** shape.f + 0.5)
    return np.clip(raw, shape.min_raw, shape.max_raw).astype(np.int64)


def _inverse_a_priori(unit: InverseTable, mat: Mat, kind: str) -> list:
    """The class docstring's bound per output from the parameters and formats alone (not the unit's
    constants): |K_q/K - 1| <= 2^-scale_bits, the offset's rounding <= 2^-scale_bits input LSBs, the
    position's rounding <= 2^-(P+1) segments; o' and o'' maximised over 200001 points of [f1, f2]."""
    w = unit.y2 - unit.y1
    h = w / (1 << unit.S)
    sb = unit.scale_bits
    dy = w * 2.0 ** -sb + unit.in_shape.lsb * 2.0 ** -sb + h * 2.0 ** -(unit.P + 1)
    t = np.linspace(mat.f1, mat.f2, 200001)
    out = []
    for (d1, d2), shape in zip(mat.derivatives(kind, t), unit.out_shapes):
        interp = h * h / 8 * float(np.max(np.abs(d2)))
        lip = float(np.max(np.abs(d1)))
        out.append({"interp": interp, "lipschitz": lip, "position": dy,
                    "total": 1.05 * (interp + lip * dy) + shape.lsb})
    return out


def _inverse_check(unit: InverseTable, mat: Mat, kind: str, y_raw: np.ndarray, label: str) -> list:
    """Check the unit at the raw magnitudes y_raw against the test's reference; no clipped entries.
    Returns per output (max |error|, its LSBs, the stated bound, bias in LSBs)."""
    stated, prior = unit.error_bounds(), _inverse_a_priori(unit, mat, kind)
    assert len(stated) == len(unit.out_shapes) == len(mat.outputs(kind, 0.0))
    for k, (st, pr) in enumerate(zip(stated, prior)):
        # no looser than the a-priori bound, and it covers the true curvature and slope
        assert st["total"] <= pr["total"] * (1 + SLACK), f"{label} out{k}: stated {st} > a priori {pr}"
        assert st["position"] <= pr["position"] * (1 + SLACK)
        assert st["interp"] >= pr["interp"] * (1 - 1e-6) and st["lipschitz"] >= pr["lipschitz"] * (1 - 1e-6)
    ys = unit.in_shape
    assert unit.y1 == pytest.approx(float(mat.g(kind)(mat.f1)), rel=1e-14, abs=1e-300)
    assert unit.y2 == pytest.approx(float(mat.g(kind)(mat.f2)), rel=1e-14)
    sat = Saturations()
    outs = unit(y_raw, sat)
    assert len(outs) == len(unit.out_shapes)
    for o in outs:
        assert o.dtype == np.int64 and o.shape == y_raw.shape
    assert sat.total == 0, f"{label}: {sat.total} saturations without clipped table entries"
    y = y_raw * 2.0 ** -ys.f                      # exact in float64
    # the pieces: exactly the comparisons with the real knees (raw Y1 = floor(y1 2^fy), Y2 = ceil(y2 2^fy))
    below, above = y_raw <= unit.Y1, y_raw >= unit.Y2
    assert np.array_equal(below, y <= unit.y1) and np.array_equal(above, y >= unit.y2)
    # outside [y1, y2] the unit gives the table's end entries: the outputs at t_lo = f1 and t_hi = f2
    first = [_fmt_round(v, s) for v, s in zip(mat.outputs(kind, mat.f1), unit.out_shapes)]
    last = [_fmt_round(v, s) for v, s in zip(mat.outputs(kind, mat.f2), unit.out_shapes)]
    for k, o in enumerate(outs):
        assert np.all(o[below] == first[k]), f"{label} out{k}: below y1 not the first entry"
        assert np.all(o[above] == last[k]), f"{label} out{k}: above y2 not the last entry"
    # monotone (every output increases with the magnitude)
    order = np.argsort(y_raw, kind="stable")
    for k, o in enumerate(outs):
        assert np.all(np.diff(o[order]) >= 0), f"{label} out{k}: not monotone"
    # the interpolated piece against the reference
    mid = ~below & ~above
    refs = mat.outputs(kind, mat.solve(kind, y[mid])) if mid.any() else []
    stats = []
    for k, (o, shape) in enumerate(zip(outs, unit.out_shapes)):
        bound = stated[k]["total"]
        if not mid.any():
            stats.append((0.0, 0.0, bound, 0.0))
            continue
        err = o[mid] * shape.lsb - refs[k]
        worst = float(np.max(np.abs(err)))
        bias = float(np.mean(err) / shape.lsb)
        assert worst <= bound * (1 + SLACK), f"{label} out{k}: max error {worst:.3e} > bound {bound:.3e}"
        assert abs(bias) <= bound / shape.lsb
        stats.append((worst, worst / shape.lsb, bound, bias))
        b = stated[k]
        _row(f"{label:<34}", f"{kind} out{k} ({unit.curve.outputs[k]:<5})", f"S={unit.S:2d}",
             f"n={int(mid.sum()):8d}", f"max |err| {worst:.3e} = {worst / shape.lsb:8.3f} LSB",
             f"bound {bound:.3e} = {bound / shape.lsb:8.3f} LSB (interp {b['interp'] / shape.lsb:.3g}, "
             f"position {b['lipschitz'] * b['position'] / shape.lsb:.3g})", f"bias {bias:+.4f} LSB")
    # the model's own reference agrees with the test's (a check of the test's solver as well)
    if mid.any():
        for r_model, r_test in zip(unit.reference(y[mid]), refs):
            assert np.allclose(r_model, r_test, rtol=1e-12, atol=0)
    return stats


INVERSE_EXHAUSTIVE = {
    # label: (material, curve, in_shape, out_shapes, segments_log2, extra kwargs); inputs up to 20 bits
    "rheological Phi": (RHEO, "phi", UQ(-3, 23), (SQ(-3, 21), SQ(-2, 20)), 6, {}),
    "rheological Psi": (RHEO, "psi", UQ(-3, 23), (SQ(-3, 21),), 8, {}),
    "series c1=0 Phi, f1=0": (SERIES, "phi", SQ(-3, 21), (SQ(-3, 21), SQ(-3, 21)), 5, {}),
    "series c1=0 Psi, f1=0": (SERIES, "psi", UQ(-4, 24), (SQ(-3, 21),), 10, {}),
    "c1 in [c_min, c_max] Phi 16-bit": (INSIDE, "phi", SQ(5, 11), (SQ(3, 13), SQ(3, 13)), 8, {}),
    "c1 in [c_min, c_max] Psi 16-bit": (INSIDE, "psi", UQ(2, 14), (SQ(3, 13),), 7, {}),
    "ratio 10 Phi": (MILD, "phi", UQ(-1, 21), (SQ(-3, 21), SQ(-2, 20)), 4, {}),
    "ratio 10 Psi": (MILD, "psi", UQ(-3, 23), (SQ(-3, 21),), 9, {}),
    "left-shifted position Psi": (STEEP, "psi", UQ(10, 6), (SQ(8, 10),), 8, dict(frac_bits=24, scale_bits=16)),
    "y2 beyond the input range Phi": (Mat(0.5, 1.0, 4.0, 1.0, 9.0), "phi", UQ(3, 15), (SQ(5, 13), SQ(5, 13)),
                                      8, {}),
}


@pytest.mark.parametrize("label", list(INVERSE_EXHAUSTIVE))
def test_inverse_exhaustive(label):
    mat, kind, ins, outs, S, kw = INVERSE_EXHAUSTIVE[label]
    assert ins.width <= 20
    unit = InverseTable(ins, outs, mat.curve(kind), segments_log2=S, **kw)
    assert unit.name == kind and not any(c.any() for c in unit.clips)
    if label.startswith("left-shifted"):
        assert unit.pos_shift < 0
    if label.startswith("y2 beyond"):
        assert unit.Y2 == ins.max_raw + 1
    if label.startswith("series"):
        assert unit.Y1 == 0
    y_raw = np.arange(0, ins.max_raw + 1, dtype=np.int64)
    _inverse_check(unit, mat, kind, y_raw, label)


def _dense_inputs(unit: InverseTable, n: int, seed: int) -> np.ndarray:
    """n random magnitudes (a quarter over the whole format, the rest over the table's piece), the ends,
    the thresholds and every breakpoint with their neighbourhoods."""
    s = unit.in_shape
    rng = np.random.default_rng(seed)
    lo, hi = max(unit.Y1 - 64, 0), min(unit.Y2 + 64, s.max_raw)
    j = np.arange((1 << unit.S) + 1)
    bp = np.floor((unit.y1 + j * (unit.y2 - unit.y1) / (1 << unit.S)) * 2.0 ** s.f).astype(np.int64)
    near = (bp[:, None] + np.arange(-3, 4)[None, :]).ravel()
    ends = [0, 1, 2, s.max_raw - 1, s.max_raw, *range(unit.Y1 - 3, unit.Y1 + 4), *range(unit.Y2 - 3, unit.Y2 + 4)]
    x = np.concatenate([rng.integers(0, s.max_raw, n // 4, endpoint=True),
                        rng.integers(lo, hi, n - n // 4, endpoint=True), near, ends]).astype(np.int64)
    return x[(x >= 0) & (x <= s.max_raw)]


INVERSE_DENSE = {
    # 32- and 24-bit inputs: 3 million random magnitudes each
    "rheological Phi 32-bit": (RHEO, "phi", UQ(-3, 35), (SQ(-3, 35), SQ(-2, 34)), 10),
    "rheological Psi 32-bit": (RHEO, "psi", UQ(-3, 35), (SQ(-3, 35),), 10),
    "c1 in [c_min, c_max] Phi 24-bit": (INSIDE, "phi", SQ(5, 19), (SQ(3, 21), SQ(3, 21)), 8),
    "series c1=0 Psi 28-bit": (SERIES, "psi", SQ(-3, 31), (SQ(-3, 29),), 6),
}


@pytest.mark.parametrize("label", list(INVERSE_DENSE))
def test_inverse_dense(label):
    mat, kind, ins, outs, S = INVERSE_DENSE[label]
    unit = InverseTable(ins, outs, mat.curve(kind), segments_log2=S)
    x = _dense_inputs(unit, 3_000_000, seed=S)
    _inverse_check(unit, mat, kind, x, label + " random")


def test_inverse_interpolation_error_shrinks_4x_per_segment_bit():
    """With wide outputs the bound's interpolation term h^2/8 max|o''| dominates, and the measured error
    follows it: 4x smaller per extra segment bit, for the inverse and the companion."""
    ins, outs = UQ(-3, 23), (SQ(-3, 35), SQ(-2, 34))
    y_raw = np.arange(0, ins.max_raw + 1, dtype=np.int64)
    errs = []
    for S in (4, 5, 6, 7):
        unit = InverseTable(ins, outs, RHEO.curve("phi"), segments_log2=S)
        stats = _inverse_check(unit, RHEO, "phi", y_raw, f"rheological Phi S={S} wide outputs")
        for k, b in enumerate(unit.error_bounds()):
            assert b["interp"] > 0.5 * b["total"]
            assert 0.5 * b["interp"] <= stats[k][0] <= b["total"]
        errs.append([s[0] for s in stats])
    errs = np.array(errs)
    ratios = errs[:-1] / errs[1:]
    assert np.all(np.abs(ratios - 4) <= 0.6), f"error ratios per segment bit {ratios.tolist()}"


def test_inverse_clamped_table_entries_are_counted():
    """Outputs whose formats cannot hold the top of the curve: the clamped ROM words count one saturation
    per output for every item whose interpolation uses them (the end point included)."""
    ins, fs, ws = UQ(-3, 23), SQ(-5, 23), SQ(-4, 22)        # force max ~0.031 < f2, w' max ~0.0625 < 0.1
    S = 8
    unit = InverseTable(ins, (fs, ws), RHEO.curve("phi"), segments_log2=S, name="phi0")
    # which entries cannot fit, from the test's own breakpoints
    yj = unit.y1 + np.arange((1 << S) + 1) * (unit.y2 - unit.y1) / (1 << S)
    tj = RHEO.solve("phi", yj)
    first_clip = []
    for v, shape in zip(RHEO.outputs("phi", tj), (fs, ws)):
        clipped = np.floor(v * 2.0 ** shape.f + 0.5) > shape.max_raw
        assert clipped[-1] and not clipped[0]
        assert np.all(np.diff(clipped.astype(int)) >= 0)       # a top run of entries
        first_clip.append(yj[np.flatnonzero(clipped)[0]])
    assert first_clip[0] < first_clip[1]
    y_raw = np.arange(0, ins.max_raw + 1, dtype=np.int64)
    y = y_raw * ins.lsb
    sat = Saturations()
    outs = unit(y_raw, sat)
    assert set(sat) == {"phi0"}
    b = [d["total"] for d in unit.error_bounds()]
    h, dy = (unit.y2 - unit.y1) / (1 << S), unit.position_error_bound()
    yc = np.clip(y, unit.y1, unit.y2)
    refs = RHEO.outputs("phi", RHEO.solve("phi", yc))
    # certain: even the exact output minus the bound leaves the format; possible: near a clamped entry
    must = sum(int(np.count_nonzero(r - bk > s.max_value)) for r, bk, s in zip(refs, b, (fs, ws)))
    can = sum(int(np.count_nonzero(y > yf - h - dy)) for yf in first_clip)
    assert must > 10000
    assert must <= sat["phi0"] <= can
    for o, s in zip(outs, (fs, ws)):
        assert np.all(o <= s.max_raw) and np.all(np.diff(o) >= 0)         # clamped, still monotone
        assert np.all(o[y_raw >= unit.Y2] == s.max_raw)
    # away from clamped entries the bounds hold
    for k, (o, s, r) in enumerate(zip(outs, (fs, ws), refs)):
        away = (y > unit.y1) & (y < first_clip[k] - h - dy)
        assert away.sum() > 10000
        assert np.max(np.abs(o[away] * s.lsb - r[away])) <= b[k] * (1 + SLACK)
    _row(f"{'clamped entries Phi':<34}", f"saturations {sat['phi0']} in [{must}, {can}]")


def test_inverse_y1_beyond_input_range_is_constant():
    """y1 above the largest input (Y1 = max_raw, OFF = 0): every item is below the table, its first entry."""
    mat = Mat(1.0, 0.5, 5.0, 10.0, 20.0)
    unit = InverseTable(UQ(2, 14), (SQ(5, 13), SQ(3, 15)), mat.curve("phi"), segments_log2=4)
    assert unit.Y1 == UQ(2, 14).max_raw and unit.OFF == 0
    y_raw = np.arange(0, UQ(2, 14).max_raw + 1)
    sat = Saturations()
    T, w = unit(y_raw, sat)
    assert np.all(T == 10 * 2 ** 13) and np.all(w == 2 * 2 ** 15) and sat.total == 0


def test_inverse_reference_and_end_entries():
    """The model's reference clamps into [y1, y2]; its end entries are the outputs at t_lo and t_hi; the
    series case (c1 = 0) has G(t) = t, so Phi's table holds the breakpoints themselves."""
    unit = InverseTable(UQ(-3, 23), (SQ(-3, 21), SQ(-2, 20)), RHEO.curve("phi"), segments_log2=6)
    T, w = unit.reference(np.array([0.0, unit.y1, unit.y2, 1.0]))
    assert list(T) == [0.01, 0.01, 0.05, 0.05]
    assert w[0] == pytest.approx(0.01 / 500, rel=1e-14) and w[3] == pytest.approx(0.05 / 0.5, rel=1e-14)
    assert unit.tabs[0][0] == _fmt_round(0.01, SQ(-3, 21)) and unit.tabs[0][-1] == _fmt_round(0.05, SQ(-3, 21))
    assert unit.tabs[1][0] == _fmt_round(2e-5, SQ(-2, 20)) and unit.tabs[1][-1] == _fmt_round(0.1, SQ(-2, 20))
    assert unit.y1 == pytest.approx(0.01 * (1 + 0.5 / 500), rel=1e-15)      # MODEL.md: Y1 = f1 (1 + c1/c_max)
    assert unit.y2 == pytest.approx(0.05 * (1 + 0.5 / 0.5), rel=1e-15)      #           Y2 = f2 (1 + c1/c_min)
    s = InverseTable(SQ(-3, 21), (SQ(-3, 21), SQ(-3, 21)), SERIES.curve("phi"), segments_log2=5)
    assert np.array_equal(s.tabs[0], _fmt_round(np.arange(33) * 0.04 / 32, SQ(-3, 21)))
    assert s.error_bounds()[0]["interp"] == 0.0
    ps = InverseTable(UQ(-3, 23), (SQ(-3, 21),), RHEO.curve("psi"), segments_log2=6)
    assert ps.y1 == pytest.approx(0.01 / 500, rel=1e-15) and ps.y2 == pytest.approx(0.05 / 0.5, rel=1e-15)
    # inputs are magnitudes
    with pytest.raises(ValueError, match="magnitudes"):
        s(np.array([-1, 5]))
    with pytest.raises(ValueError, match="outside"):
        unit(np.array([1 << 20]))


def _curve(**kw) -> OddCurve:
    base = phi_curve(RHEO.law())
    fields = {f: getattr(base, f) for f in ("name", "input", "g", "dg", "d2g", "t_lo", "t_hi", "outputs",
                                            "companions")}
    fields.update(kw)
    return OddCurve(**fields)


@pytest.mark.parametrize("kwargs,match", [
    (dict(in_shape=UQ(4, 29)), "at most 32"), (dict(in_shape="UQ(4, 16)"), "Shape"),
    (dict(out_shapes=(SQ(-3, 21), 1.0)), "Shape"), (dict(out_shapes=(SQ(-3, 21), SQ(4, 30))), "at most 32"),
    (dict(out_shapes=(SQ(-3, 21),)), "1 output formats for 1 inverse and 1 companions"),
    (dict(out_shapes=(SQ(-3, 21),) * 3), "3 output formats"),
    (dict(curve=RHEO.law()), "OddCurve"),
    (dict(segments_log2=0), "segments_log2"), (dict(segments_log2=13), "segments_log2"),
    (dict(segments_log2=4.0), "segments_log2"), (dict(frac_bits=0), "frac_bits"), (dict(frac_bits=25), "frac_bits"),
    (dict(scale_bits=7), "scale_bits"), (dict(scale_bits=30), "scale_bits"),
    (dict(curve=_curve(t_lo=0.05, t_hi=0.05)), "t_lo < t_hi"), (dict(curve=_curve(t_lo=0.06)), "t_lo < t_hi"),
    (dict(curve=_curve(t_lo=-0.01)), "0 <= t_lo"), (dict(curve=_curve(t_hi=float("nan"))), "finite"),
    (dict(curve=_curve(t_lo="low")), "real number"),
    (dict(curve=_curve(g=lambda t: -t)), "must increase"),
    (dict(curve=_curve(t_hi=0.01 + 1e-9)), "below one LSB"),
])
def test_inverse_rejects_bad_arguments(kwargs, match):
    args = dict(in_shape=UQ(-3, 23), out_shapes=(SQ(-3, 21), SQ(-2, 20)), curve=phi_curve(RHEO.law()))
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        InverseTable(**args)


# ---- the curve identities of the golden element (vectorised golden solves), over random materials

_materials = st.builds(
    lambda c1, log_cmin, log_ratio, f2, f1_frac: Mat(c1, 10.0 ** log_cmin, 10.0 ** (log_cmin + log_ratio),
                                                     f1_frac * f2, f2),
    st.floats(0.0, 10.0), st.floats(-3.0, 3.0), st.floats(1e-3, 4.0), st.floats(1e-3, 100.0),
    st.floats(0.0, 0.999))
_fractions = st.lists(st.floats(-3.0, 3.0, allow_subnormal=False), min_size=1, max_size=60)


def _golden_params(mat: Mat, n: int):
    from golden.elements import ElementParams
    k1, c1, a_min, a_max, L, c_min, c_max, f1, f2 = (np.full(n, float(v)) for v in
                                                      (1.0, mat.c1, 0.0, 1.0, 1.0, mat.c_min, mat.c_max, mat.f1, mat.f2))
    return ElementParams.build(k1, c1, a_min, a_max, L, c_min, c_max, f1, f2)


def _forces(mat: Mat, fractions) -> np.ndarray:
    """T over [-3 f2, 3 f2]: the drawn points and the knees, both signs."""
    base = np.array([0.0, mat.f1, mat.f2, 0.5 * (mat.f1 + mat.f2), 3 * mat.f2, np.nextafter(mat.f1, 0),
                     np.nextafter(mat.f2, np.inf)])
    T = np.concatenate([base, -base, np.asarray(fractions) * mat.f2])
    return T


@settings(derandomize=True, database=None, max_examples=300, deadline=None)
@given(_materials, _fractions)
def test_golden_phi_inverts_G(mat, fractions):
    """Phi(G(T)) = T to 1e-12 relative (golden ElementParams.phi), and its w' is H at the returned T."""
    T = _forces(mat, fractions)
    Y = mat.G(T)
    p = _golden_params(mat, T.size)
    assert p.nonlinear
    Tg, wd = p.phi(Y)
    assert np.all(np.abs(Tg - T) <= 1e-12 * np.abs(T) + 1e-300), f"{mat}: max rel {np.max(np.abs(Tg - T) / np.abs(T))}"
    assert np.all(np.abs(wd - mat.H(Tg)) <= 1e-12 * np.abs(mat.H(Tg)) + 1e-300)
    assert np.all(np.sign(Tg) == np.sign(T))


@settings(derandomize=True, database=None, max_examples=300, deadline=None)
@given(_materials, _fractions)
def test_golden_psi_inverts_H(mat, fractions):
    """Psi(H(T)) = T to 1e-12 relative (golden ElementParams.psi)."""
    T = _forces(mat, fractions)
    W = mat.H(T)
    p = _golden_params(mat, T.size)
    Tg = p.psi(W)
    assert np.all(np.abs(Tg - T) <= 1e-12 * np.abs(T) + 1e-300), f"{mat}: max rel {np.max(np.abs(Tg - T) / np.abs(T))}"
