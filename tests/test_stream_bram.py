"""BlockRam (hw/stream/bram.py) against a pure-Python reference: both variants, random traffic.

The "sim" variant runs in Amaranth's simulator, the "ecp5" variant (DP16KD instances with their output
register) on Icarus Verilog with the behavioural DP16KD model hw/stream/dp16kd.v: 36-, 18- and 9-bit
blocks, rows of blocks, segment (byte) enables and initial contents. Reads of a word written in the same
cycle are undefined and not compared; the model returns X for them, which the test checks too.
"""
from __future__ import annotations

import numpy as np
import pytest

from hw.stream.bram import BlockRam, plan_blocks
from stream_helpers import run_amaranth, run_verilog

pytestmark = pytest.mark.hdl      # Amaranth's simulator or HDL simulators: `make test-fast` leaves these out

INPUTS = ["w_addr", "w_data", "w_en", "r_addr"]


def reference(width, depth, segments, init, values):
    """r_data after each clock edge (-2: undefined, a read of a word written in its cycle; -3: none yet)."""
    mem = list(init) + [0] * (depth - len(init))
    seg = width // segments
    out, pipe = [], [None, None]
    for wa, wd, we, ra in values:
        collide = any((we >> s) & 1 for s in range(segments)) and wa == ra
        pipe = [None if collide else mem[ra], pipe[0]]
        for s in range(segments):
            if (we >> s) & 1:
                mask = ((1 << seg) - 1) << (s * seg)
                mem[wa] = (mem[wa] & ~mask) | (wd & mask)
        out.append(-3 if len(out) == 0 else -2 if pipe[1] is None else pipe[1])
    return out                         # after edge t: the read presented in cycle t - 1


def stimulus(rng, width, depth, segments, cycles, collide_every=0):
    vals = []
    for t in range(cycles):
        wa, ra = int(rng.integers(depth)), int(rng.integers(depth))
        if collide_every and t % collide_every == 0:
            ra = wa
        vals.append([wa, int(rng.integers(1 << width)), int(rng.integers(1 << segments)), ra])
    return vals


CASES = [  # width, depth, segments, init: the modes plan_blocks picks
    (44, 64, 2, False),       # 512 x 36 (pseudo dual port), byte enables across two blocks
    (30, 700, 1, True),       # 1024 x 18, initial contents
    (20, 3000, 1, True),      # rows of 2048 x 9 blocks, row select after the output registers
    (27, 40, 3, False),       # three 9-bit segments in one 36-bit block
]


@pytest.mark.parametrize("ram", ["sim", "ecp5"])
@pytest.mark.parametrize("width,depth,segments,with_init", CASES)
def test_block_ram_equals_reference(ram, width, depth, segments, with_init):
    rng = np.random.default_rng(width * depth)
    init = [int(v) for v in rng.integers(1 << width, size=depth)] if with_init else []
    dut = BlockRam(width, depth, init=init, segments=segments, ram=ram)
    vals = stimulus(rng, width, depth, segments, 400, collide_every=7)
    run = run_amaranth if ram == "sim" else (lambda *a: run_verilog(*a, tag=f"bram-{width}-{depth}-{segments}"))
    got = run(dut, INPUTS, vals, ["r_data"])[:, 0]
    ref = reference(width, depth, segments, init, vals)
    checked = 0
    for t in range(len(vals) - 1):
        if ref[t] == -3:
            continue
        if ref[t] == -2:
            if ram == "ecp5":                  # the model flags the collision
                assert got[t] == -1, f"cycle {t}: a colliding read returned {got[t]}"
            continue
        assert got[t] == ref[t], f"{ram} {width}x{depth}: read after edge {t}: {got[t]:#x} != {ref[t]:#x}"
        checked += 1
    assert checked > 300


@pytest.mark.parametrize("ram", ["sim", "ecp5"])
@pytest.mark.parametrize("width,depth,segments", [(60, 32, 2), (44, 128, 2), (27, 40, 1)])
def test_distributed_ram_equals_reference(ram, width, depth, segments):
    """LUT RAM (`distributed=True`, no DP16KD): the same reads, latency and segment enables."""
    rng = np.random.default_rng(width + depth)
    dut = BlockRam(width, depth, segments=segments, ram=ram, distributed=True)
    assert dut.blocks() == 0
    vals = stimulus(rng, width, depth, segments, 300, collide_every=5)
    run = run_amaranth if ram == "sim" else (lambda *a: run_verilog(*a, tag=f"lutram-{width}-{depth}-{segments}"))
    got = run(dut, INPUTS, vals, ["r_data"])[:, 0]
    ref = reference(width, depth, segments, [], vals)
    checked = [t for t in range(len(vals) - 1) if ref[t] >= 0]
    assert len(checked) > 200
    for t in checked:
        assert got[t] == ref[t], f"{ram} {width}x{depth}: read after edge {t}: {got[t]:#x} != {ref[t]:#x}"


