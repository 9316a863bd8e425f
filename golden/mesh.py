"""Meshes: built-in generators, mesh files, and the derived connectivity the model needs.

A mesh is nodes (N, D), rheological elements on its edges (E, 2) and cells: triangles (C, 3) in 2D,
tetrahedra (C, 4) in 3D, listed with positive orientation (counter-clockwise triangles, positive-volume
tetrahedra). Elements are the unique cell edges, start node = smaller index, unless given explicitly.
"""
from __future__ import annotations

from dataclasses import dataclass
from itertools import combinations, product
from pathlib import Path

import numpy as np

from .errors import RheoError


class MeshError(RheoError, ValueError):
    """A mesh that cannot be simulated; the message names the problem."""


@dataclass
class Mesh:
    nodes: np.ndarray   # (N, D) float64
    edges: np.ndarray   # (E, 2) int64
    cells: np.ndarray   # (C, D + 1) int64

    @property
    def dim(self) -> int:
        return self.nodes.shape[1]


def edges_of_cells(cells: np.ndarray) -> np.ndarray:
    """Unique undirected edges of the cells, each as (smaller, larger) node index, sorted."""
    if len(cells) == 0:
        return np.zeros((0, 2), np.int64)
    pairs = np.concatenate([cells[:, [p, q]] for p, q in combinations(range(cells.shape[1]), 2)])
    pairs.sort(axis=1)
    return np.unique(pairs, axis=0).astype(np.int64)


def signed_measure(nodes: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """Signed area of triangles (2D) or signed volume of tetrahedra (3D)."""
    p = nodes[cells]
    if cells.shape[1] == 3:
        u, w = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
        return 0.5 * (u[:, 0] * w[:, 1] - u[:, 1] * w[:, 0])
    u, w, z = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0], p[:, 3] - p[:, 0]
    return np.einsum("ij,ij->i", np.cross(u, w), z) / 6.0


def validate(mesh: Mesh, what: str) -> None:
    """Reject meshes the model cannot run: bad shapes, bad indices, zero-length edges, inverted cells."""
    n, d = mesh.nodes.shape
    if d not in (2, 3):
        raise MeshError(f"{what}: nodes must have 2 or 3 coordinates, got {d}")
    if n < 2:
        raise MeshError(f"{what}: a mesh needs at least 2 nodes, got {n}")
    if not np.all(np.isfinite(mesh.nodes)):
        raise MeshError(f"{what}: node coordinates must be finite numbers")
    for name, arr, width in (("edges", mesh.edges, 2), ("cells", mesh.cells, d + 1)):
        if arr.ndim != 2 or arr.shape[1] != width:
            raise MeshError(f"{what}: {name} must be rows of {width} node indices")
        if arr.size and (arr.min() < 0 or arr.max() >= n):
            raise MeshError(f"{what}: {name} refer to a node index outside 0..{n - 1}")
    if len(mesh.edges) == 0:
        raise MeshError(f"{what}: the mesh has no elements (edges)")
    if np.any(mesh.edges[:, 0] == mesh.edges[:, 1]):
        k = int(np.flatnonzero(mesh.edges[:, 0] == mesh.edges[:, 1])[0])
        raise MeshError(f"{what}: element {k} connects node {mesh.edges[k, 0]} to itself")
    length = np.linalg.norm(mesh.nodes[mesh.edges[:, 1]] - mesh.nodes[mesh.edges[:, 0]], axis=1)
    scale = np.ptp(mesh.nodes, axis=0).max()
    if np.any(length <= 1e-12 * max(scale, 1e-300)):
        k = int(np.argmin(length))
        raise MeshError(f"{what}: element {k} ({mesh.edges[k, 0]}-{mesh.edges[k, 1]}) has zero length")
    if len(mesh.cells):
        m = signed_measure(mesh.nodes, mesh.cells)
        bad = np.flatnonzero(m <= 0)
        if bad.size:
            kind = "triangle" if d == 2 else "tetrahedron"
            order = "counter-clockwise" if d == 2 else "with positive volume"
            raise MeshError(f"{what}: {kind} {bad[0]} {mesh.cells[bad[0]].tolist()} is inverted or "
                            f"degenerate (list its nodes {order})")


