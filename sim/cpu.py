"""The compiled CPU backend: the golden model's physics (MODEL.md v2) as Numba loops, float64.

This is the yardstick every speed claim is measured against, and a fast fallback (`--backend cpu`). It
mirrors `golden/` term for term, one function per golden function:

    golden/elements.py  solve_convex, phi / psi, element_forces   ->  _newton / _solve, _phi / _psi, _tension
    golden/topology.py  topology_forces, facet_frame, foot_weights ->  _topology, _normal, _foot
    golden/contact.py   Floor.forces, Collision.candidates/forces  ->  _floor, _collisions, _contact
    golden/probe.py     Probe.forces, design_sample, design_offset ->  _probe, _design_sample, _design_offset
    golden/model.py     Golden.forces, Golden.step                 ->  _elements, _scatter, _extras, _integrate

and is tested against golden (`tests/test_cpu.py`): after 100 steps of every built-in scene and of random
scenes, positions agree to 1e-12 of the object size and a to 1e-12 (in practice to the last bits: each
node's sum runs in golden's order; the vectorised exp below is within an ulp).

The element pass is golden's, in passes that LLVM vectorises: edge vectors, l^2 and d . (v_j - v_i);
Phi's linear pieces for every element, which flag the elements that need more; the flagged ones on a
stop go through `_tension` (scalar, exactly golden's branches), the others (a drive on the damper's
exponential piece) are compacted into a list and solved by Newton sweeps over it, with a branch-free
exp (`_exp`, within an ulp) so that the sweeps vectorise too. A material that is the same for every
element is passed as scalars (golden's ElementParams does the same), so these passes stream only the
state. Golden's scatter (a sparse product: each node's sum over its elements in element order) runs
over the elements in element order (`_scatter`), so the sums are golden's to the bit.

The nodes are cut into chunks (ranges of node numbers, one per thread); each chunk holds its own copy of
every element that touches one of its nodes, so that one chunk is a whole step for its nodes: its elements
and their sums at its nodes (`_chunk`, in blocks whose scratch stays in the cache), then the integration
of its nodes. Elements across a cut are computed by both chunks (the same arithmetic on the same words:
the copies stay equal to the bit), and positions and velocities are double-buffered (a step reads one
buffer and writes the other), so chunks never wait for each other inside a step. `advance(state, n)` runs
n steps in one compiled call (`_worker`, no Python per step). With `threads` > 1 every thread runs the
worker inside one parallel region for the whole run: each step, a thread claims chunks (an atomic
compare-and-swap of the chunk's step number), its own first, then any left unclaimed (so a thread that
runs alone or late takes them all and nothing can deadlock), and starts the next step when every chunk of
this one is done (spinning, then yielding its core). Contact terms and loads need every node's sum first:
with them a step is three passes (chunks without integration, `_extras` once, the integration in chunks).
The haptic probe (MODEL.md 4b) is the last of the extras, as in golden: its held p and pdot, and the nodes it
touched in the last step with their forces, live in small arrays that `_call` copies from and back into the
state's ProbeState (whose `record` sums the force on the probe, golden's own code); a probe no host drives
follows the scene's design poke, moved at each sample's first step inside the compiled run.
`threads=None` chooses by size (`PARALLEL_MIN_ELEMENTS`, measured with `rheo bench --backend cpu`). The
first use compiles (a minute or two); `cache=True` keeps the machine code beside this file for later runs.
"""
from __future__ import annotations

from collections import namedtuple

import numpy as np

try:
    import numba
    from numba import njit, prange, types
    from numba.core import cgutils
    from numba.extending import intrinsic, overload
    from llvmlite import ir
except ImportError as exc:          # numba is a dependency in pyproject.toml; say how to get it
    raise ImportError("the cpu backend needs Numba: pip install -e . (or pip install numba)") from exc

from golden.model import Golden, Stepper
from golden.system import State, System, component_major

def _jit(**flags):
    """njit, cached; numpy's error model (x / 0 gives inf, no exception check blocking vectorisation)."""
    return njit(cache=True, error_model="numpy", **flags)


SOLVE_RTOL, SOLVE_ATOL, SOLVE_MAX_ITER = 1e-12, 1e-300, 100   # golden/elements.py's
# Below this many elements one thread (2-core machine): two pay on the 2D square from 1e3 elements but lose
# on the 3D press of 987 and tie on small scenes. Idle machine,
# `rheo bench --backend cpu --sizes 1000 3000 10000 100000 --json` (steps/s, 1 thread against 2): square
# 1e3 90,046 against 120,238, 3e3 46,373 / 67,473, 1e4 18,381 / 26,349, 1e5 1,546 / 3,494; `--scene`:
# press-2d-rheological (134 elements) 171,145 / 166,050, press-3d-plastic (987) 16,105 / 11,949. Two
# threads pay everywhere above; on a loaded machine (CI) a waiting thread costs more.
PARALLEL_MIN_ELEMENTS = 2_000
CHUNKS_PER_THREAD = 1       # node chunks per thread (2 per thread: 31.3, 40.4, 71.5, 197, 629 us above)
BLOCK = np.uint64(1024)     # elements per block of the element passes (their scratch stays in L1)

# Inside loops, arrays are locals: a namedtuple's array costs a reference count on every access.
PARAMS = ("k1", "c1", "a_min", "a_max", "c_min", "c_max", "B", "f1", "f2")
# Every parameter (PARAMS, and Y1, Y2: Phi's knees; S_max, S_min, R_max, R_min: its slopes, `_linear_piece`;
# G_lo, G_hi: G at f1 and f2, the chord the solve starts from) is a float when the material is uniform,
# else an array over the element copies; L always an array.
# fast_exp: every damper's exponent B (t - f1) stays below EXP_MAX, so the vectorised solve applies.
# i, j: each copy's nodes; ti, tj: where `_scatter` adds its terms (the same, or the chunk's sink N + 8 c
# for a node of another chunk)
Elements = namedtuple("Elements", "i j ti tj L " + " ".join(PARAMS)
                      + " Y1 Y2 S_max S_min R_max R_min G_lo G_hi nonlinear fixed_a fast_exp")
