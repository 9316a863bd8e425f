"""The built-in 3D scenes show the seed's behaviours: press recovery (figs. 8, 9, 1 (e)), sinking under
gravity with a linear and a nonlinear damper (figs. 4, 5) and sliding with and without friction (fig. 12).

Each scene is simulated once per session (`_run`). Every measurement here is made from the frames and the
scene's raw TOML tables with this file's own code; the contact check does not use golden/contact.py.
"""
from __future__ import annotations

import functools
from itertools import combinations

import numpy as np
import pytest
from measures import quarter_sinks

from golden.model import simulate
from golden.scene import compile_scene, read_scene

PRESS = ["press-3d-viscoelastic", "press-3d-plastic", "press-3d-rheological"]
GRAVITY = ["gravity-3d-linear", "gravity-3d-nonlinear"]
FRICTION = ["friction-3d-mu0", "friction-3d-mu03"]
ALL = PRESS + GRAVITY + FRICTION


@functools.cache
def _run(name):
    scene = read_scene(name)
    system = compile_scene(scene)
    return scene, system, simulate(system)


def _in_box(x, box):
    lo, hi = np.asarray(box[0], float), np.asarray(box[1], float)
    return np.all((x >= lo) & (x <= hi), axis=1)


# ---------------------------------------------------------------- scene files

FIGURE = {"press-3d-viscoelastic": "fig. 8", "press-3d-plastic": "fig. 9", "press-3d-rheological": "fig. 1 (e)",
          "gravity-3d-linear": "fig. 4", "gravity-3d-nonlinear": "fig. 5",
          "friction-3d-mu0": "fig. 12", "friction-3d-mu03": "fig. 12"}


@pytest.mark.parametrize("name", ALL)
def test_scene_is_3d_and_names_its_figure(name):
    scene, system, run = _run(name)
    assert system.dim == 3 and system.x0.shape[1] == 3
    assert f"seed {FIGURE[name]})" in scene.description, scene.description
    assert "topology" in scene.data                      # topology preservation, as in the 2D scenes
    assert 100 <= len(run.t) <= 210, len(run.t)          # ~100-200 frames
    assert np.all(np.isfinite(run.x))


@pytest.mark.parametrize("name", ALL)
def test_no_tetrahedron_inverts(name):
    _, system, run = _run(name)
    p = run.x[:, system.cells]                                              # (F, C, 4, 3)
    vol = np.einsum("fcj,fcj->fc", np.cross(p[:, :, 1] - p[:, :, 0], p[:, :, 2] - p[:, :, 0]),
                    p[:, :, 3] - p[:, :, 0])
    assert np.all(vol > 0), np.argwhere(vol <= 0)[:5]


# ---------------------------------------------------------------- press and release (figs. 8, 9, 1 (e))

def _recovery(name):
    """1 - final / peak of the pressed patch's downward displacement relative to the bottom under it."""
    scene, system, run = _run(name)
    box = scene.data["loads"][0]["nodes"]["box"]
    x0 = system.x0
    top = np.flatnonzero(_in_box(x0, box))
    lo, hi = x0[top, :2].min(0), x0[top, :2].max(0)
    bottom = np.flatnonzero((x0[:, 2] == x0[:, 2].min()) & np.all((x0[:, :2] >= lo) & (x0[:, :2] <= hi), axis=1))
    assert len(top) >= 4 and len(bottom) == len(top)
    thickness = run.x[:, top, 2].mean(1) - run.x[:, bottom, 2].mean(1)
    disp = thickness[0] - thickness
    return 1 - disp[-1] / disp.max(), disp.max() / thickness[0]


@pytest.mark.parametrize("name,lo,hi", [("press-3d-viscoelastic", 0.95, 1.01),
                                        ("press-3d-plastic", -0.01, 0.10),
                                        ("press-3d-rheological", 0.20, 0.80)])
def test_press_recovery(name, lo, hi):
    recovery, peak = _recovery(name)
    assert peak > 0.02, peak               # a visible press: more than 2 % of the thickness
    assert lo < recovery < hi, recovery


@pytest.mark.parametrize("name", PRESS)
def test_pressed_box_comes_to_rest_after_release(name):
    # released well before the end, and at rest on the last frame (no lasting step-to-step oscillation)
    scene, system, run = _run(name)
    assert scene.data["loads"][0]["end"] < 0.7 * run.t[-1]
    speed = np.linalg.norm(run.v[-1], axis=1).max()
    assert speed < 1e-3, speed


