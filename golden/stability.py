"""Stability of the explicit scheme (MODEL.md section 7): the predicted dt limit of a scene.

predict(system) -> dict
    The largest dt at which the symplectic Euler step of MODEL.md section 5 is predicted to be stable.
    dt_pred = min(node bound, element bound).

    Node bound: each free node i is a one-mass model (mass m_i) with its element and penalty terms,
    evaluated for two kinds of fastest mode, and the smaller limit is kept:

    * mesh mode, the elements alone. Element e = (i, j) with direction e enters node i as
      w k e e^T (and w c e e^T), w = 1 + (m_i / m_j) r when j is free, w = 1 when j is pinned, r =
      sqrt(d_j / d_i) from the nodes' diagonal sums d (separately for stiffness and damping). With r = 1
      these are the column sums of the Gershgorin theorem for M^-1 K (w = 2 for two equal free masses:
      the relative coordinate has half the mass; w = 1 for a pinned far end: exact for one element);
      any r > 0 gives a valid bound, since (p - q)^2 <= (1 + al) p^2 + (1 + 1/al) q^2. The node's value
      is lambda_max of its D x D sum (directional, not the sum of norms). The sums are scaled by
      min(1, (1 + MESH_MARGIN) phi), phi = mesh_factor(): the exact largest eigenvalue of the unit-weight
      element operator of the node's connected component over its largest Gershgorin value (a mesh cannot
      move every neighbour against every node: 6.8 against 8 on an infinite right-triangle grid, 2.8
      against 8 on a 4 x 2 block); MESH_MARGIN = 0.2 covers deformed shapes.
    * contact mode, for a node that can touch a contact: the stiffest single contact it can make,
      floor (K, C) on a free surface node, one vertex-facet collision (2 K, 2 C) on a free surface node,
      one topology-preservation pair (2 K, 2 C) on a free cell node (2 K, 2 C is the Gershgorin sum over a
      vertex and its facet, whose weights add up to 1), the haptic probe (K, C) on any free node (it
      touches nodes, not a surface: a static-law contact like the floor, MODEL.md 4b), plus the node's own
      element terms with weight 1, along the floor normal (or lambda_max for the other contacts, the
      probe's normal pointing anywhere). A contact (K = 1e3..1e4) is far
      stiffer than the elements around it (k1 = 50..2000), so its fastest mode sits on the contact node
      and its neighbours follow it only by k1 / K; adding the contact to the mesh mode's Gershgorin sum
      would add up the damping of two different modes.

    For each mode the node is
    * a Voigt node when its elements have no a state (a_min = a_max: T = k1 s + c1 a ldot, so
      k = k1 a, c = c1 a): mass m on a spring k and damper c, stable iff k dt^2 + 2 c dt < 4 m, i.e.
      dt < (-c + sqrt(c^2 + 4 k m)) / k = 4 m / (c + sqrt(c^2 + 4 k m))  (voigt_limit);
    * a three-element node otherwise, a free: T = c2 (k1 s + c1 ldot) / (c1 + c2) coupled to the Voigt
      extension s, which the scheme advances explicitly. Linearised, with the node's sums (K1, C1, C2) and
      its Voigt terms (Kp, Cp: contact and fixed-a elements), it is the 3-state map (x, v, s):
          F  = -Kp x - (Cp + C1 C2 / G) v - (C2 K1 / G) s,      G = C1 + C2
          v' = v + dt F / m;   x' = x + dt v';   s' = s + dt (C2 v - K1 s) / G + a dt (v' - v)
      (the last term: the scheme moves l with the new velocity but a with the old rates, so a l moves by
      a dt (v' - v) more than the rate says). Its limit comes from the Jury conditions: closed form for
      Kp = 0 (three_element_limit; for one element, a = 1, the two conditions of MODEL.md 7:
      dt < 2 (c1 + c2) m / (c1 c2 + k1 m) and dt < (-B + sqrt(B^2 + 4 c2 k1 (c1 + c2) m)) / (c2 k1),
      B = c1 c2 + k1 m; 0.1275 for m = 1, k1 = 100, c1 = c2 = 5), bisection otherwise. The worst case is
      taken over a in {a_min, a_max} (the limit depends on a: 0.1275 at a = 1, 0.16 at a = 0.5, 0.25 at
      a = 0 in that example) and over c2 on a log grid of [c_t_min, c_max] (nonlinear damper; the worst
      is usually c_max). c2 here is the damper's tangent damping (MODEL.md 7): the element is solved
      exactly each step (T = Phi(Y), Y = k1 s + c1 ldot), so linearised it is a three-element element
      whose damper is c_t = dT/dw' = c2 / (1 + B |T|) between f1 and f2 (c2 itself outside), which ranges
      over [c_t_min, c_max] with c_t_min = c_min / (1 + B f2) (just below f2; B f2 = ln(A / c_min)).
      Not in dt_pred, reported: a sitting on a_max with adot > 0 makes the element a Voigt element
      (k1 a, c1 a) ("clamped_dt"; on a_min the Voigt part is rigid and the element is the damper alone,
      T = Psi((1 - a) ldot), damping at most c_max (1 - a_min), not reported); the clamp lets go at the
      next reversal of adot, which an unstable oscillation brings at once, and no built-in scene keeps a
      on a bound (press-2d-plastic: clamped_dt = 5.2e-5 s, yet it measures 1.20e-4 .. 1.25e-4 s, above its
      a-free prediction 1.05e-4 s).

    Element bound: the a state relaxes with rate k1 / (c1 + c_t): dt < 2 (c1 + c_t_min) / k1 (free a,
    k1 > 0; c_t_min = c_min / (1 + B f2) for a nonlinear damper, c2 for a constant one).

    Friction: the regularised friction is a damper of gain min(k_f, mu N / |v_t|), unstable above
    2 m / k_f ("friction_dt", with the same Gershgorin sums); its force is capped at mu N, so above that
    it chatters with a slip speed of about mu N dt / m instead of diverging. Not part of dt_pred.

The measured limit (bisection on real runs) is golden/measure.py; the divergence watchdog of every run
is golden/watchdog.py.
"""
from __future__ import annotations

