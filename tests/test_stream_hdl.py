"""The streaming core's Verilog on Icarus Verilog and Verilator through cocotb (sim/cocotb_core.py), bit
for bit against the bit-true model, with measured cycles equal to the schedule's.

Default set (the machine's time budget): on Icarus, the DP16KD variant (hw/stream/bram.py instances and
the model hw/stream/dp16kd.v) of a scene built to saturate, and seeded random meshes with P in {1, 2, 3}
and Q in {1, 2}; on Verilator, a 2D scene (topology, floor, nonlinear damper) at narrow with a reset in
the middle of a run and back-to-back runs, a 3D scene at medium, and `rheo bench --backend fpga`. With
RHEO_STREAM_ALL=1 the Verilator test takes every built-in scene without collisions at narrow and medium
(26 builds: an hour and more on this machine). Verilator builds use -O0 (tests/conftest.py: they are most of the time).
Also: Verilator's lint of the emitted Verilog, both RAM variants.
"""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from golden.scene import builtin_names, load_scene
from hw.bittrue import BitTrue
from sim.hdlsim import emit_core, run_job

from conftest import bittrue, scene_system

pytestmark = pytest.mark.hdl      # Amaranth's simulator or HDL simulators: `make test-fast` leaves these out

ROOT = Path(__file__).resolve().parents[1]


def run_cycles(man, n):
    s = man["schedule"]
    return s["prologue_A0"] + (n - 1) * s["period_T"] + s["drain"] + 1


def check(bt, simulator, start, frames, reset_after=0, lanes=1, node_lanes=1, ram="sim", dp16kd_budget=None):
    """Run the bit-true model to `start`, hand its state to the simulated Verilog, compare each frame."""
    st = bt.initial_state()
    for _ in range(start):
        bt.step(st)
    bt.sat.clear()
    core_dir, man, drv = emit_core(bt, lanes, node_lanes, core="stream", ram=ram, dp16kd_budget=dp16kd_budget)
    assert man["core"] == "stream" and man["ram"] == ram
    out = run_job(simulator, core_dir, drv, drv.load_words(st.X, st.U, st.A, st.step), frames,
                  reset_after=reset_after, timeout_s=1800)
    for n, (X, U, A, step, sat, _), cycles in zip(frames, out["frames"], out["cycles"]):
        for _ in range(n):
            bt.step(st)
        assert step == st.step
        for k in range(bt.system.dim):
            assert np.array_equal(X[k], st.X[k]), f"{simulator}: x{k} differs at step {st.step}"
            assert np.array_equal(U[k], st.U[k]), f"{simulator}: u{k} differs at step {st.step}"
        assert np.array_equal(A, st.A), f"{simulator}: a differs at step {st.step}"
        assert sat == bt.sat.total, (sat, dict(bt.sat))
        assert cycles == run_cycles(man, n), (cycles, run_cycles(man, n))
    return man


def _scene(tmp_path, name, text):
    p = tmp_path / f"{name}.toml"
    p.write_text(text)
    return load_scene(str(p))


def test_dp16kd_variant_of_a_saturating_scene_on_icarus(tmp_path):
    """DP16KD instances (36-, 18- and 9-bit blocks) on the model: bit for bit, saturations counted alike."""
    scenes = ROOT / "tests" / "scenes"
    gentle = load_scene(str(scenes / "pull-chain.toml"))
    hard = _scene(tmp_path, "hard", (scenes / "pull-chain.toml").read_text().replace(
        "force = [0.05, 0.0]", "force = [5.0, 0.0]"))
    bt = BitTrue(hard, "narrow", formats=BitTrue(gentle, "narrow").formats)
    man = check(bt, "icarus", 0, [2, 2, 4], lanes=2, node_lanes=2, ram="ecp5")
    assert bt.sat.total > 0
    assert man["block_rams_dp16kd"] > 0


def test_ecp5_primitives_variant_with_damper_tables_on_verilator():
    """The core `rheo synth` builds (DP16KD and MULT18X18D instances with their registers, on their models)
    of a scene with every kind of product (medium: products split into limbs; the damper's Phi and Psi
    tables, the 1/sqrt table, constants by shifts and adds): bit for bit from mid-run, while the damper
    moves. Every multiplier is an instance: the Verilog has no product operator left."""
    import re
    from hw import emit
    bt = bittrue("press-2d-rheological", "medium")
    _, text, man = emit.build(bt, 2, 2, "stream", "ecp5")
    assert len(re.findall(r"^\s*MULT18X18D\b", text, re.M)) > 0
    assert not re.search(r"[\w)\]]\s\*\s[\w($\\]", text), "a product left to Yosys"   # `$signed(a) * $signed(b)`
    check(bt, "verilator", 600, [1, 3, 2], lanes=2, node_lanes=2, ram="ecp5")


