"""Malformed scenes through the real CLI: every one must end in exit code 2 and a single line
`rheo: error: ...` on stderr that names the problem, never a traceback, and must not write the run file.

Each case starts from a small valid 2D scene (built here as a dict, written as TOML) and breaks one thing.
"""
from __future__ import annotations

import copy
import json
import math
import os
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parent.parent


# ---------------------------------------------------------------- a tiny TOML writer for the test scenes

def _key(k: str) -> str:
    return k if re.fullmatch(r"[A-Za-z0-9_-]+", k) else json.dumps(k)


def _value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, list):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{_key(k)} = {_value(x)}" for k, x in v.items()) + " }"
    raise TypeError(f"cannot write {v!r} as TOML")


def _is_table_array(v) -> bool:
    return isinstance(v, list) and len(v) > 0 and all(isinstance(x, dict) for x in v)


def _table(d: dict, prefix: str, out: list[str]):
    for k, v in d.items():
        if not isinstance(v, dict) and not _is_table_array(v):
            out.append(f"{_key(k)} = {_value(v)}")
    for k, v in d.items():
        name = f"{prefix}.{_key(k)}" if prefix else _key(k)
        if isinstance(v, dict):
            out.append(f"\n[{name}]")
            _table(v, name, out)
        elif _is_table_array(v):
            for item in v:   # entries of [[...]] are written as key = inline value
                out.append(f"\n[[{name}]]")
                out.extend(f"{_key(ik)} = {_value(iv)}" for ik, iv in item.items())


def dumps(d: dict) -> str:
    out: list[str] = []
    _table(d, "", out)
    return "\n".join(out) + "\n"


# ---------------------------------------------------------------- the valid scene every case breaks

def base_scene() -> dict:
    return {
        "name": "bad-input-base",
        "description": "one triangle, a corner pinned, pulled for a moment",
        "dim": 2,
        "integrator": {"dt": 1e-4, "duration": 0.01, "output_every": 1},
        "world": {"gravity": [0.0, -9.81], "floor": {"height": -1.0, "K": 1e4, "C": 1.0}},
        "objects": [{
            "name": "tri",
            "mesh": {"type": "explicit", "nodes": [[0.0, 0.0], [0.01, 0.0], [0.0, 0.01]],
                     "cells": [[0, 1, 2]]},
            "material": {"k1": 50.0, "c1": 0.5, "a0": 0.5, "a_min": 0.05, "a_max": 1.0,
                         "c_min": 0.5, "c_max": 500.0, "f1": 0.01, "f2": 0.05, "node_mass": 1e-3},
            "position": [0.0, 0.0],
            "velocity": [0.0, 0.0],
            "pinned": [0],
        }],
        "loads": [{"object": "tri", "nodes": [1], "force": [0.01, 0.0], "start": 0.0, "end": 0.005}],
    }


def _obj(d):
    return d["objects"][0]


def _mat(d):
    return d["objects"][0]["material"]


# ---------------------------------------------------------------- the cases
# mutate(d, tmp) edits the scene dict in place and returns None (write d), a str (write this raw text
# instead) or a Path (pass this path as the scene instead of writing anything).

def _missing_integrator(d, tmp):
    del d["integrator"]


def _missing_dt(d, tmp):
    del d["integrator"]["dt"]


def _unknown_top_key(d, tmp):
    d["colour"] = "red"


def _unknown_material_key(d, tmp):
    _mat(d)["youngs_modulus"] = 1e6


def _negative_node_mass(d, tmp):
    del _mat(d)["node_mass"]
    _obj(d)["masses"] = [1e-3, -1e-3, 1e-3]


def _infinite_node_mass(d, tmp):
    del _mat(d)["node_mass"]
    _obj(d)["masses"] = [1e-3, math.inf, 1e-3]


def _zero_node_mass(d, tmp):
    _mat(d)["node_mass"] = 0.0


def _no_mass(d, tmp):
    del _mat(d)["node_mass"]