import math

import numpy as np

from .system import System

C2_GRID = 9           # c2 values (log spaced over [c_t_min, c_max]) tried for a nonlinear damper
PATCH_DOFS = 3000     # mesh_factor solves larger components on a patch of about this many DOFs
PATCH_MARGIN = 0.02   # ... and raises the patch eigenvalue by this fraction
MESH_MARGIN = 0.2     # element terms x min(1, (1 + MESH_MARGIN) x mesh factor): deformed shapes differ

# ---------------------------------------------------------------- closed forms

def voigt_limit(k, c, m):
    """Largest dt with k dt^2 + 2 c dt < 4 m (mass m on a spring k and damper c, symplectic Euler).

    Written as 4 m / (c + sqrt(c^2 + 4 k m)) = (-c + sqrt(c^2 + 4 k m)) / k, also valid for k = 0."""
    k, c, m = np.broadcast_arrays(*(np.asarray(v, float) for v in (k, c, m)))
    den = c + np.sqrt(c * c + 4.0 * k * m)
    with np.errstate(divide="ignore"):
        return np.where(den > 0, 4.0 * m / np.where(den > 0, den, 1.0), np.inf)


def _first_root(beta, c):
    """4 / (beta + sqrt(beta^2 + c)) where beta^2 + c >= 0, else inf (no crossing). Computed on beta and c
    scaled by s = max(|beta|, sqrt|c|), so that the coefficients of a stiff element or a light node (beta
    of 1e160 and more) do not overflow beta^2 into inf, which would read as "no bound"."""
    beta, c = np.broadcast_arrays(np.asarray(beta, float), np.asarray(c, float))
    s = np.maximum(np.abs(beta), np.sqrt(np.abs(c)))
    with np.errstate(divide="ignore", invalid="ignore"):     # s = 0 (no element): nan, taken as no crossing
        b, cs = beta / s, c / s / s
        disc = b * b + cs
        ok = disc >= 0
        r = 4.0 / (s * (b + np.sqrt(np.where(ok, disc, 0.0))))
    return np.where(ok & (r > 0), r, np.inf)


def three_element_limit(m, k1, c1, c2, a=1.0, cp=0.0):
    """Largest stable dt of a mass m on one three-element element (far end pinned, a free), plus an
    optional extra damper cp on the mass. Closed form of the Jury conditions of the 2-state map (v, s):

        beta = K1/G + Cv/m,  P = (Cv K1/G + Cs C2/G)/m,  Q = a Cs/m,  Cv = C1 C2/G + cp,  Cs = C2 K1/G
        (i)   4 - 2 beta dt + (P - 2Q) dt^2 > 0
        (ii)  (P - Q) dt < beta
        (iii) 2 - beta dt + (P - Q) dt^2 > 0
    For a = 1, cp = 0 this is MODEL.md 7 (B = c1 c2 + k1 m)."""
    m, k1, c1, c2, a, cp = np.broadcast_arrays(*(np.asarray(v, float) for v in (m, k1, c1, c2, a, cp)))
    G = c1 + c2
    cv = c1 * c2 / G + cp
    cs = c2 * k1 / G
    kap = k1 / G
    beta = kap + cv / m
    P = (cv * kap + cs * c2 / G) / m
    Q = a * cs / m
    h1 = _first_root(beta, 4.0 * (2.0 * Q - P))
    with np.errstate(divide="ignore", invalid="ignore"):
        h2 = np.where(P - Q > 0, beta / np.where(P - Q > 0, P - Q, 1.0), np.inf)
    h3 = _first_root(beta, -8.0 * (P - Q))
    return np.minimum(np.minimum(h1, h2), h3)


