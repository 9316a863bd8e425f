"""The Amaranth core equals the bit-true model bit for bit: one built-in scene for each unit and mapping
the phased core builds (REPRESENTATIVE; with RHEO_ALL_SCENES=1 every built-in 2D scene and the 3D scenes
without collisions: 3D collision cores stream 30,000 pairs a step, tests/test_hdl.py runs them on
Verilator), except the scenes with a probe (this core has no probe port: issue 16 item 3).

The core runs in Amaranth's simulator behind its host interface (sim/hwsim.py); the bit-true model
(hw/bittrue.py) steps the same scene with the same formats. Both start from the same mid-run state
(loaded through the host interface), so the forces, contacts and damper tables are busy, and every
read-back (x, u, a, the step counter and the saturation count) must be identical.
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from golden.scene import builtin_names
from hw.core import CoreConfig
from hw.datapath import state_difference
from sim.hwsim import AmaranthCore

from conftest import bittrue, scene_system, sweep

pytestmark = pytest.mark.hdl      # `make test-fast` leaves these out

ROOT = Path(__file__).resolve().parents[1]
ALL_SCENES = [n for n in builtin_names() if (scene_system(n).collision is None or scene_system(n).dim == 2)
              and scene_system(n).probe is None]      # the probe port is the streaming core's (issue 16 item 3)
# One scene for each unit and mapping the phased core builds (Amaranth's simulator runs 40 to 300 cycles/s:
# the whole list took 20 minutes of a core in a 2-worker `make test`, so `make test` takes this set and RHEO_ALL_SCENES=1 all):
REPRESENTATIVE = {
    "gravity-2d-nonlinear": "topology pairs, floor, nonlinear damper table, gravity",
    "press-2d-plastic": "plastic elements: a stops at its clamp bounds",
    "press-2d-viscoelastic": "fixed-a elements (c1 a_max), constant damper",
    "rigid-on-rheo-2d": "a rigid body on a rheological one: collision pairs with friction (1/sqrt unit)",
    "table-push-2d-gravity": "external loads and a friction floor",
}   # press-2d-rheological at narrow and medium: test_core_equals_bittrue_with_narrow_words; 3D and more
    # collisions on Icarus and Verilator (tests/test_hdl.py); every scene with RHEO_ALL_SCENES=1
SCENES = sweep(ALL_SCENES, REPRESENTATIVE)


def start_step(system):
    """A step in the middle of the action: a third into the scene (at most 3000 steps in)."""
    return min(system.n_steps // 3, 3000)


def active_collision_pairs(bt, st) -> int:
    """How many collision pairs act (within the threshold, foot on the facet) in state st."""
    from hw.datapath import collision_kernel
    D, pairs = bt.system.dim, bt.params.collision["pairs"]
    X = [bt.ar.state("x", x) for x in st.X]
    U = [bt.ar.state("u", u) for u in st.U]
    roles = [pairs[:, r] for r in range(D + 1)]
    gate, _ = collision_kernel(bt.ar, bt.params, *[[bt.ar.take(v, r) for v in X] for r in roles],
                               *[[bt.ar.take(v, r) for v in U] for r in roles])
    return 0 if gate.empty else int(gate.size)


def compare(bt, hw: AmaranthCore, start: int, steps: int, every: int):
    """Advance the bit-true model to `start`, load its state into the core, then run both and compare."""
    st = bt.initial_state()
    for _ in range(start):
        bt.step(st)
    if bt.params.collision is not None:       # the comparison must cover contacts, not only their absence
        assert active_collision_pairs(bt, st) > 0, f"no contact at step {start}"
    bt.sat.clear()
    hw.call("load", st.X, st.U, st.A, st.step)
    cycles = []
    for _ in range(steps // every):
        for _ in range(every):
            bt.step(st)
        cycles.append(hw.call("run", every))
        X, U, A, step, sat, _ = hw.call("read_state")
        assert (why := state_difference(st, X, U, A, step)) is None, f"at step {st.step}: {why}"
        assert sat == bt.sat.total, (sat, dict(bt.sat))
    return st, cycles


@pytest.mark.parametrize("name", SCENES)
def test_core_equals_bittrue_bit_for_bit(name):
    bt = bittrue(name, "wide")
    hw = AmaranthCore(bt)
    # Python simulation runs a few hundred cycles/s: 2D cores take ~350 cycles a step (collision cores
    # 1,000 to 2,300), 3D ones ~3000
    every, frames = (4, 2) if bt.system.dim == 2 and bt.params.collision is None else (1, 1)
    try:
        st, cycles = compare(bt, hw, start_step(bt.system), steps=frames * every, every=every)
    finally:
        hw.close()
    moved = [np.abs(st.X[k] - bt.initial_state().X[k]).max() for k in range(bt.system.dim)]
    assert max(moved) > 0                                          # the state is not trivially still
    assert all(c == every * hw.cycles_per_step for c in cycles), (cycles, hw.cycles_per_step)


def test_core_equals_bittrue_over_20_steps_with_lanes():
    """A 20-step run on P = 2 element (and pair) lanes and Q = 2 node lanes (200 steps took 16 minutes of
    CI's time in Amaranth's simulator; the Verilog runs thousands: tests/test_hdl.py)."""
    bt = bittrue("gravity-2d-nonlinear", "wide")
    hw = AmaranthCore(bt, lanes=2, node_lanes=2)
    try:
        _, cycles = compare(bt, hw, start_step(bt.system), steps=20, every=10)
    finally:
        hw.close()
    cfg = CoreConfig.of(bt, 2, 2)
    per_step = cycles[0] / 10
    expected = (max(-(-cfg.n_elements // 2), -(-cfg.n_pairs // 2)) + hw.core.drain_elements
                + -(-cfg.n_nodes // 2) + hw.core.drain_nodes)
    assert per_step == expected


@pytest.mark.parametrize("preset", ["narrow", "medium"])
def test_core_equals_bittrue_with_narrow_words(preset):
    bt = bittrue("press-2d-rheological", preset)
    hw = AmaranthCore(bt)
    try:
        compare(bt, hw, start_step(bt.system), steps=4, every=2)
    finally:
        hw.close()


def test_saturation_counts_match_in_a_scene_built_to_saturate(tmp_path):
    """Formats sized for a gentle pull, then a 100x blow: both models count the same saturations."""
    from hw.bittrue import BitTrue
    scenes = ROOT / "tests" / "scenes"
    gentle_text = (scenes / "pull-chain.toml").read_text()
    hard_text = gentle_text.replace("force = [0.05, 0.0]", "force = [5.0, 0.0]")
    assert hard_text != gentle_text
    (tmp_path / "hard.toml").write_text(hard_text)
    from golden.scene import load_scene
    gentle = load_scene(str(scenes / "pull-chain.toml"))
    hard = load_scene(str(tmp_path / "hard.toml"))
    fmt = BitTrue(gentle, "narrow").formats
    bt = BitTrue(hard, "narrow", formats=fmt)
    hw = AmaranthCore(bt)
    try:
        compare(bt, hw, 0, steps=12, every=2)
    finally:
        hw.close()
    assert bt.sat.total > 0                                        # it did saturate, and the counts matched


def _rheo(*args):
    return subprocess.run([sys.executable, "-m", "sim.cli", *args], cwd=ROOT, capture_output=True, text=True)


def test_amaranth_backend_writes_the_same_run_file_as_the_fixed_backend(tmp_path):
    outs = {}
    for backend in ("fixed", "amaranth"):
        out = tmp_path / f"{backend}.npz"
        r = _rheo("simulate", "press-2d-viscoelastic", "--backend", backend, "--steps", "8", "--every", "4",
                  "--out", str(out))
        assert r.returncode == 0, r.stderr
        outs[backend] = np.load(out)
    for key in ("x_raw", "v_raw", "a_raw", "saturations", "x", "v"):
        assert np.array_equal(outs["fixed"][key], outs["amaranth"][key]), key
    assert outs["fixed"]["x_raw"].shape[0] == 3