# ---------------------------------------------------------------- generators

def single(length: float, dim: int = 2) -> Mesh:
    nodes = np.zeros((2, dim))
    nodes[1, 0] = length
    return Mesh(nodes, np.array([[0, 1]]), np.zeros((0, dim + 1), np.int64))


def chain(n: int, length: float, dim: int = 2) -> Mesh:
    nodes = np.zeros((n + 1, dim))
    nodes[:, 0] = np.linspace(0.0, length, n + 1)
    edges = np.stack([np.arange(n), np.arange(1, n + 1)], axis=1)
    return Mesh(nodes, edges, np.zeros((0, dim + 1), np.int64))


def rectangle(width: float, height: float, nx: int, ny: int) -> Mesh:
    """Rectangle [0, w] x [0, h] of 2 nx ny triangles, mirror-symmetric about x = w/2 when nx is even."""
    xs, ys = np.linspace(0, width, nx + 1), np.linspace(0, height, ny + 1)
    X, Y = np.meshgrid(xs, ys, indexing="xy")
    nodes = np.stack([X.ravel(), Y.ravel()], axis=1)
    iy, ix = np.meshgrid(np.arange(ny), np.arange(nx), indexing="ij")
    ix, iy = ix.ravel(), iy.ravel()
    p00 = iy * (nx + 1) + ix
    p10, p01, p11 = p00 + 1, p00 + nx + 1, p00 + nx + 2
    left = 2 * ix + 1 < nx          # diagonal "/" on the left half, "\" on the right half
    t1 = np.where(left[:, None], np.stack([p00, p10, p11], 1), np.stack([p00, p10, p01], 1))
    t2 = np.where(left[:, None], np.stack([p00, p11, p01], 1), np.stack([p10, p11, p01], 1))
    cells = np.concatenate([t1, t2]).astype(np.int64)
    return Mesh(nodes, edges_of_cells(cells), cells)


# Kuhn's subdivision of the unit cube into 6 tetrahedra along the main diagonal (conforming).
_KUHN = [(0, 1, 3, 7), (0, 1, 5, 7), (0, 2, 3, 7), (0, 2, 6, 7), (0, 4, 5, 7), (0, 4, 6, 7)]


def box(size, divisions) -> Mesh:
    """Box [0, sx] x [0, sy] x [0, sz] of 6 nx ny nz tetrahedra."""
    (sx, sy, sz), (nx, ny, nz) = size, divisions
    g = np.stack(np.meshgrid(np.linspace(0, sx, nx + 1), np.linspace(0, sy, ny + 1),
                             np.linspace(0, sz, nz + 1), indexing="ij"), -1)
    nodes = g.reshape(-1, 3)
    idx = np.arange(len(nodes)).reshape(nx + 1, ny + 1, nz + 1)
    corners = np.stack([idx[i:i + nx, j:j + ny, k:k + nz].ravel()
                        for i, j, k in product((0, 1), repeat=3)], 1)   # corner c = 4i + 2j + k
    cells = np.concatenate([corners[:, list(t)] for t in _KUHN]).astype(np.int64)
    neg = signed_measure(nodes, cells) < 0
    cells[neg] = cells[neg][:, [0, 2, 1, 3]]
    return Mesh(nodes, edges_of_cells(cells), cells)