Work = namedtuple("Work", "d l2 dd Y Tl adot flag")      # per-element scratch of the element pass
Solve = namedtuple("Solve", "elem y c1 B f1 f2 c_max G_lo G_hi t")   # the compacted lists of `_newton`
# span (C + 1): chunk c's element copies (element order); nodes (C + 1): its nodes
Chunks = namedtuple("Chunks", "span nodes")
Topo = namedtuple("Topo", "on pairs K C eps")
FloorP = namedtuple("FloorP", "on height K C mu k_f")
Coll = namedtuple("Coll", "on vertices facets nbr_ptr nbr K C threshold mu k_f")
Loads = namedtuple("Loads", "ptr nodes force start end")
# the probe (golden/probe.py Probe; on: the scene has one) and its state (ProbeState's held p and pdot, and the
# nodes touching it in the last step with their forces: count[0] of them)
ProbeP = namedtuple("ProbeP", "on radius K C mu k_f k position down depth poke_time")
ProbeIO = namedtuple("ProbeIO", "p pdot nodes node_forces count")
Nodes = namedtuple("Nodes", "inv_m_dt free g_dt dt")
# the counters of a run (int64 words, each on its own cache line): chunks done, a solve that failed, then
# one claim word per chunk and pass (the number of the step whose chunk was last claimed)
DONE, FAILED, CLAIMS = 0, 8, 16


def _at(p, e):
    """p[e] for a per-element parameter, p for a uniform one (compiled: see the overload below)."""
    return p if np.ndim(p) == 0 else p[e]


@overload(_at)
def _at_compiled(p, e):
    if isinstance(p, types.Array):
        return lambda p, e: p[e]
    return lambda p, e: p


# ---------------------------------------------------------------- atomics (the claims)

@intrinsic
def _atomic_add(typingctx, arr, idx, val):
    """arr[idx] += val as one atomic operation (sequentially consistent); the old value."""
    def codegen(context, builder, sig, args):
        aryty = sig.args[0]
        ary = context.make_array(aryty)(context, builder, args[0])
        ptr = cgutils.get_item_pointer(context, builder, aryty, ary, [args[1]])
        return builder.atomic_rmw("add", ptr, context.cast(builder, args[2], sig.args[2], aryty.dtype), "seq_cst")
    return arr.dtype(arr, idx, val), codegen


@intrinsic
def _atomic_load(typingctx, arr, idx):
    """arr[idx], read as one atomic operation (sequentially consistent: what was written before is seen)."""
    def codegen(context, builder, sig, args):
        aryty = sig.args[0]
        ary = context.make_array(aryty)(context, builder, args[0])
        ptr = cgutils.get_item_pointer(context, builder, aryty, ary, [args[1]])
        return builder.load_atomic(ptr, "seq_cst", context.get_abi_sizeof(context.get_data_type(aryty.dtype)))
    return arr.dtype(arr, idx), codegen


@intrinsic
def _claim(typingctx, arr, idx, step):
    """arr[idx] from step to step + 1 as one atomic compare-and-swap: True for the one caller that did it."""
    def codegen(context, builder, sig, args):
        aryty = sig.args[0]
        ary = context.make_array(aryty)(context, builder, args[0])
        ptr = cgutils.get_item_pointer(context, builder, aryty, ary, [args[1]])
        old = context.cast(builder, args[2], sig.args[2], aryty.dtype)
        new = builder.add(old, old.type(1))
        return builder.extract_value(builder.cmpxchg(ptr, old, new, "seq_cst", "seq_cst"), 1)
    return types.boolean(arr, idx, step), codegen


@intrinsic
def _yield_cpu(typingctx):
    """sched_yield(): let another thread run (a waiting thread on a busy machine)."""
    def codegen(context, builder, sig, args):
        fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(ir.IntType(32), []), "sched_yield")
        builder.call(fn, [])
        return context.get_dummy_value()
    return types.none(), codegen


SPINS = 2000        # reads of the counter before a waiting thread starts yielding its core


@_jit(inline="always")
def _wait(sync, target, solo):
    """Until sync[DONE] >= target: `target` chunks of the run are done (a thread alone: nothing to wait for)."""
    if solo:
        return
    spins = 0
    while _atomic_load(sync, DONE) < target:
        spins += 1
        if spins > SPINS:
            _yield_cpu()


@_jit(inline="always")
def _take(sync, slot, step, solo):
    """Claim the chunk of `slot` for step `step` (a thread alone takes every chunk)."""
    return solo or _claim(sync, slot, step)


@_jit(inline="always")
def _done(sync, solo):
    """Count a chunk done."""
    if not solo:
        _atomic_add(sync, DONE, 1)


# ---------------------------------------------------------------- the element (golden/elements.py)

@_jit(inline="always")
def _h(t, B, f1, cmax):
    """H(t) = t / c2(t) on [f1, f2], and its derivative."""
    ex = np.exp(B * (t - f1))
    return t * ex / cmax, ex * (1.0 + B * t) / cmax


@_jit()
def _solve(y, lo, hi, with_t, c, B, f1, cmax):
    """solve_convex for F(t) = with_t t + c H(t) (Phi: with_t = 1, c = c1; Psi: 0, 1); NaN if it does not
    converge (a bug, not a physics case: golden raises; here the run reports it, see `_worker`)."""
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
    return np.nan


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


