"""The 2D collision scenes of the seed's figures 6, 7 and 10-13, checked as numbers.

Penetration is measured here from the positions alone, independently of golden/contact.py: a surface
vertex lying inside a triangle that does not contain it (of another object, or of its own object for
self-collision) is penetrating; its depth is its distance to the nearest boundary edge of that
triangle's object (edges through the vertex itself excluded). Boundary edges are the edges of exactly
one triangle, computed here from the cells. The contact law pushes a vertex back only while it lies
within the threshold of a facet, so no depth may exceed the threshold.

Each scene is simulated once per session (module-level cache).
"""
from __future__ import annotations

import copy

import numpy as np
import pytest

from golden.model import simulate
from golden.scene import compile_scene, load_scene, read_scene

_RUNS: dict = {}


def _run(name):
    if name not in _RUNS:
        system = load_scene(name)
        _RUNS[name] = (system, simulate(system))
    return _RUNS[name]


# ---------------------------------------------------------------- geometry, independent of golden/

def _boundary_edges(cells):
    """Edges (B, 2) that belong to exactly one triangle."""
    e = np.concatenate([cells[:, [0, 1]], cells[:, [1, 2]], cells[:, [2, 0]]])
    key, count = np.unique(np.sort(e, axis=1), axis=0, return_counts=True)
    return key[count == 1]


def _segment_distance(p, a, b):
    """Distance from points p (..., 2) to segments [a, b] (..., 2)."""
    ab = b - a
    t = np.clip(np.sum((p - a) * ab, -1) / np.sum(ab * ab, -1), 0.0, 1.0)
    return np.linalg.norm(p - (a + t[..., None] * ab), axis=-1)


class _Surface:
    """Boundary edges and surface vertices of every object of a 2D system."""

    def __init__(self, system):
        self.cells = system.cells
        self.cell_object = system.cell_object
        self.edges = {o: _boundary_edges(system.cells[system.cell_object == o])
                      for o in np.unique(system.cell_object)}
        self.vertices = np.unique(np.concatenate([b.ravel() for b in self.edges.values()]))
        self.all_edges = np.concatenate(list(self.edges.values()))
        # mesh neighbours (joined by an element): a boundary edge touching one is not a contact partner
        n = len(system.x0)
        adj = np.zeros((n, n), bool)
        adj[system.edges[:, 0], system.edges[:, 1]] = adj[system.edges[:, 1], system.edges[:, 0]] = True
        adj[np.arange(n), np.arange(n)] = True
        self.adjacent = adj

    def penetration(self, x):
        """Deepest penetration of a surface vertex into a triangle not containing it, and where."""
        p = x[self.vertices]                                       # (V, 2)
        tri = x[self.cells]                                        # (C, 3, 2)
        a, u, w = tri[:, 0], tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
        den = u[:, 0] * w[:, 1] - u[:, 1] * w[:, 0]
        r = p[:, None, :] - a[None]                                # (V, C, 2)
        l1 = (r[..., 0] * w[:, 1] - r[..., 1] * w[:, 0]) / den
        l2 = (u[:, 0] * r[..., 1] - u[:, 1] * r[..., 0]) / den
        inside = (l1 > 0) & (l2 > 0) & (1.0 - l1 - l2 > 0)
        inside &= ~np.any(self.cells[None] == self.vertices[:, None, None], axis=2)
        worst, where = 0.0, None
        for vi, ci in zip(*np.nonzero(inside)):
            node = self.vertices[vi]
            be = self.edges[self.cell_object[ci]]
            be = be[~np.any(be == node, axis=1)]
            depth = _segment_distance(x[node], x[be[:, 0]], x[be[:, 1]]).min()
            if depth > worst:
                worst, where = float(depth), (int(node), int(ci))
        return worst, where

    def gaps(self, x, node_object):
        """Per object pair (o, q): the smallest distance of a surface vertex of o to a boundary edge of
        q that neither contains it nor touches one of its mesh neighbours (o == q: self-contact)."""
        be = self.all_edges
        d = _segment_distance(x[self.vertices][:, None, :], x[be[:, 0]][None], x[be[:, 1]][None])
        near = self.adjacent[self.vertices][:, be[:, 0]] | self.adjacent[self.vertices][:, be[:, 1]]
        d[near] = np.inf
        ov, oe = node_object[self.vertices], node_object[be[:, 0]]
        out = {}
        for o in np.unique(ov):
            for q in np.unique(oe):
                out[(int(o), int(q))] = float(d[np.ix_(ov == o, oe == q)].min())
        return out


def test_penetration_measure_finds_a_known_depth():
    """Two unit-ish triangles, one pushed 0.3 mm into the other: the measure must see 0.3 mm."""
    class S:
        x0 = np.zeros((6, 2))
        cells = np.array([[0, 1, 2], [3, 4, 5]])
        cell_object = np.array([0, 1])
        edges = np.array([[0, 1], [1, 2], [0, 2], [3, 4], [4, 5], [3, 5]])
    surf = _Surface(S)
    lower = [[0.0, 0.0], [0.01, 0.0], [0.005, 0.01]]
    upper = [[0.004, 0.0097], [0.006, 0.0097], [0.005, 0.02]]        # apex of `lower` 0.3 mm inside
    depth, where = surf.penetration(np.array(lower + upper))
    assert depth == pytest.approx(3e-4, rel=1e-9) and where == (2, 1)
    apart = np.array(lower + [[c[0], c[1] + 0.001] for c in upper])
    assert surf.penetration(apart)[0] == 0.0


# ---------------------------------------------------------------- no pass-through

