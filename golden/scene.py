"""Scenes: TOML files describing objects, materials, world, loads and integrator; validated on load.

`load_scene(name_or_path)` reads, checks and compiles a scene into the `System` of arrays the models step;
`read_scene` only reads it (the raw tables, a `Scene`), `compile_scene(scene)` checks and compiles those.
Every problem raises `SceneError` with a one-line message that names the scene, the table and the key. The
format is documented in README.md. A `[formats]` table is kept as given: number formats belong to the
hardware (hw/formats.py `check_scene_formats` validates it).
"""
from __future__ import annotations

import math
import re
import tomllib
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

from . import mesh as meshlib
from .errors import RheoError
from .builder import NONLINEAR, CollisionSpec, SystemBuilder, TopologySpec
from .contact import Floor
from .limits import mesh_nodes_fit
from .probe import Probe
from .system import Load, System


class SceneError(RheoError, ValueError):
    """A scene that cannot be loaded or run; the message names the problem."""


PLAIN_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,99}")


def file_stem(name: str) -> str:
    """`name` as a file name with no directory part, for output and build paths: no output path may come
    from inside an input file (a scene's `name` is validated as a plain name; this guards the rest)."""
    stem = re.sub(r"[^A-Za-z0-9._-]+", "-", str(name)).strip(".-")
    return stem[:100] or "scene"


# ---------------------------------------------------------------- materials

MATERIALS = {
    # a_min = a_max = 1: the Voigt part takes the whole length, c2 never acts (no a state)
    "viscoelastic": dict(k1=50.0, c1=0.5, a0=1.0, a_min=1.0, a_max=1.0, c2=1.0),
    # k1 = 0, c1 = c_max: two dampers in series; plasticity set by c_min and f2
    "plastic": dict(k1=0.0, c1=5.0, a0=0.5, a_min=0.0, a_max=1.0,
                    c_min=0.5, c_max=5.0, f1=0.01, f2=0.05),
    # the general three-element element with a force-dependent damper
    "rheological": dict(k1=50.0, c1=0.5, a0=0.5, a_min=0.05, a_max=1.0,
                        c_min=0.5, c_max=500.0, f1=0.01, f2=0.05),
    # a stiff viscoelastic object (seed fig. 11)
    "rigid": dict(k1=2000.0, c1=2.0, a0=1.0, a_min=1.0, a_max=1.0, c2=1.0),
}
_NONLINEAR = NONLINEAR
_MATERIAL_KEYS = {"preset", "k1", "c1", "a0", "a_min", "a_max", "c2", *_NONLINEAR, "density", "node_mass"}


# ---------------------------------------------------------------- table checking

class _Tables:
    """Helpers that check one TOML table and name the place of every problem."""

    def __init__(self, source: str):
        self.source = source

    def fail(self, where: str, msg: str):
        raise SceneError(f"{self.source}: [{where}] {msg}" if where else f"{self.source}: {msg}")

    def keys(self, tbl, where, required=(), optional=()):
        if not isinstance(tbl, dict):
            self.fail(where, f"must be a table, got {type(tbl).__name__}")
        allowed = set(required) | set(optional)
        for k in tbl:
            if k not in allowed:
                self.fail(where, f"unknown key '{k}' (allowed: {', '.join(sorted(allowed))})")
        for k in required:
            if k not in tbl:
                self.fail(where, f"missing required key '{k}'")

    def number(self, tbl, key, where, default=None, lo=None, lo_open=False, hi=None, allow_inf=False):
        if key not in tbl:
            if default is None:
                self.fail(where, f"missing required key '{key}'")
            return float(default)
        val = tbl[key]
        if isinstance(val, bool) or not isinstance(val, (int, float)):
            self.fail(where, f"'{key}' must be a number, got {val!r}")
        val = float(val)
        if math.isnan(val) or (math.isinf(val) and not allow_inf):
            self.fail(where, f"'{key}' must be finite, got {val}")
        if lo is not None and (val <= lo if lo_open else val < lo):
            self.fail(where, f"'{key}' must be {'>' if lo_open else '>='} {lo:g}, got {val:g}")
        if hi is not None and val > hi:
            self.fail(where, f"'{key}' must be <= {hi:g}, got {val:g}")
        return val

    def integer(self, tbl, key, where, default=None, lo=1):
        if key not in tbl:
            if default is None:
                self.fail(where, f"missing required key '{key}'")
            return int(default)
        val = tbl[key]
        if isinstance(val, bool) or not isinstance(val, int):
            self.fail(where, f"'{key}' must be an integer, got {val!r}")
        if val < lo:
            self.fail(where, f"'{key}' must be >= {lo}, got {val}")
        return val

    def vector(self, tbl, key, where, dim, default=None):
        if key not in tbl:
            if default is None:
                self.fail(where, f"missing required key '{key}'")
            return np.array(default, float)
        val = tbl[key]
        if (not isinstance(val, list) or len(val) != dim
                or not all(isinstance(c, (int, float)) and not isinstance(c, bool) for c in val)):
            self.fail(where, f"'{key}' must be a list of {dim} numbers, got {val!r}")
        arr = np.array(val, float)
        if not np.all(np.isfinite(arr)):
            self.fail(where, f"'{key}' must be finite, got {val!r}")
        return arr

    def boolean(self, tbl, key, where, default):
        val = tbl.get(key, default)
        if not isinstance(val, bool):
            self.fail(where, f"'{key}' must be true or false, got {val!r}")
        return val


