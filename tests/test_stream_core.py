"""The whole streaming core (hw/stream/core.py) equals the bit-true model bit for bit, in Amaranth's
simulator behind its host interface (sim/hwsim.py, `core="stream"`).

Each test loads a mid-run state through the host interface, runs frames of n steps (1-step frames
compare every step; longer ones run steps back to back inside one run), reads everything back (x, u, a,
the step counter, the saturation count) and compares with the bit-true model; every run's measured
cycles (CYCLES) must be the schedule's run_cycles(n). Verilog on Icarus and Verilator:
tests/test_stream_hdl.py.
"""
from __future__ import annotations

import gc
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from hw.datapath import load_window
from hw.stream import build_core, resolve_core
from hw.stream.config import NotStreamable
from sim.hwsim import AmaranthCore

from conftest import bittrue, scene_system

pytestmark = pytest.mark.hdl      # Amaranth's simulator or HDL simulators: `make test-fast` leaves these out

ROOT = Path(__file__).resolve().parents[1]


def compare(bt, hw, start, frames):
    """Advance the bit-true model to `start`, load its state, run `frames` (steps per run), compare."""
    st = bt.initial_state()
    for _ in range(start):
        bt.step(st)
    bt.sat.clear()
    hw.call("load", st.X, st.U, st.A, st.step)
    sch = hw.core.schedule
    for n in frames:
        for _ in range(n):
            bt.step(st)
        cycles = hw.call("run", n)
        X, U, A, step, sat, _ = hw.call("read_state")
        assert step == st.step
        for k in range(len(X)):
            assert np.array_equal(X[k], st.X[k]), f"x{k} differs at step {st.step}"
            assert np.array_equal(U[k], st.U[k]), f"u{k} differs at step {st.step}"
        assert np.array_equal(A, st.A), f"a differs at step {st.step}"
        assert sat == bt.sat.total, (sat, dict(bt.sat))
        assert cycles == sch.run_cycles(n), (cycles, sch.run_cycles(n))
    return st


def run_core(bt, P, Q, start, frames, Pp=None):
    hw = AmaranthCore(bt, P, Q, core="stream", pair_lanes=Pp)
    try:
        return compare(bt, hw, start, frames), hw.core
    finally:
        hw.close()


def test_every_step_and_back_to_back_runs():
    """gravity-2d-nonlinear (topology pairs, floor, nonlinear damper), wide, P = Q = 1: two 1-step runs,
    then a run of 3 steps back to back."""
    bt = bittrue("gravity-2d-nonlinear", "wide")
    st, core = run_core(bt, 1, 1, 3000, [1, 1, 3])
    assert max(np.abs(st.X[k] - bt.initial_state().X[k]).max() for k in range(2)) > 0


def test_lanes_and_the_edge_of_a_load_window():
    """press-2d-rheological, narrow, P = 2 element and pair lanes, Q = 3 node lanes (55 nodes: the last
    group is short), across the step at which the press's load switches off: the node lanes run into
    the next period, so their own step number must decide, node by node."""
    bt = bittrue("press-2d-rheological", "narrow")
    first, end = load_window(bt.params, 0)
    assert end < bt.system.n_steps
    _, core = run_core(bt, 2, 3, end - 2, [1, 1, 2])
    assert core.cfg.n_nodes % 3 != 0