def _zero_length_edge(d, tmp):
    _obj(d)["mesh"] = {"type": "explicit", "nodes": [[0.0, 0.0], [0.0, 0.0]], "edges": [[0, 1]]}


def _inverted_triangle(d, tmp):
    _obj(d)["mesh"]["cells"] = [[0, 2, 1]]   # clockwise


def _self_edge(d, tmp):
    _obj(d)["mesh"]["edges"] = [[0, 1], [2, 2]]


def _edge_index_out_of_range(d, tmp):
    _obj(d)["mesh"]["edges"] = [[0, 1], [1, 9]]


def _fractional_cell_index(d, tmp):
    _obj(d)["mesh"]["cells"] = [[0, 1.9, 2]]       # never truncated to 1


def _fractional_edge_index(d, tmp):
    _obj(d)["mesh"]["edges"] = [[0, 1], [1, 1.9]]


def _fractional_load_node(d, tmp):
    d["loads"][0]["nodes"] = [1.9]


def _fractional_pinned_node(d, tmp):
    _obj(d)["pinned"] = [0.0]


def _ragged_nodes(d, tmp):
    _obj(d)["mesh"]["nodes"] = [[0.0, 0.0], [0.01], [0.0, 0.01]]


def _nan_parameter(d, tmp):
    _mat(d)["k1"] = math.nan


def _inf_dt(d, tmp):
    d["integrator"]["dt"] = math.inf


def _too_many_steps(d, tmp):
    d["integrator"]["dt"] = 1e-300
    d["integrator"]["duration"] = 1e300


def _a_min_above_a_max(d, tmp):
    _mat(d).update(a_min=0.9, a_max=0.5, a0=0.5)


def _a0_outside(d, tmp):
    _mat(d)["a0"] = 0.01


def _f1_not_below_f2(d, tmp):
    _mat(d).update(f1=0.05, f2=0.05)


def _c_min_above_c_max(d, tmp):
    _mat(d).update(c_min=600.0, c_max=500.0)


def _c2_and_c_min(d, tmp):
    _mat(d)["c2"] = 1.0


def _unknown_preset(d, tmp):
    _obj(d)["material"] = {"preset": "jelly", "node_mass": 1e-3}


def _preset_not_a_string(d, tmp):
    _obj(d)["material"] = {"preset": ["rheological"], "node_mass": 1e-3}


def _mesh_file_not_found(d, tmp):
    _obj(d)["mesh"] = {"type": "file", "path": "no-such-mesh.msh"}


def _garbage_mesh(suffix: str, payload: bytes):
    def mutate(d, tmp):
        (tmp / f"garbage{suffix}").write_bytes(payload)
        _obj(d)["mesh"] = {"type": "file", "path": f"garbage{suffix}"}
    return mutate


_BINARY_GARBAGE = bytes(range(256)) * 3
_TEXT_GARBAGE = b"hello\nthis is not a mesh file\n"


def _scene_file_not_found(d, tmp):
    return tmp / "no-such-scene.toml"


def _not_toml(d, tmp):
    return dumps(d) + "\n[integrator\ndt = = 1\n"


def _unknown_builtin(d, tmp):
    return Path("no-such-builtin-scene")


def _gravity_wrong_length(d, tmp):
    d["world"]["gravity"] = [0.0, -9.81, 0.0]


def _dim_4(d, tmp):
    d["dim"] = 4


def _dim_float(d, tmp):
    d["dim"] = 2.0


def _load_selects_nothing(d, tmp):
    d["loads"][0]["nodes"] = {"box": [[5.0, 5.0], [6.0, 6.0]]}


def _load_end_before_start(d, tmp):
    d["loads"][0].update(start=0.005, end=0.001)


def _load_unknown_object(d, tmp):
    d["loads"][0]["object"] = "blob"


def _pinned_out_of_range(d, tmp):
    _obj(d)["pinned"] = [0, 7]


