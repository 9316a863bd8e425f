"""The measured largest stable dt (`rheo stability --measure`): bisection on dt of real runs.

measure(system) -> dict: the real limit, by bisection on dt of real runs of golden.model.Golden or of
another model (the bit-true model, hw/stability_fixed.py; the cpu backend, sim/cpu.py), each trial judged
by the divergence test (golden/watchdog.py) and, where the scene is driven, against a reference run at a
safely small dt. See `measure` and `trial`.
"""
from __future__ import annotations

import dataclasses
import math
import time

import numpy as np

from .errors import SimulationDiverged, StabilityError
from .model import Golden
from .stability import predict
from .system import State, System
from .watchdog import DivergenceTest, mechanical_energy, scene_size

MAX_STEPS = 20_000    # default cap on the steps of one measuring trial
PERTURB = 1e-6        # initial random displacement of the free nodes in measuring runs, x scene size
LOCAL = 10.0          # a trial is unstable when its energy exceeds LOCAL x the reference run near that time
FLOOR = 1e-3          # ... plus FLOOR x the peak energy of the reference run


def with_dt(system: System, dt: float, steps: int | None = None) -> System:
    """The same scene with another dt (and n_steps = duration / dt, or `steps`)."""
    duration = system.n_steps * system.dt
    n = int(steps) if steps is not None else max(1, int(math.ceil(duration / dt - 1e-9)))
    return dataclasses.replace(system, dt=float(dt), n_steps=n, every=max(1, n // 200))


@dataclasses.dataclass
class Reference:
    """Energy history of a run at a safely small dt: the yardstick of the trials."""
    t: np.ndarray
    E: np.ndarray
    dt: float
    window: float            # half width of the time window of the local maximum

    @property
    def peak(self) -> float:
        return float(self.E.max())

    def allowed(self, t: float) -> float:
        """Energy a stable trial may have at time t."""
        if t > self.t[-1] + self.window:
            return LOCAL * self.peak
        lo, hi = np.searchsorted(self.t, [t - self.window, t + self.window])
        seg = self.E[max(0, lo - 1):min(len(self.E), hi + 1)]
        return LOCAL * float(seg.max()) + FLOOR * self.peak


def _start(system: System, dt: float, n: int, seed: int, perturb: float):
    """The scene at dt for n steps and its initial state, free nodes displaced by perturb x scene size
    (random, fixed seed) so that every mode is seeded: a scene at rest in an exact equilibrium would
    otherwise never show an unstable mode."""
    s = with_dt(system, dt, n)
    st = State.initial(s)
    rng = np.random.default_rng(seed)
    free = ~s.pinned
    st.x[free] += perturb * scene_size(s) * rng.standard_normal((int(free.sum()), s.dim))
    return s, st


def _run(system: System, dt: float, n: int, check, check_every: int, seed: int, perturb: float, model=None):
    """Step the scene; every check_every steps ask the DivergenceTest, then check(t, energy); stop at the
    first reason. Returns (reason or None, steps run).

    model: None steps golden.model.Golden; else model(scene at dt, perturbed start State) returns another
    golden.model.Stepper starting there, e.g. the bit-true model (hw/stability_fixed.py); a
    SimulationDiverged it raises (runaway saturations, seen when a frame is recorded) ends the run as
    unstable."""
    s, st = _start(system, dt, n, seed, perturb)
    test = DivergenceTest(s, extra_energy=mechanical_energy(s, st.x, st.v, st.a,
                                                           None if st.probe is None else st.probe.p))
    g = Golden(s) if model is None else model(s, st)
    if model is not None:
        st = g.initial_state()
    with np.errstate(over="ignore", invalid="ignore"):
        while st.step < n:
            try:
                g.advance(st, min(n, st.step + check_every) - st.step)
                x, v, a = g.frame(st)
                g.record(st)
            except SimulationDiverged as exc:          # only other models raise (golden steps never do)
                return f"step {st.step}: {exc}", st.step
            why = test.why(x, v, a, st.step, g.probe_position(st)) or check(st.step * dt, test.last_energy)
            if why is not None:
                return f"step {st.step}: {why}", st.step
    return None, n


def reference(system: System, dt: float, t_end: float, check_every: int = 25, seed: int = 0,
              perturb: float = PERTURB, model=None) -> Reference:
    """Energy history of the scene at dt (expected stable) up to t_end (of another model: see _run)."""
    n = max(1, int(math.ceil(t_end / dt - 1e-9)))
    ts, Es = [], []

    def record(t, E):
        ts.append(t)
        Es.append(E)

    why, _ = _run(system, dt, n, record, check_every, seed, perturb, model)
    if why is not None:
        raise StabilityError(f"scene '{system.name}': the reference run at dt = {dt:.4g} s is unstable ({why})")
    return Reference(np.array(ts), np.array(Es), dt, max(0.02 * t_end, 4 * check_every * dt))


def trial(system: System, dt: float, ref: Reference | None = None, steps: int | None = None,
          max_steps: int = MAX_STEPS, check_every: int = 25, seed: int = 0, perturb: float = PERTURB,
          model=None):
    """Run the scene at dt; returns (stable, reason or None, steps run).

    Unstable: the DivergenceTest fires (non-finite, out of the box, energy > GROWTH x work bound), or,
    with a reference run, the mechanical energy exceeds LOCAL x the reference's largest energy within
    +- its window around the same time, plus FLOOR x the reference's peak. The local test catches what
    a divergence test misses: an unstable mode that a nonlinearity bounds instead of letting it blow up,
    e.g. a viscoelastic mesh just above its limit saturates geometrically at m/s speeds, and friction
    above 2 m / k_f chatters with its force capped at mu N."""
    duration = system.n_steps * system.dt
    n = int(steps) if steps is not None else min(max_steps, max(1, int(math.ceil(duration / dt - 1e-9))))

    def check(t, E):
        if ref is None:
            return None
        allowed = ref.allowed(t)
        if E > allowed:
            return (f"the mechanical energy {E:.3g} J at t = {t:.4g} s exceeds {allowed:.3g} J allowed by "
                    f"the reference run at dt = {ref.dt:.3g} s")
        return None

    why, done = _run(system, dt, n, check, check_every, seed, perturb, model)
    return why is None, why, done


def measure(system: System, lo: float | None = None, hi: float | None = None, rel_tol: float = 0.05,
            steps: int | None = None, max_steps: int = MAX_STEPS, pred: dict | None = None,
            compare: bool | None = None, verbose: bool = False, trial_fn=None, model=None) -> dict:
    """Measured largest stable dt by bisection on real runs of the golden model, or of another model:
    trial_fn(system, dt, ref, steps=, max_steps=) -> (stable, reason or None, steps run) replaces trial
    (hw.stability_fixed.trial_fixed: the bit-true model); the reference run stays a golden run. `model`
    (see _run) steps both the reference and the trials instead of golden.model.Golden: the cpu backend
    (sim/cpu.py stability_model), the same physics compiled.

    compare: judge the trials against a reference run too (see trial); by default only when the scene
    has something that moves it (loads, gravity, an initial velocity or a probe's design poke). Without, a run that only relaxes
    the measuring perturbation is unstable exactly when it diverges, which the DivergenceTest sees.

    A reference run at dt_ref = 0.5 x dt_pred (or 0.5 x lo) over the scene's duration gives the energy
    history the trials are compared with (see trial). Each trial runs the scene's duration at the trial
    dt (n_steps = duration / dt), capped at max_steps = 2e4 steps, or exactly `steps`: past its limit
    a mode grows by a few % per step or more, so a few hundred steps after the scene's events show it,
    and 2e4 steps cover the whole duration of every built-in scene at the dt that matter (> 1e-4 s).
    The bracket starts at the prediction: if dt_pred is stable it is the lower end and the upper end
    doubles until a run is unstable, else it halves down. Geometric bisection stops when
    hi / lo < 1 + rel_tol. Returns lo (largest stable dt found), hi (smallest unstable dt found),
    dt_meas = sqrt(lo hi), ratio = dt_pred / dt_meas, the trials and the wall time."""
    t0 = time.perf_counter()
    pred = predict(system) if pred is None else pred
    start = pred["dt_pred"] if math.isfinite(pred["dt_pred"]) else system.dt
    base = lo if lo is not None else (0.5 * hi if hi is not None else start)
    dt_ref = 0.5 * base
    duration = system.n_steps * system.dt
    span = duration if steps is None else min(duration, steps * 4 * base)
    if compare is None:
        compare = (bool(system.loads) or bool(np.any(system.gravity != 0)) or bool(np.any(system.v0 != 0))
                   or (system.probe is not None and system.probe.depth > 0))
    ref = None
    while compare and ref is None:
        try:
            ref = reference(system, dt_ref, min(span, 4 * max_steps * dt_ref), model=model)
        except RuntimeError:
            if dt_ref < 0.01 * base:
                raise
            dt_ref *= 0.5                              # the prediction was far too high: a smaller yardstick
    trials = []
    if trial_fn is None:
        def trial_fn(system, dt, ref_, **kw):
            return trial(system, dt, ref_, model=model, **kw)

    def run(dt):
        ok, why, n = trial_fn(system, dt, ref, steps=steps, max_steps=max_steps)
        trials.append({"dt": dt, "stable": ok, "steps": n, "why": why})
        if verbose:
            print(f"  dt = {dt:.5g}: {'stable' if ok else 'unstable'} ({n} steps){'' if ok else ' ' + why}",
                  flush=True)
        return ok

    if lo is None and hi is None:
        if run(start):
            lo, hi = start, 2.0 * start
            while run(hi):
                lo, hi = hi, 2.0 * hi
                if hi > 1e6 * start:
                    raise StabilityError(f"scene '{system.name}': no instability found up to dt = {hi:g} s")
        else:
            hi, lo = start, 0.5 * start
            while not run(lo):
                hi, lo = lo, 0.5 * lo
                if lo < 1e-6 * start:
                    raise StabilityError(f"scene '{system.name}': unstable down to dt = {lo:g} s")
    else:
        if lo is None:
            lo = 0.5 * hi
        if hi is None:
            hi = 2.0 * lo
    while hi / lo > 1.0 + rel_tol:
        mid = math.sqrt(lo * hi)
        if run(mid):
            lo = mid
        else:
            hi = mid
    dt_meas = math.sqrt(lo * hi)
    return {"dt_meas": dt_meas, "lo": lo, "hi": hi, "dt_pred": pred["dt_pred"],
            "ratio": pred["dt_pred"] / dt_meas, "dt_ref": dt_ref if compare else None, "trials": trials,
            "seconds": time.perf_counter() - t0}
