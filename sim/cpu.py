"""The compiled CPU backend: the golden model's physics (MODEL.md v2) as Numba loops, float64.

This is the yardstick every speed claim is measured against, and a fast fallback (`--backend cpu`). It
mirrors `golden/` term for term, one function per golden function:

    golden/elements.py  solve_convex, phi / psi, element_forces   ->  _newton / _solve, _phi / _psi, _tension
    golden/topology.py  topology_forces, facet_frame, foot_weights ->  _topology, _normal, _foot
    golden/contact.py   Floor.forces, Collision.candidates/forces  ->  _floor, _collisions, _contact
    golden/model.py     Golden.forces, Golden.step                 ->  _forces, _run

and is tested against golden (`tests/test_cpu.py`): after 100 steps of every built-in scene and of random
scenes, positions agree to 1e-12 of the object size and a to 1e-12 (in practice to the last bits: only
the order of floating-point sums differs, and the vectorised exp below).

The element pass is golden's, in passes that LLVM vectorises: edge vectors, l^2 and d . (v_j - v_i);
Phi's linear pieces for every element, which flag the elements that need more; the flagged ones on a
stop go through `_tension` (scalar, exactly golden's branches), the others (a drive on the damper's
exponential piece) are compacted into a list and solved by Newton sweeps over it, with a branch-free
exp (`_exp`, within an ulp) so that the sweeps vectorise too; then the scatter to the nodes. State is
stored component-major (D, N) as in golden's State. Contact terms loop over pairs with scratch vectors.

`advance(state, n)` runs n steps in one compiled call (no Python per step). With `threads` > 1 the
element passes run in parallel (`prange`; each thread scatters its share of the elements into its own
copy of the forces); `threads=None` chooses by size (`PARALLEL_MIN_ELEMENTS`, measured with
`rheo bench --backend cpu`). The first use compiles (about a minute); `cache=True` keeps the machine
code beside this file for later runs.
"""
from __future__ import annotations

import types
from collections import namedtuple

import numpy as np

try:
    import numba
    from numba import njit, prange
except ImportError as exc:          # numba is a dependency in pyproject.toml; say how to get it
    raise ImportError("the cpu backend needs Numba: pip install -e . (or pip install numba)") from exc

from golden.system import State, System, component_major
from golden.model import Stepper

def _jit(**flags):
    """njit, cached; numpy's error model (x / 0 gives inf, no exception check blocking vectorisation)."""
    return njit(cache=True, error_model="numpy", **flags)


SOLVE_RTOL, SOLVE_ATOL, SOLVE_MAX_ITER = 1e-12, 1e-300, 100   # golden/elements.py's
# Below this many elements one thread is as fast as two or faster on this 2-core machine (rheo bench --backend
# cpu: 1e4 elements 14,100 against 13,200 steps/s, 1e5 elements 1,590 against 1,930)
PARALLEL_MIN_ELEMENTS = 30_000
PARALLEL_MIN_SOLVES = 4096      # fewer solves than this: one thread (a parallel sweep costs its start-up)

# Inside loops, arrays are locals: a namedtuple's array costs a reference count on every access.
PARAMS = ("k1", "c1", "a_min", "a_max", "L", "c_min", "c_max", "B", "f1", "f2")
# Y1, Y2: Phi's knees; G_lo, G_hi: G at f1 and f2 (the chord the solve starts from); fast_exp: every damper's
# exponent B (t - f1) stays below EXP_MAX, so the vectorised solve applies.
Elements = namedtuple("Elements", "i j " + " ".join(PARAMS) + " Y1 Y2 G_lo G_hi nonlinear fixed_a fast_exp")
Work = namedtuple("Work", "d l2 dd Y Tl adot flag solve Fpart")     # per-element scratch of the element pass
Solve = namedtuple("Solve", "elem y c1 B f1 f2 c_max G_lo G_hi t")   # the compacted list of `_newton`
Topo = namedtuple("Topo", "on pairs K C eps")
FloorP = namedtuple("FloorP", "on height K C mu k_f")
Coll = namedtuple("Coll", "on vertices facets neighbour_keys n_nodes K C threshold mu k_f")
Loads = namedtuple("Loads", "ptr nodes force start end")
Nodes = namedtuple("Nodes", "inv_m_dt free g_dt dt")


# ---------------------------------------------------------------- the element (golden/elements.py)

@_jit(inline="always")
def _h(t, B, f1, cmax):
    """H(t) = t / c2(t) on [f1, f2], and its derivative."""
    ex = np.exp(B * (t - f1))
    return t * ex / cmax, ex * (1.0 + B * t) / cmax