def _negative_k1(d, tmp):
    _mat(d)["k1"] = -1.0


def _string_for_number(d, tmp):
    d["integrator"]["dt"] = "fast"


def _duplicate_object_names(d, tmp):
    twin = copy.deepcopy(_obj(d))
    twin["position"] = [0.1, 0.0]
    d["objects"].append(twin)


def _mesh_wrong_dim(d, tmp):
    _obj(d)["mesh"] = {"type": "box", "size": [0.1, 0.1, 0.1], "divisions": [1, 1, 1]}


def _floor_without_k(d, tmp):
    del d["world"]["floor"]["K"]


def _name_is_a_path(d, tmp):
    d["name"] = str(tmp / "elsewhere" / "RUN")


def _name_climbs_out(d, tmp):
    d["name"] = "../../escape"


def _name_not_a_string(d, tmp):
    d["name"] = 7


def _probe(**change):
    """A [probe] table on the base scene with one change (None removes a key)."""
    def mutate(d, tmp):
        pb = {"radius": 0.004, "K": 500.0, "C": 1.0, "mu": 0.3, "position": [0.005, 0.015], "depth": 0.002}
        for k, v in change.items():
            if v is None:
                pb.pop(k)
            else:
                pb[k] = v
        d["probe"] = pb
    return mutate


