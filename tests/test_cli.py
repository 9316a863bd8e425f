"""The `rheo` command line end to end, each command run in a subprocess as a user would run it."""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tomllib
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

ROOT = Path(__file__).resolve().parent.parent
SCENES = ROOT / "golden" / "scenes"


def rheo(*args, cwd=ROOT, timeout=300):
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.run([sys.executable, "-m", "sim.cli", *map(str, args)], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=timeout)


def ok(proc):
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr
    return proc


def one_line_error(proc, *words):
    assert "Traceback" not in proc.stderr + proc.stdout, proc.stderr
    assert proc.returncode == 2, (proc.returncode, proc.stderr)
    lines = proc.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("rheo: error:"), proc.stderr
    for w in words:
        assert w in lines[0], f"{w!r} not in {lines[0]!r}"
    return lines[0]


# ---------------------------------------------------------------- rheo scenes

def test_scenes_lists_every_builtin_with_its_description():
    proc = ok(rheo("scenes"))
    lines = proc.stdout.splitlines()
    listed = {ln.split(None, 1)[0]: ln for ln in lines if ln.strip()}
    files = sorted(SCENES.glob("*.toml"))
    assert files
    assert sorted(listed) == sorted(p.stem for p in files)
    assert len(lines) == len(files)
    for p in files:
        desc = tomllib.loads(p.read_text()).get("description", "")
        assert desc, f"{p.name} has no description"
        name, rest = listed[p.stem].split(None, 1)
        assert rest.strip() == desc.strip()


# ---------------------------------------------------------------- rheo simulate

CREEP_STEPS, CREEP_EVERY = 500, 100


@pytest.fixture(scope="module")
def creep_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("creep") / "r.npz"
    proc = ok(rheo("simulate", "creep-1d", "--steps", CREEP_STEPS, "--every", CREEP_EVERY, "--out", out))
    assert str(out) in proc.stdout
    with np.load(out, allow_pickle=False) as f:
        data = {k: f[k] for k in f.files}
    return out, data


def test_simulate_writes_the_run_file(creep_run):
    _, r = creep_run
    scene = tomllib.loads((SCENES / "creep-1d.toml").read_text())
    dt = scene["integrator"]["dt"]
    assert dt == 1e-5
    F = CREEP_STEPS // CREEP_EVERY + 1
    assert r["t"].shape == (F,)
    assert r["x"].shape == r["v"].shape == (F, 2, 2)
    assert r["a"].shape == (F, 1)
    assert r["edges"].shape == (1, 2) and r["edges"].tolist() == [[0, 1]]
    assert r["cells"].shape == (0, 3)
    assert r["pinned"].tolist() == [True, False]
    assert r["mass"].tolist() == [0.001, 0.001]
    assert int(r["dim"]) == 2
    assert str(r["scene"]) == "creep-1d"
    assert str(r["backend"]) == "golden"
    steps = np.arange(0, CREEP_STEPS + 1, CREEP_EVERY)
    np.testing.assert_allclose(r["t"], steps * dt, rtol=1e-12, atol=0)
    assert r["t"][0] == 0.0


def test_simulate_pinned_node_never_moves_and_the_free_one_does(creep_run):
    _, r = creep_run
    x, v = r["x"], r["v"]
    assert np.all(x[:, 0] == [0.0, 0.0])
    assert np.all(v[:, 0] == 0.0)
    assert x[0, 1].tolist() == [0.01, 0.0]
    dx = x[1:, 1, 0] - x[0, 1, 0]
    assert np.all(dx > 0), "the 0.05 N pull must stretch the element"
    assert np.all(np.diff(x[:, 1, 0]) > 0)
    assert np.all(x[:, 1, 1] == 0.0), "a pull along x keeps the free node on the x axis"
    a = r["a"][:, 0]
    assert a[0] == 0.5 and np.all((a >= 0.0) & (a <= 1.0))


# ---------------------------------------------------------------- rheo show / export

@pytest.mark.parametrize("suffix, fmt", [("png", "PNG"), ("gif", "GIF")])
def test_show_writes_an_image(creep_run, tmp_path, suffix, fmt):
    npz, _ = creep_run
    out = tmp_path / f"f.{suffix}"
    proc = ok(rheo("show", npz, "--out", out))
    assert str(out) in proc.stdout
    with Image.open(out) as im:
        assert im.format == fmt
        assert im.size[0] > 50 and im.size[1] > 50
        if fmt == "GIF":
            assert getattr(im, "n_frames", 1) == CREEP_STEPS // CREEP_EVERY + 1


