"""Function-unit tables shared by two lanes (hw/stream/tables.py): two RsqrtTableUnits on one TablePair,
fed different inputs in the same cycles, each equal to the bit-true model (hw/funcunits.py RsqrtTable)
for every input: Amaranth's simulator ("sim": a Memory with two read ports) and Icarus with the DP16KD
model ("ecp5": blocks in true dual-port mode)."""
from __future__ import annotations

import numpy as np
import pytest
from amaranth.hdl import Module
from amaranth.lib import wiring
from amaranth.lib.wiring import In, Out

from hw.fixed import SQ, Saturations
from hw.funcunits import RsqrtTable
from hw.rtl_funcunits import RsqrtTableUnit
from hw.stream.tables import TablePair, shares
from stream_helpers import run_amaranth, run_verilog

pytestmark = pytest.mark.hdl

MODEL = RsqrtTable(SQ(6, 8), SQ(4, 10), segments_log2=10, guard_bits=4)     # a 1024-word table, as the presets'


class TwoUnits(wiring.Component):
    def __init__(self, ram):
        self.pair = TablePair(ram)
        self.units = [RsqrtTableUnit(MODEL, side) for side in self.pair.sides]
        shape = self.units[0].i.payload.shape()
        out = self.units[0].o.payload.value.shape()
        super().__init__({"x0": In(shape), "x1": In(shape), "y0": Out(out), "y1": Out(out)})

    def elaborate(self, platform):
        m = Module()
        for side in self.pair.sides:
            side.reset()
        for k, unit in enumerate(self.units):              # side 0 first: it builds the shared ROM
            m.submodules[f"unit{k}"] = unit
            m.d.comb += [unit.i.payload.eq(getattr(self, f"x{k}")), unit.i.valid.eq(1),
                         getattr(self, f"y{k}").eq(unit.o.payload.value)]
        return m


@pytest.mark.parametrize("ram", ["sim", "ecp5"])
def test_two_units_share_one_table(ram):
    assert shares(MODEL.Y + int(MODEL.slope.max()).bit_length(), 1 << MODEL.S)
    rng = np.random.default_rng(7)
    x0 = rng.integers(1, 1 << 13, 600)                       # positive raw inputs of SQ(6, 8)
    x1 = np.concatenate([x0[::-1][:300], rng.integers(1, 1 << 13, 300)])
    dut = TwoUnits(ram)
    lat = dut.units[0].latency
    vals = [[int(a), int(b)] for a, b in zip(x0, x1)] + [[1, 1]] * (lat + 1)
    run = run_amaranth if ram == "sim" else (lambda *a: run_verilog(*a, tag="tables"))
    got = run(dut, ["x0", "x1"], vals, ["y0", "y1"])
    mask = (1 << MODEL.out_shape.width) - 1
    for k, x in enumerate((x0, x1)):
        want = np.asarray(MODEL(x.astype(np.int64), Saturations())) & mask
        hw = got[lat - 1:lat - 1 + len(x), k] & mask
        bad = np.nonzero(hw != want)[0]
        assert bad.size == 0, f"{ram} unit {k}: {bad.size} outputs differ, first at input {bad[:3].tolist()}"
    assert len(dut.pair.roms) == 1                            # one copy for both units


@pytest.mark.filterwarnings("ignore::amaranth.hdl.UnusedElaboratable")
@pytest.mark.parametrize("scene,preset,P,Q,Pp", [("press-2d-rheological", "medium", 2, 2, None),
                                                  ("poke-2d-rheological", "medium", 1, 2, 2)])
def test_a_cores_own_unit_memories_are_those_of_its_hierarchy(scene, preset, P, Q, Pp):
    """StreamCore.own_unit_memories (the manifest's list and block_rams()'s count, from the lanes' dry runs)
    equals a walk over the elaborated core: every memory inside a 1/sqrt or inverse unit that is not a shared
    table; the probe scene's node lanes have their own 1/sqrt ROM."""
    from amaranth.hdl import Fragment, Shape
    from amaranth.lib.memory import Memory
    from conftest import bittrue
    from hw.stream import build_core
    core = build_core(bittrue(scene, preset), P, Q, "stream", pair_lanes=Pp)
    walked = []

    def walk(frag, path):
        for n, (sub, name, _) in enumerate(frag.subfragments):
            where = f"{path}.{name if name is not None else f'U${n}'}" if path else str(name)
            for mem in sub.origins or ():
                if isinstance(mem, Memory) and ("rsqrt" in where or "inverse" in where) and ".shared_" not in where:
                    walked.append({"name": where, "depth": mem.depth, "width": Shape.cast(mem.shape).width})
            walk(sub, where)
    walk(Fragment.get(core, None), "")
    assert walked and core.own_unit_memories() == walked
    assert any(m["name"].startswith("nd") for m in walked) == (scene.startswith("poke"))
