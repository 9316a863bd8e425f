"""The compiled cpu backend (sim/cpu.py) equals the golden model.

After 100 steps of every built-in scene, and of seeded random scenes (hypothesis: meshes, dimensions,
materials with and without a force-dependent damper, gravity, floors with friction, loads, two colliding
objects), positions agree to 1e-12 of the object size and a to 1e-12, with one thread and with two. The
random scenes stiffen the damper's law so that its solve and the stops are exercised. The benchmark runs
as a figure (`pytest -s` prints it), not as a timed assertion; its C reference loop must agree with the
cpu backend before it is timed.
"""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from golden.model import Golden, simulate
from golden.errors import SimulationDiverged
from golden.system import State
from golden.scene import builtin_names, load_scene
from sim.cpu import Cpu

from conftest import scene_system

TOL = 1e-12
STEPS = 100


def _compare(system, steps=STEPS, threads=1, start=0):
    """Largest position difference (relative to the object size) and a difference after `steps` steps from
    golden's state at step `start`, and how far golden moved in those steps."""
    gold, g = Golden(system), State.initial(system)
    for _ in range(start):
        gold.step(g)
    cpu = Cpu(system, threads=threads)
    c, x_start = g.copy(), g.x.copy()
    for _ in range(steps):
        gold.step(g)
    cpu.advance(c, steps)
    size = float(np.ptp(system.x0, axis=0).max())
    dx = float(np.abs(c.x - g.x).max()) / size
    da = float(np.abs(c.a - g.a).max()) if len(g.a) else 0.0
    moved = float(np.abs(g.x - x_start).max()) / size
    return dx, da, moved


@pytest.mark.parametrize("name", [n for n in builtin_names() if scene_system(n).probe is None])  # probe: later
@pytest.mark.parametrize("where", ["start", "middle"])
def test_every_builtin_scene_equals_golden_after_100_steps(name, where):
    """From the initial state, and from golden's state halfway through the scene (capped at 3000 steps:
    loads, contacts and creep under way)."""
    system = scene_system(name)
    start = 0 if where == "start" else min(system.n_steps // 2, 3000)
    dx, da, moved = _compare(system, start=start)
    assert dx <= TOL and da <= TOL, f"{name}: x differs by {dx:.3g} of the size, a by {da:.3g}"
    if where == "middle":
        assert moved > 0.0, f"{name}: nothing moved in {STEPS} steps, the comparison proves nothing"


@pytest.mark.parametrize("name", ["press-2d-rheological", "friction-3d-mu03", "table-push-2d-gravity"])
def test_two_threads_equal_golden(name):
    dx, da, _ = _compare(scene_system(name), threads=2)
    assert dx <= TOL and da <= TOL, f"{name}, 2 threads: x differs by {dx:.3g}, a by {da:.3g}"


def _random_scene(tmp_path, draw_seed: int) -> tuple:
    """A valid random scene from a seed: returns (System, the TOML text)."""
    rng = np.random.default_rng(draw_seed)
    dim = int(rng.choice([2, 3], p=[0.7, 0.3]))
    size = [0.03, 0.02] if dim == 2 else [0.02, 0.02, 0.015]
    div = [int(v) for v in rng.integers(1, 4 if dim == 2 else 3, dim)]
    kind = "rectangle" if dim == 2 else "box"
    linear = bool(rng.random() < 0.25)
    k1, c1 = float(rng.uniform(5, 200)), float(rng.uniform(0.05, 2))
    a0 = float(rng.uniform(0.3, 0.9))
    a_min, a_max = float(rng.uniform(0.02, a0 * 0.98)), float(rng.uniform(min(1.0, a0 * 1.02), 1.0))
    if rng.random() < 0.3:                           # start on a stop
        a0 = a_min if rng.random() < 0.5 else a_max
    if linear:
        damper = f"c2 = {float(rng.uniform(0.2, 5))!r}"
    else:
        cmin = float(rng.uniform(0.05, 1))
        f1 = float(rng.uniform(1e-4, 5e-3))         # low knees: the loads below reach the exponential piece
        damper = (f"c_min = {cmin!r}, c_max = {cmin * float(rng.uniform(5, 2000))!r}, "
                  f"f1 = {f1!r}, f2 = {f1 * float(rng.uniform(2, 20))!r}")
    g = [0.0] * (dim - 1) + [float(rng.choice([0.0, -9.81]))]
    floor = ""
    if rng.random() < 0.5:
        floor = (f"[world.floor]\nheight = 0.0\nK = 1e4\nC = 1.0\nmu = {float(rng.choice([0.0, 0.4]))!r}\n"
                 f"k_f = 2.0\n")
    force = [float(v) for v in rng.uniform(-0.05, 0.05, dim)]
    pos = [0.0] * (dim - 1) + [float(rng.uniform(-0.0005, 0.001))]
    second = ""
    collision = ""
    # a second object resting just above the first, at an offset that puts no vertex exactly on a facet's
    # edge (there a contact's foot weight is 0 to rounding, and float64 sums in another order decide it)
    if rng.random() < 0.35:
        top = size[-1] + 0.0005
        second = f"""
[[objects]]
name = "top"
mesh = {{ type = "{kind}", size = {[s / 2 for s in size]}, divisions = {[1] * dim} }}
material = {{ preset = "viscoelastic", k1 = 100.0, c1 = 0.5, node_mass = 1e-3 }}
position = {[float(v) for v in rng.uniform(0.002, 0.008, dim - 1)] + [top]}
"""
        collision = (f"[collision]\nK = 3e3\nC = 0.3\nthreshold = 0.002\nmu = {float(rng.choice([0.0, 0.3]))!r}\n"
                     f"k_f = 2.0\n")
    topology = "[topology]\nK = 500.0\nC = 0.2\neps = 0.002\n" if rng.random() < 0.5 else ""
    text = f"""description = "random scene {draw_seed}"
dim = {dim}

[integrator]
dt = 5e-5
duration = 0.01

[world]
gravity = {g}

{floor}
{topology}
{collision}
[[objects]]
name = "body"
mesh = {{ type = "{kind}", size = {size}, divisions = {div} }}
material = {{ preset = "rheological", k1 = {k1!r}, c1 = {c1!r}, a0 = {a0!r}, a_min = {a_min!r}, a_max = {a_max!r}, {damper}, node_mass = 1e-3 }}
position = {pos}
pinned = [0]

[[loads]]
object = "body"
nodes = [{int(rng.integers(1, 3))}]
force = {force}
start = 0.0
end = {float(rng.uniform(0.001, 0.01))!r}
{second}"""
    path = tmp_path / f"random-{draw_seed}.toml"
    path.write_text(text)
    try:
        return load_scene(str(path)), text
    except Exception as exc:           # the generator must write valid scenes: show what it wrote
        raise AssertionError(f"{exc}\n{text}") from None


@settings(max_examples=40, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2 ** 31 - 1), threads=st.sampled_from([1, 2]))
def test_random_scenes_equal_golden(tmp_path, seed, threads):
    system, text = _random_scene(tmp_path, seed)
    dx, da, moved = _compare(system, threads=threads)
    assert moved > 0.0
    assert dx <= TOL and da <= TOL, f"x differs by {dx:.3g} of the size, a by {da:.3g} ({threads} threads)\n{text}"


