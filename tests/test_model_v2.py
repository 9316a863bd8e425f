"""MODEL.md version 2: the force-dependent damper solved exactly (no lag), the stops, pinned nodes at rest,
and stagnation or unfit formats never silent.

Steady creep (MODEL.md section 6): under a constant force F the Voigt part settles at F / k1 and the damper
flows at F / c2(F), so the elongation rate tends to F / c2(F) below f1, between f1 and f2 and above f2,
with no step-to-step oscillation of T (v1 alternated T = 0.027 / 0.053 N for ever under a 0.04 N pull).
The scenes use dt = 1e-3 s, node masses of 1e-3 kg and a 2 mm element: on a 1 cm element the medium
preset's 18-bit edge vector resolves only 1/50 of an LSB of the slowest creep per step (the stagnation check
below names such cases); the physics does not depend on the length.
"""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from golden.model import Golden, simulate
from golden.system import State
from golden.scene import load_scene
from hw.bittrue import BitTrue
from helpers import run_fixed
from hw.formats import FormatError
from test_cli import ok, one_line_error, rheo

RHEOLOGICAL = dict(k1=50.0, c1=0.5, a0=0.5, a_min=0.05, a_max=1.0, c_min=0.5, c_max=500.0, f1=0.01, f2=0.05)
OWN = dict(k1=80.0, c1=0.3, a0=0.5, a_min=0.02, a_max=1.0, c_min=0.3, c_max=30.0, f1=0.02, f2=0.1)
# (material, force, duration): below f1, between f1 and f2, above f2 (shorter: a must stay off a_min)
CREEP_CASES = {
    "rheological-below-f1": (RHEOLOGICAL, 0.005, 0.4),
    "rheological-between": (RHEOLOGICAL, 0.03, 0.4),
    "rheological-above-f2": (RHEOLOGICAL, 0.07, 0.15),
    "own-below-f1": (OWN, 0.01, 0.4),
    "own-between": (OWN, 0.05, 0.4),
    "own-above-f2": (OWN, 0.11, 0.15),
}


def c2_of(mat, f):
    """The damper law of MODEL.md section 2, written out here (not the code under test's)."""
    if f <= mat["f1"]:
        return mat["c_max"]
    if f >= mat["f2"]:
        return mat["c_min"]
    B = math.log(mat["c_max"] / mat["c_min"]) / (mat["f2"] - mat["f1"])
    return mat["c_max"] * math.exp(-B * (f - mat["f1"]))


def element_scene(tmp_path, mat, force, duration, name="creep", dt=1e-3, mass=1e-3, length=0.002, extra=""):
    text = "\n".join(f"{k} = {v!r}" for k, v in mat.items())
    p = tmp_path / f"{name}.toml"
    p.write_text(f"""
description = "one element, near end pinned, a constant pull"
dim = 2
[integrator]
dt = {dt!r}
duration = {duration!r}
output_every = 1
[[objects]]
mesh = {{ type = "explicit", nodes = [[0.0, 0.0], [{length!r}, 0.0]], edges = [[0, 1]] }}
masses = [{mass!r}, {mass!r}]
pinned = [0]
[objects.material]
{text}
[[loads]]
nodes = [1]
force = [{force!r}, 0.0]
{extra}""")
    return p, load_scene(p)


def late_rate(run):
    """Elongation rate over the last third of the run (the Voigt part has long settled by then)."""
    x, t = run.x[:, 1, 0], run.t
    k = len(t) - len(t) // 3
    return (x[-1] - x[k]) / (t[-1] - t[k])


@pytest.mark.parametrize("case", list(CREEP_CASES))
def test_steady_creep_rate_is_F_over_c2_of_F(tmp_path, case):
    mat, F, duration = CREEP_CASES[case]
    _, system = element_scene(tmp_path, mat, F, duration)
    expected = F / c2_of(mat, F)
    rates = {"golden": late_rate(simulate(system))}
    for preset in ("wide", "medium"):
        run, _, bt = run_fixed(system, preset)
        assert bt.sat.total == 0
        rates[preset] = late_rate(run)
    for model, rate in rates.items():
        assert abs(rate / expected - 1) <= 0.01, (model, rate, expected)