@_jit()
def _solve(y, lo, hi, with_t, c, B, f1, cmax):
    """solve_convex for F(t) = with_t t + c H(t) (Phi: with_t = 1, c = c1; Psi: 0, 1)."""
    Flo = with_t * lo + c * _h(lo, B, f1, cmax)[0]
    Fhi = with_t * hi + c * _h(hi, B, f1, cmax)[0]
    width = Fhi - Flo if Fhi > Flo else 1.0
    t = min(max(lo + (y - Flo) * (hi - lo) / width, lo), hi)
    for _ in range(SOLVE_MAX_ITER):
        H, dH = _h(t, B, f1, cmax)
        r = (with_t * t + c * H) - y
        if not abs(r) > SOLVE_RTOL * abs(y) + SOLVE_ATOL:
            return t
        t = min(max(t - r / (with_t + c * dH), lo), hi)
    raise ArithmeticError("damper solve did not converge")


@_jit()
def _phi(Y, c1, cmin, cmax, B, f1, f2, nonlinear):
    """ElementParams.phi: T = Phi(Y) and w' for one element."""
    if not nonlinear:
        return Y * (cmin / (c1 + cmin)), Y / (c1 + cmin)
    mag = abs(Y)
    Y1, Y2 = f1 * (1.0 + c1 / cmax), f2 * (1.0 + c1 / cmin)
    c2 = cmax if mag < Y1 else cmin
    if Y1 <= mag < Y2:
        t = _solve(mag, f1, f2, 1.0, c1, B, f1, cmax)
        sign = 1.0 if Y > 0 else -1.0
        return sign * t, sign * _h(t, B, f1, cmax)[0]
    return Y * (c2 / (c1 + c2)), Y / (c1 + c2)


@_jit()
def _psi(W, cmin, cmax, B, f1, f2, nonlinear):
    """ElementParams.psi: the damper's force at the rate W."""
    if not nonlinear:
        return W * cmin
    mag = abs(W)
    if f1 / cmax <= mag < f2 / cmin:
        return (1.0 if W > 0 else -1.0) * _solve(mag, f1, f2, 0.0, 1.0, B, f1, cmax)
    return W * (cmax if mag < f1 / cmax else cmin)


@_jit()
def _tension(k1, c1, a_min, a_max, L, c_min, c_max, B, f1, f2, l, inv_l, ldot, a, nonlinear):
    """element_forces for one element: its tension T and the rate of a (0 on a stop)."""
    k1s = k1 * (a * l - L)
    T, wd = _phi(k1s + c1 * ldot, c1, c_min, c_max, B, f1, f2, nonlinear)
    W = (1.0 - a) * ldot
    adot = (W - wd) * inv_l
    at_lo, at_hi = a <= a_min, a >= a_max
    if at_hi and (adot > 0 or at_lo):
        return k1s + c1 * a * ldot, 0.0
    if at_lo and adot < 0 and not at_hi:
        return _psi(W, c_min, c_max, B, f1, f2, nonlinear), 0.0
    return T, adot


def _twins(fn):
    """fn compiled twice: serial (prange runs as range) and parallel (distinct names keep the caches apart)."""
    par = types.FunctionType(fn.__code__, fn.__globals__, fn.__name__ + "_parallel", fn.__defaults__,
                             fn.__closure__)
    par.__qualname__ = fn.__qualname__ + "_parallel"
    return _jit(inline="always")(fn), _jit(parallel=True)(par)


# The element pass mirrors golden's element_forces: one pass per axis for d, l^2 and d . (v_j - v_i); one
# branch-free pass with Phi's linear pieces (or the rigid damper), which flags the elements that need
# more (a drive on the exponential piece: the solve; an a on a bound: the stops); `_tension` on those.
# Each parameter is its own 1D array: LLVM vectorises these loops only so.

def _edges(xt, vt, ii, jj, d, l2, dd):
    """xt, vt: component-major (D, N)."""
    if xt.shape[0] == 2:                  # the common case in one pass (each node's words loaded once)
        x0, x1, v0, v1, d0, d1 = xt[0], xt[1], vt[0], vt[1], d[0], d[1]
        for e in prange(len(ii)):
            i, j = ii[e], jj[e]
            dx, dy = x0[j] - x0[i], x1[j] - x1[i]
            d0[e], d1[e] = dx, dy
            l2[e] = dx * dx + dy * dy
            dd[e] = dx * (v0[j] - v0[i]) + dy * (v1[j] - v1[i])
        return
    for e in prange(len(ii)):
        l2[e] = 0.0
        dd[e] = 0.0
    for k in range(xt.shape[0]):
        xk, vk, dk_ = xt[k], vt[k], d[k]
        for e in prange(len(ii)):
            i, j = ii[e], jj[e]
            dk = xk[j] - xk[i]
            dk_[e] = dk
            l2[e] += dk * dk
            dd[e] += dk * (vk[j] - vk[i])