# ---------------------------------------------------------------- the scene

@dataclass
class Scene:
    name: str
    source: str              # file path, or "builtin:NAME"
    base_dir: Path | None    # where relative mesh paths are resolved
    data: dict               # the raw TOML tables

    @property
    def description(self) -> str:
        return str(self.data.get("description", ""))


def builtin_names() -> list[str]:
    root = resources.files("golden") / "scenes"
    return sorted(p.name[:-5] for p in root.iterdir() if p.name.endswith(".toml"))


def load_scene(ref: str | Path) -> System:
    """A scene by built-in name or file path, read, checked and compiled."""
    return compile_scene(read_scene(ref))


def read_scene(ref: str | Path) -> Scene:
    """A scene's raw tables by built-in name or file path (TOML parsed, name checked; nothing compiled)."""
    path = Path(ref)
    if path.suffix == ".toml" or path.exists():
        if not path.is_file():
            raise SceneError(f"scene file not found: {path}")
        text, source, base = _read(path), str(path), path.resolve().parent
        name = path.stem
    elif str(ref) in builtin_names():
        f = resources.files("golden") / "scenes" / f"{ref}.toml"
        text, source, base, name = f.read_text(), f"builtin:{ref}", Path(str(f)).parent, str(ref)
    else:
        raise SceneError(f"scene '{ref}' not found: not a file and not a built-in scene "
                         f"(`rheo scenes` lists them)")
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(f"{source}: not valid TOML: {exc}") from None
    if "name" in data and not (isinstance(data["name"], str) and PLAIN_NAME.fullmatch(data["name"])):
        raise SceneError(f"{source}: 'name' must be a plain name of letters, digits, '.', '_' and '-' "
                         f"(it names output files), got {data['name']!r}")
    return Scene(str(data.get("name", file_stem(name))), source, base, data)


def _read(path: Path) -> str:
    try:
        return path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise SceneError(f"cannot read scene file {path}: {exc}") from None


