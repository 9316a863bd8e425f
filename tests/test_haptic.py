"""The haptic probe (MODEL.md 4b, issue 16): its contact physics, exactness in fixed point, hysteresis of the
presets, the haptic API on every backend, the trajectory CSV, the command line and the play window.

    probe force + sum of node probe forces = 0 bit for bit (fixed point), momentum balance (golden);
    a poke-and-release leaves a dent in the plastic preset, none in the viscoelastic one (within 1 %);
    the float datapath equals golden with a driven probe; the node kernel's probe term in hardware (PipeArith)
    equals the bit-true model; the same forces from `connect(...).step(p)` on every backend.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from golden.model import Golden
from golden.scene import load_scene
from golden.system import State
from sim.haptic import HapticError, connect, design_trajectory, read_trajectory, write_trajectory

from conftest import scene_system

ROOT = Path(__file__).resolve().parents[1]


def rheo(*args, timeout=600):
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.run([sys.executable, "-m", "sim.cli", *map(str, args)], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=timeout)


def one_line_error(proc, *words):
    assert "Traceback" not in proc.stderr + proc.stdout, proc.stderr
    assert proc.returncode == 2, (proc.returncode, proc.stderr)
    lines = proc.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("rheo: error:"), proc.stderr
    for w in words:
        assert w in lines[0], f"{w!r} not in {lines[0]!r}"
    return lines[0]


def press_scene(tmp_path, dim=2, free=False, preset="viscoelastic", K=500.0, C=1.0, mu=0.3, depth=0.004,
                duration=0.05):
    """A small block (pinned at the bottom, or free in space) and a probe whose design poke presses into the
    middle of its top (1 mm of air first)."""
    if dim == 2:
        mesh = 'mesh = { type = "rectangle", size = [0.04, 0.02], divisions = [8, 4] }'
        pinned, pos = 'pinned = { box = [[-0.001, -0.001], [0.041, 0.001]] }', "[0.02, 0.027]"
        R = 0.006
    else:
        mesh = 'mesh = { type = "box", size = [0.02, 0.02, 0.01], divisions = [4, 4, 2] }'
        pinned, pos = 'pinned = { box = [[-0.001, -0.001, -0.001], [0.021, 0.021, 0.001]] }', "[0.01, 0.01, 0.017]"
        R = 0.006
    p = tmp_path / f"press{dim}{'-free' if free else ''}.toml"
    p.write_text(f"""