def _rigid_damper(a, l2, dd, k1, c1, L, Tl, adot):
    """a_min = a_max everywhere (no a state): T = k1 s + c1 a ldot."""
    for e in prange(len(a)):
        l = np.sqrt(l2[e])
        inv_l = 1.0 / l
        ae = a[e]
        Tl[e] = (k1[e] * (ae * l - L[e]) + c1[e] * ae * (dd[e] * inv_l)) * inv_l
        adot[e] = 0.0


def _linear_piece(a, l2, dd, k1, c1v, L, c_min, c_max, Y1, Y2, a_min, a_max, Yv, Tl, adot, flag):
    """Phi's linear pieces for every element (a constant damper: c_min = c_max, knees at infinity)."""
    for e in prange(len(a)):
        l = np.sqrt(l2[e])
        inv_l = 1.0 / l
        ldot = dd[e] * inv_l
        ae = a[e]
        c1 = c1v[e]
        Y = k1[e] * (ae * l - L[e]) + c1 * ldot
        Yv[e] = Y
        mag = abs(Y)
        c2 = c_max[e] if mag < Y1[e] else c_min[e]
        Tl[e] = Y * (c2 / (c1 + c2)) * inv_l
        adot[e] = ((1.0 - ae) * ldot - Y / (c1 + c2)) * inv_l
        flag[e] = ((Y1[e] <= mag) & (mag < Y2[e])) | (ae <= a_min[e]) | (ae >= a_max[e])


def _finish(a, el, wk):
    """The flagged elements: `_tension` on those on a stop; the rest are on the exponential piece and get
    the solve, vectorised over their compacted list (`_newton`). Returns how many were solved so."""
    k1, c1, a_min, a_max, L, c_min, c_max, B, f1, f2 = (el.k1, el.c1, el.a_min, el.a_max, el.L, el.c_min,
                                                        el.c_max, el.B, el.f1, el.f2)
    l2, dd, Y, Tl, adot, flag = wk.l2, wk.dd, wk.Y, wk.Tl, wk.adot, wk.flag
    sv = wk.solve
    n = 0
    if not np.any(flag):
        return n
    for e in range(len(a)):
        if not flag[e]:
            continue
        l = np.sqrt(l2[e])
        inv_l = 1.0 / l
        if el.fast_exp and a_min[e] < a[e] < a_max[e]:
            sv.elem[n], sv.y[n], sv.c1[n], sv.B[n], sv.f1[n], sv.f2[n], sv.c_max[n] = (
                e, abs(Y[e]), c1[e], B[e], f1[e], f2[e], c_max[e])
            sv.G_lo[n], sv.G_hi[n] = el.G_lo[e], el.G_hi[e]
            n += 1
            continue
        T, adot[e] = _tension(k1[e], c1[e], a_min[e], a_max[e], L[e], c_min[e], c_max[e], B[e], f1[e], f2[e],
                              l, inv_l, dd[e] * inv_l, a[e], el.nonlinear)
        Tl[e] = T * inv_l
    return n


@_jit(inline="always")
def _exp(x):
    """e^x for 0 <= x <= EXP_MAX to about an ulp, branch-free so that loops over it vectorise (a call to
    np.exp does not): Cody-Waite reduction by ln 2, a degree-13 Taylor polynomial, 2^k by an integer shift."""
    k = np.floor(x * 1.4426950408889634 + 0.5)
    r = (x - k * 6.93147180369123816490e-01) - k * 1.90821492927058770002e-10
    p = 1.0 / 6227020800.0
    for c in (1.0 / 479001600.0, 1.0 / 39916800.0, 1.0 / 3628800.0, 1.0 / 362880.0, 1.0 / 40320.0,
              1.0 / 5040.0, 1.0 / 720.0, 1.0 / 120.0, 1.0 / 24.0, 1.0 / 6.0, 0.5, 1.0, 1.0):
        p = p * r + c
    return p * float(np.int64(1) << np.int64(k))


EXP_MAX = 42.0      # 2^k by a shift of an int64: k <= 61