def test_random_scenes_reach_the_solve_and_the_stops(tmp_path):
    """The generator is not vacuous: across the seeds, elements are solved on the exponential piece and
    sit on both stops during the compared steps."""
    solved = stopped_lo = stopped_hi = 0
    for seed in range(25):
        system, _ = _random_scene(tmp_path, seed)
        p, cpu = system.elem, Cpu(system)
        st_ = cpu.initial_state()
        for _ in range(STEPS // 10):
            cpu.advance(st_, 10)
            _, adot = cpu.forces(st_, st_.step * system.dt)
            if p.nonlinear:
                solved += int(np.count_nonzero(cpu.flagged & (st_.a > p.a_min) & (st_.a < p.a_max)))
            stopped_lo += int(np.count_nonzero(st_.a <= p.a_min))
            stopped_hi += int(np.count_nonzero(st_.a >= p.a_max))
    assert solved > 0 and stopped_lo > 0 and stopped_hi > 0, (solved, stopped_lo, stopped_hi)


def test_a_diverging_cpu_run_is_reported():
    system = scene_system("press-2d-viscoelastic")
    from golden.measure import with_dt
    fast = with_dt(system, system.dt * 40, steps=400)
    with pytest.raises(SimulationDiverged, match="diverged"):
        simulate(fast, every=20, stepper=Cpu(fast))


def test_simulate_cli_cpu_backend_writes_golden_positions(tmp_path):
    outs = {}
    for backend in ("golden", "cpu"):
        out = tmp_path / f"{backend}.npz"
        r = subprocess.run([sys.executable, "-m", "sim.cli", "simulate", "press-2d-rheological", "--backend", backend,
                            "--steps", "300", "--every", "100", "--out", str(out)], capture_output=True, text=True)
        assert r.returncode == 0, r.stderr
        outs[backend] = np.load(out)
    size = float(np.ptp(outs["golden"]["x"][0], axis=0).max())
    assert np.abs(outs["cpu"]["x"] - outs["golden"]["x"]).max() <= TOL * size


def test_benchmark_prints_cpu_golden_and_c_figures():
    """`rheo bench --backend cpu` on two sizes: the figures, with the C loop checked against the cpu backend."""
    r = subprocess.run([sys.executable, "-m", "sim.cli", "bench", "--backend", "cpu", "--sizes", "1000", "10000",
                        "--seconds", "0.5", "--json"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    rows = json.loads(r.stdout)["results"]
    for row in rows:
        print(f"\n{row['elements']} elements: golden {row['golden_steps_per_s']:.0f} steps/s, "
              f"cpu 1 thread {row['cpu_1_threads_steps_per_s']:.0f}, 2 threads {row.get('cpu_2_threads_steps_per_s', 0):.0f}"
              f" ({row['cpu_ratio_to_golden']:.1f}x golden), C loop {row.get('c_reference_steps_per_s', float('nan')):.0f}")
        assert row["cpu_steps_per_s"] > 0 and row["golden_steps_per_s"] > 0
        assert row.get("c_reference_max_difference", 0.0) <= TOL
    assert [r_["elements"] for r_ in rows] == [1008, 9861]