@pytest.mark.parametrize("case", list(CREEP_CASES))
def test_tension_does_not_oscillate_once_steady(tmp_path, case):
    mat, F, duration = CREEP_CASES[case]
    _, system = element_scene(tmp_path, mat, F, duration)
    g, st = Golden(system), State.initial(system)
    T = []
    for n in range(system.n_steps):
        T.append(g.forces(st, n * system.dt)[1][0])
        g.step(st)
    late = np.array(T[-len(T) // 5:])                  # the last fifth: the transient has settled
    assert np.max(np.abs(np.diff(late))) < 1e-6 * F    # v1 alternated by half the force every step
    assert abs(late[-1] / F - 1) < 1e-3                # the element carries the load


def test_unloaded_element_on_a_min_keeps_its_damper_length(tmp_path):
    """MODEL.md 6, stops: pushed until its Voigt part sits on a_min, then released: the damper's length
    (1 - a) l holds once the element is at rest (v1 dropped the damper out of T on a_min)."""
    mat = dict(RHEOLOGICAL, a_min=0.4)
    _, system = element_scene(tmp_path, mat, -0.02, 0.4, extra="start = 0.0\nend = 0.1\n")
    run = simulate(system)
    a, x = run.a[:, 0], run.x[:, 1, 0]
    on_stop = np.flatnonzero(a <= mat["a_min"] + 1e-12)
    assert on_stop.size and run.t[on_stop[0]] < 0.1              # a reached its stop during the push
    w = (1 - a) * x                                               # the damper's length
    rest = run.t >= 0.3
    assert np.abs(run.v[rest, 1, 0]).max() < 1e-5                 # at rest
    push = w[0] - w[run.t >= 0.1][0]
    assert push > 1e-5                                            # the push shortened the damper
    # after the release only the Voigt part's recovery force still acts on the damper (int T dt / c_max,
    # a few per cent of the push); v1 lost the whole length here
    assert abs(w[-1] - w[run.t >= 0.1][0]) <= 0.05 * push
    assert np.ptp(w[rest]) <= 1e-3 * push                         # and at rest it holds


def test_pinned_nodes_have_zero_velocity_in_every_frame(tmp_path):
    p = tmp_path / "moving.toml"
    p.write_text("""
dim = 2
[integrator]
dt = 1e-4
duration = 0.01
output_every = 1
[[objects]]
mesh = { type = "rectangle", size = [0.01, 0.01], divisions = [3, 3] }
material = { preset = "rheological", density = 1000.0 }
velocity = [0.1, -0.2]
pinned = { box = [[-0.001, -0.001], [0.011, 0.001]] }
""")
    system = load_scene(p)
    pinned = system.pinned
    assert pinned.any() and (~pinned).any()
    assert np.all(system.v0[pinned] == 0.0) and np.all(system.v0[~pinned] != 0.0)
    for run in (simulate(system), run_fixed(system, "wide")[0]):
        assert np.all(run.v[:, pinned] == 0.0)
        assert np.all(run.x[:, pinned] == run.x[0, pinned])


# ---------------------------------------------------------------- never silent

NARROW_CREEP = dict(k1=80.0, c1=0.3, c2=3.0, a0=0.5, a_min=0.0, a_max=1.0)


def test_narrow_creep_is_reported_as_stagnating(tmp_path):
    """The issue's case: F = 0.02 N, m = 1e-4 kg, dt = 1e-5 s, narrow: one step's displacement is ~0.14 x LSB."""
    p, system = element_scene(tmp_path, NARROW_CREEP, 0.02, 0.05, dt=1e-5, mass=1e-4, length=0.01)
    found = {f["quantity"]: f for f in BitTrue(system, "narrow").formats.stagnation()}
    assert "x" in found and found["x"]["lsbs"] < 0.5, found
    assert not BitTrue(system, "wide").formats.stagnation()
    out = tmp_path / "run.npz"
    proc = ok(rheo("simulate", p, "--backend", "fixed", "--preset", "narrow", "--out", out))
    warnings = [ln for ln in proc.stderr.splitlines() if ln.startswith("warning:")]
    assert any("x stagnates" in ln and "LSB" in ln and " m" in ln for ln in warnings), proc.stderr
    with np.load(out) as z:
        recorded = {f["quantity"] for f in json.loads(str(z["stagnation"]))}
    assert "x" in recorded


def test_formats_that_cannot_hold_the_initial_state_are_refused(tmp_path):
    p, system = element_scene(tmp_path, NARROW_CREEP, 0.02, 0.01, dt=1e-5, mass=1e-4, length=0.01)
    system.formats = {"x": "SQ(40, -10)"}                   # LSB 1024 length units: every node rounds to 0
    with pytest.raises(FormatError, match="x rounds to zero"):
        BitTrue(system, "wide")
    text = p.read_text() + '\n[formats]\nx = "SQ(40, -10)"\n'
    p.write_text(text)
    out = tmp_path / "run.npz"
    one_line_error(rheo("simulate", p, "--backend", "fixed", "--out", out), "x rounds to zero", "SQ(40, -10)")
    assert not out.exists()
    p.write_text(text.replace('x = "SQ(40, -10)"', 'x = "SQ(-8, 20)"'))    # too narrow for the positions
    one_line_error(rheo("simulate", p, "--backend", "fixed", "--out", out), "x saturates")