def _newton(n, y, c1, B, f1, f2, c_max, G_lo, G_hi, t):
    """golden's solve_convex for Phi (G(t) = t + c1 t e^(B (t - f1)) / c_max = y) on the n listed elements:
    the chord's root, then Newton sweeps until every residual meets the tolerance."""
    for q in prange(n):
        width = G_hi[q] - G_lo[q] if G_hi[q] > G_lo[q] else 1.0
        t[q] = min(max(f1[q] + (y[q] - G_lo[q]) * (f2[q] - f1[q]) / width, f1[q]), f2[q])
    for _ in range(SOLVE_MAX_ITER):
        still = 0
        for q in prange(n):
            tq = t[q]
            ex = _exp(B[q] * (tq - f1[q]))
            r = (tq + c1[q] * (tq * ex / c_max[q])) - y[q]
            go = abs(r) > SOLVE_RTOL * abs(y[q]) + SOLVE_ATOL
            tn = min(max(tq - r / (1.0 + c1[q] * (ex * (1.0 + B[q] * tq) / c_max[q])), f1[q]), f2[q])
            t[q] = tn if go else tq
            still += go
        if still == 0:
            return
    raise ArithmeticError("damper solve did not converge")


@_jit(inline="always")
def _solved(n, a, wk):
    """T/l and adot of the n solved elements from their T magnitude t."""
    sv, l2, dd, Y, Tl, adot = wk.solve, wk.l2, wk.dd, wk.Y, wk.Tl, wk.adot
    for q in range(n):
        e, t = sv.elem[q], sv.t[q]
        sign = 1.0 if Y[e] > 0 else -1.0
        inv_l = 1.0 / np.sqrt(l2[e])
        Tl[e] = sign * t * inv_l
        wd = sign * (t * _exp(sv.B[q] * (t - sv.f1[q])) / sv.c_max[q])
        adot[e] = ((1.0 - a[e]) * (dd[e] * inv_l) - wd) * inv_l


_edges_serial, _edges_parallel = _twins(_edges)
_rigid_damper_serial, _rigid_damper_parallel = _twins(_rigid_damper)
_linear_piece_serial, _linear_piece_parallel = _twins(_linear_piece)
_newton_serial, _newton_parallel = _twins(_newton)
_finish = _jit(inline="always")(_finish)


@_jit(inline="always")
def _scatter(ii, jj, wk, Ft):
    """Golden's scatter: +T/l d to start nodes, -T/l d to end nodes (Ft component-major)."""
    d, Tl = wk.d, wk.Tl
    for k in range(Ft.shape[0]):
        Fk, dk = Ft[k], d[k]
        for e in range(len(ii)):
            f = Tl[e] * dk[e]
            Fk[ii[e]] += f
            Fk[jj[e]] -= f