# ---------------------------------------------------------------- gravity (figs. 4, 5)

def _sink(name):
    """Sink of the top face's mean height in the first and in the last quarter of the run."""
    _, system, run = _run(name)
    return quarter_sinks(system, run)


def test_linear_damper_keeps_sinking_under_gravity():
    first, last = _sink("gravity-3d-linear")
    assert first > 0 and last > 0.1 * first, (first, last)


def test_nonlinear_damper_stops_sinking_under_gravity():
    first, last = _sink("gravity-3d-nonlinear")
    assert first > 0 and abs(last) < 0.01 * first, (first, last)


def test_gravity_scenes_differ_only_in_the_damper():
    a, b = (_run(n)[0].data for n in GRAVITY)
    assert a["integrator"] == b["integrator"] and a["world"] == b["world"]
    (oa,), (ob,) = a["objects"], b["objects"]
    assert oa["mesh"] == ob["mesh"] and oa.get("position") == ob.get("position")
    assert "c2" in oa["material"] and "c2" not in ob["material"]
    assert oa["material"]["preset"] == ob["material"]["preset"] == "rheological"
    assert all(k in ob["material"] for k in ("c_max", "f1", "f2"))
    # the box is dropped: it starts above the floor
    assert oa["position"][2] > 0


# ---------------------------------------------------------------- friction (fig. 12)

def _slider(name):
    scene, system, run = _run(name)
    names = [o["name"] for o in scene.data["objects"]]
    k = names.index("slider")
    return scene, system, run, np.flatnonzero(system.node_object == k), scene.data["objects"][k]["mesh"]["size"][0]


def _slide(name):
    """Horizontal displacement of the small box's centroid from the first to the last frame."""
    _, _, run, nodes, _ = _slider(name)
    c = run.x[:, nodes, :2].mean(1)
    return float(np.linalg.norm(c[-1] - c[0]))


def test_friction_scenes_differ_only_in_mu():
    a, b = (_run(n)[0].data for n in FRICTION)
    assert a["collision"]["mu"] == 0.0 and b["collision"]["mu"] == 0.3
    strip = lambda d: {k: v for k, v in d.items() if k not in ("description", "collision")}
    assert strip(a) == strip(b)
    assert {k: v for k, v in a["collision"].items() if k != "mu"} == {k: v for k, v in b["collision"].items() if k != "mu"}
    assert 0.001 <= a["collision"]["threshold"] <= 0.002
    mats = {o["name"]: o["material"]["preset"] for o in a["objects"]}
    assert mats == {"base": "rheological", "slider": "viscoelastic"}


def test_without_friction_the_small_box_slides_far():
    _, _, _, _, width = _slider("friction-3d-mu0")
    slide = _slide("friction-3d-mu0")
    assert slide >= 0.2 * width, (slide, width)


def test_friction_holds_the_small_box_back():
    s0, s3 = _slide("friction-3d-mu0"), _slide("friction-3d-mu03")
    assert s3 < 0.5 * s0, (s3, s0)


def test_small_box_slides_towards_the_pressed_side():
    scene, system, run, nodes, _ = _slider("friction-3d-mu0")
    box = np.asarray(scene.data["loads"][0]["nodes"]["box"], float)
    c = run.x[:, nodes, :2].mean(1)
    towards = box[:, :2].mean(0) - c[0]
    assert np.dot(c[-1] - c[0], towards) > 0


# ---- contact check, independent of golden/contact.py

def boundary_triangles(cells):
    """Faces that belong to exactly one tetrahedron."""
    faces = np.array([sorted(f) for c in cells for f in combinations(c, 3)], np.int64)
    uniq, count = np.unique(faces, axis=0, return_counts=True)
    return uniq[count == 1]


def inside_tets(p, tets):
    """For points p (P, 3) and tetrahedra given as vertex positions (T, 4, 3): (P,) bool, inside one."""
    M = np.stack([tets[:, 1] - tets[:, 0], tets[:, 2] - tets[:, 0], tets[:, 3] - tets[:, 0]], axis=2)  # (T, 3, 3)
    inv = np.linalg.inv(M)
    lam = np.einsum("tij,ptj->pti", inv, p[:, None, :] - tets[None, :, 0])                            # (P, T, 3)
    tol = 1e-12                       # points on an internal face still count as inside
    inside = np.all(lam >= -tol, axis=2) & (lam.sum(2) <= 1 + tol)
    return inside.any(1)