def _det3(a):
    """Determinants of a stack of 3 x 3 matrices given as a nested list a[r][c] of arrays."""
    return (a[0][0] * (a[1][1] * a[2][2] - a[1][2] * a[2][1])
            - a[0][1] * (a[1][0] * a[2][2] - a[1][2] * a[2][0])
            + a[0][2] * (a[1][0] * a[2][1] - a[1][1] * a[2][0]))


def _cubic_stable(h, m, kp, cv, cs, sig, kap, a):
    """Jury test of the 3-state map (x, v, s) of one node (see the module docstring)."""
    km, cvm, csm = h * kp / m, h * cv / m, h * cs / m
    A = [[1 - h * km, h * (1 - cvm), -h * csm],
         [-km, 1 - cvm, -csm],
         [-a * h * km, h * sig - a * h * cvm, 1 - h * kap - a * h * csm]]
    tr = A[0][0] + A[1][1] + A[2][2]
    m2 = (A[0][0] * A[1][1] - A[0][1] * A[1][0] + A[0][0] * A[2][2] - A[0][2] * A[2][0]
          + A[1][1] * A[2][2] - A[1][2] * A[2][1])
    det = _det3(A)
    b2, b1, b0 = -tr, m2, -det                     # p(z) = z^3 + b2 z^2 + b1 z + b0
    IminusA = [[(1.0 if r == c else 0.0) - A[r][c] for c in range(3)] for r in range(3)]
    IplusA = [[(1.0 if r == c else 0.0) + A[r][c] for c in range(3)] for r in range(3)]
    p1 = _det3(IminusA)                            # p(1) = det(I - A)
    pm1 = -_det3(IplusA)                           # p(-1) = -det(I + A)
    return (p1 > 0) & (pm1 < 0) & (np.abs(b0) < 1) & (np.abs(b0 * b0 - 1) > np.abs(b0 * b2 - b1))


def node_three_element_limit(m, kp, cp, k1, c1, c2, a):
    """Largest stable dt of the linearised 1-node model: aggregated three-element element (k1, c1, c2)
    with a free, plus Voigt terms (kp, cp). Closed form when kp = 0, else bisection on the Jury test."""
    scalar = all(np.ndim(v) == 0 for v in (m, kp, cp, k1, c1, c2, a))
    m, kp, cp, k1, c1, c2, a = np.broadcast_arrays(*(np.atleast_1d(np.asarray(v, float))
                                                   for v in (m, kp, cp, k1, c1, c2, a)))
    out = np.empty(m.shape)
    G = c1 + c2
    cv = c1 * c2 / G + cp
    cs = c2 * k1 / G
    sig, kap = c2 / G, k1 / G
    # k1 = 0: s does not feed back (two dampers in series): a Voigt node with damping cv
    plain = k1 <= 0
    out[plain] = voigt_limit(kp[plain], cv[plain], m[plain])
    closed = ~plain & (kp <= 0)
    out[closed] = three_element_limit(m[closed], k1[closed], c1[closed], c2[closed], a[closed], cp[closed])
    cub = np.flatnonzero(~plain & (kp > 0))
    if cub.size:
        args = [v[cub] for v in (m, kp, cv, cs, sig, kap, a)]
        hi = 2.0 * np.minimum(voigt_limit(kp[cub] + k1[cub], cv[cub], m[cub]),
                              three_element_limit(m[cub], k1[cub], c1[cub], c2[cub], a[cub], cp[cub]))
        hi = np.where(np.isfinite(hi), hi, 1.0)
        for _ in range(200):                       # grow hi until unstable
            st = _cubic_stable(hi, *args)
            if not st.any():
                break
            hi = np.where(st, 2.0 * hi, hi)
        lo = np.zeros_like(hi)
        for _ in range(52):
            mid = 0.5 * (lo + hi)
            st = _cubic_stable(mid, *args)
            lo, hi = np.where(st, mid, lo), np.where(st, hi, mid)
        out[cub] = lo
    return float(out[0]) if scalar else out


# ---------------------------------------------------------------- prediction

def _per_element(system: System, name: str) -> np.ndarray:
    return np.broadcast_to(np.asarray(getattr(system.elem, name), float), (system.n_elements,))


