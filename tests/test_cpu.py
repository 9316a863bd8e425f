"""The compiled cpu backend (sim/cpu.py) equals the golden model.

After 100 steps of every built-in scene (the poke scenes too), and of seeded random scenes (hypothesis: meshes, dimensions,
materials with and without a force-dependent damper, gravity, floors with friction, loads, two colliding
objects), positions agree to 1e-12 of the object size and a to 1e-12, with one thread and with two. The
random scenes stiffen the damper's law so that its solve and the stops are exercised. The haptic probe
(MODEL.md 4b): on every [probe] scene through its design poke, the positions, a and the probe's force reading
after each advance() (calls of 1 to 44 steps, device samples cut inside them and at their ends) agree with
golden stepped one step at a time, to the same 1e-12 (the force: of its peak), the probe's held p and pdot
and its contacts exactly; so do a host-driven probe (hold_probe, pressed in, then dragged: friction) and
Golden.forces. The benchmark runs
as a figure (`pytest -s` prints it), not as a timed assertion; its C reference loop must agree with the
cpu backend before it is timed.
"""
from __future__ import annotations

import functools
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


@pytest.mark.parametrize("name", builtin_names())
@pytest.mark.parametrize("where", ["start", "middle"])
def test_every_builtin_scene_equals_golden_after_100_steps(name, where):
    """From the initial state, and from golden's state halfway through the scene (capped at 3000 steps:
    loads, contacts and creep under way; the poke scenes' probe pressed in, on its way back up)."""
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


# ---------------------------------------------------------------------------- the haptic probe (MODEL.md 4b)

PROBE_SCENES = [n for n in builtin_names() if scene_system(n).probe is not None]
# advance() calls of these sizes in turn (k = 10): device samples start inside a call and at its ends, and
# one call runs many samples (the reading must be the last step's, the design poke moved inside the call)
CHUNKS = (7, 10, 13, 25, 1, 44)
# the poke scenes' probe touches the block from about step 340 (1 mm of air at 30 mm/s); at step 1200 it is
# 2.6 mm in, still pressing. The slow test runs the whole scene: in, out, and the block left to itself.
PROBE_STEPS = 1200


def _chunk_sizes(steps: int) -> list:
    out, q = [], 0
    while sum(out) < steps:
        out.append(min(CHUNKS[q % len(CHUNKS)], steps - sum(out)))
        q += 1
    return out


@functools.lru_cache(maxsize=None)
def _golden_poke(name: str, steps: int) -> list:
    """Golden stepped one step at a time along the scene's design poke: at the end of each chunk
    (`_chunk_sizes`), (its state, the force on the probe, the nodes touching it)."""
    system = scene_system(name)
    gold = Golden(system)
    st = gold.initial_state()
    marks = []
    for n in _chunk_sizes(steps):
        for _ in range(n):
            gold.step(st)
        marks.append((st.copy(),) + gold.probe_reading(st))
    return marks


def _compare_poke(name: str, steps: int, threads: int):
    """The cpu backend along the design poke in `_chunk_sizes` calls against `_golden_poke`: returns the
    largest position (of the object size), a and force (of golden's peak force) differences. Asserts that the
    probe presses the block, and that its held p and pdot and its contacts equal golden's exactly."""
    system = scene_system(name)
    size = float(np.ptp(system.x0, axis=0).max())
    marks = _golden_poke(name, steps)
    peak = max(float(np.abs(f).max()) for _, f, _ in marks)
    most = max(ng for _, _, ng in marks)
    assert most >= 1 and peak > 0.02, f"{name}: the probe must press the block ({most} nodes, {peak:.3g} N)"
    cpu = Cpu(system, threads=threads)
    st_ = cpu.initial_state()
    dx = da = df = 0.0
    for n, (g, fg, ng) in zip(_chunk_sizes(steps), marks):
        cpu.advance(st_, n)
        fc, nc = cpu.probe_reading(st_)
        assert st_.step == g.step
        assert nc == ng, f"{name}, step {g.step}: {nc} nodes touch the probe, golden {ng}"
        assert np.array_equal(cpu.probe_position(st_), g.probe.p) and np.array_equal(st_.probe.pdot, g.probe.pdot), \
            f"{name}, step {g.step}: the design poke's p or pdot differs from golden's"
        assert not st_.probe.driven
        dx = max(dx, float(np.abs(st_.x - g.x).max()) / size)
        da = max(da, float(np.abs(st_.a - g.a).max()) if len(g.a) else 0.0)
        df = max(df, float(np.abs(fc - fg).max()) / peak)
    return dx, da, df


def _check_poke(name, steps, threads):
    dx, da, df = _compare_poke(name, steps, threads)
    assert dx <= TOL and da <= TOL and df <= TOL, \
        f"{name}, {threads} thread(s): x differs by {dx:.3g} of the size, a by {da:.3g}, the force by {df:.3g} of its peak"


@pytest.mark.parametrize("threads", [1, 2])
@pytest.mark.parametrize("name", PROBE_SCENES)
def test_probe_scenes_equal_golden_pressing(name, threads):
    """Every built-in [probe] scene for PROBE_STEPS steps of its design poke: through the contact and into the
    block."""
    _check_poke(name, PROBE_STEPS, threads)