# (id, mutate, words that must all appear in the error line)
CASES = [
    ("name-is-a-path", _name_is_a_path, ["'name'", "plain name", "RUN"]),
    ("name-climbs-out", _name_climbs_out, ["'name'", "plain name", "../../escape"]),
    ("name-not-a-string", _name_not_a_string, ["'name'", "plain name", "7"]),
    ("missing-integrator", _missing_integrator, ["missing", "'integrator'"]),
    ("missing-dt", _missing_dt, ["[integrator]", "missing", "'dt'"]),
    ("unknown-top-level-key", _unknown_top_key, ["unknown key", "'colour'"]),
    ("unknown-material-key", _unknown_material_key, ["[objects.0.material]", "unknown key", "'youngs_modulus'"]),
    ("negative-node-mass", _negative_node_mass, ["node 1", "mass -0.001"]),
    ("infinite-node-mass", _infinite_node_mass, ["node 1", "mass inf"]),
    ("zero-node_mass", _zero_node_mass, ["'node_mass'", "> 0"]),
    ("no-mass-at-all", _no_mass, ["no mass"]),
    ("zero-length-edge", _zero_length_edge, ["zero length"]),
    ("inverted-triangle", _inverted_triangle, ["triangle 0", "inverted"]),
    ("edge-to-itself", _self_edge, ["node 2 to itself"]),
    ("edge-index-out-of-range", _edge_index_out_of_range, ["edges", "outside 0..2"]),
    ("fractional-cell-index", _fractional_cell_index, ["'cells'", "1.9", "not an integer"]),
    ("fractional-edge-index", _fractional_edge_index, ["'edges'", "1.9", "not an integer"]),
    ("fractional-load-node", _fractional_load_node, ["[loads.0]", "'nodes'", "node indices"]),
    ("fractional-pinned-node", _fractional_pinned_node, ["'pinned'", "node indices"]),
    ("ragged-nodes", _ragged_nodes, ["'nodes'", "rows of 2"]),
    ("nan-parameter", _nan_parameter, ["'k1'", "finite", "nan"]),
    ("inf-dt", _inf_dt, ["'dt'", "finite", "inf"]),
    ("too-many-steps", _too_many_steps, ["[integrator]", "steps"]),
    ("a_min-above-a_max", _a_min_above_a_max, ["a_min (0.9)", "a_max (0.5)"]),
    ("a0-outside-range", _a0_outside, ["a0 (0.01)", "[a_min, a_max]"]),
    ("f1-not-below-f2", _f1_not_below_f2, ["f1 < f2", "f1 = 0.05"]),
    ("c_min-above-c_max", _c_min_above_c_max, ["c_min <= c_max", "c_min = 600"]),
    ("c2-and-c_min", _c2_and_c_min, ["'c2'", "c_min", "not both"]),
    ("unknown-preset", _unknown_preset, ["unknown preset", "'jelly'"]),
    ("preset-not-a-string", _preset_not_a_string, ["preset"]),
    ("mesh-file-not-found", _mesh_file_not_found, ["mesh file not found", "no-such-mesh.msh"]),
    ("garbage-binary-msh", _garbage_mesh(".msh", _BINARY_GARBAGE), ["cannot read mesh file", "garbage.msh"]),
    ("garbage-binary-vtk", _garbage_mesh(".vtk", _BINARY_GARBAGE), ["cannot read mesh file", "garbage.vtk"]),
    ("garbage-text-msh", _garbage_mesh(".msh", _TEXT_GARBAGE), ["cannot read mesh file", "garbage.msh"]),
    ("garbage-text-vtk", _garbage_mesh(".vtk", _TEXT_GARBAGE), ["cannot read mesh file", "garbage.vtk"]),
    ("scene-file-not-found", _scene_file_not_found, ["scene file not found", "no-such-scene.toml"]),
    ("unknown-builtin-scene", _unknown_builtin, ["'no-such-builtin-scene' not found"]),
    ("not-valid-toml", _not_toml, ["not valid TOML"]),
    ("gravity-wrong-length", _gravity_wrong_length, ["[world]", "'gravity'", "list of 2 numbers"]),
    ("dim-4", _dim_4, ["'dim'", "2 or 3", "got 4"]),
    ("dim-float", _dim_float, ["'dim'", "2 or 3", "got 2.0"]),
    ("load-selects-no-node", _load_selects_nothing, ["[loads.0]", "'nodes' selects no node"]),
    ("load-end-before-start", _load_end_before_start, ["[loads.0]", "'end' (0.001)", "'start' (0.005)"]),
    ("load-unknown-object", _load_unknown_object, ["[loads.0]", "'object'", "'blob'"]),
    ("pinned-index-out-of-range", _pinned_out_of_range, ["'pinned'", "outside 0..2"]),
    ("negative-k1", _negative_k1, ["'k1'", ">= 0", "-1"]),
    ("string-for-number", _string_for_number, ["'dt'", "must be a number", "'fast'"]),
    ("duplicate-object-names", _duplicate_object_names, ["[objects.1]", "unique", "'tri'"]),
    ("3d-mesh-in-2d-scene", _mesh_wrong_dim, ["box", "dim = 2"]),
    ("floor-without-K", _floor_without_k, ["[world.floor]", "missing", "'K'"]),
    ("probe-without-radius", _probe(radius=None), ["[probe]", "missing", "'radius'"]),
    ("probe-without-position", _probe(position=None), ["[probe]", "missing", "'position'"]),
    ("probe-zero-radius", _probe(radius=0.0), ["[probe]", "'radius'", "> 0", "got 0"]),
    ("probe-negative-K", _probe(K=-5.0), ["[probe]", "'K'", "> 0", "-5"]),
    ("probe-negative-C", _probe(C=-1.0), ["[probe]", "'C'", ">= 0"]),
    ("probe-nan-mu", _probe(mu=math.nan), ["[probe]", "'mu'", "finite"]),
    ("probe-zero-k_f", _probe(k_f=0.0), ["[probe]", "'k_f'", "> 0"]),
    ("probe-position-3d-in-2d", _probe(position=[0.0, 0.0, 0.0]), ["[probe]", "'position'", "list of 2 numbers"]),
    ("probe-steps-per-sample-0", _probe(steps_per_sample=0), ["[probe]", "'steps_per_sample'", ">= 1"]),
    ("probe-steps-per-sample-float", _probe(steps_per_sample=10.0), ["[probe]", "'steps_per_sample'", "integer"]),
    ("probe-negative-depth", _probe(depth=-0.001), ["[probe]", "'depth'", ">= 0"]),
    ("probe-zero-poke_time", _probe(poke_time=0.0), ["[probe]", "'poke_time'", "> 0"]),
    ("probe-unknown-key", _probe(stiffness=1.0), ["[probe]", "unknown key", "'stiffness'"]),
    ("probe-not-a-table", lambda d, tmp: d.update(probe=[1, 2]), ["[probe]", "must be a table"]),
]