def test_export_writes_vtk_frames_and_pvd(creep_run, tmp_path):
    npz, r = creep_run
    d = tmp_path / "d"
    ok(rheo("export", npz, "--vtk", d))
    pvd = d / "run.pvd"
    assert pvd.is_file()
    sets = ET.parse(pvd).getroot().findall("./Collection/DataSet")
    assert len(sets) == len(r["t"])
    np.testing.assert_array_equal([float(s.get("timestep")) for s in sets], r["t"])
    files = [d / s.get("file") for s in sets]
    assert all(f.is_file() and f.suffix == ".vtu" for f in files)
    assert sorted(d.glob("*.vtu")) == sorted(files)


def test_show_missing_run_file(tmp_path):
    out = tmp_path / "x.png"
    one_line_error(rheo("show", tmp_path / "missing.npz", "--out", out), "not found", "missing.npz")
    assert not out.exists()


def test_show_unsupported_format(creep_run, tmp_path):
    npz, _ = creep_run
    out = tmp_path / "x.jpg"
    one_line_error(rheo("show", npz, "--out", out), ".jpg")
    assert not out.exists()


# ---------------------------------------------------------------- rheo bench

def test_bench_json():
    proc = ok(rheo("bench", "--backend", "golden", "--json", "--sizes", 200, "--seconds", 0.2))
    doc = json.loads(proc.stdout)
    assert doc["backend"] == "golden"
    assert len(doc["results"]) == 1
    r = doc["results"][0]
    assert r["elements"] > 0 and r["nodes"] > 0
    assert 100 <= r["elements"] <= 400, "--sizes 200 asks for about 200 elements"
    assert r["steps_per_s"] > 0
    assert r["element_updates_per_s"] == pytest.approx(r["elements"] * r["steps_per_s"], rel=1e-9)


def test_bench_unknown_backend():
    one_line_error(rheo("bench", "--backend", "nope", "--sizes", 200, "--seconds", 0.1), "'nope'")


def test_bench_hardware_options_belong_to_fpga():
    one_line_error(rheo("bench", "--backend", "golden", "--lanes", 2, "--sizes", 200, "--seconds", 0.1),
                   "--backend fpga")


def test_generated_square_as_a_scene():
    proc = ok(rheo("bench", "--backend", "golden", "--scene", "square:300", "--json", "--seconds", 0.1))
    r = json.loads(proc.stdout)["results"][0]
    assert r["scene"].startswith("square-") and 200 <= r["elements"] <= 400
    one_line_error(rheo("verilog", "square:abc", "--out", "unused"), "square:N")


# ---------------------------------------------------------------- --help

def _subcommands() -> list[str]:
    sys.path.insert(0, str(ROOT))
    try:
        from sim.cli import build_parser
    finally:
        sys.path.remove(str(ROOT))
    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    return sorted(sub.choices)


def test_the_expected_subcommands_exist():
    assert {"scenes", "simulate", "show", "export", "bench", "run"} <= set(_subcommands())


@pytest.mark.parametrize("cmd", [[]] + [[c] for c in _subcommands()], ids=lambda c: " ".join(c) or "rheo")
def test_help(cmd):
    proc = ok(rheo(*cmd, "--help"))
    assert proc.stdout.startswith(f"usage: {' '.join(['rheo'] + cmd)}")
    assert proc.stderr == ""


def test_simulate_refuses_a_dt_above_the_stable_limit_unless_forced(tmp_path):
    scene = (SCENES / "press-2d-viscoelastic.toml").read_text().replace("dt = 1e-4", "dt = 2e-3")
    p = tmp_path / "fast.toml"
    p.write_text(scene)
    out = tmp_path / "r.npz"
    one_line_error(rheo("simulate", p, "--out", out), "exceeds the predicted stable limit")
    assert not out.exists()
    one_line_error(rheo("simulate", p, "--force", "--out", out), "diverged")
    assert not out.exists()


def test_report_refuses_a_probe_scene_in_one_line(tmp_path):
    """rheo report runs the scene at 2 dt, 4 dt and dt/16: with a probe each would hold a device sample for k
    steps of its own dt, another device rate (the cpu backend takes the probe; that is not the reason)."""
    out = tmp_path / "report"
    line = one_line_error(rheo("report", "poke-2d-rheological", "--out", out), "poke-2d-rheological", "has a probe",
                          "k = 10 steps", "another device rate", "rheo haptic")
    assert "cpu" not in line
    assert not out.exists()