@pytest.mark.slow
@pytest.mark.parametrize("threads", [1, 2])
@pytest.mark.parametrize("name", PROBE_SCENES)
def test_probe_scenes_equal_golden_whole_poke(name, threads):
    """Every built-in [probe] scene for its whole duration: the design poke in and out, then the block alone
    (6,000 steps each)."""
    _check_poke(name, scene_system(name).n_steps, threads)


def test_every_builtin_probe_scene_is_compared():
    assert set(PROBE_SCENES) >= {"poke-2d-viscoelastic", "poke-2d-plastic", "poke-2d-rheological",
                                 "poke-3d-rheological", "poke-2d-1000-elements"}


def _host_trajectory(system, press: int = 100, drag: int = 30):
    """A host's device samples: the design poke's first `press` samples (3 mm down: 2 mm into the block),
    then `drag` samples sideways at 20 mm/s with the depth held (the friction relative to the probe)."""
    pb = system.probe
    down = pb.design_path(press, system.dt)
    side = np.zeros(system.dim)
    side[0] = 1.0
    along = down[-1][None, :] + np.outer(np.arange(1, drag + 1) * 0.02 * pb.k * system.dt, side)
    return np.vstack([down, along]), press


@pytest.mark.parametrize("threads", [1, 2])
@pytest.mark.parametrize("name", ["poke-2d-rheological", "poke-3d-rheological"])
def test_host_driven_probe_equals_golden(name, threads):
    """hold_probe(p) then advance(k) per device sample (what Session.step does), on Golden and the cpu backend:
    the same held p and pdot, contacts and forces (1e-12 of the peak), positions (1e-12 of the size)."""
    system = scene_system(name)
    size = float(np.ptp(system.x0, axis=0).max())
    k = system.probe.k
    traj, press = _host_trajectory(system)
    gold, cpu = Golden(system), Cpu(system, threads=threads)
    g, c = gold.initial_state(), cpu.initial_state()
    fg_all, fc_all, dx = [], [], 0.0
    for p in traj:
        for stepper, st_ in ((gold, g), (cpu, c)):
            stepper.hold_probe(st_, p)
            stepper.advance(st_, k)
        assert c.probe.driven and c.step == g.step
        assert np.array_equal(cpu.probe_position(c), gold.probe_position(g)) and np.array_equal(c.probe.pdot, g.probe.pdot)
        fg, ng = gold.probe_reading(g)
        fc, nc = cpu.probe_reading(c)
        assert nc == ng, f"step {g.step}: {nc} nodes touch the probe, golden {ng}"
        fg_all.append(fg)
        fc_all.append(fc)
        dx = max(dx, float(np.abs(c.x - g.x).max()) / size)
    fg_all, fc_all = np.array(fg_all), np.array(fc_all)
    peak = float(np.abs(fg_all).max())
    assert peak > 0.02 and np.abs(fg_all[press:, 0]).max() > 0.05 * peak, "pressed in, then dragged with friction"
    assert dx <= TOL and float(np.abs(fc_all - fg_all).max()) <= TOL * peak, (dx, np.abs(fc_all - fg_all).max() / peak)


def test_forces_with_the_probe_equal_golden():
    """Cpu.forces against Golden.forces with the probe pressed in: the node forces, and the probe's nodes, their
    forces and the force on it (ProbeState.record of the one evaluation)."""
    system = scene_system("poke-2d-rheological")
    g = _golden_poke("poke-2d-rheological", PROBE_STEPS)[-1][0]
    a, b = g.copy(), g.copy()
    Fg, _, adot_g = Golden(system).forces(a, a.step * system.dt)
    Fc, adot_c = Cpu(system).forces(b, b.step * system.dt)
    assert a.probe.contacts >= 1
    assert np.abs(Fc - Fg).max() <= TOL * np.abs(Fg).max() and np.abs(adot_c - adot_g).max() <= TOL * np.abs(adot_g).max()
    assert np.array_equal(b.probe.nodes, a.probe.nodes) and b.probe.contacts == a.probe.contacts
    assert np.abs(b.probe.node_forces - a.probe.node_forces).max() <= TOL * np.abs(a.probe.force).max()
    assert np.abs(b.probe.force - a.probe.force).max() <= TOL * np.abs(a.probe.force).max()
    assert np.array_equal(b.probe.p, a.probe.p) and np.array_equal(b.probe.pdot, a.probe.pdot)


# ---------------------------------------------------------------------------- random scenes

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


@pytest.mark.parametrize("scene, steps", [("press-2d-rheological", 300), ("poke-2d-rheological", 600)])
def test_simulate_cli_cpu_backend_writes_golden_positions(tmp_path, scene, steps):
    """`rheo simulate --backend cpu` (a poke scene: the probe follows its design poke, in contact from step
    340) writes golden's positions."""
    outs = {}
    for backend in ("golden", "cpu"):
        out = tmp_path / f"{backend}.npz"
        r = subprocess.run([sys.executable, "-m", "sim.cli", "simulate", scene, "--backend", backend,
                            "--steps", str(steps), "--every", "100", "--out", str(out)], capture_output=True, text=True)
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