def from_file(path, dim: int, scale: float = 1.0) -> Mesh:
    """Read triangles (dim 2) or tetrahedra (dim 3) with meshio; orientation is made positive."""
    import contextlib
    import io
    import meshio
    chatter = io.StringIO()   # meshio prints its reader errors and, when no reader fits, calls sys.exit(1)
    try:
        with contextlib.redirect_stdout(chatter), contextlib.redirect_stderr(chatter):
            m = meshio.read(path)
    except FileNotFoundError:
        raise MeshError(f"mesh file not found: {path}") from None
    except (Exception, SystemExit) as exc:  # meshio raises many types for unreadable files
        said = [ln.strip() for ln in chatter.getvalue().split("Error:")[0].splitlines() if ln.strip()]
        why = (str(exc).splitlines()[0] if str(exc) and not isinstance(exc, SystemExit)
               else said[0] if said else f"not a readable {Path(path).suffix or 'mesh'} file")
        raise MeshError(f"cannot read mesh file {path}: {why}") from None
    kind = "triangle" if dim == 2 else "tetra"
    blocks = [c.data for c in m.cells if c.type == kind]
    if not blocks:
        raise MeshError(f"mesh file {path} has no {kind} cells")
    cells = np.concatenate(blocks).astype(np.int64)
    used = np.unique(cells)
    remap = np.full(len(m.points), -1, np.int64)
    remap[used] = np.arange(len(used))
    nodes = np.asarray(m.points, float)[used, :dim] * scale
    cells = remap[cells]
    mes = signed_measure(nodes, cells)
    flip = mes < 0
    cells[flip] = cells[flip][:, [1, 0] + list(range(2, dim + 1))]
    return Mesh(nodes, edges_of_cells(cells), cells)


def remove_box(m: Mesh, lo, hi) -> Mesh:
    """Cut away the cells whose centroid lies inside the box [lo, hi]; drop nodes no cell uses."""
    centre = m.nodes[m.cells].mean(1)
    keep = ~np.all((centre >= np.asarray(lo)) & (centre <= np.asarray(hi)), axis=1)
    cells = m.cells[keep]
    used = np.unique(cells)
    remap = np.full(len(m.nodes), -1, np.int64)
    remap[used] = np.arange(len(used))
    cells = remap[cells]
    return Mesh(m.nodes[used], edges_of_cells(cells), cells)


# ---------------------------------------------------------------- derived connectivity

def boundary_faces(cells: np.ndarray, nodes: np.ndarray):
    """Surface facets (edges in 2D, triangles in 3D) with the cell vertex opposite each.

    Returns (faces (S, D) oriented so their normal points out of the object, opposite (S,)).
    2D: outward normal of edge (a, b) is the right normal of b - a. 3D: cross(b - a, c - a) points out.
    """
    dim = cells.shape[1] - 1
    if len(cells) == 0:
        return np.zeros((0, dim), np.int64), np.zeros(0, np.int64)
    faces, opp = [], []
    for k in range(dim + 1):
        rest = [c for c in range(dim + 1) if c != k]
        faces.append(cells[:, rest])
        opp.append(cells[:, k])
    faces, opp = np.concatenate(faces), np.concatenate(opp)
    key = np.sort(faces, axis=1)
    _, inv, count = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    on_surface = count[inv.ravel()] == 1
    faces, opp = faces[on_surface], opp[on_surface]
    p = nodes[faces]
    if dim == 2:
        u = p[:, 1] - p[:, 0]
        outward = np.stack([u[:, 1], -u[:, 0]], 1)
    else:
        outward = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    inward = np.einsum("ij,ij->i", outward, nodes[opp] - p[:, 0]) > 0
    faces[inward] = faces[inward][:, ::-1]
    return faces.astype(np.int64), opp.astype(np.int64)


def topology_pairs(cells: np.ndarray, nodes: np.ndarray) -> np.ndarray:
    """(vertex, opposite facet) pairs of every cell: rows (k, i, j) in 2D, (k, i, j, l) in 3D.

    The facet is ordered so that its normal (left normal of j - i in 2D, cross(j - i, l - i) in 3D)
    points towards k in the rest shape.
    """
    dim = cells.shape[1] - 1
    if len(cells) == 0:
        return np.zeros((0, dim + 1), np.int64)
    rows = []
    for k in range(dim + 1):
        rest = [c for c in range(dim + 1) if c != k]
        rows.append(cells[:, [k] + rest])
    pairs = np.concatenate(rows).astype(np.int64)
    p = nodes[pairs]
    if dim == 2:
        u = p[:, 2] - p[:, 1]
        normal = np.stack([-u[:, 1], u[:, 0]], 1)
    else:
        normal = np.cross(p[:, 2] - p[:, 1], p[:, 3] - p[:, 1])
    away = np.einsum("ij,ij->i", normal, p[:, 0] - p[:, 1]) < 0
    swap = [0, 2, 1] if dim == 2 else [0, 1, 3, 2]
    pairs[away] = pairs[away][:, swap]
    return pairs
