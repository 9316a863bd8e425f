"""Topology preservation (MODEL.md section 3, seed eq. 8), vectorised over (vertex, opposite facet) pairs.

For each cell vertex P_k and its opposite facet (edge P_i P_j in 2D, triangle P_i P_j P_l in 3D):
n is the facet's unit normal on the side where P_k lies at rest, d = (x_k - x_i) . n the signed
distance, w the barycentric weights of the foot of P_k on the facet (w_1.. clipped to [0, 1], w_0 the rest), and
ddot = (v_k - sum w v) . n the normal speed of P_k relative to its foot point (exact in 2D).

    f = 0                               if d > eps
    f = -K (d - eps) - C ddot           if d <= eps

P_k receives f n; the facet vertices receive -w f n (momentum-conserving reaction, a resolution).
"""
from __future__ import annotations

import numpy as np


def facet_frame(xf: np.ndarray):
    """Unit normal (P, D) of facets given as vertex positions (P, D, D); the orientation rule of mesh.py."""
    if xf.shape[1] == 2:
        u = xf[:, 1] - xf[:, 0]
        n = np.stack([-u[:, 1], u[:, 0]], 1)
    else:
        n = np.cross(xf[:, 1] - xf[:, 0], xf[:, 2] - xf[:, 0])
    return n / np.sqrt(np.einsum("ij,ij->i", n, n))[:, None]


def foot_weights(xp: np.ndarray, xf: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Barycentric weights (P, D) of the foot of each point on its facet, unclipped."""
    if xf.shape[1] == 2:
        u = xf[:, 1] - xf[:, 0]
        t = np.einsum("ij,ij->i", xp - xf[:, 0], u) / np.einsum("ij,ij->i", u, u)
        return np.stack([1.0 - t, t], 1)
    e1, e2, r = xf[:, 1] - xf[:, 0], xf[:, 2] - xf[:, 0], xp - xf[:, 0]
    d11, d12, d22 = (np.einsum("ij,ij->i", e1, e1), np.einsum("ij,ij->i", e1, e2),
                     np.einsum("ij,ij->i", e2, e2))
    r1, r2 = np.einsum("ij,ij->i", r, e1), np.einsum("ij,ij->i", r, e2)
    den = d11 * d22 - d12 * d12
    w1 = (d22 * r1 - d12 * r2) / den
    w2 = (d11 * r2 - d12 * r1) / den
    return np.stack([1.0 - w1 - w2, w1, w2], 1)


def clip_weights(w: np.ndarray) -> np.ndarray:
    """Clip the foot onto the facet without a division: w_1.. in [0, 1], w_0 = 1 - sum of the others."""
    rest = np.clip(w[:, 1:], 0.0, 1.0)
    return np.concatenate([1.0 - rest.sum(1, keepdims=True), rest], 1)


def topology_forces(x, v, pairs, K, C, eps, out):
    """Add the preservation forces of all (k, facet) pairs into out (N, D)."""
    if len(pairs) == 0:
        return
    xf = x[pairs[:, 1:]]
    n = facet_frame(xf)
    d = np.einsum("ij,ij->i", x[pairs[:, 0]] - xf[:, 0], n)
    act = np.flatnonzero(d <= eps)
    if act.size == 0:
        return
    pr, n, d, xf = pairs[act], n[act], d[act], xf[act]
    w = clip_weights(foot_weights(x[pr[:, 0]], xf, n))
    vrel = v[pr[:, 0]] - np.einsum("ij,ijk->ik", w, v[pr[:, 1:]])
    f = -K * (d - eps) - C * np.einsum("ij,ij->i", vrel, n)
    apply_pair_forces(out, pr[:, 0], pr[:, 1:], w, f[:, None] * n)


def apply_pair_forces(out, vertex, facet, w, F):
    """Vertex gets F, facet vertices get -w F: scattered with one bincount per axis."""
    N, D = out.shape
    idx = np.concatenate([vertex[:, None], facet], 1).ravel()
    coef = np.concatenate([np.ones((len(vertex), 1)), -w], 1)           # (P, D + 1)
    contrib = coef[:, :, None] * F[:, None, :]                             # (P, D + 1, D)
    for ax in range(D):
        out[:, ax] += np.bincount(idx, weights=contrib[:, :, ax].ravel(), minlength=N)