@_jit(parallel=True)
def _scatter_parallel(ii, jj, wk, Ft, Fpart):
    """The same sums, each thread scattering a contiguous share of the elements into its own copy of the
    forces (Fpart, (threads, D, N)), then the copies added node by node."""
    d, Tl = wk.d, wk.Tl
    parts, E = Fpart.shape[0], len(ii)
    for w in prange(parts):
        Fw = Fpart[w]
        Fw[:] = 0.0
        for k in range(Ft.shape[0]):
            Fk, dk = Fw[k], d[k]
            for e in range(w * E // parts, (w + 1) * E // parts):
                f = Tl[e] * dk[e]
                Fk[ii[e]] += f
                Fk[jj[e]] -= f
    for p in prange(Ft.shape[1]):
        for k in range(Ft.shape[0]):
            acc = Ft[k, p]
            for w in range(parts):
                acc += Fpart[w, k, p]
            Ft[k, p] = acc


# ---------------------------------------------------------------- facets (golden/topology.py)
# Per-pair helpers write into scratch vectors (no temporary arrays: an allocation per pair costs more
# than the pair) and are inlined.

@_jit(inline="always")
def _diff(x, a, b, out):
    """out = x[a] - x[b]."""
    for k in range(x.shape[1]):
        out[k] = x[a, k] - x[b, k]


@_jit(inline="always")
def _dot(u, w):
    s = 0.0
    for k in range(len(u)):
        s += u[k] * w[k]
    return s


@_jit(inline="always")
def _normal(x, fn, e1, e2, out):
    """facet_frame: the unit normal of the facet with nodes fn into out (D,); e1, e2 scratch."""
    _diff(x, fn[1], fn[0], e1)
    if x.shape[1] == 2:
        out[0], out[1] = -e1[1], e1[0]
    else:
        _diff(x, fn[2], fn[0], e2)
        out[0] = e1[1] * e2[2] - e1[2] * e2[1]
        out[1] = e1[2] * e2[0] - e1[0] * e2[2]
        out[2] = e1[0] * e2[1] - e1[1] * e2[0]
    norm = np.sqrt(_dot(out, out))
    for k in range(len(out)):
        out[k] /= norm


@_jit(inline="always")
def _foot(x, p, fn, e1, e2, r, w):
    """foot_weights: barycentric weights of the foot of node p on the facet fn into w (D,), unclipped."""
    _diff(x, fn[1], fn[0], e1)
    _diff(x, p, fn[0], r)
    if x.shape[1] == 2:
        t = _dot(r, e1) / _dot(e1, e1)
        w[0], w[1] = 1.0 - t, t
        return
    _diff(x, fn[2], fn[0], e2)
    d11, d12, d22 = _dot(e1, e1), _dot(e1, e2), _dot(e2, e2)
    r1, r2 = _dot(r, e1), _dot(r, e2)
    den = d11 * d22 - d12 * d12
    w1 = (d22 * r1 - d12 * r2) / den
    w2 = (d11 * r2 - d12 * r1) / den
    w[0], w[1], w[2] = 1.0 - w1 - w2, w1, w2


@_jit(inline="always")
def _pair_force(out, p, fn, w, f):
    """apply_pair_forces: node p gets f (D,), the facet's nodes get -w f."""
    for k in range(out.shape[1]):
        out[p, k] += f[k]
        for m in range(len(fn)):
            out[fn[m], k] += -w[m] * f[k]


@_jit(inline="always")
def _relative_velocity(v, p, fn, w, out):
    for k in range(v.shape[1]):
        s = 0.0
        for m in range(len(fn)):
            s += w[m] * v[fn[m], k]
        out[k] = v[p, k] - s


@_jit(inline="always")
def _topology(x, v, tp, out):
    D = x.shape[1]
    _, pairs, K, C, eps = tp
    sc = np.empty((7, D))
    n, w, vrel, f, e1, e2, r = sc[0], sc[1], sc[2], sc[3], sc[4], sc[5], sc[6]
    fn = np.empty(D, pairs.dtype)
    for q in range(len(pairs)):
        p = pairs[q, 0]
        for m in range(D):
            fn[m] = pairs[q, m + 1]
        _normal(x, fn, e1, e2, n)
        _diff(x, p, fn[0], r)
        d = _dot(r, n)
        if not d <= eps:
            continue
        _foot(x, p, fn, e1, e2, r, w)
        rest = 0.0                          # clip_weights
        for m in range(1, D):
            w[m] = min(max(w[m], 0.0), 1.0)
            rest += w[m]
        w[0] = 1.0 - rest
        _relative_velocity(v, p, fn, w, vrel)
        mag = -K * (d - eps) - C * _dot(vrel, n)
        for k in range(D):
            f[k] = mag * n[k]
        _pair_force(out, p, fn, w, f)


# ---------------------------------------------------------------- contact (golden/contact.py)

@_jit(inline="always")
def _friction(vt, N, mu, k_f, f):
    """friction: add the regularised Coulomb force for the slip velocity vt (D,) to f."""
    speed = np.sqrt(_dot(vt, vt))
    gain = min(mu * N / max(speed, 1e-300), k_f)
    for k in range(len(vt)):
        f[k] += -gain * vt[k]


@_jit(inline="always")
def _floor(x, v, fl, out):
    D = x.shape[1]
    axis = D - 1
    vt, f = np.empty(D), np.empty(D)
    for p in range(x.shape[0]):
        d = x[p, axis] - fl.height
        if not d < 0.0:
            continue
        N = max(0.0, -fl.K * d - fl.C * v[p, axis])
        out[p, axis] += N
        if fl.mu > 0.0:
            for k in range(D):
                vt[k] = v[p, k]
                f[k] = 0.0
            vt[axis] = 0.0
            _friction(vt, N, fl.mu, fl.k_f, f)
            for k in range(D):
                out[p, k] += f[k]


@_jit(inline="always")
def _search(sorted_keys, key, right):
    """np.searchsorted(sorted_keys, key, 'right' if right else 'left')."""
    lo, hi = 0, len(sorted_keys)
    while lo < hi:
        mid = (lo + hi) // 2
        if sorted_keys[mid] < key or (right and sorted_keys[mid] == key):
            lo = mid + 1
        else:
            hi = mid
    return lo


@_jit(inline="always")
def _excluded(nk, n_nodes, p, fn):
    """Collision._excluded: p is a vertex of the facet or joined to one of them by an element (nk: the
    sorted keys a * n_nodes + b of joined pairs)."""
    for m in range(len(fn)):
        if fn[m] == p:
            return True
    for m in range(len(fn)):
        key = p * n_nodes + fn[m]
        pos = min(_search(nk, key, False), len(nk) - 1)
        if nk[pos] == key:
            return True
    return False


@_jit(inline="always")
def _contact(x, v, K, C, threshold, mu, k_f, p, fn, out, n, w, vrel, f, e1, e2, r):
    """The narrow phase of Collision.forces for the candidate (vertex p, facet fn); n .. r: scratch (D,)."""
    D = x.shape[1]
    _normal(x, fn, e1, e2, n)
    if D == 2:                              # outward normal
        n[0], n[1] = -n[0], -n[1]
    _diff(x, p, fn[0], r)
    d = _dot(r, n)
    if not abs(d) <= threshold:
        return
    _foot(x, p, fn, e1, e2, r, w)
    for m in range(D):
        if not w[m] >= 0.0:
            return
    _relative_velocity(v, p, fn, w, vrel)
    vn = _dot(vrel, n)
    N = max(0.0, K * (threshold - d) - C * vn)
    for k in range(D):
        f[k] = N * n[k]
    if mu > 0.0:
        for k in range(D):
            e1[k] = vrel[k] - vn * n[k]
        _friction(e1, N, mu, k_f, f)
    _pair_force(out, p, fn, w, f)


@_jit()
def _cell_keys(cells, stride):
    keys = np.zeros(len(cells), np.int64)
    for q in range(len(cells)):
        for k in range(len(stride)):
            keys[q] += cells[q, k] * stride[k]
    return keys


@_jit()
def _collisions(x, v, cl, out):
    """Collision.forces: golden's grid broad phase, then the narrow phase on each candidate."""
    _, vertices, facets, nk, n_nodes, K, C, threshold, mu, k_f = cl
    S, D = facets.shape
    V = len(vertices)
    if S == 0 or V == 0:
        return
    centre = np.zeros((S, D))
    for s in range(S):
        for m in range(D):
            centre[s] += x[facets[s, m]]
        centre[s] /= D
    radius = 0.0
    for s in range(S):
        for m in range(D):
            radius = max(radius, np.sqrt(np.sum((x[facets[s, m]] - centre[s]) ** 2)))
    h = radius + threshold
    lo = np.empty(D)
    for k in range(D):
        lo[k] = min(np.min(x[vertices, k]), np.min(centre[:, k])) - h
    cv = np.floor((x[vertices] - lo) / h).astype(np.int64)
    cc = np.floor((centre - lo) / h).astype(np.int64)
    stride = np.ones(D, np.int64)
    for k in range(1, D):
        stride[k] = stride[k - 1] * (max(np.max(cv[:, k - 1]), np.max(cc[:, k - 1])) + 2)
    kv = _cell_keys(cv, stride)
    order = np.argsort(kv, kind="mergesort")
    kv = kv[order]
    base = _cell_keys(cc, stride)
    sc = np.empty((7, D))
    n, w, vrel, f, e1, e2, r = sc[0], sc[1], sc[2], sc[3], sc[4], sc[5], sc[6]
    fn = np.empty(D, facets.dtype)
    for s in range(S):
        for m in range(D):
            fn[m] = facets[s, m]
        for o in range(3 ** D):
            key, rest = base[s], o
            for k in range(D):
                key += (rest % 3 - 1) * stride[k]
                rest //= 3
            for q in range(_search(kv, key, False), _search(kv, key, True)):
                p = vertices[order[q]]
                if not _excluded(nk, n_nodes, p, fn):
                    _contact(x, v, K, C, threshold, mu, k_f, p, fn, out, n, w, vrel, f, e1, e2, r)


# ---------------------------------------------------------------- the step (golden/model.py)

@_jit(inline="always")
def _elements_serial(x, v, a, el, wk):
    """Every element's T/l and adot into wk (the passes above)."""
    _edges_serial(x, v, el.i, el.j, wk.d, wk.l2, wk.dd)
    if el.fixed_a:
        _rigid_damper_serial(a, wk.l2, wk.dd, el.k1, el.c1, el.L, wk.Tl, wk.adot)
        return
    _linear_piece_serial(a, wk.l2, wk.dd, el.k1, el.c1, el.L, el.c_min, el.c_max, el.Y1, el.Y2, el.a_min,
                         el.a_max, wk.Y, wk.Tl, wk.adot, wk.flag)
    n = _finish(a, el, wk)
    if n:
        sv = wk.solve
        _newton_serial(n, sv.y, sv.c1, sv.B, sv.f1, sv.f2, sv.c_max, sv.G_lo, sv.G_hi, sv.t)
        _solved(n, a, wk)


@_jit(inline="always")
def _elements_parallel(x, v, a, el, wk):
    """The same passes, each loop shared between the threads."""
    _edges_parallel(x, v, el.i, el.j, wk.d, wk.l2, wk.dd)
    if el.fixed_a:
        _rigid_damper_parallel(a, wk.l2, wk.dd, el.k1, el.c1, el.L, wk.Tl, wk.adot)
        return
    _linear_piece_parallel(a, wk.l2, wk.dd, el.k1, el.c1, el.L, el.c_min, el.c_max, el.Y1, el.Y2, el.a_min,
                           el.a_max, wk.Y, wk.Tl, wk.adot, wk.flag)
    n = _finish(a, el, wk)
    if n:
        sv = wk.solve
        if n >= PARALLEL_MIN_SOLVES:
            _newton_parallel(n, sv.y, sv.c1, sv.B, sv.f1, sv.f2, sv.c_max, sv.G_lo, sv.G_hi, sv.t)
        else:
            _newton_serial(n, sv.y, sv.c1, sv.B, sv.f1, sv.f2, sv.c_max, sv.G_lo, sv.G_hi, sv.t)
        _solved(n, a, wk)


@_jit(inline="always")
def _forces(xt, vt, a, t, el, tp, fl, cl, ld, parallel, Ft, wk):
    """Golden.forces: the total force into Ft; positions, velocities and forces are component-major (D, N)
    (golden's State layout), seen as (N, D) by the contact terms."""
    Ft[:] = 0.0
    if parallel:
        _elements_parallel(xt, vt, a, el, wk)
        _scatter_parallel(el.i, el.j, wk, Ft, wk.Fpart)
    else:
        _elements_serial(xt, vt, a, el, wk)
        _scatter(el.i, el.j, wk, Ft)
    x, v, F = xt.T, vt.T, Ft.T
    if tp.on:
        _topology(x, v, tp, F)
    if fl.on:
        _floor(x, v, fl, F)
    if cl.on:
        _collisions(x, v, cl, F)
    ptr, nodes, force, start, end = ld
    for q in range(len(start)):
        if start[q] <= t < end[q]:
            for r in range(ptr[q], ptr[q + 1]):
                for k in range(len(force[q])):
                    F[nodes[r], k] += force[q, k]


@_jit()
def _run(n_steps, step, xt, vt, a, el, tp, fl, cl, ld, nd, parallel, Ft, wk):
    """n_steps symplectic Euler steps from step number `step`, in place (xt, vt component-major)."""
    inv_m_dt, free, g_dt, dt = nd
    a_min, a_max, adot = el.a_min, el.a_max, wk.adot
    for s in range(step, step + n_steps):
        _forces(xt, vt, a, s * dt, el, tp, fl, cl, ld, parallel, Ft, wk)
        for k in range(xt.shape[0]):
            xk, vk, Fk, g = xt[k], vt[k], Ft[k], g_dt[k]
            for p in range(len(xk)):
                u = (vk[p] + Fk[p] * inv_m_dt[p] + g) * free[p]
                vk[p] = u
                xk[p] += u * dt
        if not el.fixed_a:
            for e in range(len(a)):
                a[e] = min(max(a[e] + adot[e] * dt, a_min[e]), a_max[e])


# ---------------------------------------------------------------- the stepper

def _per_element(value, E: int) -> np.ndarray:
    return np.ascontiguousarray(np.broadcast_to(np.asarray(value, float), (E,)))


class Cpu(Stepper):
    """Steps a System in float64 with compiled loops (a golden.model.Stepper, as golden.model.Golden)."""

    def __init__(self, system: System, threads: int | None = None):
        self.system = system
        E, N, D = system.n_elements, system.n_nodes, system.dim
        if threads is None:
            threads = 2 if E >= PARALLEL_MIN_ELEMENTS else 1
        self.threads = max(1, min(int(threads), numba.config.NUMBA_NUM_THREADS))
        p = system.elem
        # unsigned indices: no negative-index wraparound in the gathers
        i, j = (np.ascontiguousarray(system.edges[:, c], np.uint32 if N < 2 ** 32 else np.uint64) for c in (0, 1))
        cols = {f: _per_element(getattr(p, f), E) for f in PARAMS}
        c1, cmin, cmax = cols["c1"], cols["c_min"], cols["c_max"]
        B, f1, f2 = cols["B"], cols["f1"], cols["f2"]
        knees = f1 * (1.0 + c1 / cmax), f2 * (1.0 + c1 / cmin)     # Phi's Y1, Y2, as golden's
        with np.errstate(invalid="ignore", over="ignore"):          # constant dampers: knees at infinity
            chord = (f1 + c1 * (f1 * np.exp(B * (f1 - f1)) / cmax), f2 + c1 * (f2 * np.exp(B * (f2 - f1)) / cmax))
            exponent = np.where(np.isfinite(f2), B * (f2 - f1), 0.0)
        self.el = Elements(i, j, *cols.values(), *knees, *chord, bool(p.nonlinear), bool(p.fixed_a),
                           bool(np.all(exponent <= EXP_MAX)))
        no_pairs = np.zeros((0, D + 1), np.int64)
        tp = system.topology
        self.tp = (Topo(True, np.ascontiguousarray(tp.pairs, np.int64), float(tp.K), float(tp.C), float(tp.eps))
                   if tp is not None and len(tp.pairs) else Topo(False, no_pairs, 0.0, 0.0, 0.0))
        fl = system.floor
        self.fl = (FloorP(True, float(fl.height), float(fl.K), float(fl.C), float(fl.mu), float(fl.k_f))
                   if fl is not None else FloorP(False, 0.0, 0.0, 0.0, 0.0, 0.0))
        cl = system.collision
        self.cl = (Coll(True, np.ascontiguousarray(cl.vertices, np.int64), np.ascontiguousarray(cl.facets, np.int64),
                        np.ascontiguousarray(cl.neighbour_keys, np.int64), int(cl.n_nodes), float(cl.K), float(cl.C),
                        float(cl.threshold), float(cl.mu), float(cl.k_f))
                   if cl is not None else Coll(False, np.zeros(0, np.int64), np.zeros((0, D), np.int64),
                                               np.zeros(1, np.int64), N, 0.0, 0.0, 0.0, 0.0, 0.0))
        nodes = [np.unique(np.asarray(l.nodes, np.int64)) for l in system.loads]    # F[nodes] += f: once a node
        self.ld = Loads(np.concatenate([[0], np.cumsum([len(s) for s in nodes])]).astype(np.int64),
                        np.concatenate(nodes + [np.zeros(0, np.int64)]),
                        np.array([np.asarray(l.force, float) for l in system.loads]).reshape(len(system.loads), D),
                        np.array([float(l.start) for l in system.loads]), np.array([float(l.end) for l in system.loads]))
        self.nd = Nodes(np.where(system.pinned, 0.0, system.dt / system.mass), (~system.pinned).astype(float),
                        np.asarray(system.gravity, float) * system.dt, float(system.dt))
        self._Ft = np.zeros((D, N))
        self._wk = Work(np.zeros((D, E)), *(np.zeros(E) for _ in range(5)), np.zeros(E, np.bool_),
                        Solve(np.zeros(E, np.int64), *(np.zeros(E) for _ in range(9))),
                        np.zeros((self.threads if self.threads > 1 else 0, D, N)))

    def initial_state(self) -> State:
        return State.initial(self.system)

    def _layout(self, st: State):
        """st's x, v as the component-major (D, N) float64 buffers the loops index (golden's State layout)."""
        for name in ("x", "v"):
            arr = getattr(st, name)
            if not (arr.T.flags.c_contiguous and arr.dtype == np.float64):
                setattr(st, name, component_major(np.asarray(arr, np.float64)))
        if not (st.a.flags.c_contiguous and st.a.dtype == np.float64):
            st.a = np.ascontiguousarray(st.a, np.float64)
        return st.x.T, st.v.T

    def advance(self, st: State, n: int, progress=None) -> None:
        """n steps in one compiled call."""
        if n <= 0:
            return
        xt, vt = self._layout(st)
        numba.set_num_threads(self.threads)
        _run(int(n), int(st.step), xt, vt, st.a, self.el, self.tp, self.fl, self.cl, self.ld,
             self.nd, self.threads > 1, self._Ft, self._wk)
        st.step += int(n)
        if progress is not None:
            progress(int(n))

    def step(self, st: State) -> None:
        self.advance(st, 1)

    def forces(self, st: State, t: float):
        """Total force (N, D) and the elements' adot at time t (for tests and tools)."""
        xt, vt = self._layout(st)
        numba.set_num_threads(self.threads)
        _forces(xt, vt, st.a, float(t), self.el, self.tp, self.fl, self.cl, self.ld,
                self.threads > 1, self._Ft, self._wk)
        return self._Ft.T.copy(), self._wk.adot.copy()


class _FromState(Cpu):
    """The cpu backend started from a given state (the stability trials, golden/measure.py)."""

    def __init__(self, system: System, start: State, threads: int | None = None):
        super().__init__(system, threads)
        self._start = start

    def initial_state(self) -> State:
        return self._start.copy()


def stability_model(system: System, start: State) -> Cpu:
    """golden.measure.measure(..., model=stability_model): trials on the cpu backend."""
    return _FromState(system, start)


def simulate_cpu(system: System, steps=None, every=None, progress=False, threads=None):
    """golden.model.simulate with the compiled stepper."""
    from golden.model import simulate
    return simulate(system, steps=steps, every=every, progress=progress, stepper=Cpu(system, threads))
