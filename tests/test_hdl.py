"""cocotb on Icarus Verilog and Verilator: the emitted Verilog equals the bit-true model bit for bit.

The core runs whole steps on its own; the testbench (sim/cocotb_core.py) loads a state through the host
interface, starts runs back to back, and reads every state word back after each. Builds are cached per
core (build directory named after the Verilog's hash). A missing simulator is an error, not a skip.
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from golden.scene import load_scene
from hw.bittrue import BitTrue
from hw.datapath import state_difference
from sim.hdlsim import emit_core, run_job

from conftest import bittrue
from test_hw_core import active_collision_pairs

pytestmark = pytest.mark.hdl      # `make test-fast` leaves these out

ROOT = Path(__file__).resolve().parents[1]
SIMULATORS = ["icarus", "verilator"]


def check(bt, simulator, start, frames, reset_after=0, lanes=1, node_lanes=1):
    """Run the bit-true model to `start`, hand its state to the simulated Verilog, compare each frame."""
    st = bt.initial_state()
    for _ in range(start):
        bt.step(st)
    if bt.params.collision is not None:       # the comparison must cover contacts, not only their absence
        assert active_collision_pairs(bt, st) > 0, f"no contact at step {start}"
    bt.sat.clear()
    core_dir, man, drv = emit_core(bt, lanes, node_lanes)
    out = run_job(simulator, core_dir, drv, drv.load_words(st.X, st.U, st.A, st.step), frames,
                  reset_after=reset_after, timeout_s=1200)
    for n, (X, U, A, step, sat, _), cycles in zip(frames, out["frames"], out["cycles"]):
        for _ in range(n):
            bt.step(st)
        assert (why := state_difference(st, X, U, A, step)) is None, f"{simulator} at step {st.step}: {why}"
        assert sat == bt.sat.total, (sat, dict(bt.sat))
        assert cycles == n * man["cycles_per_step"]["value"]
    return out


@pytest.mark.parametrize("simulator", SIMULATORS)
def test_scene_with_topology_floor_damper_and_gravity_is_bit_exact_and_survives_a_reset(simulator):
    """Reset 300 cycles into a run first: the core stops (idle, step 0, checked by the cocotb bench); reloaded,
    it computes exactly again, in back-to-back runs of 3, 5 and 8 steps."""
    bt = bittrue("gravity-2d-nonlinear", "wide")
    out = check(bt, simulator, start=3000, frames=[3, 5, 8], reset_after=300)
    assert out["wall_s"] > 0


@pytest.mark.optimised_verilator
def test_3d_collisions_with_friction_are_bit_exact_on_verilator():
    """A box resting on a pressed box: 30,524 vertex-triangle pairs a step, friction on the 1/sqrt unit."""
    bt = bittrue("friction-3d-mu03", "wide")
    check(bt, "verilator", start=1500, frames=[2, 3])


def test_2d_collisions_with_friction_are_bit_exact_on_icarus():
    bt = bittrue("friction-2d-mu03", "wide")
    check(bt, "icarus", start=2000, frames=[1, 2])


def _scene(tmp_path, name, text):
    p = tmp_path / f"{name}.toml"
    p.write_text(text)
    return load_scene(str(p))


def test_saturation_counts_match_on_icarus(tmp_path):
    scenes = ROOT / "tests" / "scenes"
    gentle = load_scene(str(scenes / "pull-chain.toml"))
    hard = _scene(tmp_path, "hard", (scenes / "pull-chain.toml").read_text().replace(
        "force = [0.05, 0.0]", "force = [5.0, 0.0]"))
    bt = BitTrue(hard, "narrow", formats=BitTrue(gentle, "narrow").formats)
    check(bt, "icarus", start=0, frames=[2, 2, 4])
    assert bt.sat.total > 0


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_random_small_meshes_and_parameters_stay_bit_exact(tmp_path, seed):
    """Seeded random chains and blocks with random materials, loads and lane counts, on Icarus."""
    rng = np.random.default_rng(seed)
    dim2 = seed != 1
    k1, c1, cmin = (float(v) for v in rng.uniform([10, 0.1, 0.2], [200, 2, 2]))
    nx, ny = (int(v) for v in rng.integers(2, 4, 2))
    mesh = (f'{{ type = "rectangle", size = [0.03, 0.02], divisions = [{nx}, {ny}] }}' if dim2
            else f'{{ type = "chain", n = {int(rng.integers(2, 6))}, length = 0.04 }}')
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
force = [{force!r}, {-force / 2 if dim2 else 0.0!r}]
start = 0.0
end = 0.01
"""
    try:
        system = _scene(tmp_path, f"random-{seed}", text)
    except Exception as exc:          # the generator must write valid scenes: show what it wrote
        raise AssertionError(f"{exc}\n{text}") from None
    bt = BitTrue(system, "medium")
    check(bt, "icarus", start=int(rng.integers(0, 50)), frames=[5, 5], lanes=int(rng.integers(1, 3)),
          node_lanes=int(rng.integers(1, 3)))


def test_icarus_backend_writes_the_same_run_file_as_the_fixed_backend(tmp_path):
    outs = {}
    for backend in ("fixed", "icarus"):
        out = tmp_path / f"{backend}.npz"
        r = subprocess.run([sys.executable, "-m", "sim.cli", "simulate", "gravity-2d-nonlinear", "--backend", backend,
                            "--steps", "20", "--every", "10", "--out", str(out)], cwd=ROOT, capture_output=True, text=True)
        assert r.returncode == 0, r.stderr
        outs[backend] = np.load(out)
    for key in ("x_raw", "v_raw", "a_raw", "saturations", "x"):
        assert np.array_equal(outs["fixed"][key], outs["icarus"][key]), key


def test_bench_fpga_measures_cycles_per_step_in_simulation():
    """`rheo bench --backend fpga`: cycles per step from the simulated core's CYCLES register (equal to the
    schedule), modelled steps/s at the stated clock, and the golden model measured on the same mesh."""
    import json
    r = subprocess.run([sys.executable, "-m", "sim.cli", "bench", "--backend", "fpga", "--sizes", "100",
                        "--lanes", "2", "--node-lanes", "2", "--fmax-mhz", "50", "--seconds", "0.2", "--json",
                        "--core", "phased"],
                       cwd=ROOT, capture_output=True, text=True, timeout=1800)
    assert r.returncode == 0, r.stderr
    row = json.loads(r.stdout)["results"][0]
    E, N = row["elements"], row["nodes"]
    assert row["simulator"] == "verilator" and row["lanes"] == 2 and row["node_lanes"] == 2
    assert row["cycles_per_step"] == row["cycles_per_step_schedule"]
    assert row["cycles_per_step"] >= -(-E // 2) + -(-N // 2)          # one element / node per lane and clock
    assert row["steps_per_s"] == pytest.approx(50e6 / row["cycles_per_step"], rel=1e-12)
    assert row["element_updates_per_s"] == pytest.approx(row["steps_per_s"] * E, rel=1e-12)
    assert row["golden_steps_per_s"] > 0
    assert row["ratio_to_golden"] == pytest.approx(row["steps_per_s"] / row["golden_steps_per_s"], rel=1e-12)
    assert row["fmax_source"].startswith("stated")