# ---------------------------------------------------------------- running the CLI

def rheo(*args, cwd=ROOT):
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.run([sys.executable, "-m", "sim.cli", *map(str, args)], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=120)


def write_case(mutate, tmp: Path):
    d = base_scene()
    res = mutate(d, tmp)
    if isinstance(res, Path):
        return res
    path = tmp / "scene.toml"
    path.write_text(res if isinstance(res, str) else dumps(d))
    return path


def assert_one_line_error(proc, words=()):
    assert "Traceback" not in proc.stderr and "Traceback" not in proc.stdout, proc.stderr
    assert proc.returncode == 2, (proc.returncode, proc.stdout, proc.stderr)
    lines = proc.stderr.splitlines()
    assert len(lines) == 1, proc.stderr
    line = lines[0]
    assert line.startswith("rheo: error:"), line
    for w in words:
        assert w in line, f"{w!r} not in {line!r}"
    return line


def test_base_scene_is_valid(tmp_path):
    """The starting point of every case runs cleanly, so each failure below is due to its one change."""
    d = base_scene()
    text = dumps(d)
    assert tomllib.loads(text) == d
    scene = tmp_path / "scene.toml"
    scene.write_text(text)
    out = tmp_path / "r.npz"
    proc = rheo("simulate", scene, "--steps", 2, "--out", out)
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr == ""
    with np.load(out) as f:
        assert f["x"].shape == (3, 3, 2)
        assert str(f["scene"]) == "bad-input-base"


def test_base_scene_with_a_probe_is_valid(tmp_path):
    """Control for the [probe] cases: the base scene with a valid probe runs (the probe follows its design
    poke), and so it does through `rheo haptic`."""
    d = base_scene()
    _probe()(d, tmp_path)
    scene = tmp_path / "scene.toml"
    scene.write_text(dumps(d))
    out = tmp_path / "r.npz"
    proc = rheo("simulate", scene, "--steps", 2, "--out", out)
    assert proc.returncode == 0 and proc.stderr == "", proc.stderr
    (tmp_path / "t.csv").write_text("dx,dy\n0,0\n0,-0.0001\n")
    proc = rheo("haptic", scene, "--trajectory", tmp_path / "t.csv", "--out", tmp_path / "h.npz")
    assert proc.returncode == 0 and "2 device samples" in proc.stdout, proc.stderr


def test_readable_mesh_file_is_valid(tmp_path):
    """Control for the garbage-mesh cases: a real .vtk with a clockwise triangle loads (and is reoriented)."""
    import meshio
    nodes = np.array([[0.0, 0.0, 0.0], [0.0, 0.01, 0.0], [0.01, 0.0, 0.0]])
    meshio.write(tmp_path / "tri.vtk", meshio.Mesh(nodes, [("triangle", np.array([[0, 1, 2]]))]))
    d = base_scene()
    _obj(d)["mesh"] = {"type": "file", "path": "tri.vtk"}
    scene = tmp_path / "scene.toml"
    scene.write_text(dumps(d))
    out = tmp_path / "r.npz"
    proc = rheo("simulate", scene, "--steps", 2, "--out", out)
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr == ""
    with np.load(out) as f:
        assert f["x"].shape == (3, 3, 2)
        tri = f["x"][0][f["cells"][0]]
        u, w = tri[1] - tri[0], tri[2] - tri[0]
        assert u[0] * w[1] - u[1] * w[0] > 0