dim = {dim}
[integrator]
dt = 1e-4
duration = {duration}
[topology]
K = 1e3
C = 0.5
eps = 0.002
[[objects]]
{mesh}
{'' if free else pinned}
material = {{ preset = "{preset}", node_mass = 2e-3 }}
[probe]
radius = {R}
K = {K}
C = {C}
mu = {mu}
position = {pos}
depth = {depth}
poke_time = {2 * duration}
""")
    return load_scene(p)


# ---------------------------------------------------------------------------------------------- physics

@pytest.mark.parametrize("preset", ["wide", "narrow"])
def test_probe_force_is_minus_the_exact_sum_of_the_node_forces_in_fixed_point(tmp_path, preset):
    """A disc pressed into a pinned block: every step, the force word on the probe plus the node probe force
    words is 0 as an integer; they sit at the node force accumulator's binary point, so each node takes its
    force exactly."""
    from hw.bittrue import BitTrue
    system = press_scene(tmp_path, depth=0.005, duration=0.05)
    bt = BitTrue(system, preset)
    fm = bt.formats
    assert fm["pfe"].f == fm["fprobe"].f == fm["facc"].f == fm["fe"].f
    st = bt.initial_state()
    touching = 0
    for _ in range(system.n_steps):
        bt.step(st)
        pr = st.probe
        if pr.contacts:
            touching += 1
            for k in range(system.dim):
                assert int(pr.F[k]) + sum(int(v) for v in pr.node_F[k]) == 0
            assert pr.F[1] > 0                                         # the block pushes the probe up
    assert touching > 100, "the probe must press the block for the test to test anything"
    assert "fprobe" not in bt.sat and "facc" not in bt.sat and "pfe" not in bt.sat, dict(bt.sat)


def test_probe_force_sum_is_exact_and_not_a_rounded_sum(tmp_path):
    """Control: summing the node forces after rounding each to a coarser grid would not give the probe's
    word; the exact sum does (the assertion above can fail)."""
    from hw.bittrue import BitTrue
    system = press_scene(tmp_path, depth=0.005, duration=0.05)
    bt = BitTrue(system, "narrow")
    st = bt.initial_state()
    misses = 0
    for _ in range(system.n_steps):
        bt.step(st)
        pr = st.probe
        if pr.contacts > 1:
            coarse = sum(((np.asarray(pr.node_F[1]) + 8) >> 4) << 4)
            misses += int(coarse + int(pr.F[1]) != 0)
    assert misses > 0


@pytest.mark.parametrize("dim", [2, 3])
def test_momentum_balance_with_the_probe_force_counted(tmp_path, dim):
    """A free block (no pins, no floor, no gravity) pushed by the probe: the momentum it gains is minus the
    impulse of the force on the probe, sum over steps of F_probe dt (golden, to rounding)."""
    system = press_scene(tmp_path, dim=dim, free=True, preset="rheological", depth=0.004, duration=0.05)
    g = Golden(system)
    st = g.initial_state()
    impulse = np.zeros(dim)
    for _ in range(system.n_steps):
        g.step(st)
        impulse += st.probe.force * system.dt
    momentum = (st.v * system.mass[:, None]).sum(0)
    assert np.linalg.norm(momentum) > 1e-6, "the probe must push the block"
    scale = float((np.abs(st.v) * system.mass[:, None]).sum())
    assert np.abs(momentum + impulse).max() <= 1e-12 * scale, (momentum, impulse)


def top_dent(system, x) -> float:
    """How far the top of the block under the probe sits below its rest height (m, positive: a dent)."""
    pb = system.probe
    side = np.linalg.norm(system.x0[:, :-1] - pb.position[None, :-1], axis=1)
    top = system.x0[:, -1] >= system.x0[:, -1].max() - 1e-9
    under = top & (side < 0.5 * pb.radius)
    return float(np.max(system.x0[under, -1] - x[under, -1]))


def poke_and_release(name):
    system = scene_system(name)
    g = Golden(system)
    st = g.initial_state()
    g.advance(st, system.n_steps)
    pb = system.probe
    indentation = pb.depth - (pb.position[-1] - pb.radius - system.x0[:, -1].max())
    return system, top_dent(system, st.x), indentation


def test_plastic_poke_leaves_a_dent():
    system, dent, depth = poke_and_release("poke-2d-plastic")
    assert depth == pytest.approx(0.005)
    assert dent > 0.8 * depth, (dent, depth)


def test_viscoelastic_poke_leaves_no_dent():
    system, dent, depth = poke_and_release("poke-2d-viscoelastic")
    assert abs(dent) < 0.01 * depth, (dent, depth)


def test_rheological_poke_keeps_part_of_its_dent():
    system, dent, depth = poke_and_release("poke-2d-rheological")
    assert 0.05 * depth < dent < 0.8 * depth, (dent, depth)


# ---------------------------------------------------------------------------------------------- datapath

def sideways(system, samples=120):
    """Down into the block, then sideways along x (the friction's slip), one position per device sample."""
    pb = system.probe
    down = np.linspace(0.0, 0.003, samples // 2)
    side = np.linspace(0.0, 0.004, samples - samples // 2)
    off = np.zeros((samples, system.dim))
    off[:samples // 2, -1] = -down
    off[samples // 2:, -1] = -0.003
    off[samples // 2:, 0] = side
    return pb.position[None, :] + off


@pytest.mark.parametrize("dim", [2, 3])
def test_float_datapath_equals_golden_with_a_driven_probe(tmp_path, dim):
    """The hardware's step in float64 (hw/datapath.py) equals golden, the probe driven sample by sample
    through the same API (pressed in, then dragged sideways: normal force, damping and friction)."""
    from hw.bittrue import FloatDatapath
    system = press_scene(tmp_path, dim=dim, preset="rheological")
    g, fd = Golden(system), FloatDatapath(system)
    gs, fs = g.initial_state(), fd.initial_state()
    size = float(np.ptp(system.x0, axis=0).max())
    worst_x = worst_f = peak = 0.0
    for p in sideways(system):
        for stp, st in ((g, gs), (fd, fs)):
            stp.hold_probe(st, p)
            stp.advance(st, system.probe.k)
        fg, cg = g.probe_reading(gs)
        ff, cf = fd.probe_reading(fs)
        assert cg == cf
        x, _, _ = fd.frame(fs)
        worst_x = max(worst_x, float(np.abs(x - gs.x).max()) / size)
        worst_f = max(worst_f, float(np.abs(ff - fg).max()))
        peak = max(peak, float(np.abs(fg).max()))
    assert peak > 0.05 and np.abs(fg[0]) > 1e-3, "pressed and dragged: normal force and friction"
    assert worst_x < 1e-12 and worst_f < 1e-12 * peak, (worst_x, worst_f, peak)


def _pipe_node_kernel(bt, X, U, P, Pdot, Lo, Hi):
    """The node kernel with the probe as a PipeArith pipeline in Amaranth's simulator, one node per cycle:
    returns (new X, new U, the probe force per node (0 outside the probe)) as raw words."""
    from amaranth.hdl import Module, Signal, signed
    from amaranth.sim import Simulator
    from hw.datapath import ProbeInputs, _node_flags, node_kernel
    from hw.pipeline import PipeArith
    from hw.rtl_fixed import as_shape
    p, fmt, D = bt.params, bt.formats, bt.system.dim
    m = Module()
    valid = Signal()
    xs = [Signal(as_shape(fmt["x"]), name=f"x{k}") for k in range(D)]
    us = [Signal(as_shape(fmt["u"]), name=f"u{k}") for k in range(D)]
    fs = [Signal(signed(fmt["facc"].width), name=f"f{k}") for k in range(D)]
    regs = {name: [Signal(as_shape(fmt[q]), name=f"{name}{k}") for k in range(D)]
            for name, q in (("P", "x"), ("Pdot", "pdot"), ("Lo", "x"), ("Hi", "x"))}
    ar = PipeArith(m, fmt, bt.ar.units, valid, "nd")
    with ar:
        const = lambda name, q: [ar.input(s, q, None) for s in regs[name]]
        inputs = ProbeInputs(const("P", "x"), const("Pdot", "pdot"), const("Lo", "x"), const("Hi", "x"))
        newX, newU, (gate, Fp) = node_kernel(ar, p, [ar.input(s, "x", 0) for s in xs],
                                             [ar.input(s, "u", 0) for s in us], [ar.input(s, "facc", 0) for s in fs],
                                             0, {"free": np.ones(1, bool)}, inputs)
        Fx = [gate.expand(f) for f in Fp]
    outs = {f"x{k}": newX[k] for k in range(D)} | {f"u{k}": newU[k] for k in range(D)} | \
           {f"F{k}": Fx[k] for k in range(D)}
    n = len(X[0])
    got = {name: np.zeros(n, np.int64) for name in outs}

    async def testbench(ctx):
        for name, vals in (("P", P), ("Pdot", Pdot), ("Lo", Lo), ("Hi", Hi)):
            for s, v in zip(regs[name], vals):
                ctx.set(s, int(v))
        horizon = max(v.stage for v in outs.values()) + 2
        for c in range(n + horizon):
            ctx.set(valid, int(c < n))
            for k in range(D):
                ctx.set(xs[k], int(X[k][c]) if c < n else 0)
                ctx.set(us[k], int(U[k][c]) if c < n else 0)
                ctx.set(fs[k], 0)
            await ctx.tick()
            for name, v in outs.items():
                j = c - v.stage + 1
                if 0 <= j < n:
                    got[name][j] = int(ctx.get(v.sig))

    sim = Simulator(m)
    sim.add_clock(1e-8)
    sim.add_testbench(testbench)
    sim.run()
    return [got[f"x{k}"] for k in range(D)], [got[f"u{k}"] for k in range(D)], [got[f"F{k}"] for k in range(D)]


@pytest.mark.hdl
@pytest.mark.parametrize("dim", [2, 3])
def test_node_kernel_probe_term_in_hardware_equals_the_bit_true_model(tmp_path, dim):
    """The one description runs on the third arithmetic too: the node kernel with the probe term, built as
    a PipeArith pipeline (the probe's P, Pdot and box as registers), equals FixedArith bit for bit on nodes
    scattered around the probe, inside it (sliding and sticking) and out."""
    from hw.bittrue import BitTrue
    from hw.datapath import ProbeInputs, node_kernel, probe_hold
    system = press_scene(tmp_path, dim=dim, preset="rheological")
    bt = BitTrue(system, "wide")
    p, fm, un, D = bt.params, bt.formats, bt.units, system.dim
    probe = bt.initial_state().probe
    P_si = system.probe.position - np.eye(D)[-1] * 0.002
    probe_hold(bt.ar, p, probe, un.length(P_si))                        # a sample with a velocity
    rng = np.random.default_rng(dim)
    n = 160
    x = P_si[None, :] + rng.uniform(-1.3, 1.3, (n, D)) * system.probe.radius
    v = rng.normal(0.0, 0.02, (n, D))
    X = [fm["x"].from_float(un.length(x[:, k])) for k in range(D)]
    U = [fm["u"].from_float(un.velocity(v[:, k])) for k in range(D)]
    ar = bt.ar
    full = lambda q, vs: [ar.state(q, np.full(n, w)) for w in vs]
    inputs = ProbeInputs(full("x", probe.P), full("pdot", probe.Pdot), full("x", probe.Lo), full("x", probe.Hi))
    newX, newU, (gate, Fp) = node_kernel(ar, p, [ar.state("x", c) for c in X], [ar.state("u", c) for c in U],
                                         [ar.zeros("facc", n) for _ in range(D)], 0, {"free": np.ones(n, bool)},
                                         inputs)
    assert 20 < gate.size < n - 20, "nodes inside and outside the probe"
    want_F = [gate.expand(f).x for f in Fp]
    hx, hu, hF = _pipe_node_kernel(bt, X, U, probe.P, probe.Pdot, probe.Lo, probe.Hi)
    for k in range(D):
        assert np.array_equal(hF[k], want_F[k]), k
        assert np.array_equal(hx[k], newX[k].x) and np.array_equal(hu[k], newU[k].x), k


# ---------------------------------------------------------------------------------------------- the API

def design_samples(name, n):
    return design_trajectory(scene_system(name), n)


API_SAMPLES = 60      # the probe touches the block after 34 samples (1 mm of air at 0.03 m/s)


def run_api(name, backend, n=API_SAMPLES, frame=False, **kw):
    """The readings of `n` device samples of the design poke through connect(...).step(p) (and the last
    frame's positions with `frame`)."""
    out = []
    with connect(scene_system(name), backend, **kw) as sim:
        for p in design_samples(name, n):
            out.append(sim.step(p))
        x = sim.frame()[0].copy()
    return (out, x) if frame else out


@pytest.fixture(scope="module")
def golden_api_run():
    return run_api("poke-2d-rheological", "golden", frame=True)


@pytest.fixture(scope="module")
def golden_readings(golden_api_run):
    return golden_api_run[0]


@pytest.fixture(scope="module")
def wide_formats():
    """The wide preset's formats for these runs: a range analysis of the design poke's first 1,000 steps (the
    API runs take 600; `connect` derives them from the whole poke)."""
    from hw.bittrue import BitTrue
    return BitTrue(scene_system("poke-2d-rheological"), "wide", range_steps=1000).formats


def fixed_session_model(formats):
    from hw.bittrue import BitTrue
    return BitTrue(scene_system("poke-2d-rheological"), "wide", formats=formats)


def test_api_fixed_backend_is_bit_for_bit_repeatable(wide_formats):
    runs = [run_api("poke-2d-rheological", "fixed", bittrue=fixed_session_model(wide_formats)) for _ in range(2)]
    a, b = (np.array([r.raw for r in run]) for run in runs)
    assert np.array_equal(a, b)
    assert np.abs(a).max() > 0


WIDE_FORCE_BUDGET = 1e-4     # of the peak force: the wide preset's force against golden's on the design poke


def test_api_wide_preset_within_its_budget_of_golden(golden_readings, wide_formats):
    fixed = run_api("poke-2d-rheological", "fixed", bittrue=fixed_session_model(wide_formats))
    g = np.array([r.force for r in golden_readings])
    f = np.array([r.force for r in fixed])
    peak = np.abs(g).max()
    assert peak > 0.02 and max(r.contacts for r in golden_readings) > 0
    assert [r.contacts for r in fixed] == [r.contacts for r in golden_readings]
    assert np.abs(f - g).max() <= WIDE_FORCE_BUDGET * peak, np.abs(f - g).max() / peak


def test_api_cpu_backend_equals_golden(golden_api_run):
    """connect(scene, "cpu").step(p), the host driving the probe: golden's contacts, forces (1e-12 of the peak)
    and positions (1e-12 of the object size), with the probe pressing the block."""
    golden_readings, xg = golden_api_run
    system = scene_system("poke-2d-rheological")
    with connect(system, "cpu") as sim:
        assert sim.stepper.takes_probe and type(sim.stepper).__name__ == "Cpu"
    cpu, xc = run_api("poke-2d-rheological", "cpu", frame=True)
    g = np.array([r.force for r in golden_readings])
    c = np.array([r.force for r in cpu])
    assert max(r.contacts for r in golden_readings) >= 1 and np.abs(g).max() > 0.02
    assert [r.contacts for r in cpu] == [r.contacts for r in golden_readings]
    assert all(r.raw is None for r in cpu)
    assert np.abs(c - g).max() <= 1e-12 * np.abs(g).max()
    assert np.abs(xc - xg).max() <= 1e-12 * float(np.ptp(system.x0, axis=0).max())


def test_api_refuses_a_stepper_that_takes_no_probe(monkeypatch):
    """A backend whose stepper takes no probe is refused when connected, with one line saying so (the cpu
    backend made to look like one)."""
    from sim.cpu import Cpu
    monkeypatch.setattr(Cpu, "takes_probe", False)
    with pytest.raises(HapticError, match="backend 'cpu' cannot take a probe yet; use golden or fixed"):
        connect(scene_system("poke-2d-rheological"), "cpu")


@pytest.mark.hdl
@pytest.mark.parametrize("backend", ["amaranth", "verilator"])
def test_api_core_backends_are_the_fixed_backend_bit_for_bit(backend):
    """connect(scene, "amaranth" | "verilator"): each sample through the streaming core's probe port
    (Amaranth's simulator, or the emitted Verilog in a cocotb session); the force words, contacts and the frame
    at the end equal the fixed backend's, each sample's latency the manifest's (tests/scenes/poke-tiny.toml:
    a few cycles a step). The same cocotb session on Icarus: test_haptic_cli_on_icarus_writes_the_fixed_backends_run."""
    from hw.bittrue import BitTrue
    system = load_scene(str(Path(__file__).resolve().parent / "scenes" / "poke-tiny.toml"))
    formats = BitTrue(system, "wide").formats
    path = system.probe.position - np.outer(np.arange(1, 7), [0.0, 3e-4])
    runs = {}
    for b in ("fixed", backend):
        with connect(system, b, bittrue=BitTrue(system, "wide", formats=formats)) as sim:
            runs[b] = ([sim.step(p) for p in path], sim.frame()[0].copy())
            if b == backend:
                assert sim.stepper.latency == [sim.stepper.hw.probe_latency] * len(path)
    (fixed, xf), (hw, xh) = runs["fixed"], runs[backend]
    assert max(r.contacts for r in fixed) > 0
    assert [(r.raw.tolist(), r.contacts) for r in hw] == [(r.raw.tolist(), r.contacts) for r in fixed]
    assert np.array_equal(xh, xf)


def test_api_refuses_a_scene_without_a_probe_and_bad_positions():
    with pytest.raises(HapticError, match="no \\[probe\\] table"):
        connect("press-2d-rheological")
    with connect("poke-2d-viscoelastic") as sim:
        for bad in ([0.0], [0.0, float("nan")], [[0.0, 0.0]]):
            with pytest.raises(HapticError, match="2 finite numbers"):
                sim.step(bad)
        r = sim.step(sim.system.probe.position)
        assert r.contacts == 0 and np.all(r.force == 0) and sim.time == pytest.approx(1e-3)


def test_api_holds_p_for_k_steps_with_pdot_from_the_previous_sample():
    with connect("poke-2d-viscoelastic") as sim:
        p0 = sim.system.probe.position
        sim.step(p0 + [0.0, -0.0002])
        pr = sim.state.probe
        assert pr.driven and np.allclose(pr.p, p0 + [0.0, -0.0002])
        assert np.allclose(pr.pdot, [0.0, -0.0002 / (10 * 1e-4)])
        assert sim.state.step == 10


# ---------------------------------------------------------------------------------------------- trajectories

def test_trajectory_offsets_and_absolute_positions_agree(tmp_path):
    system = scene_system("poke-2d-viscoelastic")
    traj = design_trajectory(system, 50)
    write_trajectory(tmp_path / "abs.csv", traj)
    write_trajectory(tmp_path / "off.csv", traj, offsets_from=system.probe.position)
    a = read_trajectory(tmp_path / "abs.csv", system)
    b = read_trajectory(tmp_path / "off.csv", system)
    assert (tmp_path / "off.csv").read_text().startswith("dx,dy\n")
    assert np.allclose(a, traj, atol=1e-12) and np.allclose(b, traj, atol=1e-12)


BAD_CSV = [
    ("empty", "", ["empty"]),
    ("header-only", "dx,dy\n", ["no rows after the header"]),
    ("wrong-header", "a,b\n0,0\n", ["line 1", "header", "x,y", "dx,dy", "'a,b'"]),
    ("3d-header-in-2d", "x,y,z\n0,0,0\n", ["line 1", "x,y", "'x,y,z'"]),
    ("mixed-header", "x,dy\n0,0\n", ["line 1", "'x,dy'"]),
    ("too-few-fields", "dx,dy\n0,0\n0\n", ["row 2 (line 3)", "1 field(s)", "expected 2"]),
    ("too-many-fields", "dx,dy\n0,0,0\n", ["row 1 (line 2)", "3 field(s)"]),
    ("not-a-number", "dx,dy\n0,0\n0,0\n0,abc\n", ["row 3 (line 4)", "column 'dy'", "'abc' is not a number"]),
    ("nan", "x,y\nnan,0.04\n", ["row 1 (line 2)", "column 'x'", "not finite"]),
    ("inf", "dx,dy\n0,-inf\n", ["row 1", "column 'dy'", "not finite"]),
]


@pytest.mark.parametrize("text, words", [pytest.param(t, w, id=i) for i, t, w in BAD_CSV])
def test_trajectory_reader_errors(tmp_path, text, words):
    path = tmp_path / "traj.csv"
    path.write_text(text)
    with pytest.raises(HapticError) as exc:
        read_trajectory(path, scene_system("poke-2d-viscoelastic"))
    msg = str(exc.value)
    assert "\n" not in msg and str(path) in msg
    for w in words:
        assert w in msg, (w, msg)


def test_trajectory_errors_through_the_cli(tmp_path):
    out = tmp_path / "r.npz"
    (tmp_path / "bad.csv").write_text("dx,dy\n0,0\n0,x\n")
    one_line_error(rheo("haptic", "poke-2d-viscoelastic", "--trajectory", tmp_path / "bad.csv", "--out", out),
                   "row 2 (line 3)", "column 'dy'")
    one_line_error(rheo("haptic", "poke-2d-viscoelastic", "--trajectory", tmp_path / "none.csv", "--out", out),
                   "trajectory file not found")
    one_line_error(rheo("haptic", "press-2d-rheological", "--trajectory", tmp_path / "bad.csv", "--out", out),
                   "no [probe] table")
    assert not out.exists()


# ---------------------------------------------------------------------------------------------- CLI

@pytest.fixture(scope="module")
def haptic_run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("haptic")
    system = scene_system("poke-2d-viscoelastic")
    write_trajectory(tmp / "t.csv", design_trajectory(system, 120), offsets_from=system.probe.position)
    out = tmp / "run.npz"
    proc = rheo("haptic", "poke-2d-viscoelastic", "--trajectory", tmp / "t.csv", "--every", 10, "--out", out)
    assert proc.returncode == 0, proc.stderr
    assert "120 device samples" in proc.stdout and str(out) in proc.stdout
    return tmp, out


def test_haptic_run_file(haptic_run):
    _, out = haptic_run
    with np.load(out) as f:
        assert f["x"].shape == (13, 153, 2) and f["t"][-1] == pytest.approx(0.12)
        assert f["probe_p"].shape == (120, 2) and f["probe_force"].shape == (120, 2)
        assert f["probe_contacts"].shape == (120,) and f["probe_t"][0] == pytest.approx(1e-3)
        assert f["probe_force"][-1, 1] > 0.05 and f["probe_contacts"].max() >= 1
        assert float(f["probe_radius"]) == 0.008 and str(f["backend"]) == "golden"


@pytest.mark.hdl
def test_haptic_cli_on_icarus_writes_the_fixed_backends_run(tmp_path):
    """`rheo haptic --backend icarus` (the probe port in a cocotb session): the fixed backend's force words and
    frames, the hardware's saturation count and the port's latency per sample in the run file."""
    scene = Path(__file__).resolve().parent / "scenes" / "poke-tiny.toml"
    traj = tmp_path / "traj.csv"
    traj.write_text("dx,dy\n" + "".join(f"0,{-3e-4 * (s + 1):.6g}\n" for s in range(6)))
    files = {}
    for backend in ("fixed", "icarus"):
        files[backend] = tmp_path / f"{backend}.npz"
        proc = rheo("haptic", scene, "--trajectory", traj, "--backend", backend, "--out", files[backend])
        assert proc.returncode == 0, proc.stderr[-3000:]
    with np.load(files["fixed"]) as a, np.load(files["icarus"]) as b:
        assert np.array_equal(a["probe_force_raw"], b["probe_force_raw"]) and b["probe_contacts"].max() == 2
        assert np.array_equal(a["x"], b["x"]) and str(b["backend"]) == "icarus"
        assert list(b["saturation_counts"]) == [0] and len(set(b["probe_latency_cycles"].tolist())) == 1


def test_show_and_plot_force_draw_a_haptic_run(haptic_run):
    from PIL import Image
    tmp, out = haptic_run
    for cmd, png in ((["show", out, "--frames", 3], tmp / "show.png"), (["plot-force", out, out], tmp / "loops.png")):
        proc = rheo(*cmd, "--out", png)
        assert proc.returncode == 0, proc.stderr
        with Image.open(png) as im:
            assert im.size[0] > 300
    one_line_error(rheo("plot-force", ROOT / "no-such.npz", "--out", tmp / "x.png"), "run file not found")


def test_probe_painter_draws_the_probe_and_the_force(haptic_run):
    """The picture has the probe: the frame with the force holds the probe's red pixels and the arrow."""
    from sim.render import render
    from PIL import Image
    tmp, out = haptic_run
    render(out, tmp / "last.png", frames=[-1])
    img = np.asarray(Image.open(tmp / "last.png").convert("RGB")).astype(int)
    red = (img[:, :, 0] > 150) & (img[:, :, 1] < 80) & (img[:, :, 2] < 60)
    assert red.sum() > 200


def test_haptic_on_the_cpu_backend_writes_golden_run(haptic_run):
    """`rheo haptic --backend cpu` runs a probe scene (it used to refuse) and writes golden's run: the probe's
    positions, forces (1e-12 of the peak), contacts and the frames (1e-12 of the object size)."""
    tmp, golden_out = haptic_run
    out = tmp / "cpu.npz"
    proc = rheo("haptic", "poke-2d-viscoelastic", "--trajectory", tmp / "t.csv", "--every", 10, "--backend", "cpu",
                "--out", out)
    # nothing on stderr but the progress bar, which shows when the first sample compiles the cpu backend
    # (a fresh machine: about a minute)
    noise = [ln for ln in proc.stderr.replace("\r", "\n").splitlines() if ln.strip() and "sample]" not in ln]
    assert proc.returncode == 0 and noise == [], proc.stderr
    assert "120 device samples" in proc.stdout and "on cpu" in proc.stdout
    with np.load(golden_out) as g, np.load(out) as c:
        assert str(c["backend"]) == "cpu" and "probe_force_raw" not in c.files
        peak = np.abs(g["probe_force"]).max()
        assert peak > 0.05 and g["probe_contacts"].max() >= 1
        assert np.array_equal(c["probe_p"], g["probe_p"]) and np.array_equal(c["probe_contacts"], g["probe_contacts"])
        assert np.abs(c["probe_force"] - g["probe_force"]).max() <= 1e-12 * peak
        assert c["x"].shape == g["x"].shape and np.array_equal(c["t"], g["t"])
        assert np.abs(c["x"] - g["x"]).max() <= 1e-12 * float(np.ptp(g["x"][0], axis=0).max())


@pytest.mark.parametrize("backend", ["golden", "cpu"])
def test_bench_haptic_json(tmp_path, backend):
    press_scene(tmp_path)
    proc = rheo("bench", "--haptic", "--scene", tmp_path / "press2.toml", "--backend", backend, "--samples", 30,
                "--seconds", 0.2, "--json")
    assert proc.returncode == 0, proc.stderr
    r = json.loads(proc.stdout)["results"][0]
    assert r["backend"] == backend
    assert r["samples"] == 30 and r["device_rate_hz"] == pytest.approx(1000.0)
    assert 0 < r["median_us"] <= r["p999_us"] <= r["max_us"]
    assert r["golden_samples_per_s"] > 0 and r["fixed_samples_per_s"] > 0
    one_line_error(rheo("bench", "--haptic", "--scene", "press-2d-rheological"), "no [probe] table")
    one_line_error(rheo("bench", "--haptic", "--scene", "poke-2d-plastic", "--backend", "fpga"), "--haptic")


# ---------------------------------------------------------------------------------------------- play

@pytest.mark.parametrize("backend", ["golden", "cpu"])
def test_play_window_driven_headless(backend):
    """rheo play's controller on the Agg backend: a press in the block below the probe and a drag, then
    animation frames; the object moves and the force on the probe rises."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.backend_bases import MouseEvent
    from sim.play import PlayController
    sim = connect("poke-2d-viscoelastic", backend)
    fig = plt.figure(figsize=(6, 4))
    try:
        ctl = PlayController(sim, fig, max_speed=0.05, samples_per_frame=2)
        fig.canvas.draw()
        x0 = sim.frame()[0].copy()

        def mouse(name, xy, button=1):
            px, py = ctl.ax.transData.transform(xy)
            ev = MouseEvent(name, fig.canvas, px, py, button)
            fig.canvas.callbacks.process(name, ev)

        p0 = sim.system.probe.position
        mouse("button_press_event", (p0[0], p0[1] - 0.002))
        assert ctl.dragging
        forces = []
        for i in range(50):
            if i % 5 == 0:
                mouse("motion_notify_event", (p0[0], p0[1] - 0.004 - 0.0002 * i))
            forces.append(float(np.linalg.norm(ctl.tick().force)))
        mouse("button_release_event", (p0[0], p0[1] - 0.014))
        assert not ctl.dragging
        x = sim.frame()[0]
        assert sim.samples == 100 and sim.position[1] < p0[1] - 0.004
        assert np.abs(x - x0).max() > 5e-4, "the object moved"
        assert forces[0] == 0.0 and forces[-1] > 0.05 and max(forces[-5:]) > max(forces[:15]), "the force rose"
        assert "probe force" in ctl.probe_art["text"].get_text() and ctl.probe_art["text"].get_text() != \
            "probe force 0 N, 0 nodes"
        before = sim.position.copy()
        ctl.tick()
        assert np.allclose(sim.position, before), "released: the probe stays where it was left"
        mouse("button_press_event", (10.0, 10.0))                     # outside the axes: ignored
        assert not ctl.dragging
    finally:
        plt.close(fig)


def test_play_without_a_display_is_one_line():
    env = dict(os.environ)
    env.pop("DISPLAY", None)
    env.pop("WAYLAND_DISPLAY", None)
    proc = subprocess.run([sys.executable, "-m", "sim.cli", "play", "poke-2d-plastic"], cwd=ROOT,
                          env=dict(env, PYTHONPATH=str(ROOT)), capture_output=True, text=True, timeout=120)
    if sys.platform.startswith("linux"):
        one_line_error(proc, "no display")