# The element pass mirrors golden's element_forces on the elements e0 <= e < e1 (one ticket; the bounds
# are unsigned, so that indexing needs no wraparound and the loops vectorise): one pass
# for d, l^2 and d . (v_j - v_i); one branch-free pass with Phi's linear pieces (or the rigid damper),
# which flags the elements that need more (a drive on the exponential piece: the solve; an a on a bound:
# the stops); `_tension` on those. A per-element parameter is its own 1D array: LLVM vectorises these
# loops only so; `_at` reads it (or the uniform material's scalar).

@_jit(inline="always")
def _edges(xt, vt, ii, jj, d, l2, dd, e0, e1):
    """xt, vt: component-major (D, N)."""
    if xt.shape[0] == 2:                  # the common case in one pass (each node's words loaded once)
        x0, x1, v0, v1, d0, d1 = xt[0], xt[1], vt[0], vt[1], d[0], d[1]
        for e in range(e0, e1):
            i, j = ii[e], jj[e]
            dx, dy = x0[j] - x0[i], x1[j] - x1[i]
            d0[e], d1[e] = dx, dy
            l2[e] = dx * dx + dy * dy
            dd[e] = dx * (v0[j] - v0[i]) + dy * (v1[j] - v1[i])
        return
    for e in range(e0, e1):
        l2[e] = 0.0
        dd[e] = 0.0
    for k in range(xt.shape[0]):
        xk, vk, dk_ = xt[k], vt[k], d[k]
        for e in range(e0, e1):
            i, j = ii[e], jj[e]
            dk = xk[j] - xk[i]
            dk_[e] = dk
            l2[e] += dk * dk
            dd[e] += dk * (vk[j] - vk[i])


@_jit(inline="always")
def _rigid_damper(a, l2, dd, k1, c1, L, Tl, adot, e0, e1):
    """a_min = a_max everywhere (no a state): T = k1 s + c1 a ldot."""
    for e in range(e0, e1):
        l = np.sqrt(l2[e])
        inv_l = 1.0 / l
        ae = a[e]
        Tl[e] = (_at(k1, e) * (ae * l - L[e]) + _at(c1, e) * ae * (dd[e] * inv_l)) * inv_l
        adot[e] = 0.0


@_jit(inline="always")
def _linear_piece(a, l2, dd, k1, c1, L, Y1, Y2, S_max, S_min, R_max, R_min, a_min, a_max, Yv, Tl, adot, flag,
                  e0, e1):
    """Phi's linear pieces for every element (a constant damper: c_min = c_max, knees at infinity): T = Y S
    and w' = Y / R with c2 = c_max below the knee Y1, c_min above, S = c2 / (c1 + c2) and R = c1 + c2 (the
    same words as golden's, made once: one division less per element)."""
    for e in range(e0, e1):
        l = np.sqrt(l2[e])
        inv_l = 1.0 / l
        ldot = dd[e] * inv_l
        ae = a[e]
        Y = _at(k1, e) * (ae * l - L[e]) + _at(c1, e) * ldot
        Yv[e] = Y
        mag = abs(Y)
        below = mag < _at(Y1, e)
        S = _at(S_max, e) if below else _at(S_min, e)
        R = _at(R_max, e) if below else _at(R_min, e)
        Tl[e] = Y * S * inv_l
        adot[e] = ((1.0 - ae) * ldot - Y / R) * inv_l
        flag[e] = (((_at(Y1, e) <= mag) & (mag < _at(Y2, e))) | (ae <= _at(a_min, e))
                   | (ae >= _at(a_max, e)))