def test_copies_moved_into_lut_ram_on_icarus(tmp_path):
    """A block RAM budget of 0 moves every force ring's node copy and every window copy into LUT RAM
    (hw/stream/core.py): the DP16KD variant with those memories distributed, bit for bit on Icarus."""
    bt = bittrue("press-2d-rheological", "narrow")
    man = check(bt, "icarus", 40, [1, 2], lanes=2, node_lanes=2, ram="ecp5", dp16kd_budget=0)
    moved = man["block_ram_fit"]["lut_ram_memories"]
    assert sum(n.startswith("window_copy") for n in moved) == 2 * 2 + 3 * 2 + 1   # 2 P + (D + 1) Pp reads, Q lanes'
    assert sum(n.endswith("_node_copy") for n in moved) == 2 * 2 + 3 * 2        # a ring per lane role
    assert all(m["dp16kd"] == 0 for m in man["memories"] if m["name"] in moved)


@pytest.mark.parametrize("seed,P,Q", [(1, 1, 2), (2, 2, 1), (3, 3, 2)])
def test_random_small_meshes_on_icarus(tmp_path, seed, P, Q):
    """Seeded random blocks and chains with random materials and loads (as tests/test_hdl.py)."""
    rng = np.random.default_rng(seed)
    k1, c1, cmin = (float(v) for v in rng.uniform([10, 0.1, 0.2], [200, 2, 2]))
    nx, ny = (int(v) for v in rng.integers(2, 4, 2))
    mesh = (f'{{ type = "rectangle", size = [0.03, 0.02], divisions = [{nx}, {ny}] }}' if seed != 1
            else f'{{ type = "chain", n = {int(rng.integers(3, 6))}, length = 0.04 }}')
    force = float(rng.uniform(0.01, 0.2))
    text = f"""
description = "random scene {seed}"
dim = 2

[integrator]
dt = 1e-4
duration = 0.02

[[objects]]
name = "body"
mesh = {mesh}
material = {{ preset = "rheological", k1 = {k1!r}, c1 = {c1!r}, c_min = {cmin!r}, node_mass = 1e-3 }}
pinned = [0]

[[loads]]
nodes = [1]
force = [{force!r}, {-force / 2!r}]
start = 0.0
end = 0.01
"""
    bt = BitTrue(_scene(tmp_path, f"random-{seed}", text), "medium")
    check(bt, "icarus", int(rng.integers(0, 50)), [2, 1], lanes=P, node_lanes=Q)


VERILATOR_SCENES = [("gravity-2d-nonlinear", "narrow", 2, 2, 3000), ("press-3d-rheological", "medium", 3, 2, 2000)]
if os.environ.get("RHEO_STREAM_ALL"):
    VERILATOR_SCENES = [(n, preset, 2, 2, min(scene_system(n).n_steps // 3, 3000)) for n in builtin_names()
                        if scene_system(n).collision is None for preset in ("narrow", "medium")]


@pytest.mark.parametrize("name,preset,P,Q,start", VERILATOR_SCENES)
def test_builtin_scenes_on_verilator(name, preset, P, Q, start):
    """Back-to-back runs of 1, 3 and 2 steps; the first scene also resets the core in the middle of a run
    first (the core stops, idle, step 0; reloaded, it computes exactly again)."""
    bt = bittrue(name, preset)
    reset = 150 if name == VERILATOR_SCENES[0][0] else 0
    check(bt, "verilator", start, [1, 3, 2], reset_after=reset, lanes=P, node_lanes=Q)


def test_bench_fpga_measures_the_streaming_period():
    """`rheo bench --backend fpga`: the streaming core by default; its period from runs of 1 and n steps
    equals the schedule's T, which is at least ceil(E / P)."""
    r = subprocess.run([sys.executable, "-m", "sim.cli", "bench", "--backend", "fpga", "--sizes", "300", "--lanes", "2",
                        "--node-lanes", "2", "--fmax-mhz", "50", "--seconds", "0.2", "--hdl-steps", "3", "--json"],
                       cwd=ROOT, capture_output=True, text=True, timeout=3600)
    assert r.returncode == 0, r.stderr
    row = json.loads(r.stdout)["results"][0]
    assert row["core"] == "stream" and row["lanes"] == 2 and row["node_lanes"] == 2
    # --preset auto: narrow saturates the square's strains (a runaway), medium is within 1e-3 of golden
    assert row["preset"] == "medium" and row["error_vs_golden"] <= 1e-3 and "narrow cannot run it" in row["preset_why"]
    assert row["cycles_per_step"] == row["cycles_per_step_schedule"] >= math.ceil(row["elements"] / 2)
    assert row["steps_per_s"] == pytest.approx(50e6 / row["cycles_per_step"], rel=1e-12)


def _verilator():
    from sim.simulators import find_verilator
    return find_verilator()


@pytest.mark.parametrize("ram", ["sim", "ecp5"])
def test_emitted_verilog_passes_verilator_lint(tmp_path, ram):
    from hw import emit
    bt = bittrue("press-2d-rheological", "narrow")
    man = emit.write(bt, tmp_path, 1, 1, core="stream", ram=ram)
    extra = [str(p) for p in emit.primitive_models()] if ram == "ecp5" else []
    r = subprocess.run([_verilator(), "--lint-only", "-Wno-WIDTH", "--top-module", man["top"],
                        str(tmp_path / man["verilog"]), *extra], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr[-3000:]