def _mesh(chk: _Tables, tbl, where, dim, base_dir) -> meshlib.Mesh:
    kinds = {
        "single": (("length",), ()),
        "chain": (("n", "length"), ()),
        "rectangle": (("size", "divisions"), ("remove",)),
        "box": (("size", "divisions"), ("remove",)),
        "file": (("path",), ("scale",)),
        "explicit": (("nodes",), ("edges", "cells")),
    }
    if not isinstance(tbl, dict):
        chk.fail(where, "must be a table")
    kind = tbl.get("type")
    if kind not in kinds:
        chk.fail(where, f"'type' must be one of {', '.join(kinds)}, got {kind!r}")
    req, opt = kinds[kind]
    chk.keys(tbl, where, ("type",) + req, opt)
    if kind in ("rectangle", "box") and dim != (2 if kind == "rectangle" else 3):
        chk.fail(where, f"a {kind} mesh is {'2D' if kind == 'rectangle' else '3D'}, but the scene has dim = {dim}")
    if kind == "single":
        return meshlib.single(chk.number(tbl, "length", where, lo=0, lo_open=True), dim)
    if kind == "chain":
        n = chk.integer(tbl, "n", where)
        if (why := mesh_nodes_fit(n + 1, f"a chain of n = {n}")) is not None:
            chk.fail(where, why)
        return meshlib.chain(n, chk.number(tbl, "length", where, lo=0, lo_open=True), dim)
    if kind in ("rectangle", "box"):
        size = chk.vector(tbl, "size", where, dim)
        if np.any(size <= 0):
            chk.fail(where, f"'size' must be positive, got {size.tolist()}")
        div = tbl["divisions"]
        if not (isinstance(div, list) and len(div) == dim and all(isinstance(n, int) and not isinstance(n, bool) and n >= 1 for n in div)):
            chk.fail(where, f"'divisions' must be a list of {dim} integers >= 1, got {div!r}")
        if (why := mesh_nodes_fit(math.prod(n + 1 for n in div), f"a {kind} of divisions {div}")) is not None:
            chk.fail(where, why)
        m = meshlib.rectangle(size[0], size[1], *div) if dim == 2 else meshlib.box(size, div)
        cuts = tbl.get("remove", [])
        if not isinstance(cuts, list):
            chk.fail(where, "'remove' must be a list of boxes [[lo...], [hi...]]")
        for c, cut in enumerate(cuts):
            if not (isinstance(cut, list) and len(cut) == 2):
                chk.fail(where, f"'remove' box {c} must be [[lo...], [hi...]]")
            lo = chk.vector({"lo": cut[0]}, "lo", f"{where}.remove.{c}", dim)
            hi = chk.vector({"hi": cut[1]}, "hi", f"{where}.remove.{c}", dim)
            m = meshlib.remove_box(m, lo, hi)
            if len(m.cells) == 0:
                chk.fail(where, f"'remove' box {c} removes every cell")
        return m
    if kind == "file":
        if not isinstance(tbl["path"], str):
            chk.fail(where, "'path' must be a string")
        p = Path(tbl["path"])
        if not p.is_absolute() and base_dir is not None:
            p = base_dir / p
        if not p.is_file():
            chk.fail(where, f"mesh file not found: {p}")
        try:
            return meshlib.from_file(str(p), dim, chk.number(tbl, "scale", where, default=1.0, lo=0, lo_open=True))
        except meshlib.MeshError as exc:
            chk.fail(where, str(exc))
    # explicit: every index an integer (1.9 is refused, not truncated), every coordinate a number
    nodes = np.array(_rows(chk, tbl["nodes"], where, "nodes", dim, (int, float), "numbers"), float).reshape(-1, dim)
    cells = np.array(_rows(chk, tbl.get("cells", []), where, "cells", dim + 1, int, "node indices"),
                     np.int64).reshape(-1, dim + 1)
    edges = (np.array(_rows(chk, tbl["edges"], where, "edges", 2, int, "node indices"), np.int64).reshape(-1, 2)
             if "edges" in tbl else meshlib.edges_of_cells(cells))
    if len(nodes) == 0:
        chk.fail(where, f"'nodes' must be rows of {dim} numbers")
    return meshlib.Mesh(nodes, edges, cells)


def _rows(chk: _Tables, val, where, key, width, types, what) -> list:
    """`val` as a flat list: a list of rows of `width` entries (or one flat list of them), each entry of
    `types` (never a bool): indices must be integers, not numbers that would be truncated."""
    if not isinstance(val, list):
        chk.fail(where, f"'{key}' must be a list of rows of {width} {what}, got {val!r}")
    flat = []
    for r, row in enumerate(val):
        entries = row if isinstance(row, list) else [row]
        if isinstance(row, list) and len(row) != width:
            chk.fail(where, f"'{key}' must be rows of {width} {what}: row {r} is {row!r}")
        for v in entries:
            if isinstance(v, bool) or not isinstance(v, types):
                chk.fail(where, f"'{key}' row {r}: {v!r} is not {'an integer' if types is int else 'a number'} "
                                f"({key} are rows of {width} {what})")
        flat += entries
    if len(flat) % width:
        chk.fail(where, f"'{key}' must be rows of {width} {what}, got {len(flat)} entries")
    return flat


