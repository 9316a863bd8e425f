"""Divergence watchdog: every run is checked once per recorded frame, so no run ends in a silently wrong
result. `EnergyWatch(system).check(frame)` raises SimulationDiverged when the state is not finite, a node
is further than BOX x the scene size from its centre, or the mechanical energy (kinetic + k1 s^2 / 2 +
penalty) is above GROWTH x the work bound (initial energy + gravity, loads and the probe acting over the
scene size); the message names the step, the time, the reason and the predicted dt limit (golden/stability.py).
`DivergenceTest` is the same decision without raising (the stability trials, golden/measure.py)."""
from __future__ import annotations

import math

import numpy as np

from .errors import SimulationDiverged
from .stability import predict
from .system import System

GROWTH = 1e3          # energy above GROWTH x the work bound counts as divergence
BOX = 1e3             # positions further than BOX x the scene size from its centre: divergence


def scene_size(system: System) -> float:
    ext = float(np.max(np.ptp(system.x0, axis=0))) if system.n_nodes > 1 else 0.0
    if system.floor is not None:
        ext = max(ext, float(np.max(system.x0[:, -1]) - system.floor.height))
    return ext if ext > 0 else 1.0


def mechanical_energy(system: System, x, v, a, probe_p=None) -> float:
    """Kinetic + element spring energy k1 s^2 / 2 + penalty energy (floor, topology, collision, the probe at
    probe_p, by default at its initial position)."""
    x = np.asarray(x, float)
    v = np.asarray(v, float)
    free = ~system.pinned
    E = 0.5 * float(np.sum(system.mass[free] * np.einsum("ij,ij->i", v[free], v[free])))
    d = x[system.edges[:, 1]] - x[system.edges[:, 0]]
    l = np.sqrt(np.einsum("ij,ij->i", d, d))
    s = a * l - system.elem.L
    E += 0.5 * float(np.sum(system.elem.k1 * s * s))
    if system.floor is not None:
        h = x[:, -1] - system.floor.height
        pen = h[h < 0]
        E += 0.5 * system.floor.K * float(pen @ pen)
    if system.topology is not None and len(system.topology.pairs):
        from .topology import facet_frame
        tp = system.topology
        xf = x[tp.pairs[:, 1:]]
        n = facet_frame(xf)
        dd = np.einsum("ij,ij->i", x[tp.pairs[:, 0]] - xf[:, 0], n) - tp.eps
        pen = dd[dd < 0]
        E += 0.5 * tp.K * float(pen @ pen)
    if system.collision is not None and len(system.collision.facets):
        E += _collision_energy(system.collision, x)
    if system.probe is not None:
        E += system.probe.energy(x, system.probe.position if probe_p is None else probe_p)
    return E


def _collision_energy(col, x) -> float:
    """Penalty energy K (h - d)^2 / 2 of the vertex-facet contacts the collision forces would use."""
    from .topology import facet_frame, foot_weights
    vi, fi = col.candidates(x)
    node, fn = col.vertices[vi], col.facets[fi]
    keep = ~col._excluded(node, fn)
    node, fn = node[keep], fn[keep]
    if node.size == 0:
        return 0.0
    xf = x[fn]
    n = -facet_frame(xf) if x.shape[1] == 2 else facet_frame(xf)
    d = np.einsum("ij,ij->i", x[node] - xf[:, 0], n)
    near = np.abs(d) <= col.threshold
    if not near.any():
        return 0.0
    w = foot_weights(x[node[near]], xf[near], n[near])
    on = np.all(w >= 0.0, axis=1)
    pen = col.threshold - d[near][on]
    return 0.5 * col.K * float(pen @ pen)


def work_bound(system: System) -> float:
    """An upper scale of the energy the scene can legitimately hold: initial energy plus the work of
    gravity, of the loads and of the probe (golden/probe.py max_force) over the scene size."""
    size = scene_size(system)
    free = ~system.pinned
    W = float(np.linalg.norm(system.gravity)) * float(np.sum(system.mass[free])) * size
    for ld in system.loads:
        W += float(np.linalg.norm(ld.force)) * len(ld.nodes) * size
    if system.probe is not None:
        from .probe import max_force
        W += max_force(system.probe, system.x0) * size
    return W + mechanical_energy(system, system.x0, system.v0, system.a0)


class DivergenceTest:
    """Decides from frames whether a run diverged: non-finite state, a node further than BOX x the scene
    size from the scene's centre, or mechanical energy above GROWTH x the work bound (initial energy plus
    what gravity and the loads can put in over the scene size, see work_bound). The bound does not come
    from the run itself (say its first 10 %): a run unstable from its first steps would raise it with it."""

    def __init__(self, system: System, extra_energy: float = 0.0):
        self.system = system
        self.size = scene_size(system)
        self.centre = 0.5 * (system.x0.min(0) + system.x0.max(0))
        self.reference = max(work_bound(system) + extra_energy, 1e-300)
        self.last_energy = 0.0

    def why(self, x, v, a, step: int = 0, probe_p=None) -> str | None:
        """None while the run is sane, else a short reason (probe_p: where the probe is, if it moved)."""
        if not (np.isfinite(x).all() and np.isfinite(v).all() and np.isfinite(a).all()):
            bad = np.flatnonzero(~np.isfinite(np.asarray(x)).all(1) | ~np.isfinite(np.asarray(v)).all(1))
            return "the state is no longer finite" + (f" (node {bad[0]})" if bad.size else "")
        far = float(np.max(np.abs(np.asarray(x) - self.centre)))
        if far > BOX * self.size:
            return f"a node is {far:.3g} m from the scene centre ({BOX:g} x the scene size {self.size:.3g} m)"
        with np.errstate(over="ignore", invalid="ignore"):
            E = mechanical_energy(self.system, x, v, a, probe_p)
        self.last_energy = E
        if not math.isfinite(E):
            return "the mechanical energy is no longer finite"
        if E > GROWTH * self.reference:
            return (f"the mechanical energy {E:.3g} J is {E / self.reference:.3g} x the work bound "
                    f"{self.reference:.3g} J")
        return None


class EnergyWatch:
    """Divergence watchdog of a run; call check(frame) once per output frame (any object with x, v, a in SI
    units and step; cheap: one pass over elements, penalty pairs and nodes). Raises SimulationDiverged
    with the step, time, reason and the predicted dt limit."""

    def __init__(self, system: System):
        self.system = system
        self.test = DivergenceTest(system)
        self._pred = None

    def prediction(self) -> dict:
        if self._pred is None:
            self._pred = predict(self.system)
        return self._pred

    def check(self, state, probe_p=None) -> None:
        why = self.test.why(state.x, state.v, state.a, state.step, probe_p)
        if why is None:
            return
        system = self.system
        p = self.prediction()
        raise SimulationDiverged(
            f"scene '{system.name}' diverged at step {state.step} (t = {state.step * system.dt:.6g} s): {why}; "
            f"reduce dt (now {system.dt:g} s) below the predicted limit {p['dt_pred']:.4g} s "
            f"(limited by {p['limiting']})")
