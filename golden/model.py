"""The float64 golden model: one symplectic Euler step over the whole system (MODEL.md section 5), and the
run loop every backend shares.

All forces come from the state at the start of the step:
    F = element forces + topology preservation + floor + collisions + probe + loads
    v <- v + dt (F / m + g)   (pinned nodes: v = 0)
    x <- x + dt v
    a <- clip(a + dt adot, a_min, a_max)
Everything is vectorised over elements, nodes and contact pairs; no Python loop inside a step
except over the (few) load entries and the D axes of a scatter.

`Stepper` is the one integrator interface (as warp's `sim/integrator.py`): golden, the cpu backend
(sim/cpu.py), the bit-true model (hw/bittrue.py) and the simulated hardware (sim/hwsim.py) implement it,
and `simulate` runs any of them, recording frames and watching for divergence.
"""
from __future__ import annotations

import time
from abc import ABC, abstractmethod

import numpy as np

from .elements import element_forces
from .errors import RheoError
from .probe import design_sample
from .system import Run, State, System, component_major, frame_steps
from .topology import topology_forces
from .watchdog import EnergyWatch


class Stepper(ABC):
    """Steps one System's state. `initial_state()` gives the state at step 0 (any object with a `step`
    counter), `step(st)` advances it one step in place, `advance(st, n)` n steps (backends that run many
    steps in one call override it), `frame(st)` returns (x, v, a) in SI units, and `record(st)` the extra
    per-frame arrays a backend adds to its run file (raw fixed-point words, saturation counts)."""

    system: System
    takes_probe: bool = False     # implements hold_probe / probe_reading (and steps a scene's probe)

    @abstractmethod
    def initial_state(self):
        """The state at step 0."""

    @abstractmethod
    def step(self, st) -> None:
        """One step, in place."""

    def advance(self, st, n: int, progress=None) -> None:
        """n steps, in place; `progress(k)` is told of every k steps done."""
        for _ in range(n):
            self.step(st)
            if progress is not None:
                progress(1)

    def frame(self, st):
        """(x, v, a) in SI units."""
        return st.x, st.v, st.a

    def record(self, st) -> dict:
        """Extra arrays of this frame for the run file (none for float backends)."""
        return {}

    def run_info(self) -> dict:
        """Run-file metadata of this backend (none for float backends)."""
        return {}

    # ---- the haptic probe (MODEL.md 4b): a host holds p for the next k steps, then reads the force
    def hold_probe(self, st, p) -> None:
        """A device sample: p (D,) in metres, held for the next k steps with pdot = (p - p_prev) / (k dt);
        from now on a host drives the probe (no design poke)."""
        raise RheoError(f"the {type(self).__name__} backend cannot take a probe yet")

    def probe_reading(self, st) -> tuple:
        """(force on the probe in the last step (D,) in newtons, nodes touching it)."""
        raise RheoError(f"the {type(self).__name__} backend cannot take a probe yet")

    def probe_position(self, st):
        """Where the probe is held now (D,) in metres; None without a probe."""
        return None

    def probe_raw(self, st):
        """The force on the probe as the raw words a fixed-point backend computes it in; None in float."""
        return None

    def close(self) -> None:
        """Release what the backend holds (a simulator); nothing for most."""