def _segment_distance(p, a, b):
    ab = b - a
    t = np.clip(np.einsum("ptk,ptk->pt", p[:, None] - a, ab[None]) / np.einsum("tk,tk->t", ab, ab), 0, 1)
    foot = a[None] + t[..., None] * ab[None]
    return np.linalg.norm(p[:, None] - foot, axis=2)


def triangle_distance(p, tri):
    """Euclidean distance (P, T) from points (P, 3) to solid triangles (T, 3, 3)."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    n = np.cross(b - a, c - a)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    r = p[:, None] - a[None]                                              # (P, T, 3)
    h = np.einsum("ptk,tk->pt", r, n)
    q = p[:, None] - h[..., None] * n[None]                               # projection on the plane
    # the projection lies in the triangle iff it is on the inner side of all three edges
    inner = np.ones(h.shape, bool)
    for u, v in ((a, b), (b, c), (c, a)):
        inner &= np.einsum("ptk,tk->pt", np.cross(v - u, q - u[None]), n) >= 0
    edge = np.minimum(np.minimum(_segment_distance(p, a, b), _segment_distance(p, b, c)), _segment_distance(p, c, a))
    return np.where(inner, np.abs(h), edge)


def penetration_depths(x, points, cells, faces):
    """Depth of the nodes `points` inside the object made of `cells` (0 when outside): the distance to the
    object's nearest boundary triangle (`faces`). x: positions of all nodes."""
    p = x[points]
    inside = inside_tets(p, x[cells])
    depth = np.zeros(len(p))
    if inside.any():
        depth[inside] = triangle_distance(p[inside], x[faces]).min(1)
    return depth


def test_penetration_check_finds_a_known_depth():
    # a unit cube of 6 tetrahedra (Kuhn), written out here; a point 0.1 below its top face is 0.1 deep
    nodes = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)], float)
    cells = np.array([[0, 1, 3, 7], [0, 1, 5, 7], [0, 2, 3, 7], [0, 2, 6, 7], [0, 4, 5, 7], [0, 4, 6, 7]])
    faces = boundary_triangles(cells)
    assert len(faces) == 12
    x = np.vstack([nodes, [[0.4, 0.45, 0.9], [0.5, 0.5, 1.05], [0.95, 0.5, 0.45], [1.2, 1.3, 0.5]]])
    d = penetration_depths(x, np.arange(8, 12), cells, faces)
    assert d == pytest.approx([0.1, 0.0, 0.05, 0.0])
    # distance to a triangle from beyond a vertex and beyond an edge
    tri = np.array([[[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]])
    assert triangle_distance(np.array([[-1.0, -1, 0], [0.5, -2, 1], [0.2, 0.2, -3]]), tri)[:, 0] == \
        pytest.approx([np.sqrt(2), np.sqrt(5), 3.0])


@pytest.mark.parametrize("name", FRICTION)
def test_no_vertex_passes_through_the_other_object(name):
    scene, system, run = _run(name)
    h = scene.data["collision"]["threshold"]
    objs = []
    for k in range(len(scene.data["objects"])):
        cells = system.cells[system.cell_object == k]
        objs.append((np.flatnonzero(system.node_object == k), cells, boundary_triangles(cells)))
    worst = 0.0
    for x in run.x:
        for a, b in ((0, 1), (1, 0)):          # vertices of object b inside object a
            nodes_b, (_, cells_a, faces_a) = objs[b][0], objs[a]
            worst = max(worst, penetration_depths(x, nodes_b, cells_a, faces_a).max())
    assert worst <= h, (worst, h)


@pytest.mark.parametrize("name", FRICTION)
def test_small_box_rests_on_the_large_one(name):
    # the contact check above is not vacuous: the boxes touch (within 2 thresholds) on the last frame
    scene, system, run = _run(name)
    h = scene.data["collision"]["threshold"]
    base_cells = system.cells[system.cell_object == 0]
    base_faces = boundary_triangles(base_cells)
    _, _, _, slider, _ = _slider(name)
    x = run.x[-1]
    gap = triangle_distance(x[slider], x[base_faces]).min()
    assert gap < 2 * h, gap
