"""The golden model against closed forms (MODEL.md section 6), physics invariants and element laws."""
from __future__ import annotations

import math

import numpy as np
import pytest

from golden.elements import ElementParams, element_forces
from golden.errors import SimulationDiverged
from golden.model import simulate
from golden.scene import load_scene
from measures import quarter_sinks


def scene_from(tmp_path, text: str, name="scene"):
    p = tmp_path / f"{name}.toml"
    p.write_text(text)
    return load_scene(p)


# ---------------------------------------------------------------- closed forms

@pytest.fixture(scope="module")
def creep():
    system = load_scene("creep-1d")
    return system, simulate(system)


def test_creep_displacement_at_end_of_load(creep):
    system, run = creep
    F, k1, c1, c2, t = 0.05, 50.0, 0.5, 5.0, 0.2
    expected = (F / k1) * (1 - math.exp(-t * k1 / c1)) + F * t / c2
    got = np.interp(t, run.t, run.x[:, 1, 0]) - 0.01
    assert abs(got - expected) <= 0.02 * expected, (got, expected)


def test_creep_permanent_set(creep):
    system, run = creep
    expected = 0.05 * 0.2 / 5.0          # integral of F dt over c2
    got = run.x[-1, 1, 0] - 0.01
    assert abs(got - expected) <= 0.005 * expected, (got, expected)
    assert np.all(run.x[:, 0] == 0.0)     # the pinned node never moves


def test_constant_stretch_rate_force_law():
    """Drive one element at constant stretch rate V; T(t) = c2 V (1 - c2/(c1+c2) exp(-t k1/(c1+c2)))."""
    k1, c1, c2, a0, l0, V, dt = 40.0, 0.3, 2.0, 0.5, 0.01, 0.02, 1e-6
    p = ElementParams.build(np.array([k1]), np.array([c1]), np.array([0.0]), np.array([1.0]),
                            np.array([a0 * l0]), np.array([c2]), np.array([c2]), np.array([0.0]), np.array([1.0]))
    i, j = np.array([0]), np.array([1])
    a = np.array([a0])
    tau = (c1 + c2) / k1
    worst = 0.0
    for step in range(int(0.1 / dt) + 1):
        t = step * dt
        xt = np.array([[0.0, l0 + V * t], [0.0, 0.0]])
        vt = np.array([[0.0, V], [0.0, 0.0]])
        T, _, _, adot = element_forces(xt, vt, a, i, j, p)
        if step % 1000 == 0:
            expected = c2 * V * (1 - c2 / (c1 + c2) * math.exp(-t / tau))
            worst = max(worst, abs(T[0] - expected) / (c2 * V))
        a = a + dt * adot
    assert worst < 1e-3, worst


def test_hanging_mass_sinks_at_mg_over_c2(tmp_path):
    m, c2, g = 0.01, 5.0, 9.81
    system = scene_from(tmp_path, f"""
dim = 2
[integrator]
dt = 1e-4
duration = 1.0
[world]
gravity = [0.0, {-g}]
[[objects]]
mesh = {{ type = "explicit", nodes = [[0.0, 0.0], [0.0, -0.01]], edges = [[0, 1]] }}
material = {{ k1 = 50.0, c1 = 0.5, c2 = {c2}, a0 = 0.5, a_min = 0.0, a_max = 1.0 }}
masses = [{m}, {m}]
pinned = [0]
""")
    run = simulate(system, every=100)
    late = run.t >= 0.8
    speed = -run.v[late, 1, 1]
    assert np.all(np.abs(speed - m * g / c2) <= 0.01 * m * g / c2), (speed.min(), speed.max(), m * g / c2)


# ---------------------------------------------------------------- element laws

def _one_element(k1, c1, c2, a, a_min, a_max, l0=0.01):
    p = ElementParams.build(np.array([k1]), np.array([c1]), np.array([a_min]), np.array([a_max]),
                            np.array([a * l0]), np.array([c2]), np.array([c2]), np.array([0.0]), np.array([1.0]))
    return p


def test_stretched_element_pulls_its_ends_together():
    p = _one_element(50.0, 0.5, 5.0, 0.5, 0.0, 1.0)
    xt = np.array([[0.0, 0.012], [0.0, 0.0]])       # stretched by 2 mm, at rest
    T, T_l, d, _ = element_forces(xt, np.zeros((2, 2)), np.array([0.5]), np.array([0]), np.array([1]), p)
    assert T[0] > 0
    force_on_start = T_l[0] * d[0][0]               # +T e on the start node
    assert force_on_start > 0                       # points towards the end node (+x)


