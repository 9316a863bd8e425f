"""Contact: the floor plane and vertex-facet collisions with Coulomb friction (MODEL.md section 4).

Penalty (a Voigt element, like eq. 8) with distance d along the facet's outward normal n:
    N = max(0, K (h - d) - C ddot)        while -h <= d <= h and the foot lies on the facet
h is the collision threshold (0 for the floor, where d is the height above it). A contact pushes, never
pulls (the max, a resolution: a penalty damper must not glue separating surfaces together).
Friction, regularised near zero slip (MODEL.md resolution), from the slip velocity v_t of the vertex
relative to its foot point:
    F_t = -min(mu N, k_f |v_t|) v_t / |v_t|
The vertex receives N n + F_t; the facet vertices receive -w (N n + F_t), w the foot's barycentric
weights (momentum conserving).

Broad phase: a uniform grid with cell size >= (largest facet radius + h). Each surface vertex is
binned; each facet looks in the 3^D cells around its centroid. Sorting the vertex keys once and a
searchsorted per neighbour offset make the cost O(S log S) in the surface size S.
"""
from __future__ import annotations

from dataclasses import dataclass
from itertools import product

import numpy as np

from .topology import apply_pair_forces, facet_frame, foot_weights


def friction(vrel_t, N, mu, k_f):
    """Regularised Coulomb friction force for tangential slip velocities vrel_t (P, D)."""
    speed = np.sqrt(np.einsum("ij,ij->i", vrel_t, vrel_t))
    gain = np.minimum(mu * N / np.maximum(speed, 1e-300), k_f)
    return -gain[:, None] * vrel_t


@dataclass
class Floor:
    height: float
    K: float
    C: float
    mu: float
    k_f: float

    def forces(self, x, v, out):
        axis = x.shape[1] - 1
        d = x[:, axis] - self.height
        act = np.flatnonzero(d < 0.0)
        if act.size == 0:
            return
        vn = v[act, axis]
        N = np.maximum(0.0, -self.K * d[act] - self.C * vn)
        out[act, axis] += N
        if self.mu > 0.0:
            vt = v[act].copy()
            vt[:, axis] = 0.0
            out[act] += friction(vt, N, self.mu, self.k_f)


@dataclass
class Collision:
    """Vertex-facet penalty contact between surface vertices and surface facets of all objects."""
    vertices: np.ndarray     # (V,) surface node indices
    facets: np.ndarray       # (S, D) node indices, outward orientation
    neighbour_keys: np.ndarray  # sorted keys a * N + b of node pairs joined by an element (both orders)
    n_nodes: int
    K: float
    C: float
    threshold: float
    mu: float
    k_f: float

    def candidates(self, x):
        """Broad phase: (vertex, facet) index pairs that may be within the threshold."""
        xv = x[self.vertices]
        xf = x[self.facets]
        centre = xf.mean(1)
        radius = np.sqrt(((xf - centre[:, None]) ** 2).sum(-1)).max()
        h = radius + self.threshold
        lo = np.minimum(xv.min(0), centre.min(0)) - h
        cv = np.floor((xv - lo) / h).astype(np.int64)
        cc = np.floor((centre - lo) / h).astype(np.int64)
        dims = np.maximum(cv.max(0), cc.max(0)) + 2
        stride = np.cumprod(np.concatenate([[1], dims[:-1]]))
        kv = cv @ stride
        order = np.argsort(kv, kind="stable")
        kv = kv[order]
        D = x.shape[1]
        fac, start, count = [], [], []
        base = cc @ stride
        for off in product((-1, 0, 1), repeat=D):
            key = base + np.asarray(off) @ stride
            s = np.searchsorted(kv, key, "left")
            c = np.searchsorted(kv, key, "right") - s
            keep = c > 0
            fac.append(np.flatnonzero(keep))
            start.append(s[keep])
            count.append(c[keep])
        fac, start, count = np.concatenate(fac), np.concatenate(start), np.concatenate(count)
        total = int(count.sum())
        first = np.repeat(np.cumsum(count) - count, count)
        vert = order[np.repeat(start, count) + np.arange(total) - first]
        return vert, np.repeat(fac, count)

    def all_pairs(self) -> np.ndarray:
        """Every (vertex, facet) pair that may ever touch, as (P, D + 1) node indices: each surface vertex
        with each surface facet, less the excluded ones. The hardware streams all of them every step
        (no broad phase); the gate inside the pair computation selects the touching ones."""
        V, S = len(self.vertices), len(self.facets)
        node = np.repeat(self.vertices, S)
        fn = np.tile(self.facets, (V, 1))
        keep = ~self._excluded(node, fn)
        return np.concatenate([node[keep, None], fn[keep]], 1).astype(np.int64)

    def _excluded(self, node, facet_nodes):
        """A vertex of the facet itself or joined to one of its vertices by an element."""
        excl = np.any(facet_nodes == node[:, None], axis=1)
        for col in facet_nodes.T:
            key = node * self.n_nodes + col
            pos = np.searchsorted(self.neighbour_keys, key)
            pos = np.minimum(pos, len(self.neighbour_keys) - 1)
            excl |= self.neighbour_keys[pos] == key
        return excl

    def forces(self, x, v, out):
        if len(self.facets) == 0:
            return
        vi, fi = self.candidates(x)
        node, fn = self.vertices[vi], self.facets[fi]
        keep = ~self._excluded(node, fn)
        node, fn = node[keep], fn[keep]
        if node.size == 0:
            return
        xf = x[fn]
        n = -facet_frame(xf) if x.shape[1] == 2 else facet_frame(xf)   # outward normal
        d = np.einsum("ij,ij->i", x[node] - xf[:, 0], n)
        near = np.abs(d) <= self.threshold
        w = foot_weights(x[node[near]], xf[near], n[near])
        on = np.all(w >= 0.0, axis=1)
        sel = np.flatnonzero(near)[on]
        if sel.size == 0:
            return
        node, fn, n, d, w = node[sel], fn[sel], n[sel], d[sel], w[on]
        vrel = v[node] - np.einsum("ij,ijk->ik", w, v[fn])
        vn = np.einsum("ij,ij->i", vrel, n)
        N = np.maximum(0.0, self.K * (self.threshold - d) - self.C * vn)
        F = N[:, None] * n
        if self.mu > 0.0:
            F += friction(vrel - vn[:, None] * n, N, self.mu, self.k_f)
        apply_pair_forces(out, node, fn, w, F)
