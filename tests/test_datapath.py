"""The hardware datapath run in float64 equals the golden model: the datapath computes the physics.

Any difference beyond float rounding would mean the hardware description (hw/datapath.py) and the
physics reference (golden/) disagree on an equation, an order of operations or a unit conversion.
"""
from __future__ import annotations

import numpy as np
import pytest

from golden.model import simulate
from golden.scene import builtin_names, compile_scene, load_scene
from hw.arith import FloatArith
from hw.bittrue import float_state
from hw.datapath import NotSupported, Params, step
from hw.units import HardwareUnits

STEPS = 1500


def _compare(sys, steps=STEPS):
    run = simulate(sys, steps=steps, every=steps)
    units = HardwareUnits.of(sys)
    p = Params.of(sys, units)
    st = float_state(sys, units, sys.x0, sys.v0, sys.a0)
    ar = FloatArith()
    for _ in range(steps):
        st = step(ar, st, p)
    x = np.stack([units.to_length(c) for c in st.X], 1)
    v = np.stack([units.to_velocity(c) for c in st.U], 1)
    size = np.ptp(sys.x0, axis=0).max()
    moved = np.abs(run.x[-1] - run.x[0]).max()
    return np.abs(x - run.x[-1]).max() / size, np.abs(v - run.v[-1]).max(), np.abs(st.A - run.a[-1]).max(), moved, ar


def _no_collision_scenes():
    names = []
    for n in builtin_names():
        if compile_scene(load_scene(n)).collision is None:
            names.append(n)
    return names


@pytest.mark.parametrize("name", _no_collision_scenes())
def test_float_datapath_equals_golden(name):
    sys = compile_scene(load_scene(name))
    ex, ev, ea, moved, _ = _compare(sys)
    assert moved > 0                                       # something happened in these steps
    assert ex < 1e-12 and ea < 1e-12, (ex, ev, ea)
    assert ev < 1e-9 * max(1.0, np.abs(sys.v0).max()), ev


def _crush(tmp_path, dim):
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
material = {{ preset = "rheological", k1 = 5.0, c2 = 5.0, node_mass = 1e-3 }}
velocity = {"[0.05, 0.0]" if dim == 2 else "[0.05, 0.02, 0.0]"}
pinned = {pinned}
[[loads]]
nodes = [{apex}]
force = {force}
""")
    return compile_scene(load_scene(p))


@pytest.mark.parametrize("dim", [2, 3])
def test_float_datapath_equals_golden_with_topology_floor_and_friction(tmp_path, dim):
    """A cell crushed towards inversion onto a frictional floor: every optional unit is active.

    Constant c2 here: the one-step-lagged nonlinear damper can flip between two forces every step
    (a period-2 oscillation of the lagged scheme), which amplifies float rounding differences.
    """
    sys = _crush(tmp_path, dim)
    ex, ev, ea, moved, ar = _compare(sys, steps=2000)
    assert {"tdist", "w", "fe"} <= set(ar.peak)           # the topology unit really acted
    assert ex < 1e-12 and ea < 1e-12, (ex, ea)


def test_collision_scenes_are_refused_with_a_message():
    name = next(n for n in builtin_names() if compile_scene(load_scene(n)).collision is not None)
    sys = compile_scene(load_scene(name))
    with pytest.raises(NotSupported, match="collisions"):
        Params.of(sys, HardwareUnits.of(sys))