@pytest.mark.parametrize("mutate, words", [pytest.param(m, w, id=i) for i, m, w in CASES])
def test_bad_scene(tmp_path, mutate, words):
    scene = write_case(mutate, tmp_path)
    out = tmp_path / "r.npz"
    proc = rheo("simulate", scene, "--steps", 2, "--out", out)
    assert_one_line_error(proc, words)
    assert proc.stdout == ""
    assert not out.exists()
    assert not list(tmp_path.glob("*.npz")), "a temporary run file was left behind"


def test_case_ids_are_unique():
    ids = [c[0] for c in CASES]
    assert len(ids) == len(set(ids)) and len(ids) >= 20


@pytest.mark.parametrize("args, words", [
    pytest.param(["--steps", "0"], ["--steps", ">= 1", "got 0"], id="steps-0"),
    pytest.param(["--steps", "-3"], ["--steps", ">= 1"], id="steps-negative"),
    pytest.param(["--steps", "many"], ["--steps", "whole number", "'many'"], id="steps-not-a-number"),
    pytest.param(["--every", "0"], ["--every", ">= 1"], id="every-0"),
    pytest.param(["--backend", "nope"], ["--backend", "'nope'"], id="unknown-backend"),
])
def test_bad_arguments(tmp_path, args, words):
    """argparse errors: exit 2, a usage line and one error line, no traceback, nothing written."""
    out = tmp_path / "r.npz"
    proc = rheo("simulate", "creep-1d", "--out", out, *args)
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr + proc.stdout
    assert proc.stderr.startswith("usage: rheo simulate")
    errors = [ln for ln in proc.stderr.splitlines() if "error:" in ln]
    assert len(errors) == 1, proc.stderr
    assert errors[0].startswith("rheo simulate: error: argument")
    for w in words:
        assert w in errors[0], f"{w!r} not in {errors[0]!r}"
    assert proc.stdout == ""
    assert not out.exists()


def test_out_must_be_npz(tmp_path):
    scene = write_case(lambda d, tmp: None, tmp_path)
    out = tmp_path / "r.txt"
    proc = rheo("simulate", scene, "--steps", 2, "--out", out)
    assert_one_line_error(proc, ["--out", ".npz"])
    assert not out.exists()


@pytest.mark.parametrize("mutate", [
    pytest.param(_unknown_material_key, id="bad-material"),
    pytest.param(_garbage_mesh(".msh", _TEXT_GARBAGE), id="unreadable-mesh"),
    pytest.param(_not_toml, id="not-toml"),
])
def test_existing_output_is_left_untouched(tmp_path, mutate):
    scene = write_case(mutate, tmp_path)
    out = tmp_path / "r.npz"
    old = b"an earlier run, not to be clobbered\x00\xff"
    out.write_bytes(old)
    before = sorted(p.name for p in tmp_path.iterdir())
    proc = rheo("simulate", scene, "--steps", 2, "--out", out)
    assert_one_line_error(proc)
    assert out.read_bytes() == old
    assert sorted(p.name for p in tmp_path.iterdir()) == before


def test_output_and_build_paths_never_come_from_a_scene_name(tmp_path):
    """Names that reach paths without passing load_scene (a System built in code, a file's stem) are reduced
    to a plain file name: the build directory of a core stays inside its root."""
    import dataclasses
    from golden.scene import file_stem, load_scene
    from hw.bittrue import BitTrue
    from sim.hdlsim import emit_core
    assert file_stem("/abs/path/RUN") == "abs-path-RUN" and file_stem("../..") == "scene"
    assert file_stem("my scene") == "my-scene" and file_stem("press-2d-rheological") == "press-2d-rheological"
    system = dataclasses.replace(load_scene("creep-1d"), name=str(tmp_path / "outside" / "x"))
    core_dir, _, _ = emit_core(BitTrue(system, "wide", range_steps=20), root=tmp_path / "build")
    assert core_dir.parent == tmp_path / "build"
    assert not (tmp_path / "outside").exists()