class Golden(Stepper):
    """Steps a System in float64."""

    takes_probe = True

    def __init__(self, system: System):
        import scipy.sparse as sp
        self.system = system
        self.i = np.ascontiguousarray(system.edges[:, 0])
        self.j = np.ascontiguousarray(system.edges[:, 1])
        N, E = system.n_nodes, system.n_elements
        # scatter of +T e to start nodes and -T e to end nodes as one sparse product per axis
        self._scatter = sp.csr_matrix(
            (np.concatenate([np.ones(E), -np.ones(E)]),
             (np.concatenate([self.i, self.j]), np.concatenate([np.arange(E), np.arange(E)]))),
            shape=(N, E))
        self._inv_m_dt = np.where(system.pinned, 0.0, system.dt / system.mass)
        self._free = (~system.pinned).astype(float)
        self._g_dt = system.gravity * system.dt
        self._has_extra = bool(system.floor or system.topology or system.collision or system.loads)

    def forces(self, st: State, t: float):
        """Total force on every node as a component-major (N, D) array, and the elements' (T, adot)."""
        system = self.system
        if not st.x.T.flags.c_contiguous:
            st.x, st.v = component_major(st.x), component_major(st.v)
        T, T_l, d, adot = element_forces(st.x.T, st.v.T, st.a, self.i, self.j, system.elem)
        F = np.stack([self._scatter @ (T_l * dk) for dk in d])      # (D, N)
        F = F.T
        if self._has_extra:
            if system.topology is not None:
                tp = system.topology
                topology_forces(st.x, st.v, tp.pairs, tp.K, tp.C, tp.eps, F)
            if system.floor is not None:
                system.floor.forces(st.x, st.v, F)
            if system.collision is not None:
                system.collision.forces(st.x, st.v, F)
            for ld in system.loads:
                if ld.start <= t < ld.end:
                    F[ld.nodes] += ld.force
        if system.probe is not None:
            pst = st.probe
            pst.record(*system.probe.forces(st.x, st.v, pst.p, pst.pdot, F))
        return F, T, adot

    def initial_state(self) -> State:
        return State.initial(self.system)

    def hold_probe(self, st: State, p) -> None:
        st.probe.driven = True
        st.probe.hold(self.system.probe, p, self.system.dt)

    def probe_reading(self, st: State) -> tuple:
        return st.probe.force.copy(), st.probe.contacts

    def probe_position(self, st: State):
        return None if st.probe is None else st.probe.p.copy()

    def step(self, st: State) -> None:
        system = self.system
        dt = system.dt
        if system.probe is not None:
            design_sample(system.probe, st.probe, st.step, dt)
        F, T, adot = self.forces(st, st.step * dt)
        vt, xt, Ft = st.v.T, st.x.T, F.T
        for k in range(system.dim):
            vt[k] += Ft[k] * self._inv_m_dt
            if self._g_dt[k] != 0.0:
                vt[k] += self._g_dt[k]
            vt[k] *= self._free
            xt[k] += vt[k] * dt
        if not system.elem.fixed_a:
            st.a += adot * dt
            np.clip(st.a, system.elem.a_min, system.elem.a_max, out=st.a)
        st.step += 1


def simulate(system: System, steps: int | None = None, every: int | None = None,
             progress: bool = False, stepper: Stepper | None = None) -> Run:
    """Run `system` for `steps` steps recording every `every`-th state. `stepper` defaults to Golden. Every
    frame is checked by the divergence watchdog (golden/watchdog.py)."""
    steps = system.n_steps if steps is None else int(steps)
    every = max(1, system.every if every is None else int(every))
    stepper = stepper or Golden(system)
    st = stepper.initial_state()
    at = frame_steps(steps, every)
    frames = FrameRecorder(system, stepper, len(at))
    bar = _progress(steps, system.name) if progress else None
    tick = bar.update if bar is not None else None
    t0 = time.perf_counter()
    for target in at:
        if target > st.step:
            stepper.advance(st, target - st.step, tick)
        frames.add(st)
    if bar is not None:
        bar.close()
    return frames.run(at * system.dt, time.perf_counter() - t0)


class FrameRecorder:
    """Records the frames of a run as a stepper presents them (SI frame, extra per-frame arrays), each
    checked by the divergence watchdog; also for states a simulated core computed in one go."""

    def __init__(self, system: System, stepper: Stepper, n_frames: int):
        self.system, self.stepper = system, stepper
        self.x = np.empty((n_frames,) + system.x0.shape)
        self.v = np.empty_like(self.x)
        self.a = np.empty((n_frames, system.n_elements))
        self.raw: dict = {}
        self.n = 0
        self.watch = EnergyWatch(system)

    def add(self, st) -> None:
        f = self.n
        self.x[f], self.v[f], self.a[f] = self.stepper.frame(st)
        self.watch.check(State(self.x[f], self.v[f], self.a[f], st.step), self.stepper.probe_position(st))
        for k, val in self.stepper.record(st).items():
            self.raw.setdefault(k, []).append(val)
        self.n += 1

    def run(self, t: np.ndarray, wall_seconds: float) -> Run:
        return Run(t, self.x, self.v, self.a, wall_seconds, raw={k: np.asarray(v) for k, v in self.raw.items()},
                   info=self.stepper.run_info())


def _progress(total: int, name: str):
    from tqdm import tqdm
    # shown only when the run takes longer than a couple of seconds
    return tqdm(total=total, desc=name, unit="step", delay=2.0, mininterval=0.5, leave=False)
