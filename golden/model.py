"""The float64 golden model: one symplectic Euler step over the whole system (MODEL.md section 5).

All forces come from the state at the start of the step:
    F = element forces + topology preservation + floor + collisions + loads
    v <- v + dt (F / m + g)   (pinned nodes: v = 0)
    x <- x + dt v
    a <- clip(a + dt adot, a_min, a_max)
Everything is vectorised over elements, nodes and contact pairs; no Python loop inside a step
except over the (few) load entries and the D axes of a scatter.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from .contact import Collision, Floor
from .elements import ElementParams, element_forces
from .topology import topology_forces


class SimulationDiverged(RuntimeError):
    """The run blew up (non-finite state); the message says when and where."""


@dataclass
class Load:
    nodes: np.ndarray        # (n,) node indices
    force: np.ndarray        # (D,) force on each selected node, N
    start: float
    end: float


@dataclass
class Topology:
    pairs: np.ndarray        # (P, D + 1): vertex, then its opposite facet
    K: float
    C: float
    eps: float


@dataclass
class System:
    """A compiled scene: every array the step needs, in SI units."""
    name: str
    dim: int
    x0: np.ndarray           # (N, D)
    v0: np.ndarray           # (N, D)
    mass: np.ndarray         # (N,)
    pinned: np.ndarray       # (N,) bool
    edges: np.ndarray        # (E, 2) start, end
    a0: np.ndarray           # (E,)
    elem: ElementParams
    cells: np.ndarray        # (C, D + 1)
    node_object: np.ndarray  # (N,)
    cell_object: np.ndarray  # (C,)
    object_names: list
    gravity: np.ndarray      # (D,)
    dt: float
    n_steps: int
    every: int
    floor: Floor | None = None
    topology: Topology | None = None
    collision: Collision | None = None
    loads: list = field(default_factory=list)
    materials: list = field(default_factory=list)   # per object: the resolved material table
    formats: dict = field(default_factory=dict)     # [formats] overrides for the bit-true model / hardware

    @property
    def n_nodes(self) -> int:
        return len(self.x0)

    @property
    def n_elements(self) -> int:
        return len(self.edges)


def component_major(arr: np.ndarray) -> np.ndarray:
    """The same (N, D) array, stored as a contiguous (D, N) buffer (fast per-axis gathers)."""
    return np.ascontiguousarray(arr.T).T


@dataclass
class State:
    x: np.ndarray            # (N, D), component-major storage
    v: np.ndarray
    a: np.ndarray            # (E,)
    step: int = 0

    @classmethod
    def initial(cls, sys: System) -> "State":
        return cls(component_major(sys.x0), component_major(sys.v0), sys.a0.copy())

    def copy(self) -> "State":
        """An independent state (component_major alone returns its argument when it is already so stored)."""
        return State(component_major(self.x.copy()), component_major(self.v.copy()), self.a.copy(), self.step)


class Golden:
    """Steps a System in float64."""

    def __init__(self, sys: System):
        import scipy.sparse as sp
        self.sys = sys
        self.i = np.ascontiguousarray(sys.edges[:, 0])
        self.j = np.ascontiguousarray(sys.edges[:, 1])
        N, E = sys.n_nodes, sys.n_elements
        # scatter of +T e to start nodes and -T e to end nodes as one sparse product per axis
        self._scatter = sp.csr_matrix(
            (np.concatenate([np.ones(E), -np.ones(E)]),
             (np.concatenate([self.i, self.j]), np.concatenate([np.arange(E), np.arange(E)]))),
            shape=(N, E))
        self._inv_m_dt = np.where(sys.pinned, 0.0, sys.dt / sys.mass)
        self._free = (~sys.pinned).astype(float)
        self._g_dt = sys.gravity * sys.dt
        self._has_extra = bool(sys.floor or sys.topology or sys.collision or sys.loads)

    def forces(self, st: State, t: float):
        """Total force on every node as a component-major (N, D) array, and the elements' (T, adot)."""
        sys = self.sys
        if not st.x.T.flags.c_contiguous:
            st.x, st.v = component_major(st.x), component_major(st.v)
        T, T_l, d, adot = element_forces(st.x.T, st.v.T, st.a, self.i, self.j, sys.elem)
        F = np.stack([self._scatter @ (T_l * dk) for dk in d])      # (D, N)
        F = F.T
        if self._has_extra:
            if sys.topology is not None:
                tp = sys.topology
                topology_forces(st.x, st.v, tp.pairs, tp.K, tp.C, tp.eps, F)
            if sys.floor is not None:
                sys.floor.forces(st.x, st.v, F)
            if sys.collision is not None:
                sys.collision.forces(st.x, st.v, F)
            for ld in sys.loads:
                if ld.start <= t < ld.end:
                    F[ld.nodes] += ld.force
        return F, T, adot

    def step(self, st: State) -> None:
        sys = self.sys
        dt = sys.dt
        F, T, adot = self.forces(st, st.step * dt)
        vt, xt, Ft = st.v.T, st.x.T, F.T
        for k in range(sys.dim):
            vt[k] += Ft[k] * self._inv_m_dt
            if self._g_dt[k] != 0.0:
                vt[k] += self._g_dt[k]
            vt[k] *= self._free
            xt[k] += vt[k] * dt
        if not sys.elem.fixed_a:
            st.a += adot * dt
            np.clip(st.a, sys.elem.a_min, sys.elem.a_max, out=st.a)
        st.step += 1


