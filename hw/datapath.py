"""The hardware's time step, operation by operation, in hardware units (hw/units.py: dt = 1).

This is the one description of what the accelerator computes; `FloatArith` runs it in float64 (it then
equals the golden model up to float rounding, a test) and `FixedArith` runs it bit-true. Quantity names
(the strings) select the number formats in hw/formats.py. Order of operations within a step:

  elements    d = x_j - x_i, du = u_j - u_i, l2 = sum d^2, inv_l = rsqrt(l2), l = l2 inv_l, e = d inv_l,
              ldot = sum e du, s = a l - L, k1s = k1 s, the drive Y = k1s + c1 ldot,
              T, w' = Phi(Y), W(Y)  [constant damper: Y c2/(c1 + c2), Y/(c1 + c2); nonlinear: sign, linear
              pieces below Y1 / above Y2, the Phi table between], Wa = (1 - a) ldot, adot = (Wa - w') inv_l;
              stops: a on a_max and adot > 0: T = k1s + c1 (a ldot); a on a_min and adot < 0: T = Psi(Wa)
              [c2 Wa, or linear pieces and the Psi table]; adot = 0 on a stop
              [viscoelastic: T = k1s + (c1 a_max) ldot]
              fe = T e: +fe to node i, -fe to node j
  topology    per (vertex k, facet): the facet normal n, distance d, foot weights w, normal speed;
              f = K (eps - d) - C ddot where d <= eps; +f n to k, -w f n to the facet (exact sum 0)
  collisions  per (surface vertex, surface facet) of the static pair list (no broad phase): outward
              normal n, distance d; where |d| <= h and the foot lies on the facet:
              N = max(0, K (h - d) - C vn), friction -clip(k_f v_t, mu N); +F to the vertex, -w F to
              the facet (exact sum 0)
  floor       N = max(0, -K h - C u_z) where h < 0, friction -clip(k_f u_t, mu N)
  probe       (MODEL.md 4b) per device sample: pdot = (p - p_prev) / k, the bounding box p -+ R; per node:
              inside the box, r = x - p, then the gate |r|^2 < R^2 before any square root (a far node
              computes nothing, so it saturates nothing); 1/d (rsqrt unit), n = r / d,
              N = max(0, K (R - d) - C (u - pdot) . n), friction -clip(k_f v_t, mu N) as the floor's; the
              probe's force is minus the exact integer sum of the node forces (at their binary point)
  loads       constant forces in their time windows
  nodes       u += mu_i F + g; pinned: u = 0; x += u;  a = clip(a + adot, a_min, a_max)
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from golden.errors import RheoError
from golden.elements import DamperLaw
from golden.system import System
from .formats import Q
from .funcunits import OddCurve
from .units import HardwareUnits


class NotSupported(RheoError, ValueError):
    """A scene feature the bit-true model and the hardware do not implement (yet)."""


def phi_curve(law: DamperLaw) -> OddCurve:
    """Phi = G^-1 on its nonlinear piece, with the damper's rate H beside it (outputs T and w')."""
    return OddCurve("phi", Q.drive, law.G, law.dG, law.d2G, law.f1, law.f2, (Q.force, Q.wdot),
                    ((law.H, law.dH, law.d2H),))


def psi_curve(law: DamperLaw) -> OddCurve:
    """Psi = H^-1 on its nonlinear piece (the damper's force from its rate, on the a_min stop)."""
    return OddCurve("psi", Q.wdot, law.H, law.dH, law.d2H, law.f1, law.f2, (Q.force,))


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
    c2: object = None          # constant damper: Psi(W) = c2 W
    phi_s: object = None       # constant damper: Phi(Y) = phi_s Y, phi_s = c2 / (c1 + c2)
    ic12: object = None        # constant damper: w' = ic12 Y, ic12 = 1 / (c1 + c2)
    damper: DamperLaw | None = None      # the nonlinear damper (one material per scene)
    curves: dict = field(default_factory=dict)     # "phi", "psi": the inverse tables' curves
    inv_mass: object = None    # None: uniform mass (mu = 1, no multiplier)
    gravity: np.ndarray | None = None
    free: np.ndarray = None    # (N,) bool
    topology: dict | None = None
    collision: dict | None = None
    floor: dict | None = None
    probe: dict | None = None
    loads: list = field(default_factory=list)
    dt: float = 1.0

    @classmethod
    def of(cls, system: System, units: HardwareUnits) -> "Params":
        el = system.elem
        u = units
        uniform = lambda v: float(v) if np.isscalar(v) else (float(v[0]) if np.all(v == v[0]) else v)
        k1 = uniform(u.stiffness(el.k1))
        c1 = uniform(u.damping(el.c1))
        p = cls(system.dim, system.n_nodes, system.edges[:, 0].copy(), system.edges[:, 1].copy(), u.length(el.L),
                None if np.all(np.asarray(k1) == 0) else k1, c1,
                uniform(np.asarray(c1) * np.asarray(el.a_max)), el.a_min, el.a_max, el.fixed_a)
        if not el.fixed_a:
            if el.nonlinear:
                # one damper table per scene: every element whose a moves shares it (elements with
                # a_min = a_max, viscoelastic objects beside rheological ones, never use their c2)
                E = len(system.edges)
                moving = np.broadcast_to(np.asarray(el.a_min) < np.asarray(el.a_max), (E,))
                varies = np.broadcast_to(np.asarray(el.c_max) > np.asarray(el.c_min), (E,))
                if np.any(moving & ~varies):
                    raise NotSupported(f"scene '{system.name}': the hardware cannot mix constant and nonlinear "
                                       f"dampers among elements whose a varies")
                vals = [np.broadcast_to(np.asarray(v, float), (E,))[moving]
                        for v in (el.c1, el.c_min, el.c_max, el.A, el.B)]
                if any(not np.all(v == v[0]) for v in vals):
                    raise NotSupported(f"scene '{system.name}': the hardware damper tables take one nonlinear "
                                       f"damper material per scene")
                c1, c_min, c_max, A, B = (float(v[0]) for v in vals)
                f1 = float(np.log(A / c_max) / B)
                f2 = float(np.log(A / c_min) / B)
                p.damper = DamperLaw(float(u.damping(c1)), float(u.damping(c_min)), float(u.damping(c_max)),
                                     float(u.force(f1)), float(u.force(f2)))
                p.curves = {"phi": phi_curve(p.damper), "psi": psi_curve(p.damper)}
            else:
                p.c2 = uniform(u.damping(el.c_min))
                c12 = np.asarray(p.c1) + np.asarray(p.c2)
                p.phi_s = uniform(np.asarray(p.c2) / c12)
                p.ic12 = uniform(1.0 / c12)
        m_ratio = u.m_ref / system.mass
        p.inv_mass = None if np.all(m_ratio[~system.pinned] == 1.0) else np.where(system.pinned, 0.0, m_ratio)
        p.gravity = u.acceleration(system.gravity) if np.any(system.gravity != 0) else None
        p.free = ~system.pinned
        if system.topology is not None and len(system.topology.pairs):
            tp = system.topology
            p.topology = dict(pairs=tp.pairs, K=float(u.stiffness(tp.K)), C=float(u.damping(tp.C)),
                              eps=float(u.length(tp.eps)))
        if system.collision is not None and len(system.collision.facets):
            co = system.collision
            p.collision = dict(pairs=co.all_pairs(), K=float(u.stiffness(co.K)), C=float(u.damping(co.C)),
                               h=float(u.length(co.threshold)), mu=co.mu, kf=float(u.damping(co.k_f)))
        if system.floor is not None:
            fl = system.floor
            p.floor = dict(h=float(u.length(fl.height)), K=float(u.stiffness(fl.K)), C=float(u.damping(fl.C)),
                           mu=fl.mu, kf=float(u.damping(fl.k_f)))
        if system.probe is not None:
            pb = system.probe
            R = float(u.length(pb.radius))
            p.probe = dict(R=R, R2=R * R, K=float(u.stiffness(pb.K)), C=float(u.damping(pb.C)), mu=pb.mu,
                           kf=float(u.damping(pb.k_f)), k=int(pb.k), inv_k=1.0 / pb.k,
                           p0=u.length(pb.position),
                           design=lambda s, pb=pb, dt=system.dt: u.length(pb.design_position(s, dt)))
        p.loads = [(ld.nodes, [np.full(len(ld.nodes), fk) if fk != 0.0 else None for fk in u.force(ld.force)],
                    ld.start, ld.end) for ld in system.loads]
        p.dt = system.dt
        return p

    def features(self) -> dict:
        """Which units this scene needs (hardware specialisation)."""
        return {"dim": self.dim, "k1_multiply": self.k1 is not None, "a_state": not self.fixed_a,
                "damper_table": self.damper is not None, "per_node_mass": self.inv_mass is not None,
                "gravity": self.gravity is not None, "topology": self.topology is not None,
                "collision": self.collision is not None,
                "collision_friction": bool(self.collision and self.collision["mu"] > 0),
                "floor": self.floor is not None, "friction": bool(self.floor and self.floor["mu"] > 0),
                "probe": self.probe is not None, "probe_friction": bool(self.probe and self.probe["mu"] > 0),
                "loads": bool(self.loads)}


@dataclass
class HwProbe:
    """The probe's registers, in the arithmetic's own numbers (raw words in fixed point): the position P
    (x format) held for the device sample with its velocity Pdot and bounding box Lo, Hi (hw units), and the
    outputs of the last step: the force on the probe F (fprobe), the contact count, and which nodes touch
    it with their forces node_F (pfe). `driven`: a host holds P (else the scene's design poke does)."""
    P: list
    Pdot: list
    Lo: list
    Hi: list
    F: list
    contacts: int = 0
    driven: bool = False
    nodes: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    node_F: list = field(default_factory=list)

    def copy(self) -> "HwProbe":
        return HwProbe(list(self.P), list(self.Pdot), list(self.Lo), list(self.Hi), list(self.F), self.contacts,
                       self.driven, self.nodes.copy(), [np.copy(f) for f in self.node_F])


class ProbeInputs(NamedTuple):
    """What the node kernel reads of the probe (values of the arithmetic, per dimension): its position P,
    velocity Pdot and bounding box Lo = P - R, Hi = P + R (hardware: registers loaded per sample)."""
    P: list
    Pdot: list
    Lo: list
    Hi: list


@dataclass
class HwState:
    X: list            # D arrays (N,)
    U: list
    A: np.ndarray      # (E,)
    step: int = 0
    probe: HwProbe | None = None


def state_difference(expected: HwState, X, U, A, step: int | None = None) -> str | None:
    """None when the raw words X, U, A (and the step counter, if given) equal `expected` bit for bit, else
    what differs first (a core's read-back against the bit-true model)."""
    if step is not None and step != expected.step:
        return f"the step counter reads {step}, expected {expected.step}"
    for name, got, want in [(f"x{k}", g, w) for k, (g, w) in enumerate(zip(X, expected.X))] + \
                           [(f"u{k}", g, w) for k, (g, w) in enumerate(zip(U, expected.U))] + [("a", A, expected.A)]:
        got, want = np.asarray(got), np.asarray(want)
        if got.shape != want.shape:
            return f"{name} has {got.size} words, expected {want.size}"
        bad = np.flatnonzero(got != want)
        if bad.size:
            i = int(bad[0])
            return f"{name} differs in {bad.size} word(s), first at {i}: {int(got[i])} instead of {int(want[i])}"
    return None


def step(ar, st: HwState, p: Params) -> HwState:
    """One time step of the whole system on arrays (float or bit-true); returns the new state.

    Gathers node values per element / pair, runs the per-item kernels below on whole arrays, and
    scatters their forces: exactly what the hardware pipelines do one item per clock.
    """
    D, N = p.dim, p.n_nodes
    X = [ar.state(Q.x, x) for x in st.X]
    U = [ar.state(Q.u, u) for u in st.U]
    A = ar.state(Q.a, st.A)

    # ---- elements
    take = lambda vs, idx: [ar.take(v, idx) for v in vs]
    fe, newA = element_kernel(ar, p, take(X, p.i), take(X, p.j), take(U, p.i), take(U, p.j), A)
    parts = [[(fe[k], p.i), (ar.neg(fe[k]), p.j)] for k in range(D)]

    # ---- topology preservation, collisions: (vertex, facet) pairs
    for kernel, table in ((pair_kernel, p.topology), (collision_kernel, p.collision)):
        if table is None:
            continue
        pairs = table["pairs"]
        roles = [pairs[:, 0]] + [pairs[:, 1 + m] for m in range(D)]
        gate, contribs = kernel(ar, p, *[take(X, r) for r in roles], *[take(U, r) for r in roles])
        for k, v, role in contribs:
            parts[k].append((v, roles[role][gate.full_idx]))

    F_elem = [ar.scatter(parts[k], N, Q.fe) for k in range(D)]     # exact sums, no rounding yet

    # ---- nodes
    if p.probe is None:
        newX, newU = node_kernel(ar, p, X, U, F_elem, st.step, _node_flags(p))
        probe = None
    else:
        probe = st.probe.copy()
        if not probe.driven and st.step % p.probe["k"] == 0:        # the scene's design poke
            probe_hold(ar, p, probe, p.probe["design"](st.step // p.probe["k"]))
        full = lambda q, vs: [ar.state(q, np.full(N, v)) for v in vs]
        inputs = ProbeInputs(full(Q.x, probe.P), full(Q.pdot, probe.Pdot), full(Q.x, probe.Lo), full(Q.x, probe.Hi))
        newX, newU, (gate, Fp) = node_kernel(ar, p, X, U, F_elem, st.step, _node_flags(p), inputs)
        _probe_outputs(ar, p, probe, gate, Fp)
    return HwState([x.x for x in newX], [u.x for u in newU], newA.x if newA is not None else st.A,
                   st.step + 1, probe)


def probe_hold(ar, p: Params, probe: HwProbe, position) -> None:
    """A device sample: the host's position (hardware units) into the probe's registers, through the
    per-sample kernel (pdot from the previous position, the bounding box)."""
    P = [ar.host_value(Q.x, np.array([v], float)) for v in np.asarray(position, float)]
    Pprev = [ar.state(Q.x, np.array([v])) for v in probe.P]
    Pdot, Lo, Hi = probe_sample_kernel(ar, p, P, Pprev)
    probe.P, probe.Pdot, probe.Lo, probe.Hi = ([v.x[0] for v in vs] for vs in (P, Pdot, Lo, Hi))


def probe_initial(ar, p: Params) -> HwProbe:
    """The probe's registers at step 0: at its initial position (converted like the initial state), at rest."""
    P = [ar.initial_value(Q.x, np.array([v], float)) for v in p.probe["p0"]]
    Pdot, Lo, Hi = probe_sample_kernel(ar, p, P, P)
    zero = ar.zeros(Q.fprobe, 1).x[0]
    return HwProbe(*([v.x[0] for v in vs] for vs in (P, Pdot, Lo, Hi)), [zero] * p.dim,
                   node_F=[ar.zeros(Q.pfe, 0).x for _ in range(p.dim)])


def _probe_outputs(ar, p: Params, probe: HwProbe, gate, Fp) -> None:
    """The force on the probe: minus the exact sum of the node probe forces (an integer sum at their binary
    point in fixed point; hardware: an adder tree over the node lanes), and the contact count."""
    if gate.empty:
        probe.F = [ar.zeros(Q.fprobe, 1).x[0]] * p.dim
        probe.contacts, probe.nodes = 0, np.zeros(0, np.int64)
        probe.node_F = [ar.zeros(Q.pfe, 0).x for _ in range(p.dim)]
        return
    one = np.zeros(gate.size, np.int64)             # every touching node into the one sum
    probe.F = [ar.neg(ar.convert(ar.scatter([(f, one)], 1, Q.fprobe), Q.fprobe)).x[0] for f in Fp]
    probe.contacts, probe.nodes = int(gate.size), gate.full_idx
    probe.node_F = [f.x for f in Fp]


def probe_sample_kernel(ar, p: Params, P, Pprev):
    """Once per device sample (hardware: when the port loads a sample): the probe's velocity
    Pdot = (P - P_prev) / k and its bounding box Lo = P - R, Hi = P + R, per dimension."""
    inv_k = ar.const(Q.inv_k, p.probe["inv_k"])
    R = ar.const(Q.probe_R, p.probe["R"])
    Pdot = [ar.mul(ar.sub(P[k], Pprev[k], Q.psample), inv_k, Q.pdot) for k in range(p.dim)]
    Lo = [ar.sub(P[k], R, Q.x) for k in range(p.dim)]
    Hi = [ar.add(P[k], R, Q.x) for k in range(p.dim)]
    return Pdot, Lo, Hi


def _node_flags(p: Params) -> dict:
    """Per-node boolean arrays the node kernel selects on (cached on the Params)."""
    if getattr(p, "_flags", None) is None:
        flags = {"free": p.free}
        for n, (nodes, _, _, _) in enumerate(p.loads):
            member = np.zeros(p.n_nodes, bool)
            member[nodes] = True
            flags[f"load{n}"] = member
        p._flags = flags
    return p._flags


def load_window(p: Params, n: int) -> tuple[int, int]:
    """The steps [first, end) during which load n acts: start <= step dt < end, as the float test says."""
    _, _, start, end = p.loads[n]
    first = lambda t: next(s for s in range(max(int(np.floor(t / p.dt)) - 2, 0), 1 << 62) if s * p.dt >= t)
    a = first(start)
    b = max(first(end), a) if np.isfinite(end) else 1 << 62
    return a, b


def element_kernel(ar, p: Params, Xi, Xj, Ui, Uj, A):
    """One element (per item): returns (fe per dimension, new a or None). Node i receives +fe, node j -fe."""
    D = p.dim
    d = [ar.sub(Xj[k], Xi[k], Q.d) for k in range(D)]
    du = [ar.sub(Uj[k], Ui[k], Q.du) for k in range(D)]
    l2 = ar.sum([ar.mul(dk, dk, Q.l2) for dk in d], Q.l2)
    inv_l = ar.rsqrt(l2, Q.inv_l)
    l = ar.mul(l2, inv_l, Q.l)
    e = [ar.mul(dk, inv_l, Q.e) for dk in d]
    ldot = ar.sum([ar.mul(e[k], du[k], Q.ldot) for k in range(D)], Q.ldot)
    s = ar.sub(ar.mul(A, l, Q.l), ar.param(Q.L, p.L), Q.s)
    k1s = ar.mul(ar.param(Q.k1, p.k1), s, Q.force) if p.k1 is not None else ar.zeros(Q.force, len(p.i))
    newA = None
    if p.fixed_a:
        T = ar.add(k1s, ar.mul(ar.param(Q.c1a, p.c1a), ldot, Q.force), Q.force)
    else:
        c1 = ar.param(Q.c1, p.c1)
        Y = ar.add(k1s, ar.mul(c1, ldot, Q.drive), Q.drive)
        T, wd = _phi(ar, p, Y)
        Wa = ar.mul(ar.sub(ar.const(Q.a, 1.0), A, Q.a), ldot, Q.wdot)     # the damper's rate, Voigt part rigid
        adot = ar.mul(ar.sub(Wa, wd, Q.wdot), inv_l, Q.adot)
        zero = ar.zeros(Q.adot, len(p.i))
        a_min, a_max = ar.param(Q.a, p.a_min), ar.param(Q.a, p.a_max)
        at_lo, at_hi = ar.le(A, a_min), ar.le(a_max, A)
        hi_stop = at_hi & (ar.lt(zero, adot) | at_lo)         # a_min = a_max: the damper is rigid
        lo_stop = at_lo & ar.lt(adot, zero) & ~at_hi
        T_hi = ar.add(k1s, ar.mul(c1, ar.mul(A, ldot, Q.sdot), Q.force), Q.force)
        on_lo = ar.gate(lo_stop)          # Psi only for the elements on the a_min stop
        if not on_lo.empty:
            T = ar.select(lo_stop, on_lo.lift(_psi(ar, p, on_lo.take(Wa), on_lo)), T)
        T = ar.select(hi_stop, T_hi, T)
        adot = ar.select(hi_stop | lo_stop, zero, adot)
        a = ar.add(A, adot, Q.a)
        a = ar.select(ar.le(a, a_min), a_min, a)
        newA = ar.select(ar.le(a_max, a), a_max, a)
    fe = [ar.mul(T, e[k], Q.fe) for k in range(D)]
    return fe, newA


def _odd_piecewise(ar, x, curve, slopes, zero, within=None):
    """An odd curve's inverse (and companions) at x: sign, the linear pieces below / above the table (the
    constants `slopes` = [(lo, hi) per output]), the inverse table between them; the table unit says
    which piece the magnitude lies on. Each linear piece is formed under its gate (nested in `within`,
    the gate of x's items), so a product no item uses neither sets a format nor counts a saturation."""
    neg = ar.lt(x, zero)
    mag = ar.select(neg, ar.neg(x), x)
    below, above, tabs = ar.inverse(mag, curve)
    pieces = [(within.gate(c) if within is not None else ar.gate(c), c) for c in (above, below)]
    out = []
    for q, v, (lo, hi) in zip(curve.outputs, tabs, slopes):
        for (g, cond), (cq, slope) in zip(pieces, (hi, lo)):
            if not g.empty:
                v = ar.select(cond, g.lift(ar.mul(ar.const(cq, slope), g.take(mag), q)), v)
        out.append(ar.select(neg, ar.neg(v), v))
    return out


def _phi(ar, p: Params, Y):
    """(T, w') = (Phi(Y), W(Y)): the element's tension and its damper's rate from the drive Y."""
    if p.damper is None:
        return ar.mul(ar.param(Q.phi_s, p.phi_s), Y, Q.force), ar.mul(ar.param(Q.ic12, p.ic12), Y, Q.wdot)
    law = p.damper
    (t_lo, w_lo), (t_hi, w_hi) = law.slopes(law.c_max), law.slopes(law.c_min)
    slopes = [((Q.phi_lo, t_lo), (Q.phi_hi, t_hi)), ((Q.rate_lo, w_lo), (Q.rate_hi, w_hi))]
    return _odd_piecewise(ar, Y, p.curves["phi"], slopes, ar.zeros(Q.drive, 1))


def _psi(ar, p: Params, W, within):
    """Psi(W): the damper's force at its rate W (the Voigt part on its a_min stop), W the items of the
    gate `within`."""
    if p.damper is None:
        c2 = ar.param(Q.c2, p.c2)
        return ar.mul(within.take(c2) if np.ndim(p.c2) else c2, W, Q.force)
    law = p.damper
    slopes = [((Q.psi_lo, law.c_max), (Q.psi_hi, law.c_min))]
    return _odd_piecewise(ar, W, p.curves["psi"], slopes, ar.zeros(Q.wdot, 1), within)[0]


def node_kernel(ar, p: Params, X, U, F_elem, step_no, flags, probe: ProbeInputs | None = None):
    """One node (per item): forces from elements and pairs (exact sums), floor, probe, loads -> new u and x.

    Returns (new X, new U); with a probe (the scene has one: `probe` gives its ProbeInputs) also
    (gate, F): the nodes inside the probe and, for them, their probe force per dimension (pfe), which each
    node takes exactly and whose sum over nodes is minus the force on the probe."""
    D = p.dim
    terms = [[F_elem[k]] for k in range(D)]
    if p.floor is not None:
        for k, v in floor_kernel(ar, p, X, U):
            terms[k].append(v)
    if (p.probe is None) != (probe is None):
        raise ValueError("node_kernel: the probe's inputs must be given exactly when the scene has a probe")
    if probe is not None:
        gate, Fp = probe_kernel(ar, p, X, U, probe)
        for k, f in enumerate(Fp):
            terms[k].append(gate.expand(f))
    for n, (nodes, force, _, _) in enumerate(p.loads):
        first, end = load_window(p, n)
        on = ar.flag(f"load{n}", flags[f"load{n}"]) & ar.window(step_no, first, end)
        for k in range(D):
            if force[k] is not None:
                terms[k].append(ar.select(on, ar.const(Q.load, float(force[k][0])), ar.zeros(Q.load, 1)))
    F = [ar.sum(terms[k], Q.facc) for k in range(D)]
    free = ar.flag("free", flags["free"])
    zero_u = ar.zeros(Q.u, 1)
    newU, newX = [], []
    for k in range(D):
        if p.inv_mass is not None:
            dv = ar.mul(ar.param(Q.inv_mass, p.inv_mass), ar.convert(F[k], Q.fnode), Q.dv)
        else:
            dv = ar.convert(F[k], Q.dv)
        u = ar.add(U[k], dv, Q.u)
        if p.gravity is not None and p.gravity[k] != 0.0:
            u = ar.add(u, ar.const(Q.g, p.gravity[k]), Q.u)
        u = ar.select(free, u, zero_u)
        newU.append(u)
        newX.append(ar.add(X[k], u, Q.x))
    if probe is not None:
        return newX, newU, (gate, Fp)
    return newX, newU


def probe_kernel(ar, p: Params, X, U, probe: ProbeInputs):
    """The probe's force on one node (MODEL.md 4b): returns (gate, F), the nodes with |x - p| < R and their
    force per dimension (pfe; none when the gate is empty). Inside the probe's bounding box only (x compared
    with the box: no arithmetic for a far node) r = x - p, then |r|^2 < R^2 before the square root."""
    D, pb = p.dim, p.probe
    box = None
    for k in range(D):
        c = ar.lt(probe.Lo[k], X[k]) & ar.lt(X[k], probe.Hi[k])
        box = c if box is None else box & c
    near = ar.gate(box)
    if near.empty:
        return near, []
    r = [ar.sub(near.take(X[k]), near.take(probe.P[k]), Q.pr) for k in range(D)]
    r2 = ar.sum([ar.mul(c, c, Q.pr2) for c in r], Q.pr2)
    touch = near.gate(ar.lt(r2, ar.const(Q.probe_R2, pb["R2"])))
    if touch.empty:
        return touch, []
    r, r2 = [touch.take(c) for c in r], touch.take(r2)
    inv = ar.rsqrt(r2, Q.pinv)
    n = [ar.mul(c, inv, Q.e) for c in r]
    pen = ar.sub(ar.const(Q.probe_R, pb["R"]), ar.mul(r2, inv, Q.pdist), Q.pdist)
    vrel = [ar.sub(touch.take(near.take(U[k])), touch.take(near.take(probe.Pdot[k])), Q.pdu) for k in range(D)]
    vn = ar.sum([ar.mul(vrel[k], n[k], Q.pdu) for k in range(D)], Q.pdu)
    N = ar.sub(ar.mul(ar.const(Q.probe_K, pb["K"]), pen, Q.pforce),
               ar.mul(ar.const(Q.probe_C, pb["C"]), vn, Q.pforce), Q.pforce)
    zero = touch.zeros(Q.pforce)
    N = ar.select(ar.lt(N, zero), zero, N)
    F = [ar.mul(N, n[k], Q.pfe) for k in range(D)]
    if pb["mu"] > 0.0:
        muN = ar.mul(ar.const(Q.mu, pb["mu"]), N, Q.pforce)
        kf = ar.const(Q.probe_kf, pb["kf"])
        if D == 2:
            # slip speed along the tangent (-n_y, n_x); friction -clip(k_f v_t, mu N) on it
            vt = ar.sub(ar.mul(vrel[1], n[0], Q.pdu), ar.mul(vrel[0], n[1], Q.pdu), Q.pdu)
            f = ar.mul(kf, vt, Q.pforce)
            f = ar.select(ar.lt(muN, f), muN, f)
            f = ar.select(ar.lt(f, ar.neg(muN)), ar.neg(muN), f)
            F = [ar.add(F[0], ar.mul(f, n[1], Q.pfe), Q.pfe), ar.sub(F[1], ar.mul(f, n[0], Q.pfe), Q.pfe)]
        else:
            kfu = [ar.mul(kf, ar.sub(vrel[k], ar.mul(vn, n[k], Q.pdu), Q.pdu), Q.pforce) for k in range(3)]
            F = [ar.sub(F[k], fk, Q.pfe)
                 for k, fk in enumerate(_capped_friction(ar, touch, kfu, muN, Q.pfmag2, Q.pfinv, Q.pforce))]
    return touch, F


def _facet_normal(ar, XF):
    """Unit normal of a facet (the golden orientation rule) from its vertices; returns (n, inv_len, edges)."""
    D = len(XF[0])
    if D == 2:
        u = [ar.sub(XF[1][k], XF[0][k], Q.tr) for k in range(2)]
        n2 = ar.sum([ar.mul(c, c, Q.tl2) for c in u], Q.tl2)
        inv = ar.rsqrt(n2, Q.tinv)
        n = [ar.neg(ar.mul(u[1], inv, Q.e)), ar.mul(u[0], inv, Q.e)]
        return n, inv, u
    e1 = [ar.sub(XF[1][k], XF[0][k], Q.tr) for k in range(3)]
    e2 = [ar.sub(XF[2][k], XF[0][k], Q.tr) for k in range(3)]
    c = [ar.sub(ar.mul(e1[(k + 1) % 3], e2[(k + 2) % 3], Q.tl2), ar.mul(e1[(k + 2) % 3], e2[(k + 1) % 3], Q.tl2), Q.tl2)
         for k in range(3)]
    n2 = ar.sum([ar.mul(ck, ck, Q.tl4) for ck in c], Q.tl4)
    inv = ar.rsqrt(n2, Q.tinv2)
    n = [ar.mul(ck, inv, Q.e) for ck in c]
    return n, inv, (e1, e2)


def pair_kernel(ar, p: Params, *nodes):
    """One topology pair (vertex, facet): returns (gate, [(dim, force, role)]), role 0 = the vertex,
    role m = facet vertex m - 1. Only pairs with d <= eps (the gate) act; the forces sum to exactly 0."""
    D = p.dim
    tp = p.topology
    XV, XF = nodes[0], nodes[1:D + 1]
    UV, UF = nodes[D + 1], nodes[D + 2:]
    n, inv, edges = _facet_normal(ar, XF)
    r = [ar.sub(XV[k], XF[0][k], Q.tr) for k in range(D)]
    dist = ar.sum([ar.mul(r[k], n[k], Q.tdist) for k in range(D)], Q.tdist)
    eps = ar.const(Q.eps, tp["eps"])
    gate = ar.gate(ar.le(dist, eps))
    if gate.empty:
        return gate, []
    sub = gate.take
    n, r, dist = [sub(c) for c in n], [sub(c) for c in r], sub(dist)
    UV, UF = [sub(c) for c in UV], [[sub(c) for c in uf] for uf in UF]
    one = ar.const(Q.w, 1.0)
    zero_w = gate.zeros(Q.w)
    if D == 2:
        u = [sub(c) for c in edges]
        inv = sub(inv)
        t = ar.mul(ar.mul(ar.sum([ar.mul(r[k], u[k], Q.tl2) for k in range(2)], Q.tl2), inv, Q.tdist), inv, Q.w)
        t = ar.select(ar.lt(t, zero_w), zero_w, t)
        t = ar.select(ar.lt(one, t), one, t)
        w_rest = [t]
    else:
        e1, e2 = [[sub(c) for c in e] for e in edges]
        inv = sub(inv)
        d11 = ar.sum([ar.mul(c, c, Q.tl2) for c in e1], Q.tl2)
        d22 = ar.sum([ar.mul(c, c, Q.tl2) for c in e2], Q.tl2)
        d12 = ar.sum([ar.mul(e1[k], e2[k], Q.tl2) for k in range(3)], Q.tl2)
        r1 = ar.sum([ar.mul(r[k], e1[k], Q.tl2) for k in range(3)], Q.tl2)
        r2 = ar.sum([ar.mul(r[k], e2[k], Q.tl2) for k in range(3)], Q.tl2)
        inv2 = ar.mul(inv, inv, Q.tinv4)
        w1 = ar.mul(ar.sub(ar.mul(d22, r1, Q.tl4), ar.mul(d12, r2, Q.tl4), Q.tl4), inv2, Q.w)
        w2 = ar.mul(ar.sub(ar.mul(d11, r2, Q.tl4), ar.mul(d12, r1, Q.tl4), Q.tl4), inv2, Q.w)
        w_rest = []
        for w in (w1, w2):
            w = ar.select(ar.lt(w, zero_w), zero_w, w)
            w = ar.select(ar.lt(one, w), one, w)
            w_rest.append(w)
    vrel = _foot_velocity(ar, D, UV, UF, w_rest)
    ddot = ar.sum([ar.mul(vrel[k], n[k], Q.ldot) for k in range(D)], Q.ldot)
    f = ar.sub(ar.mul(ar.const(Q.topo_K, tp["K"]), ar.sub(eps, dist, Q.tdist), Q.force),
               ar.mul(ar.const(Q.topo_C, tp["C"]), ddot, Q.force), Q.force)
    return gate, _split_to_facet(ar, D, [ar.mul(f, n[k], Q.fe) for k in range(D)], w_rest)


def _split_to_facet(ar, D, F, w_rest):
    """Contributions of a pair force F (per dimension): +F to the vertex (role 0), -w_m F to facet vertex m
    (role 1 + m), the first facet vertex taking the remainder so that the pair's forces sum to exactly 0."""
    out = []
    for k in range(D):
        out.append((k, F[k], 0))
        rest_sum = None
        for m, w in enumerate(w_rest, start=1):
            Fm = ar.mul(w, F[k], Q.fe)
            out.append((k, ar.neg(Fm), 1 + m))
            rest_sum = Fm if rest_sum is None else ar.add(rest_sum, Fm, Q.fe)
        out.append((k, ar.neg(ar.sub(F[k], rest_sum, Q.fe)), 1))
    return out


def _foot_velocity(ar, D, UV, UF, w_rest):
    """Velocity of the vertex relative to its foot point: (u_k - u_0) - sum_m w_m (u_m - u_0)."""
    vrel = []
    for k in range(D):
        u0 = UF[0][k]
        v = ar.sub(UV[k], u0, Q.du)
        for m, w in enumerate(w_rest, start=1):
            v = ar.sub(v, ar.mul(w, ar.sub(UF[m][k], u0, Q.du), Q.du), Q.du)
        vrel.append(v)
    return vrel


def collision_kernel(ar, p: Params, *nodes):
    """One collision pair (surface vertex, surface facet): returns (gate, [(dim, force, role)]) like
    pair_kernel. The gate: |d| <= h along the facet's outward normal, then the foot on the facet, tested
    on the weights' numerators (no division before the gate, so far pairs never saturate a weight)."""
    D, co = p.dim, p.collision
    XV, XF = nodes[0], nodes[1:D + 1]
    UV, UF = nodes[D + 1], nodes[D + 2:]
    r = [ar.sub(XV[k], XF[0][k], Q.cr) for k in range(D)]
    if D == 2:
        edge = [ar.sub(XF[1][k], XF[0][k], Q.cr) for k in range(2)]
        n2 = ar.sum([ar.mul(c, c, Q.cl2) for c in edge], Q.cl2)
        inv = ar.rsqrt(n2, Q.cinv)
        n = [ar.mul(edge[1], inv, Q.e), ar.neg(ar.mul(edge[0], inv, Q.e))]     # outward: (u_y, -u_x) / |u|
    else:
        e1 = [ar.sub(XF[1][k], XF[0][k], Q.cr) for k in range(3)]
        e2 = [ar.sub(XF[2][k], XF[0][k], Q.cr) for k in range(3)]
        c = [ar.sub(ar.mul(e1[(k + 1) % 3], e2[(k + 2) % 3], Q.cl2), ar.mul(e1[(k + 2) % 3], e2[(k + 1) % 3], Q.cl2),
                    Q.cl2) for k in range(3)]
        n2 = ar.sum([ar.mul(ck, ck, Q.cl4) for ck in c], Q.cl4)
        inv = ar.rsqrt(n2, Q.cinv2)
        n = [ar.mul(ck, inv, Q.e) for ck in c]
    dist = ar.sum([ar.mul(r[k], n[k], Q.cdist) for k in range(D)], Q.cdist)
    h = ar.const(Q.coll_h, co["h"])
    near = ar.gate(ar.le(dist, h) & ar.le(ar.const(Q.coll_h, -co["h"]), dist))
    if near.empty:
        return near, []
    sub = near.take
    r, n, dist, n2, inv = [sub(v) for v in r], [sub(v) for v in n], sub(dist), sub(n2), sub(inv)
    if D == 2:
        edge = [sub(v) for v in edge]
        proj = ar.sum([ar.mul(r[k], edge[k], Q.cl2) for k in range(2)], Q.cl2)
        foot = near.gate(ar.le(ar.zeros(Q.cl2, 1), proj) & ar.le(proj, n2))
        if foot.empty:
            return foot, []
        t = ar.mul(ar.mul(foot.take(proj), foot.take(inv), Q.cdist), foot.take(inv), Q.w)
        w_rest = [t]
    else:
        e1, e2 = [sub(v) for v in e1], [sub(v) for v in e2]
        dot = lambda a, b: ar.sum([ar.mul(a[k], b[k], Q.cl2) for k in range(3)], Q.cl2)
        d11, d22, d12, r1, r2 = dot(e1, e1), dot(e2, e2), dot(e1, e2), dot(r, e1), dot(r, e2)
        w1n = ar.sub(ar.mul(d22, r1, Q.cl4), ar.mul(d12, r2, Q.cl4), Q.cl4)
        w2n = ar.sub(ar.mul(d11, r2, Q.cl4), ar.mul(d12, r1, Q.cl4), Q.cl4)
        zero4 = ar.zeros(Q.cl4, 1)
        foot = near.gate(ar.le(zero4, w1n) & ar.le(zero4, w2n) & ar.le(ar.sum([w1n, w2n], Q.cl4), n2))
        if foot.empty:
            return foot, []
        inv2 = ar.mul(foot.take(inv), foot.take(inv), Q.cinv4)
        w_rest = [ar.mul(foot.take(wn), inv2, Q.w) for wn in (w1n, w2n)]
    n, dist = [foot.take(v) for v in n], foot.take(dist)
    UV, UF = [foot.take(near.take(v)) for v in UV], [[foot.take(near.take(v)) for v in uf] for uf in UF]
    vrel = _foot_velocity(ar, D, UV, UF, w_rest)
    vn = ar.sum([ar.mul(vrel[k], n[k], Q.ldot) for k in range(D)], Q.ldot)
    N = ar.sub(ar.mul(ar.const(Q.coll_K, co["K"]), ar.sub(h, dist, Q.cdist), Q.force),
               ar.mul(ar.const(Q.coll_C, co["C"]), vn, Q.force), Q.force)
    zero = foot.zeros(Q.force)
    N = ar.select(ar.lt(N, zero), zero, N)
    F = [ar.mul(N, n[k], Q.fe) for k in range(D)]
    if co["mu"] > 0.0:
        muN = ar.mul(ar.const(Q.mu, co["mu"]), N, Q.force)
        kf = ar.const(Q.coll_kf, co["kf"])
        if D == 2:
            # slip speed along the tangent (-n_y, n_x); friction -clip(k_f v_t, mu N) on it
            vt = ar.sub(ar.mul(vrel[1], n[0], Q.ldot), ar.mul(vrel[0], n[1], Q.ldot), Q.ldot)
            f = ar.mul(kf, vt, Q.force)
            f = ar.select(ar.lt(muN, f), muN, f)
            f = ar.select(ar.lt(f, ar.neg(muN)), ar.neg(muN), f)
            F = [ar.add(F[0], ar.mul(f, n[1], Q.fe), Q.fe), ar.sub(F[1], ar.mul(f, n[0], Q.fe), Q.fe)]
        else:
            kfu = [ar.mul(kf, ar.sub(vrel[k], ar.mul(vn, n[k], Q.du), Q.du), Q.force) for k in range(3)]
            F = [ar.sub(F[k], fk, Q.fe) for k, fk in enumerate(_capped_friction(ar, foot, kfu, muN))]
    return foot, _split_to_facet(ar, D, F, w_rest)


def floor_kernel(ar, p: Params, X, U):
    """Floor contact and friction of one node: [(dim, force)], zero where the node is above the floor."""
    D, fl = p.dim, p.floor
    z = D - 1
    h = ar.sub(X[z], ar.const(Q.x, fl["h"]), Q.tdist)
    gate = ar.gate(ar.lt(h, ar.zeros(Q.tdist, 1)))
    if gate.empty:
        return []
    h, uz = gate.take(h), gate.take(U[z])
    N = ar.sub(ar.mul(ar.const(Q.floor_K, fl["K"]), ar.neg(h), Q.force),
               ar.mul(ar.const(Q.floor_C, fl["C"]), uz, Q.force), Q.force)
    zero = gate.zeros(Q.force)
    N = ar.select(ar.lt(N, zero), zero, N)
    out = [(z, gate.expand(N))]
    if fl["mu"] <= 0.0:
        return out
    muN = ar.mul(ar.const(Q.mu, fl["mu"]), N, Q.force)
    kfu = [ar.mul(ar.const(Q.floor_kf, fl["kf"]), gate.take(U[k]), Q.force) for k in range(D - 1)]
    if D == 2:
        f = kfu[0]
        f = ar.select(ar.lt(muN, f), muN, f)
        f = ar.select(ar.lt(f, ar.neg(muN)), ar.neg(muN), f)
        return out + [(0, gate.expand(ar.neg(f)))]
    for k, fk in enumerate(_capped_friction(ar, gate, kfu, muN)):
        out.append((k, gate.expand(ar.neg(fk))))
    return out


def _capped_friction(ar, gate, kfu, muN, q_mag2=Q.fmag2, q_inv=Q.finv, q_force=Q.force):
    """|friction| = min(mu N, |k_f v_t|) along kfu = k_f v_t (a vector, items of `gate`), without a division:
    sticking (|kfu|^2 <= (mu N)^2) gives kfu itself; sliding scales kfu by mu N / |kfu| < 1 (1/sqrt unit).
    The ratio is only formed when below 1, so it never saturates. Returns the force components (to negate).
    The quantities: the floor's (default) or the probe's."""
    mag2 = ar.sum([ar.mul(c, c, q_mag2) for c in kfu], q_mag2)
    sliding = ar.lt(ar.mul(muN, muN, q_mag2), mag2)
    slide = gate.gate(sliding)
    if slide.empty:
        return kfu
    ratio = ar.mul(slide.take(muN), ar.rsqrt(slide.take(mag2), q_inv), Q.w)
    return [ar.select(sliding, slide.lift(ar.mul(slide.take(c), ratio, q_force)), c) for c in kfu]