def _material(chk: _Tables, tbl, where) -> dict:
    chk.keys(tbl, where, (), _MATERIAL_KEYS)
    mat = {}
    if "preset" in tbl:
        if not isinstance(tbl["preset"], str) or tbl["preset"] not in MATERIALS:
            chk.fail(where, f"unknown preset {tbl['preset']!r} (known: {', '.join(MATERIALS)})")
        mat.update(MATERIALS[tbl["preset"]])
    user_nl = [k for k in _NONLINEAR if k in tbl]
    if "c2" in tbl and user_nl:
        chk.fail(where, f"give either a constant 'c2' or a nonlinear damper ({', '.join(_NONLINEAR)}), not both")
    if "c2" in tbl:
        for k in _NONLINEAR:
            mat.pop(k, None)
    if user_nl:
        mat.pop("c2", None)
    for k in tbl:
        if k != "preset":
            mat[k] = chk.number(tbl, k, where)
    for k in ("k1", "c1", "a0", "a_min", "a_max"):
        if k not in mat:
            chk.fail(where, f"missing required key '{k}' (or give a preset)")
    if "c2" not in mat and not all(k in mat for k in _NONLINEAR):
        chk.fail(where, f"give a constant 'c2' or all of {', '.join(_NONLINEAR)}")
    for k in ("k1", "c1"):
        if mat[k] < 0:
            chk.fail(where, f"'{k}' must be >= 0, got {mat[k]:g}")
    if not 0 <= mat["a_min"] <= 1 or not 0 < mat["a_max"] <= 1:
        chk.fail(where, f"need 0 <= a_min and 0 < a_max <= 1, got a_min = {mat['a_min']:g}, a_max = {mat['a_max']:g}")
    if mat["a_min"] > mat["a_max"]:
        chk.fail(where, f"a_min ({mat['a_min']:g}) must not exceed a_max ({mat['a_max']:g})")
    if not mat["a_min"] <= mat["a0"] <= mat["a_max"]:
        chk.fail(where, f"a0 ({mat['a0']:g}) must lie in [a_min, a_max] = [{mat['a_min']:g}, {mat['a_max']:g}]")
    if "c2" in mat:
        if mat["c2"] <= 0:
            chk.fail(where, f"'c2' must be > 0, got {mat['c2']:g}")
    else:
        if not 0 < mat["c_min"] <= mat["c_max"]:
            chk.fail(where, f"need 0 < c_min <= c_max, got c_min = {mat['c_min']:g}, c_max = {mat['c_max']:g}")
        if not 0 <= mat["f1"] < mat["f2"]:
            chk.fail(where, f"need 0 <= f1 < f2, got f1 = {mat['f1']:g}, f2 = {mat['f2']:g}")
    for k in ("density", "node_mass"):
        if k in mat and mat[k] <= 0:
            chk.fail(where, f"'{k}' must be > 0, got {mat[k]:g}")
    if "density" in mat and "node_mass" in mat:
        chk.fail(where, "give either 'density' or 'node_mass', not both")
    return mat


def _selection(chk: _Tables, sel, where, key, local_nodes) -> np.ndarray:
    """Node selection: "all", a list of node indices, or {box = [[lo...], [hi...]]} in mesh coordinates."""
    n, dim = local_nodes.shape
    if sel == "all":
        return np.arange(n)
    if isinstance(sel, list):
        if not all(isinstance(i, int) and not isinstance(i, bool) for i in sel):
            chk.fail(where, f"'{key}' must be a list of node indices, \"all\" or {{box = ...}}")
        idx = np.array(sel, np.int64)
        if idx.size and (idx.min() < 0 or idx.max() >= n):
            chk.fail(where, f"'{key}' names a node outside 0..{n - 1}")
    elif isinstance(sel, dict):
        chk.keys(sel, f"{where}.{key}", ("box",))
        b = sel["box"]
        if not (isinstance(b, list) and len(b) == 2):
            chk.fail(where, f"'{key}.box' must be [[lo...], [hi...]]")
        lo = chk.vector({"lo": b[0]}, "lo", f"{where}.{key}.box", dim)
        hi = chk.vector({"hi": b[1]}, "hi", f"{where}.{key}.box", dim)
        idx = np.flatnonzero(np.all((local_nodes >= lo) & (local_nodes <= hi), axis=1))
    else:
        chk.fail(where, f"'{key}' must be a list of node indices, \"all\" or {{box = ...}}")
    if idx.size == 0:
        chk.fail(where, f"'{key}' selects no node")
    return idx