@_jit(inline="always")
def _finish(a, el, wk, sv, e0, e1):
    """The flagged elements: `_tension` on those on a stop; the rest are on the exponential piece and get
    the solve, vectorised over their compacted list (`_newton`; from index e0 of sv). Returns how
    many were listed so, and whether every scalar solve converged."""
    k1, c1, a_min, a_max, L, c_min, c_max, B, f1, f2 = (el.k1, el.c1, el.a_min, el.a_max, el.L, el.c_min,
                                                        el.c_max, el.B, el.f1, el.f2)
    l2, dd, Y, Tl, adot, flag = wk.l2, wk.dd, wk.Y, wk.Tl, wk.adot, wk.flag
    q, ok = e0, True
    one, eight = np.uint64(1), np.uint64(8)
    words = flag.view(np.uint64)                    # eight flags a word: most words are 0
    for w in range(e0 // eight, (e1 + eight - one) // eight):
        if words[w] == 0:
            continue
        for e in range(max(w * eight, e0), min(w * eight + eight, e1)):
            if not flag[e]:
                continue
            l = np.sqrt(l2[e])
            inv_l = 1.0 / l
            if el.fast_exp and _at(a_min, e) < a[e] < _at(a_max, e):
                sv.elem[q], sv.y[q], sv.c1[q], sv.B[q], sv.f1[q], sv.f2[q], sv.c_max[q] = (
                    e, abs(Y[e]), _at(c1, e), _at(B, e), _at(f1, e), _at(f2, e), _at(c_max, e))
                sv.G_lo[q], sv.G_hi[q] = _at(el.G_lo, e), _at(el.G_hi, e)
                q += one
                continue
            T, adot[e] = _tension(_at(k1, e), _at(c1, e), _at(a_min, e), _at(a_max, e), L[e], _at(c_min, e),
                                  _at(c_max, e), _at(B, e), _at(f1, e), _at(f2, e), l, inv_l, dd[e] * inv_l, a[e],
                                  el.nonlinear)
            Tl[e] = T * inv_l
            ok &= not (np.isnan(T) and not np.isnan(Y[e]))     # a finite drive whose solve did not converge
    return q - e0, ok


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


@_jit(inline="always")
def _newton(q0, n, y, c1, B, f1, f2, c_max, G_lo, G_hi, t):
    """golden's solve_convex for Phi (G(t) = t + c1 t e^(B (t - f1)) / c_max = y) on the n listed elements
    from q0: the chord's root, then Newton sweeps until every residual meets the tolerance. False if that
    takes more than SOLVE_MAX_ITER sweeps (a bug, not a physics case)."""
    for q in range(q0, q0 + n):
        width = G_hi[q] - G_lo[q] if G_hi[q] > G_lo[q] else 1.0
        t[q] = min(max(f1[q] + (y[q] - G_lo[q]) * (f2[q] - f1[q]) / width, f1[q]), f2[q])
    for _ in range(SOLVE_MAX_ITER):
        still = 0
        for q in range(q0, q0 + n):
            tq = t[q]
            ex = _exp(B[q] * (tq - f1[q]))
            r = (tq + c1[q] * (tq * ex / c_max[q])) - y[q]
            go = abs(r) > SOLVE_RTOL * abs(y[q]) + SOLVE_ATOL
            tn = min(max(tq - r / (1.0 + c1[q] * (ex * (1.0 + B[q] * tq) / c_max[q])), f1[q]), f2[q])
            t[q] = tn if go else tq
            still += go
        if still == 0:
            return True
    return False


@_jit(inline="always")
def _solved(q0, n, a, wk, sv):
    """T/l and adot of the n solved elements listed from q0, from their T magnitude t."""
    l2, dd, Y, Tl, adot = wk.l2, wk.dd, wk.Y, wk.Tl, wk.adot
    for q in range(q0, q0 + n):
        e, t = sv.elem[q], sv.t[q]
        sign = 1.0 if Y[e] > 0 else -1.0
        inv_l = 1.0 / np.sqrt(l2[e])
        Tl[e] = sign * t * inv_l
        wd = sign * (t * _exp(sv.B[q] * (t - sv.f1[q])) / sv.c_max[q])
        adot[e] = ((1.0 - a[e]) * (dd[e] * inv_l) - wd) * inv_l


@_jit(inline="always")
def _elements(xt, vt, a, el, wk, sv, e0, e1, integrate, dt):
    """element_forces on the element copies e0 <= e < e1: their T/l, d and adot into wk; with `integrate`
    their a steps too (a <- clip(a + dt adot), golden's last line; nothing else reads a). False if a solve
    did not converge."""
    _edges(xt, vt, el.i, el.j, wk.d, wk.l2, wk.dd, e0, e1)
    if el.fixed_a:
        _rigid_damper(a, wk.l2, wk.dd, el.k1, el.c1, el.L, wk.Tl, wk.adot, e0, e1)
        return True
    _linear_piece(a, wk.l2, wk.dd, el.k1, el.c1, el.L, el.Y1, el.Y2, el.S_max, el.S_min, el.R_max, el.R_min,
                  el.a_min, el.a_max, wk.Y, wk.Tl, wk.adot, wk.flag, e0, e1)
    n, ok = _finish(a, el, wk, sv, e0, e1)
    if n:
        ok &= _newton(e0, n, sv.y, sv.c1, sv.B, sv.f1, sv.f2, sv.c_max, sv.G_lo, sv.G_hi, sv.t)
        _solved(e0, n, a, wk, sv)
    if integrate:
        a_min, a_max, adot = el.a_min, el.a_max, wk.adot
        for e in range(e0, e1):
            a[e] = min(max(a[e] + adot[e] * dt, _at(a_min, e)), _at(a_max, e))
    return ok


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
def _exclude(nbr_ptr, nbr, fn, s, mark):
    """Collision._excluded for the facet s with nodes fn: mark[p] = s for every p that is a vertex of the facet
    or joined to one of them by an element (nbr: each node's joined nodes from nbr_ptr[node], golden's
    neighbour_keys by rows; both orders are there)."""
    for m in range(len(fn)):
        mark[fn[m]] = s
        for q in range(nbr_ptr[fn[m]], nbr_ptr[fn[m] + 1]):
            mark[nbr[q]] = s


@_jit(inline="always")
def _outward(x, fn, e1, e2, n):
    """facet_frame's unit normal of the facet fn into n, outward (golden flips it in 2D)."""
    _normal(x, fn, e1, e2, n)
    if x.shape[1] == 2:
        n[0], n[1] = -n[0], -n[1]


@_jit(inline="always")
def _contact(x, v, K, C, threshold, mu, k_f, p, fn, out, n, w, vrel, f, e1, e2, r):
    """The narrow phase of Collision.forces for the candidate (vertex p, facet fn) with the facet's outward
    normal n (`_outward`); w .. r: scratch (D,)."""
    D = x.shape[1]
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
def _collisions(x, v, cl, out):
    """Collision.forces: golden's grid broad phase, then the narrow phase on each candidate (each facet,
    the 3^D cells around its centre, the vertices of each cell in key order). The vertices of a cell come
    from a table indexed by the key when the grid is small (a binary search otherwise); no temporary
    arrays but the grid's."""
    _, vertices, facets, nbr_ptr, nbr, K, C, threshold, mu, k_f = cl
    S, D = facets.shape
    V = len(vertices)
    if S == 0 or V == 0:
        return
    centre = np.zeros((S, D))
    for s in range(S):
        for m in range(D):
            for k in range(D):
                centre[s, k] += x[facets[s, m], k]
        for k in range(D):
            centre[s, k] /= D
    radius = 0.0
    for s in range(S):
        for m in range(D):
            r2 = 0.0
            for k in range(D):
                r2 += (x[facets[s, m], k] - centre[s, k]) ** 2
            radius = max(radius, np.sqrt(r2))
    h = radius + threshold
    lo = np.empty(D)
    for k in range(D):
        low = np.inf
        for q in range(V):
            low = min(low, x[vertices[q], k])
        for s in range(S):
            low = min(low, centre[s, k])
        lo[k] = low - h
    cv = np.empty((V, D), np.int64)
    cc = np.empty((S, D), np.int64)
    top = np.zeros(D, np.int64)
    for k in range(D):
        for q in range(V):
            cv[q, k] = np.int64(np.floor((x[vertices[q], k] - lo[k]) / h))
            top[k] = max(top[k], cv[q, k])
        for s in range(S):
            cc[s, k] = np.int64(np.floor((centre[s, k] - lo[k]) / h))
            top[k] = max(top[k], cc[s, k])
    stride = np.ones(D, np.int64)
    for k in range(1, D):
        stride[k] = stride[k - 1] * (top[k - 1] + 2)
    cells = stride[D - 1] * (top[D - 1] + 2)
    kv = np.zeros(V, np.int64)
    for q in range(V):
        for k in range(D):
            kv[q] += cv[q, k] * stride[k]
    order = np.argsort(kv, kind="mergesort")
    kv = kv[order]
    table = cells <= 8 * (V + S) + 4096             # a cell's vertices are order[start[key]:start[key + 1]]
    start = np.zeros(cells + 1 if table else 1, np.int64)
    if table:
        for q in range(V):
            start[kv[q] + 1] += 1
        for key in range(cells):
            start[key + 1] += start[key]
    sc = np.empty((7, D))
    n, w, vrel, f, e1, e2, r = sc[0], sc[1], sc[2], sc[3], sc[4], sc[5], sc[6]
    fn = np.empty(D, facets.dtype)
    mark = np.full(x.shape[0], -1, np.int64)
    for s in range(S):
        base = 0
        for k in range(D):
            fn[k] = facets[s, k]
            base += cc[s, k] * stride[k]
        _exclude(nbr_ptr, nbr, fn, s, mark)
        _outward(x, fn, e1, e2, n)
        for o in range(3 ** D):
            key, rest = base, o
            for k in range(D):
                key += (rest % 3 - 1) * stride[k]
                rest //= 3
            if table:
                if key < 0 or key >= cells:
                    continue
                first, last = start[key], start[key + 1]
            else:
                first, last = _search(kv, key, False), _search(kv, key, True)
            for q in range(first, last):
                p = vertices[order[q]]
                if mark[p] != s:
                    _contact(x, v, K, C, threshold, mu, k_f, p, fn, out, n, w, vrel, f, e1, e2, r)


# ---------------------------------------------------------------- the probe (golden/probe.py)

@_jit(inline="always")
def _design_offset(pb, t):
    """Probe.design_offset: the design poke's depth below the initial position at time t."""
    u = t / pb.poke_time
    return pb.depth * max(min(2.0 * u, 2.0 * (1.0 - u)), 0.0)


@_jit(inline="always")
def _design_sample(pb, ps, step, dt):
    """design_sample for a probe no host drives: at the first step of a device sample, hold the design poke's
    position (Probe.design_position) with pdot = (p - p_prev) / (k dt) (ProbeState.hold)."""
    if step % pb.k != 0:
        return
    off = _design_offset(pb, (step // pb.k) * pb.k * dt)
    for k in range(len(ps.p)):
        p = pb.position[k] + off * pb.down[k]
        ps.pdot[k] = (p - ps.p[k]) / (pb.k * dt)
        ps.p[k] = p


@_jit(inline="always")
def _probe(x, v, pb, ps, out):
    """Probe.forces: every node within the radius of p (the box first, then the distance, as golden) gets N n
    and the friction on its velocity relative to the probe, added to out (N, D); the nodes touching it and
    their forces, in node order, go to ps (`Cpu._call` hands them to ProbeState.record, which sums the force
    on the probe)."""
    D = x.shape[1]
    R, K, C, mu, k_f = pb.radius, pb.K, pb.C, pb.mu, pb.k_f
    P, Pdot, nodes, nf = ps.p, ps.pdot, ps.nodes, ps.node_forces
    sc = np.empty((4, D))
    r, n, vrel, f = sc[0], sc[1], sc[2], sc[3]
    m = 0
    for p in range(x.shape[0]):
        near = True
        for k in range(D):
            r[k] = x[p, k] - P[k]
            near &= abs(r[k]) < R
        if not near:
            continue
        d2 = _dot(r, r)
        if not d2 < R * R:
            continue
        d = np.sqrt(d2)
        for k in range(D):
            n[k] = r[k] / d
            vrel[k] = v[p, k] - Pdot[k]
        vn = _dot(vrel, n)
        N = max(0.0, K * (R - d) - C * vn)
        for k in range(D):
            f[k] = N * n[k]
        if mu > 0.0:
            for k in range(D):
                r[k] = vrel[k] - vn * n[k]          # the slip velocity
            _friction(r, N, mu, k_f, f)
        for k in range(D):
            out[p, k] += f[k]
            nf[m, k] = f[k]
        nodes[m] = p
        m += 1
    ps.count[0] = m


# ---------------------------------------------------------------- the step (golden/model.py)

@_jit(inline="always")
def _scatter(ti, tj, Tl, d, Ft, e0, e1):
    """Golden's scatter from the element copies e0 <= e < e1: +T/l d to the start node ti, -T/l d to the end
    node tj (a node of another chunk: the chunk's sink), in element order as golden's sparse product adds
    each node's terms. Consecutive elements of one start node add into a register (in the same order: none
    of them ends at that node)."""
    if Ft.shape[0] == 2:                  # the common case in one pass
        F0, F1, d0, d1 = Ft[0], Ft[1], d[0], d[1]
        cur = ti[e0]
        a0, a1 = F0[cur], F1[cur]
        for e in range(e0, e1):
            i, j = ti[e], tj[e]
            if i != cur:
                F0[cur], F1[cur] = a0, a1
                cur = i
                a0, a1 = F0[i], F1[i]
            t = Tl[e]
            f0, f1 = t * d0[e], t * d1[e]
            a0 += f0
            a1 += f1
            F0[j] -= f0
            F1[j] -= f1
        F0[cur], F1[cur] = a0, a1
        return
    for k in range(Ft.shape[0]):
        Fk, dk = Ft[k], d[k]
        cur = ti[e0]
        acc = Fk[cur]
        for e in range(e0, e1):
            i = ti[e]
            if i != cur:
                Fk[cur] = acc
                cur = i
                acc = Fk[i]
            f = Tl[e] * dk[e]
            acc += f
            Fk[tj[e]] -= f
        Fk[cur] = acc


@_jit(inline="always")
def _chunk(xr, vr, a, el, wk, sv, Ft, e0, e1, p0, p1, integrate, dt):
    """Golden.forces' element part for the nodes p0 <= p < p1 from their element copies e0 <= e < e1, in
    blocks of BLOCK (each block's scratch stays in the cache from one pass to the next): `_elements`, then
    `_scatter` into Ft (zero first). False if a solve did not converge."""
    for k in range(Ft.shape[0]):
        Fk = Ft[k]
        for p in range(p0, p1):
            Fk[p] = 0.0
    ok = True
    b0 = e0
    while b0 < e1:
        b1 = min(b0 + BLOCK, e1)
        ok &= _elements(xr, vr, a, el, wk, sv, b0, b1, integrate, dt)
        _scatter(el.ti, el.tj, wk.Tl, wk.d, Ft, b0, b1)
        b0 = b1
    return ok


@_jit(inline="always")
def _integrate(xr, vr, xw, vw, Ft, nd, p0, p1):
    """Golden.step's node update on p0 <= p < p1: v <- (v + F dt / m + g dt) free, x <- x + dt v, from the
    buffers xr, vr into xw, vw."""
    inv_m_dt, free, g_dt, dt = nd
    for k in range(xr.shape[0]):
        xrk, vrk, xwk, vwk, Fk, g = xr[k], vr[k], xw[k], vw[k], Ft[k], g_dt[k]
        for p in range(p0, p1):
            u = (vrk[p] + Fk[p] * inv_m_dt[p] + g) * free[p]
            vwk[p] = u
            xwk[p] = xrk[p] + u * dt


@_jit(inline="always")
def _extras(xt, vt, t, tp, fl, cl, ld, pb, ps, Ft):
    """The rest of Golden.forces, in its order: topology, floor, collisions, loads, the probe. Positions,
    velocities and forces are component-major (D, N), seen as (N, D) by the contact terms."""
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
    if pb.on:
        _probe(x, v, pb, ps, F)


@_jit()
def _worker(w, threads, n_steps, step, t_forces, integrate, driven, X, V, a, el, tp, fl, cl, ld, pb, ps, nd, ch, Ft,
            wk, sv, sync):
    """n_steps symplectic Euler steps (Golden.step) from step number `step`; every thread of a run calls this
    (w: which one of `threads`). Step s reads X[s % 2], V[s % 2] and writes the other buffers. Each pass of
    a step starts when every chunk of the passes before is done; a thread then claims chunks, its own share
    first, and runs each it claims. A probe no host `driven` follows the design poke. Without `integrate`:
    Golden.forces at time t_forces (one step's forces into Ft and wk, nothing moves)."""
    C = len(ch.nodes) - 1
    extras = tp.on or fl.on or cl.on or len(ld.start) > 0 or pb.on
    split = extras or not integrate             # the node sums before the integration: three passes
    per_step = C + ((1 + C) if extras and integrate else (1 if extras else 0))
    mine = w * C // threads                      # the first chunk of this thread's share
    solo = threads == 1                          # no counters to keep
    dt = nd.dt
    for s in range(n_steps):
        xr, vr, xw, vw = X[s % 2], V[s % 2], X[1 - s % 2], V[1 - s % 2]
        first = s * per_step
        if _atomic_load(sync, FAILED) != 0:
            return
        _wait(sync, first, solo)
        for q in range(C):
            c = (mine + q) % C
            if _take(sync, CLAIMS + 8 * c, s, solo):
                e0, e1, p0, p1 = ch.span[c], ch.span[c + 1], ch.nodes[c], ch.nodes[c + 1]
                if not _chunk(xr, vr, a, el, wk, sv, Ft, e0, e1, p0, p1, integrate, dt):
                    _atomic_add(sync, FAILED, 1)
                if not split:
                    _integrate(xr, vr, xw, vw, Ft, nd, p0, p1)
                _done(sync, solo)
        if extras:
            _wait(sync, first + C, solo)
            if _take(sync, CLAIMS + 8 * C, s, solo):
                if pb.on and integrate and not driven:
                    _design_sample(pb, ps, step + s, dt)
                _extras(xr, vr, (step + s) * dt if integrate else t_forces, tp, fl, cl, ld, pb, ps, Ft)
                _done(sync, solo)
            if integrate:
                _wait(sync, first + C + 1, solo)
                for q in range(C):
                    c = (mine + q) % C
                    if _take(sync, CLAIMS + 8 * (C + 1 + c), s, solo):
                        _integrate(xr, vr, xw, vw, Ft, nd, ch.nodes[c], ch.nodes[c + 1])
                        _done(sync, solo)
    _wait(sync, n_steps * per_step, solo)         # the last step's chunks (some may be the other thread's)


@_jit(parallel=True)
def _run_parallel(threads, n_steps, step, t_forces, integrate, driven, X, V, a, el, tp, fl, cl, ld, pb, ps, nd, ch, Ft,
                  wk, sv, sync):
    """_worker on `threads` threads at once: one parallel region for the whole run."""
    for w in prange(threads):
        _worker(w, threads, n_steps, step, t_forces, integrate, driven, X, V, a, el, tp, fl, cl, ld, pb, ps, nd, ch, Ft,
                wk, sv, sync)


# ---------------------------------------------------------------- the stepper

def _column(value, E: int) -> np.ndarray:
    return np.ascontiguousarray(np.broadcast_to(np.asarray(value, float), (E,)))


def _chunks(i: np.ndarray, j: np.ndarray, N: int, C: int):
    """Node chunks with equal shares of the elements (by start node) and each chunk's element copies (every
    element with a node in the chunk, in element order). Returns (Chunks, the element of each copy, the
    copies that own their element: those in their start node's chunk, and where each copy's terms go)."""
    E = len(i)
    starts = np.bincount(i, minlength=N)
    cut = np.searchsorted(np.cumsum(starts), (np.arange(1, C) * E) // C, side="right")
    nodes = np.concatenate([[0], cut, [N]]).astype(np.int64)
    nodes = np.maximum.accumulate(nodes)
    chunk = np.searchsorted(nodes, np.arange(N), side="right") - 1      # the chunk of each node
    ci, cj = chunk[i], chunk[j]
    elem = np.arange(E)
    across = cj != ci
    copy_chunk = np.concatenate([ci, cj[across]])
    copy_elem = np.concatenate([elem, elem[across]])
    order = np.lexsort((copy_elem, copy_chunk))
    copy_chunk, copy_elem = copy_chunk[order], copy_elem[order]
    owner = order < E                                                   # the copy in the start node's chunk
    span = np.concatenate([[0], np.cumsum(np.bincount(copy_chunk, minlength=C))])
    sink = N + 8 * copy_chunk                           # each chunk's sink on its own cache line
    ti = np.where(ci[copy_elem] == copy_chunk, i[copy_elem], sink)
    tj = np.where(cj[copy_elem] == copy_chunk, j[copy_elem], sink)
    return Chunks(span.astype(np.uint64), nodes.astype(np.uint64)), copy_elem, owner, ti, tj


class Cpu(Stepper):
    """Steps a System in float64 with compiled loops; the same interface as golden.model.Golden."""

    takes_probe = True

    def __init__(self, system: System, threads: int | None = None, chunks: int | None = None):
        self.system = system
        E, N, D = system.n_elements, system.n_nodes, system.dim
        if threads is None:
            threads = 2 if E >= PARALLEL_MIN_ELEMENTS else 1
        self.threads = max(1, min(int(threads), numba.config.NUMBA_NUM_THREADS))
        C = max(1, min(int(chunks or self.threads * CHUNKS_PER_THREAD), N))
        p = system.elem
        edges = np.asarray(system.edges, np.int64)
        self.ch, self._copy, owner, ti, tj = _chunks(edges[:, 0], edges[:, 1], N, C)
        self._owned = np.flatnonzero(owner)                 # the copies that give each element's a back
        self._owned_elem = self._copy[self._owned]
        copy = self._copy
        Ec = len(copy)
        # unsigned indices: no negative-index wraparound in the gathers
        index = np.uint32 if N + 8 * C < 2 ** 32 else np.uint64
        i, j, ti, tj = (np.ascontiguousarray(v, index) for v in (edges[copy, 0], edges[copy, 1], ti, tj))
        cols = {f: _column(getattr(p, f), E) for f in PARAMS}
        c1, cmin, cmax = cols["c1"], cols["c_min"], cols["c_max"]
        B, f1, f2 = cols["B"], cols["f1"], cols["f2"]
        knees = f1 * (1.0 + c1 / cmax), f2 * (1.0 + c1 / cmin)     # Phi's Y1, Y2, as golden's
        with np.errstate(invalid="ignore", over="ignore"):          # constant dampers: knees at infinity
            chord = (f1 + c1 * (f1 * np.exp(B * (f1 - f1)) / cmax), f2 + c1 * (f2 * np.exp(B * (f2 - f1)) / cmax))
            exponent = np.where(np.isfinite(f2), B * (f2 - f1), 0.0)
        derived = dict(Y1=knees[0], Y2=knees[1], S_max=cmax / (c1 + cmax), S_min=cmin / (c1 + cmin),
                       R_max=c1 + cmax, R_min=c1 + cmin, G_lo=chord[0], G_hi=chord[1])
        every = {**cols, **derived}
        # a uniform material (every parameter the same for every element): scalars, as golden's _compact
        uniform = E > 0 and all(np.array_equal(v, np.full(E, v[0]), equal_nan=True) for v in every.values())
        every = {k: (float(v[0]) if uniform else np.ascontiguousarray(v[copy])) for k, v in every.items()}
        self.el = Elements(i, j, ti, tj, np.ascontiguousarray(_column(p.L, E)[copy]), *(every[f] for f in PARAMS),
                           *(every[f] for f in ("Y1", "Y2", "S_max", "S_min", "R_max", "R_min", "G_lo", "G_hi")),
                           bool(p.nonlinear), bool(p.fixed_a),
                           bool(np.all(exponent <= EXP_MAX)))
        no_pairs = np.zeros((0, D + 1), np.int64)
        tp = system.topology
        self.tp = (Topo(True, np.ascontiguousarray(tp.pairs, np.int64), float(tp.K), float(tp.C), float(tp.eps))
                   if tp is not None and len(tp.pairs) else Topo(False, no_pairs, 0.0, 0.0, 0.0))
        fl = system.floor
        self.fl = (FloorP(True, float(fl.height), float(fl.K), float(fl.C), float(fl.mu), float(fl.k_f))
                   if fl is not None else FloorP(False, 0.0, 0.0, 0.0, 0.0, 0.0))
        cl = system.collision
        if cl is not None:          # golden's sorted keys a * n_nodes + b of joined nodes, as rows a of b's
            keys = np.asarray(cl.neighbour_keys, np.int64)
            nbr_ptr = np.concatenate([[0], np.cumsum(np.bincount(keys // cl.n_nodes, minlength=N))])
            self.cl = Coll(True, np.ascontiguousarray(cl.vertices, np.int64),
                           np.ascontiguousarray(cl.facets, np.int64),
                           nbr_ptr.astype(np.int64), np.ascontiguousarray(keys % cl.n_nodes), float(cl.K),
                           float(cl.C), float(cl.threshold), float(cl.mu), float(cl.k_f))
        else:
            self.cl = Coll(False, np.zeros(0, np.int64), np.zeros((0, D), np.int64), np.zeros(N + 1, np.int64),
                           np.zeros(0, np.int64), 0.0, 0.0, 0.0, 0.0, 0.0)
        nodes = [np.unique(np.asarray(l.nodes, np.int64)) for l in system.loads]    # F[nodes] += f: once a node
        self.ld = Loads(np.concatenate([[0], np.cumsum([len(s) for s in nodes])]).astype(np.int64),
                        np.concatenate(nodes + [np.zeros(0, np.int64)]),
                        np.array([np.asarray(l.force, float) for l in system.loads]).reshape(len(system.loads), D),
                        np.array([float(l.start) for l in system.loads]), np.array([float(l.end) for l in system.loads]))
        pb = system.probe          # the same types with and without a probe: one compiled worker
        self.pb = (ProbeP(True, float(pb.radius), float(pb.K), float(pb.C), float(pb.mu), float(pb.k_f), int(pb.k),
                          np.asarray(pb.position, float).copy(), pb.down, float(pb.depth), float(pb.poke_time))
                   if pb is not None else ProbeP(False, 0.0, 0.0, 0.0, 0.0, 0.0, 1, np.zeros(D), np.zeros(D), 0.0, 1.0))
        M = N if pb is not None else 0
        self._ps = ProbeIO(np.zeros(D), np.zeros(D), np.zeros(M, np.int64), np.zeros((M, D)), np.zeros(1, np.int64))
        self.nd = Nodes(np.where(system.pinned, 0.0, system.dt / system.mass), (~system.pinned).astype(float),
                        np.asarray(system.gravity, float) * system.dt, float(system.dt))
        self._X, self._V = np.zeros((2, D, N)), np.zeros((2, D, N))
        self._a = np.zeros(Ec)
        self._Ft = np.zeros((D, N + 8 * C))           # and the chunks' sinks (`_scatter`)
        self._wk = Work(np.zeros((D, Ec)), *(np.zeros(Ec) for _ in range(5)),
                        np.zeros(-(-Ec // 8) * 8, np.bool_))       # whole words for `_finish`
        self._sv = Solve(np.zeros(Ec, np.int64), *(np.zeros(Ec) for _ in range(9)))
        self._sync = np.zeros(CLAIMS + 8 * (2 * C + 1), np.int64)

    def initial_state(self) -> State:
        return State.initial(self.system)

    def _layout(self, st: State):
        """st's x, v as the component-major (D, N) float64 buffers of golden's State layout."""
        for name in ("x", "v"):
            arr = getattr(st, name)
            if not (arr.T.flags.c_contiguous and arr.dtype == np.float64):
                setattr(st, name, component_major(np.asarray(arr, np.float64)))
        if not (st.a.flags.c_contiguous and st.a.dtype == np.float64):
            st.a = np.ascontiguousarray(st.a, np.float64)
        return st.x.T, st.v.T

    def _call(self, n: int, t_forces: float, integrate: bool, st: State) -> None:
        """The compiled run on st (copied into the double buffers and the element copies, and back)."""
        xt, vt = self._layout(st)
        self._X[0], self._V[0] = xt, vt
        np.take(st.a, self._copy, out=self._a)
        self._sync[:] = 0
        pst, ps = st.probe, self._ps
        if pst is not None:
            ps.p[:], ps.pdot[:] = pst.p, pst.pdot
        args = (int(n), int(st.step), float(t_forces), integrate, pst is not None and pst.driven, self._X, self._V,
                self._a, self.el, self.tp, self.fl, self.cl, self.ld, self.pb, ps, self.nd, self.ch, self._Ft,
                self._wk, self._sv, self._sync)
        if self.threads > 1:
            numba.set_num_threads(self.threads)
            _run_parallel(self.threads, *args)
        else:
            _worker(0, 1, *args)
        if integrate:
            xt[...], vt[...] = self._X[n % 2], self._V[n % 2]
            st.a[self._owned_elem] = self._a[self._owned]
        if pst is not None:               # the held inputs (the design poke moves them) and the last step's reading
            pst.p, pst.pdot = ps.p.copy(), ps.pdot.copy()
            m = int(ps.count[0])
            pst.record(ps.nodes[:m].copy(), ps.node_forces[:m].copy())
        if self._sync[FAILED]:
            raise ArithmeticError("damper solve did not converge")

    def advance(self, st: State, n: int, progress=None) -> None:
        """n steps in one compiled call."""
        if n <= 0:
            return
        self._call(n, 0.0, True, st)
        st.step += int(n)
        if progress is not None:
            progress(int(n))

    def step(self, st: State) -> None:
        self.advance(st, 1)

    # the haptic probe: golden's own methods (they touch only the state's ProbeState and the system)
    hold_probe = Golden.hold_probe
    probe_reading = Golden.probe_reading
    probe_position = Golden.probe_position

    def forces(self, st: State, t: float):
        """Total force (N, D) and the elements' adot at time t (for tests and tools); `flagged` then holds the
        elements that needed more than Phi's linear pieces."""
        self._call(1, t, False, st)
        adot = np.zeros(self.system.n_elements)
        adot[self._owned_elem] = self._wk.adot[self._owned]
        self.flagged = np.zeros(self.system.n_elements, np.bool_)
        self.flagged[self._owned_elem] = self._wk.flag[self._owned]
        return self._Ft[:, :self.system.n_nodes].T.copy(), adot


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
