"""The bit-true fixed-point model: arithmetic rules, budgets against the golden model, run files."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from golden.model import simulate
from golden.scene import builtin_names, load_scene
from hw.bittrue import BitTrue
from helpers import run_fixed
from hw.fixed import SQ, UQ, Saturations, add, mul, shift_round
from hw.formats import FormatError, check_scene_formats

from conftest import bittrue as cached_bittrue, scene_system, sweep

ROOT = Path(__file__).resolve().parents[1]


# ---------------------------------------------------------------- arithmetic rules

def test_rounding_is_to_nearest_ties_up_never_truncation():
    raw = np.arange(-64, 65, dtype=np.int64)
    got = shift_round(raw, 3)
    expected = np.floor(raw / 8 + 0.5).astype(np.int64)        # real rounding, computed independently
    assert np.array_equal(got, expected)
    assert np.any(got != raw >> 3)                             # differs from truncation


def test_saturation_clamps_and_counts_instead_of_wrapping():
    fmt = SQ(4, 4)                                             # range [-8, 8 - 1/16]
    sat = Saturations()
    got = mul(np.array([7 * 16, -7 * 16, 16]), SQ(8, 4), np.array([2 * 16, 2 * 16, 2 * 16]), SQ(8, 4), fmt, sat, "p")
    assert got.tolist() == [fmt.max_raw, fmt.min_raw, 2 * 16]  # 14 -> max, -14 -> min, 2 -> 2
    assert sat["p"] == 2
    s = add(np.array([fmt.max_raw]), fmt, np.array([1]), fmt, fmt, sat, "s")
    assert s[0] == fmt.max_raw and sat["s"] == 1               # no wrap to the negative end


def test_formats_of_mixed_binary_points_add_exactly():
    a, b = UQ(4, 8), SQ(2, 20)
    x = add(np.array([3 << 8]), a, np.array([1 << 19]), b, SQ(6, 20))
    assert x[0] == (3 << 20) + (1 << 19)                       # 3 + 0.5 exactly


# ---------------------------------------------------------------- budgets

SENSITIVITY_FACTOR = 3.0       # a sensitive scene's bit-true error may reach 3x its sensitivity floor


# One scene per family (element law, collisions and friction, probe, dimension): the whole list is about
# 40 minutes of a core in a 2-worker `make test`, so it takes these and RHEO_ALL_SCENES=1 all
BUDGET_SCENES = {
    "fold-2d": "topology pairs folding into self-contact",
    "multi-2d": "several objects colliding in 2D, with friction",
    "friction-3d-mu03": "3D rheological blocks colliding with friction",
    "gravity-2d-nonlinear": "the nonlinear damper under gravity",
    "press-2d-plastic": "plastic elements", "press-2d-viscoelastic": "viscoelastic elements",
    "poke-2d-rheological": "the haptic probe",
    "rigid-on-rheo-2d": "a rigid body on a soft one", "table-push-2d-gravity": "loads and a friction floor",
}       # the other 3D scenes and the parameter variants with RHEO_ALL_SCENES=1


@pytest.mark.slow
@pytest.mark.parametrize("name", sweep([n for n in builtin_names() if n != "creep-1d"], BUDGET_SCENES))
def test_wide_preset_within_budget_of_golden_over_the_whole_scene(name):
    """Max position error of the wide preset <= 1e-4 of the object size, every frame, full duration.

    Scenes where an element reaches a clamp bound of a, or contacts start and stop, are sensitive: a
    one-LSB difference can move such a switch by a step, and trajectories part whatever the arithmetic.
    There the budget is what the physics allows: the golden model with only its states rounded to the
    wide grid (hw/sensitivity.py) must itself part from golden by more than 1e-4 (measured here, not
    assumed), and the bit-true model may not be more than 3x further away than that floor.
    tests/test_bittrue.py::test_one_step_error_of_the_wide_preset_is_small checks such scenes step by step.
    """
    from hw.sensitivity import rounded_golden
    system = load_scene(name)
    every = max(1, system.n_steps // 50)
    gold = simulate(system, every=every)
    run, raws, bt = run_fixed(system, "wide", every=every, bittrue=cached_bittrue(name, "wide"))
    size = np.ptp(system.x0, axis=0).max()
    err = np.abs(run.x - gold.x).max() / size
    assert bt.sat.total == 0, dict(bt.sat)
    if err <= 1e-4:
        return
    floor = np.abs(rounded_golden(system, bt.formats, bt.units, every=every) - gold.x).max() / size
    assert floor > 1e-4, f"error {err:.2e} of the object size, but the scene is not sensitive (floor {floor:.2e})"
    assert err <= SENSITIVITY_FACTOR * floor, (err, floor)


@pytest.mark.slow
@pytest.mark.parametrize("name", sweep([n for n in builtin_names() if scene_system(n).collision is not None], {
    "friction-2d-mu03": "2D contacts with friction", "friction-3d-mu03": "3D contacts with friction",
    "multi-2d": "contacts between several objects", "fold-2d": "self-contact",
    "rigid-on-rheo-2d": "a rigid body's contacts"}))         # the frictionless variants with RHEO_ALL_SCENES=1
def test_one_step_error_of_the_wide_preset_is_small(name):
    """From the same golden state, one bit-true step equals one golden step to 1e-5 of the scene's peak
    speed, on every (sampled) step of the scene, contacts included: the datapath computes the physics
    step by step, so what parts whole trajectories of sensitive scenes is the scene, not the datapath."""
    from golden.model import Golden
    from golden.system import State
    from hw.datapath import HwState, step
    bt = cached_bittrue(name, "wide")
    system, fm, un = bt.system, bt.formats, bt.units
    gold, st = Golden(system), State.initial(system)
    every = 5 if system.dim == 2 else 25
    worst, vmax = 0.0, 0.0
    for n in range(system.n_steps):
        check = n % every == 0
        if check:
            X = [fm["x"].from_float(un.length(st.x[:, k])) for k in range(system.dim)]
            U = [fm["u"].from_float(un.velocity(st.v[:, k])) for k in range(system.dim)]
            new = step(bt.ar, HwState(X, U, fm["a"].from_float(st.a), st.step), bt.params)
        gold.step(st)
        vmax = max(vmax, np.abs(st.v).max())
        if check:
            u = np.stack([un.to_velocity(fm["u"].to_float(c)) for c in new.U], 1)
            worst = max(worst, np.abs(u - st.v).max())
    assert bt.sat.total == 0, dict(bt.sat)
    assert worst <= 1e-5 * vmax, (worst, vmax)


@pytest.mark.slow
@pytest.mark.parametrize("preset", ["wide", "medium"])
def test_creep_permanent_set_in_fixed_point(preset):
    """Round-to-nearest stagnation would destroy the permanent set: it must stay within 0.5 %."""
    system = load_scene("creep-1d")
    steps = 30_000              # 0.3 s: the 0.2 s pulse and ten Voigt time constants c1/k1 of recovery
    run, _, bt = run_fixed(system, preset, steps=steps, every=steps)
    expected = 0.05 * 0.2 / 5.0
    got = run.x[-1, 1, 0] - 0.01
    assert abs(got - expected) <= 0.005 * expected, (got, expected)
    assert bt.sat.total == 0


@pytest.mark.slow
def test_narrow_preset_shows_stagnation_on_creep():
    """The narrow preset loses the creep increments (the reason the presets exist): the report must show it."""
    system = load_scene("creep-1d")
    run, _, _ = run_fixed(system, "narrow", steps=30_000, every=30_000)
    assert abs(run.x[-1, 1, 0] - 0.01 - 0.002) > 0.1 * 0.002


def test_internal_forces_cancel_bit_for_bit():
    """Element and topology forces are applied as +/- the same word: with no external force the node
    force accumulators sum to exactly zero on every step (momentum is conserved before the per-node
    rounding of the velocity update)."""
    from hw.arith import FixedArith

    class Spy(FixedArith):
        sums = []

        def scatter(self, parts, n, q):
            out = super().scatter(parts, n, q)
            Spy.sums.append(int(np.sum(out.x)))
            Spy.nonzero = np.any(out.x != 0)
            return out

    system = load_scene("press-2d-rheological")
    system.loads, system.floor = [], None
    system.pinned = np.zeros_like(system.pinned)
    rng = np.random.default_rng(0)
    system.x0 = system.x0 + rng.normal(0, 3e-4, system.x0.shape)
    bt = BitTrue(system, "wide", range_steps=300)
    bt.ar.__class__ = Spy
    st = bt.initial_state()
    for _ in range(300):
        bt.step(st)
    assert len(Spy.sums) == 600 and Spy.nonzero
    assert set(Spy.sums) == {0}


# ---------------------------------------------------------------- the run file

def test_fixed_backend_run_file_carries_raw_states_and_saturations(tmp_path):
    out = tmp_path / "r.npz"
    r = subprocess.run([sys.executable, "-m", "sim.cli", "simulate", "press-2d-viscoelastic", "--backend", "fixed",
                        "--preset", "medium", "--steps", "400", "--every", "100", "--out", str(out)],
                       cwd=ROOT, capture_output=True, text=True, env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"})
    assert r.returncode == 0, r.stderr
    with np.load(out) as f:
        assert f["x_raw"].shape == f["x"].shape and f["x_raw"].dtype == np.int64
        assert f["v_raw"].shape == f["v"].shape and f["a_raw"].shape == f["a"].shape
        assert f["saturations"].shape == (5,)
        assert str(f["backend"]) == "fixed" and str(f["preset"]) == "medium"
        assert f["saturation_names"].shape == f["saturation_counts"].shape
        assert np.any(f["x_raw"][-1] != f["x_raw"][0])


def test_scene_can_override_a_format(tmp_path):
    text = (ROOT / "golden" / "scenes" / "press-2d-viscoelastic.toml").read_text()
    p = tmp_path / "s.toml"
    p.write_text(text + '\n[formats]\nx = "SQ(3, 20)"\n')
    system = load_scene(p)
    # the whole run's range analysis: a shorter one never sees the press, and its load constant would not
    # fit the force accumulator (refused, tests/test_model_v2.py)
    bt = BitTrue(system, "wide")
    assert str(bt.formats["x"]) == "SQ(3, 20)"
    assert str(BitTrue(load_scene("press-2d-viscoelastic"), "wide").formats["x"]) != "SQ(3, 20)"
    p.write_text(text + '\n[formats]\nxx = "SQ(3, 20)"\n')
    with pytest.raises(ValueError, match="unknown quantity 'xx'"):
        check_scene_formats(load_scene(p))
    p.write_text(text + '\n[formats]\nx = "Q3.20"\n')
    with pytest.raises(ValueError, match=r"SQ\(i, f\)"):
        check_scene_formats(load_scene(p))


def test_runaway_saturations_stop_the_run(tmp_path):
    """Formats sized for a gentle press cannot hold a press 1000x stronger: the run stops with a message."""
    from golden.errors import SimulationDiverged
    gentle = load_scene("press-2d-viscoelastic")
    bt_gentle = BitTrue(gentle, "narrow", range_steps=gentle.n_steps)
    text = (ROOT / "golden" / "scenes" / "press-2d-viscoelastic.toml").read_text()
    p = tmp_path / "hard.toml"
    # 1000x: the load constant itself does not fit the force accumulator: refused before any step
    p.write_text(text.replace("force = [0.0, -0.05]", "force = [0.0, -50.0]"))
    with pytest.raises(FormatError, match="load saturates"):
        BitTrue(load_scene(p), "narrow", formats=bt_gentle.formats)
    # 40x: the load fits, what it does to the object does not
    p.write_text(text.replace("force = [0.0, -0.05]", "force = [0.0, -2.0]"))
    hard = load_scene(p)
    bt_hard = BitTrue(hard, "narrow", formats=bt_gentle.formats)
    with pytest.raises(SimulationDiverged, match="runaway saturations"):
        run_fixed(hard, "narrow", steps=3000, every=100, bittrue=bt_hard)
    run, _, bt = run_fixed(gentle, "narrow", steps=3000, every=100, bittrue=BitTrue(gentle, "narrow", formats=bt_gentle.formats))
    assert bt.sat.total == 0


def test_a_scenes_range_analysis_runs_once_per_content_and_is_shared_through_the_store(tmp_path, monkeypatch):
    """hw/bittrue.py scene_ranges: the same scene content and step count reuse one analysis (in this process,
    and from the RHEO_RANGE_STORE directory in another, here one whose memory is empty); another content,
    step count or code does not."""
    import hw.bittrue as bittrue_module
    runs = []
    real = bittrue_module.range_analysis

    def counted(system, params, units, steps):
        runs.append((system.name, steps))
        return real(system, params, units, steps)

    monkeypatch.setattr(bittrue_module, "range_analysis", counted)
    monkeypatch.setenv(bittrue_module.RANGE_STORE_VARIABLE, str(tmp_path / "store"))
    monkeypatch.setattr(bittrue_module, "_ranges_memo", {})
    a = load_scene("press-2d-viscoelastic")
    first = bittrue_module.scene_ranges(a, 40)
    first[0]["x"] = -1.0                                     # a caller's copy: the kept result is not touched
    again = bittrue_module.scene_ranges(load_scene("press-2d-viscoelastic"), 40)
    assert again[0]["x"] > 0 and runs == [("press-2d-viscoelastic", 40)]
    monkeypatch.setattr(bittrue_module, "_ranges_memo", {})  # another process: the store answers
    assert bittrue_module.scene_ranges(a, 40) == again and len(runs) == 1
    bittrue_module.scene_ranges(a, 41)
    b = load_scene("press-2d-viscoelastic")
    b.dt = b.dt / 2
    bittrue_module.scene_ranges(b, 40)
    monkeypatch.setattr(bittrue_module, "_ranges_memo", {})  # other code: nothing kept answers it
    monkeypatch.setattr(bittrue_module, "_code_digest", lambda: "other code")
    bittrue_module.scene_ranges(a, 40)
    assert runs == [("press-2d-viscoelastic", 40), ("press-2d-viscoelastic", 41), ("press-2d-viscoelastic", 40),
                    ("press-2d-viscoelastic", 40)]
    assert len(list((tmp_path / "store").glob("*.pickle"))) == 4