def test_pair_lanes_apart_from_element_lanes():
    """press-2d-rheological, narrow, P = 1 element lane, Pp = 3 pair lanes, Q = 2: the pairs take a third
    of the slots they take on one lane, and the core stays bit for bit."""
    bt = bittrue("press-2d-rheological", "narrow")
    _, core = run_core(bt, 1, 2, 40, [1, 2], Pp=3)
    sch, n_pairs = core.schedule, core.cfg.n_pairs
    assert n_pairs > 3 and len(core.pairs) == 3 and sch.pair_lanes == 3
    assert sch.pair_slots == -(-n_pairs // 3) and sch.element_slots == core.cfg.n_elements
    assert sum(info.kind == "pr" for info in core.cfg.rings) == 3 * 3


def test_pair_lanes_belong_to_the_streaming_core():
    """--pair-lanes on a scene the phased core runs (collisions) is refused in one line, exit 2."""
    r = subprocess.run([sys.executable, "-m", "sim.cli", "verilog", "friction-2d-mu03", "--pair-lanes", "2",
                        "--out", "unused"], cwd=ROOT, capture_output=True, text=True)
    assert r.returncode == 2
    lines = [ln for ln in r.stderr.splitlines() if ln.startswith("rheo: error:")]
    assert len(lines) == 1 and "--pair-lanes" in lines[0] and "phased" in lines[0], r.stderr
    assert not (ROOT / "unused").exists()


def test_saturation_counts_match_in_a_scene_built_to_saturate(tmp_path):
    """Formats sized for a gentle pull, then a 100x blow (as tests/test_hw_core.py): the same counts."""
    from golden.scene import load_scene
    from hw.bittrue import BitTrue
    scenes = ROOT / "tests" / "scenes"
    (tmp_path / "hard.toml").write_text((scenes / "pull-chain.toml").read_text().replace(
        "force = [0.05, 0.0]", "force = [5.0, 0.0]"))
    gentle = load_scene(str(scenes / "pull-chain.toml"))
    hard = load_scene(str(tmp_path / "hard.toml"))
    bt = BitTrue(hard, "narrow", formats=BitTrue(gentle, "narrow").formats)
    run_core(bt, 1, 1, 0, [2, 2, 4])
    assert bt.sat.total > 0


def test_collision_scenes_are_refused_with_a_message():
    from hw.datapath import Params
    from hw.units import HardwareUnits
    system = scene_system("friction-2d-mu03")
    params = Params.of(system, HardwareUnits.of(system))
    with pytest.raises(NotStreamable, match="collisions .* --core phased"):
        resolve_core(params, "stream")
    assert resolve_core(params, "auto") == "phased"
    assert resolve_core(Params.of(scene_system("press-2d-plastic"), HardwareUnits.of(scene_system("press-2d-plastic"))), "auto") == "stream"
    r = subprocess.run([sys.executable, "-m", "sim.cli", "verilog", "friction-2d-mu03", "--core", "stream", "--out",
                        "unused"], cwd=ROOT, capture_output=True, text=True)
    assert r.returncode == 2
    lines = [ln for ln in r.stderr.splitlines() if ln.startswith("rheo: error:")]
    assert len(lines) == 1 and "collisions" in lines[0]


@pytest.mark.filterwarnings("ignore::amaranth.hdl.UnusedElaboratable")
def test_everything_static_is_known_at_construction():
    """cycles per step, the schedule, the saturation flags and the memory inventory before elaboration."""
    bt = bittrue("press-2d-rheological", "narrow")
    core = build_core(bt, 2, 2, "stream")
    sch = core.schedule
    assert core.cycles_per_step == sch.period >= max(sch.element_slots, sch.pair_slots)
    assert core.sat_quantities and all(isinstance(q, str) for q in core.sat_quantities)
    mems = core.memories()
    assert sum(m["dp16kd"] for m in mems) > 0
    assert sum(m["name"].startswith("window_copy") for m in mems) == 2 * 2 + 3 * 2 + 1
    del core                                  # never elaborated: silence its components' warnings here
    gc.collect()


def test_block_ram_fit_moves_the_cheapest_copies_into_lut_ram():
    """press-2d-rheological, narrow, P = Q = 2: window copies 32 x 144 (4 DP16KD, 18 DPR16X4 a block saved),
    force-ring node copies 16 x 84 and 16 x 88 in two segments (the rings' Wr = 16 slots; 3 DP16KD, 22
    DPR16X4: 7.3 a block): 114 DP16KD in all."""
    bt = bittrue("press-2d-rheological", "narrow")
    fits = {b: build_core(bt, 2, 2, "stream", "ecp5", dp16kd_budget=b) for b in (None, 114, 110, 0)}
    assert [fits[b].block_rams() for b in fits] == [114, 114, 108, 40]    # 0: 114 - 11 x 4 - 10 x 3
    assert fits[None].lut_memories == fits[114].lut_memories == []
    assert fits[110].lut_memories == ["ring_el0_r0_node_copy", "runsum_el0_r1_node_copy"]
    assert len(fits[0].lut_memories) == 21
    recs = {m["name"]: m for m in fits[110].memories()}
    assert recs["ring_el0_r0_node_copy"]["dp16kd"] == 0 and recs["ring_el0_r0_node_copy"]["dpr16x4"] == 1 * 11 * 2
    with pytest.raises(ValueError, match="dp16kd_budget"):
        build_core(bt, 2, 2, "stream", dp16kd_budget=-1)
    del fits                                  # never elaborated
    gc.collect()


def test_a_scene_beyond_the_window_is_refused_in_one_line(tmp_path):
    """A wheel of 1,100 spokes (every rim node tied to the hub): no numbering puts its nodes closer than
    about 550 apart, beyond the 512-node window of one node lane: `rheo verilog` prints the bandwidth and
    the window on one line and exits 2."""
    n = 1100
    ang = np.linspace(0, 2 * np.pi, n, endpoint=False)
    nodes = [[0.0, 0.0]] + [[float(np.cos(a)) * 0.05, float(np.sin(a)) * 0.05] for a in ang]
    edges = [[0, k] for k in range(1, n + 1)] + [[k, k % n + 1] for k in range(1, n + 1)]
    (tmp_path / "wheel.toml").write_text(f"""
description = "a wheel"
dim = 2

[integrator]
dt = 1e-4
duration = 0.001

[[objects]]
name = "wheel"
mesh = {{ type = "explicit", nodes = {nodes}, edges = {edges} }}
material = {{ preset = "viscoelastic", node_mass = 1e-3 }}
pinned = [0]
""")
    r = subprocess.run([sys.executable, "-m", "sim.cli", "verilog", str(tmp_path / "wheel.toml"), "--core", "stream",
                        "--out", str(tmp_path / "out")], cwd=ROOT, capture_output=True, text=True)
    assert r.returncode == 2, r.stderr[-2000:]
    lines = [ln for ln in r.stderr.splitlines() if ln.startswith("rheo: error:")]
    assert len(lines) == 1, r.stderr[-2000:]
    assert "bandwidth" in lines[0] and "512 groups of 1 nodes (512 nodes)" in lines[0], lines[0]
    assert "Traceback" not in r.stderr