def compile_scene(scene: Scene) -> System:
    """Turn the checked tables into the arrays of a System."""
    chk = _Tables(scene.source)
    d = scene.data
    chk.keys(d, "", ("dim", "integrator", "objects"),
             ("name", "description", "world", "topology", "collision", "loads", "formats", "probe"))
    dim = d["dim"]
    if isinstance(dim, bool) or not isinstance(dim, int) or dim not in (2, 3):
        chk.fail("", f"'dim' must be 2 or 3, got {dim!r}")

    integ = d["integrator"]
    chk.keys(integ, "integrator", ("dt", "duration"), ("output_every",))
    dt = chk.number(integ, "dt", "integrator", lo=0, lo_open=True)
    duration = chk.number(integ, "duration", "integrator", lo=0, lo_open=True)
    if not duration / dt < 2**53:
        chk.fail("integrator", f"'duration' / 'dt' = {duration / dt:g} steps is too many")
    n_steps = max(1, int(round(duration / dt)))
    every = chk.integer(integ, "output_every", "integrator", default=max(1, n_steps // 200))

    world = d.get("world", {})
    chk.keys(world, "world", (), ("gravity", "floor"))
    gravity = chk.vector(world, "gravity", "world", dim, default=np.zeros(dim))
    floor = None
    if "floor" in world:
        fl = world["floor"]
        chk.keys(fl, "world.floor", ("K",), ("height", "C", "mu", "k_f"))
        floor = Floor(chk.number(fl, "height", "world.floor", default=0.0),
                      chk.number(fl, "K", "world.floor", lo=0, lo_open=True),
                      chk.number(fl, "C", "world.floor", default=0.0, lo=0),
                      chk.number(fl, "mu", "world.floor", default=0.0, lo=0),
                      chk.number(fl, "k_f", "world.floor", default=math.nan, lo=0, lo_open=True))

    objs = d["objects"]
    if not isinstance(objs, list) or not objs:
        chk.fail("objects", "need at least one [[objects]] table")
    builder = SystemBuilder(dim)
    local, starts = [], []
    for o, obj in enumerate(objs):
        where = f"objects.{o}"
        chk.keys(obj, where, ("mesh", "material"), ("name", "position", "velocity", "pinned", "masses"))
        name = obj.get("name", f"object{o}")
        if not isinstance(name, str) or name in builder.names:
            chk.fail(where, f"'name' must be a unique string, got {name!r}")
        m = _mesh(chk, obj["mesh"], f"{where}.mesh", dim, scene.base_dir)
        try:
            meshlib.validate(m, f"[{where}.mesh]")
        except meshlib.MeshError as exc:
            raise SceneError(f"{scene.source}: {exc}") from None
        mat = _material(chk, obj["material"], f"{where}.material")
        n = len(m.nodes)
        if "masses" in obj:
            ms = obj["masses"]
            if not (isinstance(ms, list) and len(ms) == n and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in ms)):
                chk.fail(where, f"'masses' must be a list of {n} numbers (one per node)")
            mnode = np.array(ms, float)
        elif "node_mass" in mat:
            mnode = np.full(n, mat["node_mass"])
        elif "density" in mat:
            if len(m.cells) == 0:
                chk.fail(f"{where}.material", "this mesh has no cells to spread a density over: give 'node_mass' or the object's 'masses'")
            share = np.abs(meshlib.signed_measure(m.nodes, m.cells)) * mat["density"] / (dim + 1)
            mnode = np.bincount(m.cells.ravel(), weights=np.repeat(share, dim + 1), minlength=n)
        else:
            chk.fail(f"{where}.material", "no mass: give 'density' or 'node_mass' here, or the object's 'masses'")
        if not np.all(np.isfinite(mnode) & (mnode > 0)):
            k = int(np.flatnonzero(~(np.isfinite(mnode) & (mnode > 0)))[0])
            chk.fail(where, f"node {k} has mass {mnode[k]:g}: every node needs a positive, finite mass")
        pin = np.zeros(n, bool)
        if "pinned" in obj:
            pin[_selection(chk, obj["pinned"], where, "pinned", m.nodes)] = True
        pos = chk.vector(obj, "position", where, dim, default=np.zeros(dim))
        vel = chk.vector(obj, "velocity", where, dim, default=np.zeros(dim))
        local.append(m.nodes)
        starts.append(builder.add_object(name, m, mat, mnode, pin, pos, vel))
    names = builder.names

    topology = None
    if "topology" in d:
        tp = d["topology"]
        chk.keys(tp, "topology", ("K", "C", "eps"), ("enabled",))
        if chk.boolean(tp, "enabled", "topology", True):
            topology = TopologySpec(chk.number(tp, "K", "topology", lo=0, lo_open=True),
                                    chk.number(tp, "C", "topology", lo=0),
                                    chk.number(tp, "eps", "topology", lo=0))

    collision = None
    if "collision" in d:
        co = d["collision"]
        chk.keys(co, "collision", ("K", "threshold"), ("enabled", "C", "mu", "k_f"))
        if chk.boolean(co, "enabled", "collision", True):
            collision = CollisionSpec(chk.number(co, "K", "collision", lo=0, lo_open=True),
                                      chk.number(co, "C", "collision", default=0.0, lo=0),
                                      chk.number(co, "threshold", "collision", lo=0, lo_open=True),
                                      chk.number(co, "mu", "collision", default=0.0, lo=0),
                                      chk.number(co, "k_f", "collision", default=math.nan, lo=0, lo_open=True))

    loads = []
    lds = d.get("loads", [])
    if not isinstance(lds, list):
        chk.fail("loads", "must be an array of tables ([[loads]])")
    for q, ld in enumerate(lds):
        where = f"loads.{q}"
        chk.keys(ld, where, ("nodes", "force"), ("object", "start", "end"))
        oname = ld.get("object", names[0] if len(names) == 1 else None)
        if oname not in names:
            chk.fail(where, f"'object' must name one of the objects ({', '.join(names)}), got {oname!r}")
        o = names.index(oname)
        sel = _selection(chk, ld["nodes"], where, "nodes", local[o]) + starts[o]
        start = chk.number(ld, "start", where, default=0.0, lo=0)
        end = chk.number(ld, "end", where, default=math.inf, allow_inf=True)
        if end <= start:
            chk.fail(where, f"'end' ({end:g}) must be after 'start' ({start:g})")
        loads.append(Load(sel, chk.vector(ld, "force", where, dim), start, end))

    probe = _probe(chk, d["probe"], dim, n_steps * dt) if "probe" in d else None

    formats = d.get("formats", {})
    if not isinstance(formats, dict):
        chk.fail("formats", "must be a table of quantity = \"SQ(i, f)\"")
    return builder.build(scene.name, gravity, dt, n_steps, every, floor, topology, collision, loads, formats,
                         description=scene.description, probe=probe)


def _probe(chk: _Tables, tbl, dim: int, duration: float) -> Probe:
    """[probe]: the haptic probe (MODEL.md 4b) and its design poke."""
    w = "probe"
    chk.keys(tbl, w, ("radius", "K", "position"), ("C", "mu", "k_f", "steps_per_sample", "depth", "poke_time"))
    return Probe(chk.number(tbl, "radius", w, lo=0, lo_open=True),
                 chk.number(tbl, "K", w, lo=0, lo_open=True),
                 chk.number(tbl, "C", w, default=0.0, lo=0),
                 chk.number(tbl, "mu", w, default=0.0, lo=0),
                 chk.number(tbl, "k_f", w, default=math.nan, lo=0, lo_open=True),
                 chk.integer(tbl, "steps_per_sample", w, default=10),
                 chk.vector(tbl, "position", w, dim),
                 chk.number(tbl, "depth", w, default=0.0, lo=0),
                 chk.number(tbl, "poke_time", w, default=0.5 * duration, lo=0, lo_open=True))