def test_viscoelastic_clamp_gives_voigt_element():
    """a_min = a_max = 1: T = k1 (l - L) + c1 ldot exactly (the active-clamp resolution)."""
    k1, c1, c2, l0 = 50.0, 0.5, 5.0, 0.01
    p = _one_element(k1, c1, c2, 1.0, 1.0, 1.0, l0)
    rng = np.random.default_rng(1)
    for _ in range(50):
        l, ldot = l0 * rng.uniform(0.5, 1.5), rng.uniform(-0.1, 0.1)
        xt = np.array([[0.0, l], [0.0, 0.0]])
        vt = np.array([[0.0, ldot], [0.0, 0.0]])
        T, *_ = element_forces(xt, vt, np.array([1.0]), np.array([0]), np.array([1]), p)
        assert T[0] == pytest.approx(k1 * (l - l0) + c1 * ldot, rel=1e-12, abs=1e-15)


def test_unclamped_tension_equals_series_form():
    """While a is free: T = c2 (k1 s + c1 ldot) / (c1 + c2) = damper force c2 ((1 - a) ldot - adot l)."""
    k1, c1, c2, l0 = 30.0, 0.7, 3.0, 0.01
    rng = np.random.default_rng(2)
    for _ in range(50):
        a = rng.uniform(0.2, 0.8)
        p = _one_element(k1, c1, c2, 0.5, 0.0, 1.0, l0)
        l, ldot = l0 * rng.uniform(0.5, 1.5), rng.uniform(-0.1, 0.1)
        xt = np.array([[0.0, 0.0], [0.0, l]])
        vt = np.array([[0.0, 0.0], [0.0, ldot]])
        T, _, _, adot = element_forces(xt, vt, np.array([a]), np.array([0]), np.array([1]), p)
        s = a * l - 0.5 * l0
        assert T[0] == pytest.approx(c2 * (k1 * s + c1 * ldot) / (c1 + c2), rel=1e-10, abs=1e-15)
        assert T[0] == pytest.approx(c2 * ((1 - a) * ldot - adot[0] * l), rel=1e-10, abs=1e-15)


def test_nonlinear_damper_curve():
    c_min, c_max, f1, f2 = 0.5, 50.0, 0.01, 0.1
    p = ElementParams.build(*[np.full(5, v) for v in (1.0, 1.0, 0.0, 1.0, 0.01, c_min, c_max, f1, f2)])
    f = np.array([0.0, f1, 0.5 * (f1 + f2), f2, 1.0])
    c2 = p.damper(f)
    B = math.log(c_max / c_min) / (f2 - f1)
    assert c2[0] == c_max and c2[-1] == c_min
    assert c2[1] == pytest.approx(c_max) and c2[3] == pytest.approx(c_min)
    assert c2[2] == pytest.approx(c_max * math.exp(-B * 0.5 * (f2 - f1)), rel=1e-12)


# ---------------------------------------------------------------- invariants

def _free_objects_scene(tmp_path, with_collision: bool):
    col = """
[collision]
K = 2e3
C = 0.5
threshold = 0.002
mu = 0.3
""" if with_collision else ""
    return scene_from(tmp_path, f"""
dim = 2
[integrator]
dt = 1e-4
duration = 0.1
[topology]
K = 1e3
C = 0.5
eps = 0.002
{col}
[[objects]]
name = "left"
mesh = {{ type = "rectangle", size = [0.03, 0.02], divisions = [3, 2] }}
material = {{ preset = "rheological", node_mass = 1e-3 }}
velocity = [0.2, 0.05]
[[objects]]
name = "right"
mesh = {{ type = "rectangle", size = [0.03, 0.02], divisions = [3, 2] }}
material = {{ preset = "viscoelastic", node_mass = 2e-3 }}
position = [0.035, 0.005]
velocity = [-0.2, 0.0]
""")


@pytest.mark.parametrize("with_collision", [False, True], ids=["free", "colliding"])
def test_momentum_conserved_without_external_force(tmp_path, with_collision):
    system = _free_objects_scene(tmp_path, with_collision)
    rng = np.random.default_rng(3)
    system.v0 = system.v0 + rng.normal(0, 0.05, system.v0.shape)      # random internal motion
    system.x0 = system.x0 + rng.normal(0, 5e-4, system.x0.shape)      # pre-stressed elements
    run = simulate(system, every=100)
    p = (run.v * system.mass[None, :, None]).sum(1)
    scale = (np.abs(run.v[0]) * system.mass[:, None]).sum()
    assert np.max(np.abs(p - p[0])) <= 1e-12 * scale, np.max(np.abs(p - p[0])) / scale
    if with_collision:   # the objects did touch: otherwise the test would not test contact forces
        gap = run.x[:, system.node_object == 1, 0].min(1) - run.x[:, system.node_object == 0, 0].max(1)
        assert gap.min() < system.collision.threshold