@dataclass
class Run:
    """Frames of a run, in SI units."""
    t: np.ndarray            # (F,)
    x: np.ndarray            # (F, N, D)
    v: np.ndarray
    a: np.ndarray            # (F, E)
    wall_seconds: float = 0.0


def check_finite(sys: System, x, v, a, step: int) -> None:
    if not (np.isfinite(x).all() and np.isfinite(v).all() and np.isfinite(a).all()):
        bad = np.flatnonzero(~np.isfinite(x).all(1) | ~np.isfinite(v).all(1))
        where = f" (node {bad[0]})" if bad.size else ""
        raise SimulationDiverged(
            f"scene '{sys.name}' diverged at step {step} (t = {step * sys.dt:.6g} s){where}: "
            f"the state is no longer finite; reduce dt (now {sys.dt:g} s) or stiffen less")


def frame_steps(n_steps: int, every: int) -> np.ndarray:
    """Step numbers at which frames are recorded: 0, every, 2 every, ..., and always the last."""
    s = np.arange(0, n_steps + 1, every)
    if s[-1] != n_steps:
        s = np.append(s, n_steps)
    return s


def simulate(sys: System, steps: int | None = None, every: int | None = None,
             progress: bool = False, stepper=None) -> Run:
    """Run sys for `steps` steps recording every `every`-th state. `stepper` defaults to Golden."""
    steps = sys.n_steps if steps is None else int(steps)
    every = max(1, sys.every if every is None else int(every))
    stepper = stepper or Golden(sys)
    st = stepper.initial_state() if hasattr(stepper, "initial_state") else State.initial(sys)
    at = frame_steps(steps, every)
    F = len(at)
    xs = np.empty((F,) + sys.x0.shape)
    vs = np.empty_like(xs)
    as_ = np.empty((F, sys.n_elements))
    from .stability import EnergyWatch      # divergence watchdog: non-finite or exploding energy
    watch = EnergyWatch(sys)
    bar = _progress(steps, sys.name) if progress else None
    t0 = time.perf_counter()
    for f, target in enumerate(at):
        if hasattr(stepper, "advance"):           # backends that run many steps at once (hardware)
            n = target - st.step
            if n > 0:
                stepper.advance(st, n)
                if bar is not None:
                    bar.update(n)
        while st.step < target:
            stepper.step(st)
            if bar is not None and st.step % 256 == 0:
                bar.update(256)
        x, v, a = stepper.frame(st) if hasattr(stepper, "frame") else (st.x, st.v, st.a)
        xs[f], vs[f], as_[f] = x, v, a
        check_finite(sys, xs[f], vs[f], as_[f], st.step)
        watch.check(_Frame(xs[f], vs[f], as_[f], st.step))
    if bar is not None:
        bar.close()
    return Run(at * sys.dt, xs, vs, as_, time.perf_counter() - t0)


@dataclass
class _Frame:
    x: np.ndarray
    v: np.ndarray
    a: np.ndarray
    step: int


def _progress(total: int, name: str):
    from tqdm import tqdm
    # shown only when the run takes longer than a couple of seconds
    return tqdm(total=total, desc=name, unit="step", delay=2.0, mininterval=0.5, leave=False)
