"""Fixed-point values for Amaranth (hw/rtl_fixed.py) equal the bit-true arithmetic (hw/fixed.py)."""
from __future__ import annotations

import numpy as np
import pytest
from amaranth.hdl import Module, Signal
from amaranth.sim import Simulator

from hw.fixed import SQ, UQ, Saturations, add, mul
from hw.rtl_fixed import Const, FixedValue, as_shape

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