COLLISION_SCENES = ["rigid-on-rheo-2d", "friction-2d-mu0", "friction-2d-mu03", "multi-2d", "fold-2d"]


@pytest.mark.parametrize("name", COLLISION_SCENES)
def test_no_vertex_passes_through_an_edge(name):
    system, run = _run(name)
    assert system.collision is not None
    h = system.collision.threshold
    surf = _Surface(system)
    depth = [surf.penetration(x) for x in run.x]
    f = int(np.argmax([d for d, _ in depth]))
    assert depth[f][0] <= h, f"{name}: node {depth[f][1]} {depth[f][0] * 1e3:.3f} mm deep at t = {run.t[f]:.3f} s"
    # the contacts really happened (the penalty acts below h): otherwise this test would test nothing
    gap = {}
    for x in run.x[::2]:
        for k, v in surf.gaps(x, system.node_object).items():
            gap[k] = min(gap.get(k, np.inf), v)
    if name == "fold-2d":
        touching = [gap[(0, 0)]]                                  # the arms meet
    else:
        touching = [min(gap[(o, q)] for q in range(len(system.object_names)) if q != o)
                    for o in range(len(system.object_names))]       # every object touches another
    assert max(touching) < 1.05 * h, touching                      # 5 % slack for grazing contacts


def test_penetration_is_detected_without_collisions():
    """The same falling blocks with collisions switched off do pass through each other."""
    scene = read_scene("multi-2d")
    scene.data["collision"]["enabled"] = False
    system = compile_scene(scene)
    run = simulate(system, steps=3000, every=100)
    surf = _Surface(system)
    assert max(surf.penetration(x)[0] for x in run.x) > 5e-3


# ---------------------------------------------------------------- fig. 11: rigid block on a soft one

def test_rigid_block_sinks_into_the_soft_block_and_stays_on_top():
    system, run = _run("rigid-on-rheo-2d")
    soft = system.node_object == system.object_names.index("soft")
    rigid = system.node_object == system.object_names.index("rigid")
    height = np.ptp(system.x0[soft, 1])
    top0 = system.x0[soft, 1].max()
    low = run.x[-1, rigid, 1].min()
    assert low > run.x[-1, soft, 1].min() + 0.5 * height, low      # not pushed through
    assert low < top0 - 0.1 * height, low                          # but sunk in by a visible amount
    cx = run.x[-1, rigid, 0].mean()
    assert run.x[-1, soft, 0].min() < cx < run.x[-1, soft, 0].max()
    # above the soft nodes it covers: it rests on the soft block
    under = soft & (run.x[-1, :, 0] > run.x[-1, rigid, 0].min()) & (run.x[-1, :, 0] < run.x[-1, rigid, 0].max())
    assert low > run.x[-1, under, 1].max() - system.collision.threshold


def test_rigid_block_keeps_its_shape():
    system, run = _run("rigid-on-rheo-2d")
    rigid = system.object_names.index("rigid")
    e = system.edges[system.node_object[system.edges[:, 0]] == rigid]
    length = np.linalg.norm(run.x[:, e[:, 1]] - run.x[:, e[:, 0]], axis=-1)
    change = np.abs(length / length[0] - 1.0).max()
    assert change < 0.01, change


# ---------------------------------------------------------------- fig. 12: friction

def _slide(name):
    system, run = _run(name)
    small = system.node_object == system.object_names.index("small")
    return run.x[-1, small, 0].mean() - run.x[0, small, 0].mean(), np.ptp(system.x0[small, 0])


def test_friction_scenes_differ_only_in_mu():
    a, b = read_scene("friction-2d-mu0").data, read_scene("friction-2d-mu03").data
    a, b = copy.deepcopy(a), copy.deepcopy(b)
    assert a["collision"].pop("mu") == 0.0 and b["collision"].pop("mu") == 0.3
    a.pop("description"), b.pop("description")
    assert a == b


def test_friction_slows_the_slide():
    free, width = _slide("friction-2d-mu0")
    rough, _ = _slide("friction-2d-mu03")
    assert free >= 0.2 * width, (free, width)                      # slides right, down the slope
    assert abs(rough) < 0.5 * free, (rough, free)


# ---------------------------------------------------------------- figs. 6, 7: push on the table

def _load_window(system):
    return system.loads[0].start, system.loads[0].end


def test_table_push_without_gravity_lifts_off_after_release():
    system, run = _run("table-push-2d")
    assert np.all(system.gravity == 0.0)
    start, end = _load_window(system)
    m = system.mass / system.mass.sum()
    vy = run.v[:, :, 1] @ m                                        # centre-of-mass velocity
    before = run.t < start
    assert np.abs(vy[before]).max() < 1e-12                        # at rest until pushed
    after = np.flatnonzero(run.t >= end + 0.02)[0]
    assert vy[after] > 0.01, vy[after]                             # the table's reaction throws it up
    assert run.x[-1, :, 1].min() > system.floor.height + 1e-3, run.x[-1, :, 1].min()


def test_table_push_with_gravity_ends_on_the_table():
    system, run = _run("table-push-2d-gravity")
    assert system.gravity[1] < 0
    start, end = _load_window(system)
    pressed = system.loads[0].nodes
    during = (run.t >= start) & (run.t <= end)
    dent = system.x0[pressed, 1].mean() - run.x[during][:, pressed, 1].mean(1).min()
    assert dent > 2e-3, dent                                       # it really was pushed
    bottom = np.flatnonzero(system.x0[:, 1] == system.x0[:, 1].min())
    y = run.x[-1, bottom, 1] - system.floor.height
    assert np.abs(y).max() <= 5e-4, y
