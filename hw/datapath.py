"""The hardware's time step, operation by operation, in hardware units (hw/units.py: dt = 1).

This is the one description of what the accelerator computes; `FloatArith` runs it in float64 (it then
equals the golden model up to float rounding, a test) and `FixedArith` runs it bit-true. Quantity names
(the strings) select the number formats in hw/formats.py. Order of operations within a step:

  elements    d = x_j - x_i, du = u_j - u_i, l2 = sum d^2, inv_l = rsqrt(l2), l = l2 inv_l, e = d inv_l,
              ldot = sum e du, s = a l - L, k1s = k1 s,
              [c2, c1 + c2, 1/(c1 + c2) from |T_prev| by table, or constants]
              num = (c2 - (c1 + c2) a) ldot - k1s, adot = (num / (c1 + c2)) inv_l, clamp on a bound,
              T = k1s + c1 (adot l + a ldot)   [viscoelastic: T = k1s + (c1 a_max) ldot]
              fe = T e: +fe to node i, -fe to node j
  topology    per (vertex k, facet): the facet normal n, distance d, foot weights w, normal speed;
              f = K (eps - d) - C ddot where d <= eps; +f n to k, -w f n to the facet (exact sum 0)
  floor       N = max(0, -K h - C u_z) where h < 0, friction -clip(k_f u_t, mu N)
  loads       constant forces in their time windows
  nodes       u += mu_i F + g; pinned: u = 0; x += u;  a = clip(a + adot, a_min, a_max); f_prev = |T|
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from golden.model import System
from .units import HardwareUnits


class NotSupported(ValueError):
    """A scene feature the bit-true model and the hardware do not implement (yet)."""


@dataclass
class DamperParams:
    """The nonlinear damper in hardware units (scalars: one material per scene for tables)."""
    c1: float
    c_min: float
    c_max: float
    f1: float
    f2: float

    @property
    def B(self):
        return np.log(self.c_max / self.c_min) / (self.f2 - self.f1)

    @property
    def A(self):
        return self.c_max * np.exp(self.B * self.f1)


@dataclass
class Params:
    """Everything the datapath needs, in hardware units, plus which units the scene needs."""
    dim: int
    n_nodes: int
    i: np.ndarray
    j: np.ndarray
    L: np.ndarray
    k1: object                 # array (E,) or float; None when k1 = 0 everywhere (no multiplier)
    c1: object
    c1a: object                # c1 a_max, for fixed-a (viscoelastic) scenes
    a_min: object
    a_max: object
    fixed_a: bool
    c2: object = None          # constant damper
    c12: object = None
    ic12: object = None
    damper: DamperParams | None = None
    inv_mass: object = None    # None: uniform mass (mu = 1, no multiplier)
    gravity: np.ndarray | None = None
    free: np.ndarray = None    # (N,) bool
    topology: dict | None = None
    floor: dict | None = None
    loads: list = field(default_factory=list)
    dt: float = 1.0

    @classmethod
    def of(cls, sys: System, units: HardwareUnits) -> "Params":
        if sys.collision is not None:
            raise NotSupported(f"scene '{sys.name}' uses collisions, which the bit-true model and the "
                               f"hardware do not implement yet")
        el = sys.elem
        u = units
        uniform = lambda v: float(v) if np.isscalar(v) else (float(v[0]) if np.all(v == v[0]) else v)
        k1 = uniform(u.stiffness(el.k1))
        c1 = uniform(u.damping(el.c1))
        p = cls(sys.dim, sys.n_nodes, sys.edges[:, 0].copy(), sys.edges[:, 1].copy(), u.length(el.L),
                None if np.all(np.asarray(k1) == 0) else k1, c1,
                uniform(np.asarray(c1) * np.asarray(el.a_max)), el.a_min, el.a_max, el.fixed_a)
        if not el.fixed_a:
            if el.nonlinear:
                vals = [np.atleast_1d(v) for v in (el.c1, el.c_min, el.c_max)]
                if any(not np.all(v == v[0]) for v in vals) or not (np.isscalar(el.A) and np.isscalar(el.B)):
                    raise NotSupported(f"scene '{sys.name}': the hardware damper tables take one nonlinear "
                                       f"damper material per scene")
                f1 = float(np.log(el.A / el.c_max) / el.B)
                f2 = float(np.log(el.A / el.c_min) / el.B)
                p.damper = DamperParams(float(u.damping(vals[0][0])), float(u.damping(el.c_min)),
                                        float(u.damping(el.c_max)), float(u.force(f1)), float(u.force(f2)))
            else:
                p.c2 = uniform(u.damping(el.c_min))
                p.c12 = uniform(np.asarray(p.c1) + np.asarray(p.c2))
                p.ic12 = uniform(1.0 / np.asarray(p.c12))
        m_ratio = u.m_ref / sys.mass
        p.inv_mass = None if np.all(m_ratio[~sys.pinned] == 1.0) else np.where(sys.pinned, 0.0, m_ratio)
        p.gravity = u.acceleration(sys.gravity) if np.any(sys.gravity != 0) else None
        p.free = ~sys.pinned
        if sys.topology is not None and len(sys.topology.pairs):
            tp = sys.topology
            p.topology = dict(pairs=tp.pairs, K=float(u.stiffness(tp.K)), C=float(u.damping(tp.C)),
                              eps=float(u.length(tp.eps)))
        if sys.floor is not None:
            fl = sys.floor
            p.floor = dict(h=float(u.length(fl.height)), K=float(u.stiffness(fl.K)), C=float(u.damping(fl.C)),
                           mu=fl.mu, kf=float(u.damping(fl.k_f)))
        p.loads = [(ld.nodes, [np.full(len(ld.nodes), fk) if fk != 0.0 else None for fk in u.force(ld.force)],
                    ld.start, ld.end) for ld in sys.loads]
        p.dt = sys.dt
        return p

    def features(self) -> dict:
        """Which units this scene needs (hardware specialisation)."""
        return {"dim": self.dim, "k1_multiply": self.k1 is not None, "a_state": not self.fixed_a,
                "damper_table": self.damper is not None, "per_node_mass": self.inv_mass is not None,
                "gravity": self.gravity is not None, "topology": self.topology is not None,
                "floor": self.floor is not None, "friction": bool(self.floor and self.floor["mu"] > 0),
                "loads": bool(self.loads)}


@dataclass
class HwState:
    X: list            # D arrays (N,)
    U: list
    A: np.ndarray      # (E,)
    FP: np.ndarray     # (E,) |T| of the previous step
    step: int = 0


def step(ar, st: HwState, p: Params) -> HwState:
    """One time step; returns the new state (values as the arithmetic holds them)."""
    D, N = p.dim, p.n_nodes
    X = [ar.state("x", x) for x in st.X]
    U = [ar.state("u", u) for u in st.U]
    A = ar.state("a", st.A)

    # ---- elements
    d = [ar.sub(ar.take(X[k], p.j), ar.take(X[k], p.i), "d") for k in range(D)]
    du = [ar.sub(ar.take(U[k], p.j), ar.take(U[k], p.i), "du") for k in range(D)]
    l2 = ar.sum([ar.mul(dk, dk, "l2") for dk in d], "l2")
    inv_l = ar.rsqrt(l2, "inv_l")
    l = ar.mul(l2, inv_l, "l")
    e = [ar.mul(dk, inv_l, "e") for dk in d]
    ldot = ar.sum([ar.mul(e[k], du[k], "ldot") for k in range(D)], "ldot")
    s = ar.sub(ar.mul(A, l, "l"), ar.const("L", p.L), "s")
    k1s = ar.mul(ar.const("k1", p.k1), s, "force") if p.k1 is not None else ar.zeros("force", len(p.i))
    adot = None
    if p.fixed_a:
        T = ar.add(k1s, ar.mul(ar.const("c1a", p.c1a), ldot, "force"), "force")
    else:
        if p.damper is not None:
            c2, c12, ic12 = ar.damper(ar.state("force", st.FP), p.damper)
        else:
            c2, c12, ic12 = ar.const("c2", p.c2), ar.const("c12", p.c12), ar.const("ic12", p.ic12)
        g = ar.sub(c2, ar.mul(c12, A, "c12"), "c12")
        num = ar.sub(ar.mul(g, ldot, "force"), k1s, "force")
        adot = ar.mul(ar.mul(num, ic12, "num_ic"), inv_l, "adot")
        zero = ar.zeros("adot", len(p.i))
        a_min, a_max = ar.const("a", p.a_min), ar.const("a", p.a_max)
        outward = (ar.le(A, a_min) & ar.lt(adot, zero)) | (ar.le(a_max, A) & ar.lt(zero, adot))
        adot = ar.select(~outward, adot, zero)
        sdot = ar.add(ar.mul(adot, l, "sdot"), ar.mul(A, ldot, "sdot"), "sdot")
        T = ar.add(k1s, ar.mul(ar.const("c1", p.c1), sdot, "force"), "force")
    fe = [ar.mul(T, e[k], "fe") for k in range(D)]
    parts = [[(fe[k], p.i), (ar.neg(fe[k]), p.j)] for k in range(D)]

    # ---- topology preservation
    if p.topology is not None:
        _topology(ar, X, U, p, parts)

    # ---- floor
    if p.floor is not None:
        _floor(ar, X, U, p, parts)

    # ---- loads
    t = st.step * p.dt
    for nodes, force, start, end in p.loads:
        if start <= t < end:
            for k in range(D):
                if force[k] is not None:
                    parts[k].append((ar.const("load", force[k]), nodes))

    F = [ar.scatter(parts[k], N, "facc") for k in range(D)]

    # ---- nodes
    free = p.free
    zero_u = ar.zeros("u", N)
    newU, newX = [], []
    for k in range(D):
        if p.inv_mass is not None:
            dv = ar.mul(ar.const("inv_mass", p.inv_mass), ar.convert(F[k], "fnode"), "dv")
        else:
            dv = ar.convert(F[k], "dv")
        u = ar.add(U[k], dv, "u")
        if p.gravity is not None and p.gravity[k] != 0.0:
            u = ar.add(u, ar.const("g", p.gravity[k]), "u")
        u = ar.select(free, u, zero_u)
        newU.append(u)
        newX.append(ar.add(X[k], u, "x"))
    if adot is not None:
        a = ar.add(A, adot, "a")
        a = ar.select(ar.le(a, a_min), a_min, a)
        a = ar.select(ar.le(a_max, a), a_max, a)
        newA = a.x
    else:
        newA = st.A
    newFP = ar.select(ar.lt(T, ar.zeros("force", len(p.i))), ar.neg(T), T).x if p.damper is not None else st.FP
    return HwState([x.x for x in newX], [u.x for u in newU], newA, newFP, st.step + 1)


def _facet_normal(ar, X, facet):
    """Unit normal of each facet (the golden orientation rule) from positions; returns (n, inv_len)."""
    D = len(X)
    if D == 2:
        u = [ar.sub(ar.take(X[k], facet[:, 1]), ar.take(X[k], facet[:, 0]), "tr") for k in range(2)]
        n2 = ar.sum([ar.mul(c, c, "tl2") for c in u], "tl2")
        inv = ar.rsqrt(n2, "tinv")
        n = [ar.neg(ar.mul(u[1], inv, "e")), ar.mul(u[0], inv, "e")]
        return n, inv, u
    e1 = [ar.sub(ar.take(X[k], facet[:, 1]), ar.take(X[k], facet[:, 0]), "tr") for k in range(3)]
    e2 = [ar.sub(ar.take(X[k], facet[:, 2]), ar.take(X[k], facet[:, 0]), "tr") for k in range(3)]
    c = [ar.sub(ar.mul(e1[(k + 1) % 3], e2[(k + 2) % 3], "tl2"), ar.mul(e1[(k + 2) % 3], e2[(k + 1) % 3], "tl2"), "tl2")
         for k in range(3)]
    n2 = ar.sum([ar.mul(ck, ck, "tl4") for ck in c], "tl4")
    inv = ar.rsqrt(n2, "tinv2")
    n = [ar.mul(ck, inv, "e") for ck in c]
    return n, inv, (e1, e2)


def _topology(ar, X, U, p: Params, parts):
    D = p.dim
    tp = p.topology
    pairs = tp["pairs"]
    k_, facet = pairs[:, 0], pairs[:, 1:]
    n, inv, edges = _facet_normal(ar, X, facet)
    r = [ar.sub(ar.take(X[k], k_), ar.take(X[k], facet[:, 0]), "tr") for k in range(D)]
    dist = ar.sum([ar.mul(r[k], n[k], "tdist") for k in range(D)], "tdist")
    eps = ar.const("eps", tp["eps"])
    act = np.flatnonzero(ar.le(dist, eps))
    if act.size == 0:
        return
    sub = lambda v: ar.take(v, act)
    n, r, dist = [sub(c) for c in n], [sub(c) for c in r], sub(dist)
    k_, facet = k_[act], facet[act]
    one = ar.const("w", 1.0)
    zero_w = ar.zeros("w", act.size)
    if D == 2:
        u = [sub(c) for c in edges]
        inv = sub(inv)
        t = ar.mul(ar.mul(ar.sum([ar.mul(r[k], u[k], "tl2") for k in range(2)], "tl2"), inv, "tdist"), inv, "w")
        t = ar.select(ar.lt(t, zero_w), zero_w, t)
        t = ar.select(ar.lt(one, t), one, t)
        w_rest = [t]
    else:
        e1, e2 = [[sub(c) for c in e] for e in edges]
        inv = sub(inv)
        d11 = ar.sum([ar.mul(c, c, "tl2") for c in e1], "tl2")
        d22 = ar.sum([ar.mul(c, c, "tl2") for c in e2], "tl2")
        d12 = ar.sum([ar.mul(e1[k], e2[k], "tl2") for k in range(3)], "tl2")
        r1 = ar.sum([ar.mul(r[k], e1[k], "tl2") for k in range(3)], "tl2")
        r2 = ar.sum([ar.mul(r[k], e2[k], "tl2") for k in range(3)], "tl2")
        inv2 = ar.mul(inv, inv, "tinv4")
        w1 = ar.mul(ar.sub(ar.mul(d22, r1, "tl4"), ar.mul(d12, r2, "tl4"), "tl4"), inv2, "w")
        w2 = ar.mul(ar.sub(ar.mul(d11, r2, "tl4"), ar.mul(d12, r1, "tl4"), "tl4"), inv2, "w")
        w_rest = []
        for w in (w1, w2):
            w = ar.select(ar.lt(w, zero_w), zero_w, w)
            w = ar.select(ar.lt(one, w), one, w)
            w_rest.append(w)
    # relative velocity of the vertex and its foot: (u_k - u_0) - sum_m w_m (u_m - u_0)
    vrel = []
    for k in range(D):
        u0 = ar.take(U[k], facet[:, 0])
        v = ar.sub(ar.take(U[k], k_), u0, "du")
        for m, w in enumerate(w_rest, start=1):
            v = ar.sub(v, ar.mul(w, ar.sub(ar.take(U[k], facet[:, m]), u0, "du"), "du"), "du")
        vrel.append(v)
    ddot = ar.sum([ar.mul(vrel[k], n[k], "ldot") for k in range(D)], "ldot")
    f = ar.sub(ar.mul(ar.const("topo_K", tp["K"]), ar.sub(eps, dist, "tdist"), "force"),
               ar.mul(ar.const("topo_C", tp["C"]), ddot, "force"), "force")
    for k in range(D):
        Fk = ar.mul(f, n[k], "fe")
        parts[k].append((Fk, k_))
        rest_sum = None
        for m, w in enumerate(w_rest, start=1):
            Fm = ar.mul(w, Fk, "fe")
            parts[k].append((ar.neg(Fm), facet[:, m]))
            rest_sum = Fm if rest_sum is None else ar.add(rest_sum, Fm, "fe")
        # the first facet vertex takes the remainder, so the pair's forces sum to exactly zero
        parts[k].append((ar.neg(ar.sub(Fk, rest_sum, "fe")), facet[:, 0]))


def _floor(ar, X, U, p: Params, parts):
    D, fl = p.dim, p.floor
    z = D - 1
    h = ar.sub(X[z], ar.const("x", fl["h"]), "tdist")
    act = np.flatnonzero(ar.lt(h, ar.zeros("tdist", 1)))
    if act.size == 0:
        return
    h = ar.take(h, act)
    uz = ar.take(U[z], act)
    N = ar.sub(ar.mul(ar.const("floor_K", fl["K"]), ar.neg(h), "force"),
               ar.mul(ar.const("floor_C", fl["C"]), uz, "force"), "force")
    zero = ar.zeros("force", act.size)
    N = ar.select(ar.lt(N, zero), zero, N)
    parts[z].append((N, act))
    if fl["mu"] <= 0.0:
        return
    muN = ar.mul(ar.const("mu", fl["mu"]), N, "force")
    kfu = [ar.mul(ar.const("floor_kf", fl["kf"]), ar.take(U[k], act), "force") for k in range(D - 1)]
    if D == 2:
        f = kfu[0]
        f = ar.select(ar.lt(muN, f), muN, f)
        f = ar.select(ar.lt(f, ar.neg(muN)), ar.neg(muN), f)
        parts[0].append((ar.neg(f), act))
        return
    mag2 = ar.sum([ar.mul(c, c, "fmag2") for c in kfu], "fmag2")
    slip = np.flatnonzero(ar.lt(ar.zeros("fmag2", 1), mag2))     # no slip, no friction (and no rsqrt(0))
    if slip.size == 0:
        return
    inv = ar.rsqrt(ar.take(mag2, slip), "finv")
    ratio = ar.mul(ar.take(muN, slip), inv, "w")
    one = ar.const("w", 1.0)
    ratio = ar.select(ar.lt(one, ratio), one, ratio)
    for k in range(D - 1):
        parts[k].append((ar.neg(ar.mul(ar.take(kfu[k], slip), ratio, "force")), act[slip]))