@pytest.mark.parametrize("ram", ["sim", "ecp5"])
@pytest.mark.parametrize("width,depth,segments,distributed", [(44, 64, 2, False), (20, 3000, 1, False),
                                                              (60, 32, 2, True)])
def test_registered_inputs_act_one_cycle_later(ram, width, depth, segments, distributed):
    """`registered=True`: the same memory as its inputs presented a cycle later (each block's own
    registers in the "ecp5" variant), read latency 3."""
    rng = np.random.default_rng(width + depth + 1)
    dut = BlockRam(width, depth, segments=segments, ram=ram, distributed=distributed, registered=True)
    assert dut.latency == 3
    vals = stimulus(rng, width, depth, segments, 300, collide_every=6)
    tag = f"bramreg-{width}-{depth}-{segments}-{int(distributed)}"
    run = run_amaranth if ram == "sim" else (lambda *a: run_verilog(*a, tag=tag))
    got = run(dut, INPUTS, vals, ["r_data"])[:, 0]
    ref = reference(width, depth, segments, [], [[0, 0, 0, 0]] + vals[:-1])   # the registers' first word
    checked = [t for t in range(len(vals) - 1) if ref[t] >= 0]
    assert len(checked) > 200
    for t in checked:
        assert got[t] == ref[t], f"{ram} {width}x{depth}: read after edge {t}: {got[t]:#x} != {ref[t]:#x}"
    with pytest.raises(ValueError, match="registered"):
        BlockRam(8, 16, writable=False, registered=True)


def test_block_plan_counts():
    assert plan_blocks(72, 128) == (36, 512, 1, 2)            # a 2D narrow node: two 36-bit columns
    assert plan_blocks(144, 128) == (36, 512, 1, 4)
    assert plan_blocks(18, 1682) == (9, 2048, 1, 2)
    assert plan_blocks(44, 64, 2) == (36, 512, 1, 2)           # 2 x 22 bits padded to 2 x 27 = 54
    assert BlockRam(20, 3000).blocks() == 6


ROM2_CASES = [  # width, depth: two read ports (true dual port: 1024 x 18 or 2048 x 9 blocks)
    (35, 1024),               # two 18-bit columns (the 1/sqrt table's shape)
    (31, 256),                # 36 bits would take one block with one port; two ports take 2
    (34, 4096),               # rows of blocks, row select per port (the Psi table's shape)
]


@pytest.mark.parametrize("ram", ["sim", "ecp5"])
@pytest.mark.parametrize("width,depth", ROM2_CASES)
def test_two_port_rom_returns_both_words(ram, width, depth):
    rng = np.random.default_rng(width + depth)
    init = [int(v) for v in rng.integers(1 << width, size=depth)]
    dut = BlockRam(width, depth, init=init, writable=False, read_ports=2, ram=ram)
    addrs = [[int(a), int(b)] for a, b in rng.integers(depth, size=(300, 2))] + [[depth - 1, 0], [0, depth - 1]]
    vals = addrs + [[0, 0], [0, 0]]
    run = run_amaranth if ram == "sim" else (lambda *a: run_verilog(*a, tag=f"rom2-{width}-{depth}"))
    got = run(dut, ["r_addr", "r2_addr"], vals, ["r_data", "r2_data"])
    for t, (a, b) in enumerate(addrs):          # presented in cycle t, in the register after edge t + 1
        assert (got[t + 1, 0], got[t + 1, 1]) == (init[a], init[b]), f"{ram} {width}x{depth}: cycle {t}"


@pytest.mark.filterwarnings("ignore::amaranth.hdl.UnusedElaboratable")
def test_two_port_plan_counts():
    assert plan_blocks(31, 256, read_ports=2) == (18, 1024, 1, 2)     # no 36-bit mode with two ports
    assert plan_blocks(34, 4096, read_ports=2)[2] * plan_blocks(34, 4096, read_ports=2)[3] == 8
    assert BlockRam(35, 1024, writable=False, read_ports=2).blocks() == 2
    with pytest.raises(ValueError):
        BlockRam(8, 16, read_ports=2)                                  # a writable RAM has one read port
    with pytest.raises(ValueError, match="distributed"):
        BlockRam(8, 16, writable=False, distributed=True)              # LUT RAM: writable memories only
