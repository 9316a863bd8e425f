"""The hardware datapath run in float64 equals the golden model: the datapath computes the physics.

Any difference beyond float rounding would mean the hardware description (hw/datapath.py) and the
physics reference (golden/) disagree on an equation, an order of operations or a unit conversion.
"""
from __future__ import annotations

import numpy as np
import pytest

from golden.model import simulate
from golden.scene import builtin_names, load_scene
from hw.arith import FloatArith
from hw.bittrue import float_state
from hw.datapath import Params, step
from hw.units import HardwareUnits

from conftest import sweep

STEPS = 1500


def _compare(system, steps=STEPS):
    run = simulate(system, steps=steps, every=steps)
    units = HardwareUnits.of(system)
    p = Params.of(system, units)
    st = float_state(system, units, system.x0, system.v0, system.a0)
    ar = FloatArith()
    for _ in range(steps):
        st = step(ar, st, p)
    x = np.stack([units.to_length(c) for c in st.X], 1)
    v = np.stack([units.to_velocity(c) for c in st.U], 1)
    size = np.ptp(system.x0, axis=0).max()
    moved = np.abs(run.x[-1] - run.x[0]).max()
    return np.abs(x - run.x[-1]).max() / size, np.abs(v - run.v[-1]).max(), np.abs(st.A - run.a[-1]).max(), moved, ar


def _no_collision_scenes():
    names = []
    for n in builtin_names():
        if load_scene(n).collision is None:
            names.append(n)
    return names


@pytest.mark.parametrize("name", _no_collision_scenes())
def test_float_datapath_equals_golden(name):
    system = load_scene(name)
    ex, ev, ea, moved, _ = _compare(system)
    assert moved > 0                                       # something happened in these steps
    assert ex < 1e-12 and ea < 1e-12, (ex, ev, ea)
    assert ev < 1e-9 * max(1.0, np.abs(system.v0).max()), ev


def _crush(tmp_path, dim, damper=""):
    if dim == 2:
        mesh = 'mesh = { type = "explicit", nodes = [[0.0, 0.0], [0.01, 0.0], [0.005, 0.008]], cells = [[0, 1, 2]] }'
        force, pinned, apex = "[0.0, -1.0]", "[0, 1]", 2
    else:
        mesh = ('mesh = { type = "explicit", nodes = [[0.0, 0.0, 0.0], [0.01, 0.0, 0.0], [0.0, 0.01, 0.0], '
                '[0.003, 0.003, 0.008]], cells = [[0, 1, 2, 3]] }')
        force, pinned, apex = "[0.0, 0.0, -1.0]", "[0, 1, 2]", 3
    p = tmp_path / f"crush{dim}.toml"
    p.write_text(f"""
dim = {dim}
[integrator]
dt = 1e-5
duration = 0.02
[world]
gravity = {"[0.0, -9.81]" if dim == 2 else "[0.0, 0.0, -9.81]"}
[world.floor]
height = -0.001
K = 1e4
C = 1.0
mu = 0.3
k_f = 50.0
[topology]
K = 1e3
C = 0.5
eps = 0.002
[[objects]]
{mesh}
material = {{ preset = "rheological", k1 = 5.0, {damper}node_mass = 1e-3 }}
velocity = {"[0.05, 0.0]" if dim == 2 else "[0.05, 0.02, 0.0]"}
pinned = {pinned}
[[loads]]
nodes = [{apex}]
force = {force}
""")
    return load_scene(p)


@pytest.mark.parametrize("damper", ["c2 = 5.0, ", ""], ids=["constant-damper", "nonlinear-damper"])
@pytest.mark.parametrize("dim", [2, 3])
def test_float_datapath_equals_golden_with_topology_floor_and_friction(tmp_path, dim, damper):
    """A cell crushed towards inversion onto a frictional floor: every optional unit is active, with a
    constant c2 and with the preset's nonlinear damper (solved exactly each step, no lag since model v2)."""
    system = _crush(tmp_path, dim, damper)
    ex, ev, ea, moved, ar = _compare(system, steps=2000)
    assert {"tdist", "w", "fe"} <= set(ar.peak)           # the topology unit really acted
    assert ex < 1e-12 and ea < 1e-12, (ex, ea)


def _collision_scenes():
    return [n for n in builtin_names() if load_scene(n).collision is not None]


COLLISION_REPRESENTATIVE = {          # the frictionless variants and rigid-on-rheo-2d with RHEO_ALL_SCENES=1
    "friction-2d-mu03": "2D vertex-edge contacts with friction",
    "friction-3d-mu03": "3D vertex-facet contacts with friction",
    "multi-2d": "contacts between several objects",
    "fold-2d": "self-contact",
}


@pytest.mark.slow
@pytest.mark.parametrize("name", sweep(_collision_scenes(), COLLISION_REPRESENTATIVE))
def test_float_datapath_equals_golden_step_by_step_with_collisions(name, monkeypatch):
    """Collision scenes are sensitive: contact gates (within the threshold, foot on the facet) switch
    forces on and off, so a 1e-16 difference can decide the step at which a contact starts, and
    whole trajectories part (tests/test_bittrue.py measures it). Here every checked step starts both
    models from the same golden state: one step of the float datapath must equal one golden step."""
    import hw.datapath as dp
    from golden.model import Golden
    from golden.system import State
    system = load_scene(name)
    units, p = HardwareUnits.of(system), None
    p = Params.of(system, units)
    active = []
    kernel = dp.collision_kernel

    def spy(ar, p_, *nodes):
        gate, contribs = kernel(ar, p_, *nodes)
        active.append(0 if gate.empty else gate.size)
        return gate, contribs

    monkeypatch.setattr(dp, "collision_kernel", spy)
    gold, st = Golden(system), State.initial(system)
    every = 7 if system.dim == 2 else 29
    worst_v = worst_x = 0.0
    size = np.ptp(system.x0, axis=0).max()
    for n in range(system.n_steps):
        if n % every == 0:
            hs = float_state(system, units, st.x, st.v, st.a, st.step)
            new = step(FloatArith(), hs, p)
            gold.step(st)
            v = np.stack([units.to_velocity(c) for c in new.U], 1)
            x = np.stack([units.to_length(c) for c in new.X], 1)
            worst_v = max(worst_v, np.abs(v - st.v).max() / (np.abs(st.v).max() + 1e-3))
            worst_x = max(worst_x, np.abs(x - st.x).max() / size)
        else:
            gold.step(st)
    assert sum(a > 0 for a in active) >= 10, "contacts never became active: the test would test nothing"
    assert worst_v < 1e-10 and worst_x < 1e-13, (worst_v, worst_x)
