"""LaneRom (hw/stream/lanerom.py) with dictionary-encoded fields: every field's value at every address
equals the numpy array it was given (Amaranth's simulator; the "ecp5" variant on Icarus with the DP16KD
model), for constant fields, fields of 2 and a few distinct values (dictionaries, several groups) and
fields of many distinct values (plain), unsigned and signed."""
from __future__ import annotations

import numpy as np
import pytest
from amaranth.hdl import Module, signed, unsigned
from amaranth.lib import wiring
from amaranth.lib.wiring import In, Out

from hw.stream.lanerom import DICT_ENTRIES, LaneRom
from stream_helpers import run_amaranth, run_verilog

pytestmark = pytest.mark.hdl

DEPTH, ITEMS = 300, 287          # slots beyond the items are padding


def fields(rng):
    """name -> (shape, values): the cases of the module docstring."""
    return {
        "const": (unsigned(18), np.full(ITEMS, 12345)),
        "const_neg": (signed(10), np.full(ITEMS, -7)),
        "two": (unsigned(18), rng.choice([3, 200000], ITEMS)),
        "flag": (unsigned(1), rng.integers(2, size=ITEMS)),
        "three_signed": (signed(16), rng.choice([-30000, 5, 777], ITEMS)),
        "four_a": (unsigned(12), rng.choice([1, 2, 3, 4000], ITEMS)),
        "four_b": (unsigned(12), rng.choice([9, 99, 999, 3], ITEMS)),
        "many": (unsigned(9), rng.integers(512, size=ITEMS)),
        "seventeen": (signed(20), rng.choice(np.arange(-8, 9) * 4001, ITEMS)),
    }


class RomDut(wiring.Component):
    def __init__(self, spec, ram):
        self.rom = LaneRom(DEPTH, ram, dictionary=True)
        for name, (shape, vals) in spec.items():
            self.rom.add(name, shape, vals)
        super().__init__({"addr": In(range(DEPTH)),
                          **{name: Out(shape) for name, (shape, _) in spec.items()}})

    def elaborate(self, platform):
        m = Module()
        self.rom.build(m, "rom", self.addr)
        for name, sig, _ in self.rom.fields:
            m.d.comb += getattr(self, name).eq(sig)
        return m


def test_lane_rom_plan():
    rom = LaneRom(DEPTH, "sim", dictionary=True)
    for name, (shape, vals) in fields(np.random.default_rng(1)).items():
        rom.add(name, shape, vals)
    enc = rom.encoding()
    assert enc["const"] == enc["const_neg"] == "const"
    assert enc["many"] == "plain" and enc["seventeen"] == "plain"           # more than DICT_ENTRIES values
    assert enc["two"].startswith("dict") and enc["three_signed"].startswith("dict")
    assert len({v for v in enc.values() if v.startswith("dict")}) >= 2     # 2 x 2 x 3 x 4 x 4 > 16: two groups
    for members, tuples in rom.plan()[2]:
        assert 2 <= len(tuples) <= DICT_ENTRIES
    plain = sum(len(sig) for _, sig, _ in rom.fields)
    assert rom.bits <= 9 + 20 + 8 < plain                            # two indices of at most 4 bits


@pytest.mark.parametrize("ram", ["sim", "ecp5"])
def test_lane_rom_returns_every_field(ram):
    spec = fields(np.random.default_rng(2))
    dut = RomDut(spec, ram)
    addrs = list(range(DEPTH)) + [5, 5, 0, ITEMS - 1, 17]
    vals = [[a] for a in addrs] + [[0], [0]]
    names = list(spec)
    run = run_amaranth if ram == "sim" else (lambda *a: run_verilog(*a, tag="lanerom"))
    got = run(dut, ["addr"], vals, names)
    checked = 0
    for t, a in enumerate(addrs):                     # address presented in cycle t, field after edge t + 1
        if a >= ITEMS:
            continue
        for k, name in enumerate(names):
            shape, v = spec[name]
            want = int(v[a]) & ((1 << shape.width) - 1)
            assert int(got[t + 1, k]) & ((1 << shape.width) - 1) == want, f"{ram} {name} at {a}"
            checked += 1
    assert checked == (ITEMS + 5) * len(names)