@pytest.mark.parametrize("scene", ["press-2d-viscoelastic", "press-2d-rheological"])
def test_symmetric_press_stays_mirror_symmetric(scene):
    system = load_scene(scene)
    run = simulate(system, steps=6000, every=500)
    width = system.x0[:, 0].max()
    mirror = np.lexsort(((width - system.x0[:, 0]).round(12), system.x0[:, 1].round(12)))
    order = np.lexsort((system.x0[:, 0].round(12), system.x0[:, 1].round(12)))
    partner = np.empty(system.n_nodes, np.int64)
    partner[order] = mirror
    assert np.allclose(system.x0[partner, 0], width - system.x0[:, 0]) and np.allclose(system.x0[partner, 1], system.x0[:, 1])
    x = run.x
    err_x = np.abs(x[:, partner, 0] - (width - x[:, :, 0])).max()
    err_y = np.abs(x[:, partner, 1] - x[:, :, 1]).max()
    moved = np.abs(x[-1] - x[0]).max()
    assert moved > 1e-4                                  # it was really pressed
    assert max(err_x, err_y) <= 1e-9 * width, (err_x, err_y)


def test_divergence_is_detected(tmp_path):
    system = scene_from(tmp_path, """
dim = 2
[integrator]
dt = 0.05
duration = 20.0
[[objects]]
mesh = { type = "rectangle", size = [0.02, 0.02], divisions = [2, 2] }
material = { preset = "rigid", node_mass = 1e-3 }
velocity = [0.0, 0.0]
pinned = [0]
[[loads]]
nodes = [8]
force = [0.1, 0.0]
""")
    with pytest.raises(SimulationDiverged, match="diverged at step"):
        with np.errstate(all="ignore"):
            simulate(system)


# ---------------------------------------------------------------- topology preservation

def _triangle_crush(tmp_path, topology: bool):
    topo = """
[topology]
K = 1e3
C = 0.5
eps = 0.002
""" if topology else ""
    system = scene_from(tmp_path, f"""
dim = 2
[integrator]
dt = 1e-5
duration = 0.05
{topo}
[[objects]]
mesh = {{ type = "explicit", nodes = [[0.0, 0.0], [0.01, 0.0], [0.005, 0.008]], cells = [[0, 1, 2]] }}
material = {{ preset = "viscoelastic", k1 = 5.0, node_mass = 1e-3 }}
pinned = [0, 1]
[[loads]]
nodes = [2]
force = [0.0, -1.0]
""", name=f"crush{topology}")
    run = simulate(system, every=100)
    return run.x[:, 2, 1]      # height of the apex above the base edge


def test_topology_preservation_prevents_inversion(tmp_path):
    assert _triangle_crush(tmp_path, topology=False).min() < 0      # without it the triangle inverts
    assert _triangle_crush(tmp_path, topology=True).min() > 0       # with it the apex stays above


# ---------------------------------------------------------------- behaviours of the seed's figures

def _recovery(name):
    system = load_scene(name)
    run = simulate(system)
    top = system.loads[0].nodes
    lo, hi = system.x0[top, 0].min(), system.x0[top, 0].max()
    bottom = np.flatnonzero((system.x0[:, 1] == system.x0[:, 1].min()) & (system.x0[:, 0] >= lo) & (system.x0[:, 0] <= hi))
    thickness = run.x[:, top, 1].mean(1) - run.x[:, bottom, 1].mean(1)
    disp = thickness[0] - thickness
    return 1 - disp[-1] / disp.max(), disp.max() / thickness[0]


@pytest.mark.parametrize("name,lo,hi", [("press-2d-viscoelastic", 0.95, 1.01),
                                        ("press-2d-plastic", -0.01, 0.10),
                                        ("press-2d-rheological", 0.20, 0.80)])
def test_press_recovery(name, lo, hi):
    recovery, peak = _recovery(name)
    assert peak > 0.02                 # a visible press: more than 2 % of the thickness
    assert lo < recovery < hi, recovery


def _sink_rates(name):
    system = load_scene(name)
    return quarter_sinks(system, simulate(system))


def test_linear_damper_keeps_sinking_under_gravity():
    first, last = _sink_rates("gravity-2d-linear")
    assert first > 0 and last > 0.1 * first, (first, last)


def test_nonlinear_damper_stops_sinking_under_gravity():
    first, last = _sink_rates("gravity-2d-nonlinear")
    assert first > 0 and abs(last) < 0.01 * first, (first, last)


def test_state_copy_is_independent():
    """State.copy shares no buffer with its original (a stepped original must leave the copy alone)."""
    from golden.model import Golden
    from golden.system import State
    from conftest import scene_system
    system = scene_system("gravity-2d-linear")
    st = State.initial(system)
    cp = st.copy()
    Golden(system).step(st)
    assert not np.shares_memory(cp.x, st.x) and not np.shares_memory(cp.v, st.v)
    assert np.array_equal(cp.x, system.x0) and not np.array_equal(st.v, cp.v)
