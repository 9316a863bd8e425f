"""The haptic probe (MODEL.md section 4b), vectorised over the nodes: a rigid sphere (a disc in 2D) whose
centre p is an input of every step, given by a host (a haptic device) or, in a run without one, by the
scene's design poke.

Each node x_i with d_i = |x_i - p| < R (every node: no surface list) gets the floor's laws along
n_i = (x_i - p) / d_i, with the velocity relative to the probe:

    N_i = max(0, K (R - d_i) - C (v_i - pdot) . n_i)
    F_i = N_i n_i - min(mu N_i, k_f |v_t|) v_t / |v_t|,     v_t = (v_i - pdot) - ((v_i - pdot) . n_i) n_i

and the probe feels minus their sum, the force a device renders. The position is held for k steps (one
device sample: a 1 kHz device at dt = 1e-4 s gives k = 10), with pdot = (p - p_prev) / (k dt) held too;
the force returned for a sample is that of its last step.

Without a host, a scene's probe follows its design poke: straight down (-y in 2D, -z in 3D) from its
initial position by `depth` at constant speed and back up, over `poke_time` seconds, then it stays at
the initial position; sample s holds the position of time s k dt. That poke is also what the fixed-point
formats are derived for (the range analysis runs the scene).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .contact import friction


@dataclass
class Probe:
    """A scene's probe: radius R (m), penalty K (N/m) and C (N s/m), Coulomb friction mu with its
    regularisation k_f (N s/m), k steps per device sample, initial centre `position` (m) and the design
    poke (`depth` m straight down and back over `poke_time` s)."""
    radius: float
    K: float
    C: float
    mu: float
    k_f: float
    k: int
    position: np.ndarray
    depth: float = 0.0
    poke_time: float = 1.0

    @property
    def dim(self) -> int:
        return len(self.position)

    @property
    def down(self) -> np.ndarray:
        """The direction of the design poke: -y in 2D, -z in 3D."""
        e = np.zeros(self.dim)
        e[-1] = -1.0
        return e

    def design_offset(self, t):
        """Depth below the initial position of the design poke at time(s) t: a triangle, down at constant
        speed to `depth` at poke_time / 2, back up by poke_time, zero after."""
        u = np.asarray(t, float) / self.poke_time
        return self.depth * np.clip(np.minimum(2.0 * u, 2.0 * (1.0 - u)), 0.0, None)

    def design_position(self, sample: int, dt: float) -> np.ndarray:
        """The centre the design poke holds during device sample `sample` (its steps sample k .. sample k +
        k - 1): the poke's position at the sample's first step."""
        return self.position + float(self.design_offset(sample * self.k * dt)) * self.down

    def design_path(self, n_samples: int, dt: float) -> np.ndarray:
        """(S, D) positions of the design poke, one row per device sample."""
        off = self.design_offset(np.arange(n_samples) * self.k * dt)
        return self.position[None, :] + off[:, None] * self.down[None, :]

    def velocity(self, p, p_prev, dt: float) -> np.ndarray:
        """pdot = (p - p_prev) / (k dt), held with p."""
        return (np.asarray(p, float) - np.asarray(p_prev, float)) / (self.k * dt)

    def forces(self, x, v, p, pdot, out) -> tuple[np.ndarray, np.ndarray]:
        """Add the probe's force on every node it touches to out (N, D); return (the touching nodes, their
        forces (n, D)). x, v: (N, D)."""
        R = self.radius
        r = x - p
        near = np.flatnonzero(np.all(np.abs(r) < R, axis=1))      # the box first: cheap, and exact
        r = r[near]
        d2 = np.einsum("ij,ij->i", r, r)
        inside = d2 < R * R
        nodes, r, d2 = near[inside], r[inside], d2[inside]
        if nodes.size == 0:
            return nodes, np.zeros((0, x.shape[1]))
        d = np.sqrt(d2)
        n = r / d[:, None]
        vrel = v[nodes] - pdot
        vn = np.einsum("ij,ij->i", vrel, n)
        N = np.maximum(0.0, self.K * (R - d) - self.C * vn)
        F = N[:, None] * n
        if self.mu > 0.0:
            F += friction(vrel - vn[:, None] * n, N, self.mu, self.k_f)
        out[nodes] += F
        return nodes, F

    def energy(self, x, p) -> float:
        """Penalty energy K (R - d)^2 / 2 of the nodes inside the probe."""
        d = np.linalg.norm(np.asarray(x, float) - p, axis=1)
        pen = self.radius - d[d < self.radius]
        return 0.5 * self.K * float(pen @ pen)


@dataclass
class ProbeState:
    """The probe's inputs held for the current device sample (p, pdot) and its outputs of the last step:
    the force on the probe (minus the sum of its node forces), how many nodes touch it, and which ones with
    their forces. `driven`: a host sets p (`hold`); otherwise the scene's design poke does, at every sample
    boundary."""
    p: np.ndarray
    pdot: np.ndarray
    force: np.ndarray
    contacts: int = 0
    driven: bool = False
    nodes: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    node_forces: np.ndarray = None

    @classmethod
    def initial(cls, probe: Probe) -> "ProbeState":
        D = probe.dim
        return cls(probe.position.astype(float).copy(), np.zeros(D), np.zeros(D),
                   node_forces=np.zeros((0, D)))

    def copy(self) -> "ProbeState":
        return ProbeState(self.p.copy(), self.pdot.copy(), self.force.copy(), self.contacts, self.driven,
                          self.nodes.copy(), self.node_forces.copy())

    def hold(self, probe: Probe, p, dt: float) -> None:
        """A device sample: hold p for the next k steps, with pdot = (p - p_prev) / (k dt)."""
        p = np.asarray(p, float).reshape(probe.dim)
        self.pdot = probe.velocity(p, self.p, dt)
        self.p = p.copy()

    def record(self, nodes, node_forces) -> None:
        self.nodes, self.node_forces = nodes, node_forces
        self.contacts = int(nodes.size)
        self.force = -node_forces.sum(0)


def design_sample(probe: Probe, pst: ProbeState, step: int, dt: float) -> None:
    """At the first step of a device sample, move an undriven probe to its design poke's position."""
    if not pst.driven and step % probe.k == 0:
        pst.hold(probe, probe.design_position(step // probe.k, dt), dt)


def max_force(probe: Probe, x0: np.ndarray) -> float:
    """A scale of the largest force the probe can exert: K R on each of the most nodes the probe can hold at
    rest spacing (the most nodes within R of any node)."""
    from scipy.spatial import cKDTree
    tree = cKDTree(x0)
    counts = tree.query_ball_point(x0, probe.radius, return_length=True)
    return probe.K * probe.radius * float(max(1, int(np.max(counts)) if len(counts) else 1))