def tangent_c_min(system: System) -> np.ndarray:
    """Per element (E,): the smallest tangent damping of its damper, MODEL.md 7.

    The damper's tangent damping is c_t = dT/dw' = c2 / (1 + B |T|) between f1 and f2 (w' = T / c2(|T|)
    = T exp(B |T|) / A there, so dw'/dT = (1 + B |T|) / c2) and c2 itself outside; its smallest value is
    c_min / (1 + B f2), just below f2, with B = ln(c_max / c_min) / (f2 - f1) and f2 = ln(A / c_min) / B,
    i.e. B f2 = ln(A / c_min). A constant damper (c_min = c_max, B = 0) gives c_min."""
    c_min = _per_element(system, "c_min")
    c_max = _per_element(system, "c_max")
    A, B = _per_element(system, "A"), _per_element(system, "B")
    varies = (c_max > c_min) & (B > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        bf2 = np.where(varies, np.log(np.where(varies, A / c_min, 1.0)), 0.0)      # B f2
    return c_min / (1.0 + np.maximum(bf2, 0.0))


def _boundary_nodes(system: System) -> np.ndarray:
    """Nodes that can touch the floor: nodes of the facets that belong to one cell only, and every node
    that is in no cell (facets keyed as integers: faster than a row-wise unique)."""
    N = system.n_nodes
    on = np.ones(N, bool)
    cells = system.cells
    if len(cells):
        D1 = cells.shape[1]
        faces = np.concatenate([np.delete(cells, k, axis=1) for k in range(D1)])
        faces = np.sort(faces, axis=1).astype(np.int64)
        if float(N) ** faces.shape[1] >= 2.0 ** 62:           # keys would overflow: row-wise unique
            _, inv, cnt = np.unique(faces, axis=0, return_inverse=True, return_counts=True)
            on[:] = False
            on[faces[cnt[inv.ravel()] == 1].ravel()] = True
            return on | ~np.isin(np.arange(N), cells)
        key = faces[:, 0]
        for c in range(1, faces.shape[1]):
            key = key * N + faces[:, c]
        order = np.argsort(key, kind="stable")
        ks = key[order]
        first = np.r_[True, ks[1:] != ks[:-1]]
        last = np.r_[ks[1:] != ks[:-1], True]
        single = order[first & last]
        on[:] = False
        on[faces[single].ravel()] = True
        in_cell = np.zeros(N, bool)
        in_cell[cells.ravel()] = True
        on |= ~in_cell
    return on


class _Geometry:
    """Element directions at rest and the two ends of every element, for per-node sums."""

    def __init__(self, system: System):
        self.N, self.D = system.n_nodes, system.dim
        self.m = np.asarray(system.mass, float)
        self.free = ~np.asarray(system.pinned, bool)
        i, j = system.edges[:, 0], system.edges[:, 1]
        d = system.x0[j] - system.x0[i]
        e = d / np.linalg.norm(d, axis=1)[:, None]
        self.ends = np.concatenate([i, j])                 # the node receiving the term
        self.other = np.concatenate([j, i])
        self.elem = np.concatenate([np.arange(len(i))] * 2)
        E2 = np.concatenate([e, e])
        self.outer = [(a, b, E2[:, a] * E2[:, b]) for a in range(self.D) for b in range(a, self.D)]
        self.e = e
        self._cache = {}

    def weights(self, diag=None) -> np.ndarray:
        """Weight of each (end, element) entry in the bound of its end node i (other end j):
        w = 1 + (m_i / m_j) r with r = sqrt(d_j / d_i) (d: the nodes' diagonal sums, r = 1 without),
        w = 1 when j is pinned, 0 when i is pinned."""
        m, free, ends, other = self.m, self.free, self.ends, self.other
        r = 1.0
        if diag is not None:
            eps = 1e-12 * float(np.max(diag)) + 1e-300
            r = np.clip(np.sqrt((diag[other] + eps) / (diag[ends] + eps)), 1e-3, 1e3)
        return np.where(free[other], 1.0 + m[ends] / m[other] * r, 1.0) * free[ends]

    def lmax(self, w, values, mask=None) -> np.ndarray:
        """Per node: largest eigenvalue of the sum over its elements of w * value * e e^T (D x D).
        A value that is the same on every selected element scales a cached unit sum."""
        values = np.asarray(values, float)
        sel = values if mask is None else values[mask]
        if sel.size == 0:
            return np.zeros(self.N)
        if np.all(sel == sel[0]):
            key = (id(w), None if mask is None else mask.tobytes())
            if key not in self._cache:
                self._cache[key] = (w, self._lmax(w, np.ones_like(values), mask))
            return sel[0] * self._cache[key][1]
        return self._lmax(w, values, mask)

    def _lmax(self, w, values, mask=None) -> np.ndarray:
        wv = w * np.asarray(values, float)[self.elem]
        if mask is not None:
            wv = wv * mask[self.elem]
        S = np.zeros((self.N, self.D, self.D))
        for a, b, ee in self.outer:
            S[:, a, b] = S[:, b, a] = np.bincount(self.ends, weights=wv * ee, minlength=self.N)
        return np.linalg.eigvalsh(S)[:, -1]

    def along(self, w, values, mask=None, axis=-1) -> np.ndarray:
        """Per node: sum over its elements of w * value * e_axis^2 (the element terms along one axis)."""
        wv = w * np.asarray(values, float)[self.elem]
        if mask is not None:
            wv = wv * mask[self.elem]
        ez = np.concatenate([self.e, self.e])[:, axis]
        return np.bincount(self.ends, weights=wv * ez * ez, minlength=self.N)

    def total(self, values) -> np.ndarray:
        """Per node: plain sum of the values of its elements."""
        return np.bincount(self.ends, weights=np.asarray(values, float)[self.elem], minlength=self.N)


def mesh_factor(system: System, geo: _Geometry | None = None) -> np.ndarray:
    """Per node phi <= 1: the exact largest eigenvalue of the unit-weight, mass-scaled element operator
    M^-1/2 (sum_e g_e g_e^T) M^-1/2 of the node's connected component, over the largest per-node Gershgorin
    value lambda_max(sum_e w e e^T) / m_i (w = 1 + m_i / m_j) in that component. The Gershgorin sum assumes
    that every neighbour moves against the node at once, which a mesh cannot do (8 against 6.8 for an
    infinite right-triangle grid, 8 against 2.8 on a 4 x 2 block).

    A component of more than PATCH_DOFS DOFs is not solved whole: its eigenvalue is taken from the patch of
    about PATCH_DOFS DOFs around its three largest Gershgorin nodes (a principal submatrix, so a lower
    bound by interlacing, within about 1 % of the whole for a uniform mesh), raised by PATCH_MARGIN."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components
    geo = _Geometry(system) if geo is None else geo
    N, D, free, m = geo.N, geo.D, geo.free, geo.m
    lam_node = geo.lmax(geo.weights(), np.ones(system.n_elements)) / m
    phi = np.ones(N)
    i, j = system.edges[:, 0], system.edges[:, 1]
    both = free[i] & free[j]
    adj = sp.coo_matrix((np.ones(int(both.sum())), (i[both], j[both])), shape=(N, N)).tocsr()
    adj = (adj + adj.T).tocsr()
    ncomp, label = connected_components(adj, directed=False)
    order = np.argsort(label, kind="stable")
    bounds = np.searchsorted(label[order], np.arange(ncomp + 1))
    for c in range(ncomp):
        nodes = order[bounds[c]:bounds[c + 1]]
        nodes = nodes[free[nodes]]
        if nodes.size == 0:
            continue
        top = float(lam_node[nodes].max())
        if top <= 0:
            continue
        patch = nodes
        if nodes.size * D > PATCH_DOFS:
            patch = _patch(adj, nodes[np.argsort(lam_node[nodes])[-3:]], PATCH_DOFS // D)
        sub = _unit_operator(system, geo, np.sort(patch))
        dofs = sub.shape[0]
        if dofs <= 48:     # dense LAPACK only for tiny blocks: threaded BLAS is slow on busy machines
            lam = float(np.linalg.eigvalsh(sub.toarray())[-1])
        else:
            from scipy.sparse.linalg import eigsh
            try:
                lam = float(eigsh(sub, k=1, which="LA", tol=1e-6, return_eigenvectors=False)[0])
            except Exception:       # no convergence: keep the plain Gershgorin bound
                lam = top
        if patch is not nodes:
            lam *= 1.0 + PATCH_MARGIN
        phi[nodes] = min(1.0, lam / top)
    return phi


def _unit_operator(system: System, geo: _Geometry, nodes: np.ndarray):
    """Principal submatrix, on the DOFs of the (free, sorted) nodes, of the unit-weight mass-scaled
    element operator M^-1/2 (sum_e g_e g_e^T) M^-1/2 (g_e = e at the end node, -e at the start node)."""
    import scipy.sparse as sp
    N, D = geo.N, geo.D
    loc = np.full(N, -1)
    loc[nodes] = np.arange(len(nodes))
    i, j = system.edges[:, 0], system.edges[:, 1]
    keep = (loc[i] >= 0) | (loc[j] >= 0)
    i, j, e = i[keep], j[keep], geo.e[keep]
    rows, cols, vals = [], [], []
    inv = 1.0 / np.sqrt(geo.m)
    for p, q, sgn in ((i, i, 1.0), (j, j, 1.0), (i, j, -1.0), (j, i, -1.0)):
        ok = (loc[p] >= 0) & (loc[q] >= 0)
        scale = sgn * inv[p[ok]] * inv[q[ok]]
        for a in range(D):
            for b in range(D):
                rows.append(loc[p[ok]] * D + a)
                cols.append(loc[q[ok]] * D + b)
                vals.append(scale * e[ok, a] * e[ok, b])
    n = len(nodes) * D
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n))


def _patch(adj, seeds, max_nodes: int) -> np.ndarray:
    """Nodes within a few element hops of the seeds (breadth first, at most about max_nodes)."""
    inside = np.zeros(adj.shape[0], bool)
    inside[seeds] = True
    front = np.asarray(seeds)
    while front.size and inside.sum() < max_nodes:
        nxt = np.unique(adj[front].indices)
        nxt = nxt[~inside[nxt]]
        if inside.sum() + nxt.size > max_nodes:
            nxt = nxt[:max_nodes - int(inside.sum())]
        inside[nxt] = True
        front = nxt
    return np.flatnonzero(inside)


def node_terms(system: System) -> dict:
    """Per-node (N,) scalars of the node model: mass; penalty (kp, cp) of the stiffest single contact
    the node can make; fixed-a Voigt elements (kf, cf); moving-a three-element elements (k1, c1, c2 on a
    grid over [c_t_min, c_max], c_t_min = c_min / (1 + B f2) the smallest tangent damping, MODEL.md 7).
    Element terms are directional Gershgorin sums (balanced weights, see _Geometry.weights) scaled by
    min(1, (1 + MESH_MARGIN) x mesh_factor)."""
    geo = _Geometry(system)
    N, free, m = geo.N, geo.free, geo.m
    k1, c1 = _per_element(system, "k1"), _per_element(system, "c1")
    a_min, a_max = _per_element(system, "a_min"), _per_element(system, "a_max")
    c_max = _per_element(system, "c_max")
    c_lo = tangent_c_min(system)                              # smallest tangent damping of each damper
    moving = (not system.elem.fixed_a) & (a_max > a_min)      # elements with an a state
    fixed = ~moving
    t = {"m": m, "free": free}

    # penalty terms that can touch the node: the stiffest single contact among the floor (K, C), one
    # vertex-facet collision, the probe (K, C: any node) and one topology-preservation pair (2 K, 2 C: the
    # Gershgorin sum over the vertex and its facet, whose weights add up to 1)
    zeros = np.zeros(N)
    for name in ("k_floor", "c_floor", "k_collision", "c_collision", "k_topology", "c_topology", "k_probe",
                 "c_probe", "friction"):
        t[name] = zeros.copy()
    if system.floor is not None:
        b = _boundary_nodes(system) & free
        t["k_floor"][b] = system.floor.K
        t["c_floor"][b] = system.floor.C
        if system.floor.mu > 0:
            t["friction"][b] = np.maximum(t["friction"][b], system.floor.k_f)
    if system.collision is not None and len(system.collision.facets):
        on = np.zeros(N, bool)
        on[system.collision.vertices] = True
        on[system.collision.facets.ravel()] = True
        on &= free
        t["k_collision"][on] = 2.0 * system.collision.K
        t["c_collision"][on] = 2.0 * system.collision.C
        if system.collision.mu > 0:
            t["friction"][on] = np.maximum(t["friction"][on], 2.0 * system.collision.k_f)
    if system.topology is not None and len(system.topology.pairs):
        on = np.zeros(N, bool)
        on[system.topology.pairs.ravel()] = True
        on &= free
        t["k_topology"][on] = 2.0 * system.topology.K
        t["c_topology"][on] = 2.0 * system.topology.C
    if system.probe is not None:
        pb = system.probe
        t["k_probe"][free] = pb.K
        t["c_probe"][free] = pb.C
        if pb.mu > 0:
            t["friction"][free] = np.maximum(t["friction"][free], pb.k_f)
    kinds = ("floor", "collision", "topology", "probe")
    K = np.stack([t[f"k_{k}"] for k in kinds])
    C = np.stack([t[f"c_{k}"] for k in kinds])
    pick = np.argmax(K, 0)
    col = np.arange(N)
    t["kp"], t["cp"] = K[pick, col], C[pick, col]
    t["contact"] = np.where(t["kp"] > 0, np.array(kinds)[pick], "")

    # mesh mode: the element terms alone, directional Gershgorin sums with balanced weights (one set
    # for stiffness, one for damping), scaled by the mesh factor
    kmax = np.maximum(k1 * a_max, k1)
    cmax = np.maximum(np.maximum(c1 * a_max, c1), np.where(moving, c_max, 0.0))
    wk = geo.weights(geo.total(kmax))        # plain sums: the mass ratio enters once, in weights()
    wc = geo.weights(geo.total(cmax))
    phi = mesh_factor(system, geo)
    t["phi"] = phi
    scale = np.minimum(1.0, (1.0 + MESH_MARGIN) * phi)
    t["scale"] = scale
    grid = np.linspace(0.0, 1.0, C2_GRID) if system.elem.nonlinear else np.zeros(1)
    t["c2_values"] = [float(np.median(c_lo[moving] ** (1 - g) * c_max[moving] ** g)) if moving.any() else 0.0
                      for g in grid]
    c2s = [c_lo ** (1 - g) * c_max ** g for g in grid]

    def terms(sum_k, sum_c, kp, cp):
        return {"kp": kp + sum_k(k1 * a_max, fixed), "cp": cp + sum_c(c1 * a_max, fixed),
                "k1": sum_k(k1, moving), "c1": sum_c(c1, moving),
                "c2": np.stack([sum_c(c2, moving) for c2 in c2s])}

    t["mesh"] = terms(lambda v, mask: scale * geo.lmax(wk, v, mask), lambda v, mask: scale * geo.lmax(wc, v, mask),
                      zeros, zeros)
    # contact mode: a contact is far stiffer than the elements around it (K = 1e3..1e4 against k1 = 50..2000
    # in the built-in scenes), so its fastest mode sits on the contact node and its neighbours follow it only
    # by k1 / K: the node's own element terms enter with weight 1 (as if their far ends were held), along the
    # floor normal, or in their stiffest direction for a collision or topology contact. Adding the contact to
    # the mesh mode's Gershgorin sum instead would add the damping of two different modes.
    w1 = free[geo.ends].astype(float)
    floor_like = t["contact"] == "floor"

    def contact_sum(v, mask):
        return np.where(floor_like, geo.along(w1, v, mask), geo.lmax(w1, v, mask))

    t["touch"] = terms(contact_sum, contact_sum, t["kp"], t["cp"])
    t["has_contact"] = (t["kp"] > 0) & free
    # element sums reported for the limiting node
    t["kf"] = t["mesh"]["kp"]
    t["cf"] = t["mesh"]["cp"]
    t["k1"] = t["mesh"]["k1"]
    t["c1"] = t["mesh"]["c1"]
    # a clamped on a bound (reported, not in dt_pred): Voigt k1 a_max, c1 a_max
    t["k_clamped"] = scale * geo.lmax(wk, k1 * a_max)
    t["c_clamped"] = scale * geo.lmax(wc, c1 * a_max)
    a_hi = np.full(N, -np.inf)
    a_lo = np.full(N, np.inf)
    w0 = geo.weights()
    sel = moving[geo.elem] & (w0 > 0)
    np.maximum.at(a_hi, geo.ends[sel], a_max[geo.elem][sel])
    np.minimum.at(a_lo, geo.ends[sel], a_min[geo.elem][sel])
    t["a_hi"], t["a_lo"] = np.where(np.isfinite(a_hi), a_hi, 1.0), np.where(np.isfinite(a_lo), a_lo, 1.0)
    t["has_moving"] = (t["k1"] + t["c1"] > 0) & free
    return t


def node_limits(system: System, t: dict | None = None):
    """Per-node predicted limit (N,), the index of the case that sets it, and the case names.

    Cases: the mesh mode and, for nodes that can touch a contact, the contact mode; each as a Voigt node
    when the node has no a state, else as the three-element node model with a free at a_max and at a_min,
    for every c2 on the grid over [c_t_min, c_max] (tangent damping, MODEL.md 7). Nodes with identical
    parameters are evaluated once."""
    t = node_terms(system) if t is None else t
    m, free = t["m"], t["free"]
    modes = (("mesh mode", t["mesh"], free), ("contact mode", t["touch"], t["has_contact"]))
    G = len(t["c2_values"])
    cols = [m, t["a_hi"], t["a_lo"], t["has_moving"].astype(float)]
    for _, tm, sel in modes:
        cols += [sel.astype(float), tm["kp"], tm["cp"], tm["k1"], tm["c1"], *tm["c2"]]
    F = np.ascontiguousarray(np.stack(cols, 1)[free])
    rows = F.view(np.dtype((np.void, F.dtype.itemsize * F.shape[1]))).ravel()
    _, first, inv = np.unique(rows, return_index=True, return_inverse=True)
    U = F[first]
    um, a_hi, a_lo, moving = U[:, 0], U[:, 1], U[:, 2], U[:, 3] > 0
    cases, lims, batch = [], [], []
    for q, (mode, _, _) in enumerate(modes):
        base = 4 + q * (5 + G)
        sel, kp, cp, k1, c1 = U[:, base] > 0, U[:, base + 1], U[:, base + 2], U[:, base + 3], U[:, base + 4]
        lims.append(np.where(sel & ~moving, voigt_limit(kp, cp, um), np.inf))
        cases.append(f"{mode}, Voigt (fixed a)")
        mv = np.flatnonzero(sel & moving)
        for g in range(G):
            c2 = U[:, base + 5 + g]
            for which, a in (("a_max", a_hi), ("a_min", a_lo)):
                batch.append((len(lims), mv, [um[mv], kp[mv], cp[mv], k1[mv], c1[mv], c2[mv], a[mv]]))
                lims.append(np.full(len(U), np.inf))
                cases.append(f"{mode}, three-element, a free at {which}, c2 = {t['c2_values'][g]:.4g}")
    if batch and sum(len(mv) for _, mv, _ in batch):
        args = [np.concatenate([b[2][k] for b in batch]) for k in range(7)]
        vals = node_three_element_limit(*args)
        pos = 0
        for k, mv, _ in batch:
            lims[k][mv] = vals[pos:pos + mv.size]
            pos += mv.size
    lims = np.stack(lims)                               # (cases, U)
    ucase = np.argmin(lims, 0)
    ulim = lims[ucase, np.arange(len(U))]
    out = np.full(len(m), np.inf)
    case = np.zeros(len(m), int)
    out[free] = ulim[inv.ravel()]
    case[free] = ucase[inv.ravel()]
    return out, case, cases


def element_limits(system: System) -> np.ndarray:
    """Per-element bound on the a state, dt < 2 (c1 + c_t_min) / k1 (inf without an a state or k1 = 0),
    with c_t_min = c_min / (1 + B f2) the damper's smallest tangent damping (MODEL.md 7; c2 for a constant
    damper): linearised, a relaxes with rate k1 / (c1 + c_t)."""
    k1, c1 = _per_element(system, "k1"), _per_element(system, "c1")
    a_min, a_max = _per_element(system, "a_min"), _per_element(system, "a_max")
    c_lo = tangent_c_min(system)
    moving = (not system.elem.fixed_a) & (a_max > a_min) & (k1 > 0)
    out = np.full(system.n_elements, np.inf)
    out[moving] = 2.0 * (c1[moving] + c_lo[moving]) / k1[moving]
    return out


def predict(system: System) -> dict:
    """The predicted largest stable dt of the scene, its limiting node or element and its parts."""
    t = node_terms(system)
    nl, case, cases = node_limits(system, t)
    el = element_limits(system)
    n_at = int(np.argmin(nl)) if len(nl) else 0
    e_at = int(np.argmin(el)) if len(el) else 0
    node_bound = float(nl[n_at]) if len(nl) else math.inf
    element_bound = float(el[e_at]) if len(el) else math.inf
    kinds = ["elements"] + ([str(t["contact"][n_at])] if cases[int(case[n_at])].startswith("contact") else [])
    if node_bound <= element_bound:
        dt_pred, limiting = node_bound, f"node {n_at} ({' + '.join(kinds)})"
    else:
        dt_pred, limiting = element_bound, f"element {e_at} (a state)"
    i = n_at
    name = cases[int(case[i])]
    contact_mode = name.startswith("contact")
    tm = t["touch" if contact_mode else "mesh"]
    kp0, cp0 = (t["kp"][i], t["cp"][i]) if contact_mode else (0.0, 0.0)
    parts = {
        "node": n_at, "mass": float(t["m"][i]), "case": name, "mode": "contact" if contact_mode else "mesh",
        "k_elements": float(tm["kp"][i] - kp0 + tm["k1"][i]), "c_elements": float(tm["cp"][i] - cp0 + tm["c1"][i]),
        "mesh_factor": float(t["phi"][i]), "element_scale": 1.0 if contact_mode else float(t["scale"][i]),
        "contact": str(t["contact"][i]) if contact_mode else None,
        "k_contact": float(kp0), "c_contact": float(cp0),
        "element": e_at,
    }
    if t["has_moving"][i]:
        g = int(np.argmin(np.abs(np.array(t["c2_values"]) - float(name.rsplit("= ", 1)[-1])))) if "c2 =" in name else 0
        parts["c2_elements"] = float(tm["c2"][g][i])
    if len(el) and np.isfinite(element_bound):
        parts.update(element_k1=float(_per_element(system, "k1")[e_at]), element_c1=float(_per_element(system, "c1")[e_at]),
                     element_c_min=float(_per_element(system, "c_min")[e_at]),
                     element_c_t_min=float(tangent_c_min(system)[e_at]))
    fr = t["friction"] > 0
    friction_dt = float(np.min(2.0 * t["m"][fr] / t["friction"][fr])) if fr.any() else math.inf
    clamped = voigt_limit(t["k_clamped"], t["c_clamped"], t["m"])
    clamped_dt = float(np.min(clamped[t["has_moving"]])) if t["has_moving"].any() else math.inf
    notes = []
    if clamped_dt < dt_pred:
        notes.append(f"an element whose a sits on a_max with adot pointing out acts as a Voigt element "
                     f"(k1 a, c1 a): stable only below {clamped_dt:.3g} s while it stays clamped; the clamp "
                     f"releases on the next reversal, so this bounds chatter, not divergence")
    if fr.any():
        notes.append(f"friction regularisation k_f acts as a damper, stable below {friction_dt:.3g} s (2 m / k_f); "
                     f"its force is capped at mu N, so above that it chatters (slip speed ~ mu N dt / m) "
                     f"instead of diverging; not part of dt_pred")
    return {"dt_pred": dt_pred, "limiting": limiting, "node_bound": node_bound, "element_bound": element_bound,
            "dt": float(system.dt), "margin": dt_pred / float(system.dt), "parts": parts,
            "friction_dt": friction_dt, "clamped_dt": clamped_dt, "notes": notes}
