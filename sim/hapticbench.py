"""The haptic loop's rates (`rheo bench --haptic --scene poke-...`): time per device sample (one sample =
hold p, k steps, read the force) of a backend through the haptic API (sim/haptic.py), as a latency
distribution, and the golden and bit-true loop rates in the same run.

The measured backend (normally the cpu backend, what a host would run instead of the FPGA) steps `samples`
device samples (10,000 by default: 10 s of a 1 kHz device) along the scene's design poke, repeated; each
sample is timed on its own (time.perf_counter around `Session.step`), and the distribution is stated as
its median, 99th and 99.9th percentiles and maximum, against the device period k dt. The golden model and
the bit-true model (its preset) run the same trajectory for at least `min_seconds` each: their samples/s.
The FPGA's case is a latency fixed at construction (issue 16 item 7, with the streaming core's probe port).
"""
from __future__ import annotations

import time

import numpy as np

from golden.system import System

from .haptic import connect, design_trajectory


def _trajectory(system: System, n: int) -> np.ndarray:
    """n device samples of the scene's design poke, repeated."""
    one = design_trajectory(system)
    return one[np.arange(n) % len(one)]


def sample_times(system: System, backend: str, samples: int, preset: str = "wide", warmup: int = 20) -> np.ndarray:
    """Seconds per device sample of `samples` samples on `backend` (after `warmup` untimed ones)."""
    traj = _trajectory(system, samples + warmup)
    out = np.empty(samples)
    clock = time.perf_counter
    with connect(system, backend, preset) as sim:
        for s in range(warmup):
            sim.step(traj[s])
        for s in range(samples):
            t0 = clock()
            sim.step(traj[warmup + s])
            out[s] = clock() - t0
    return out


def loop_rate(system: System, backend: str, min_seconds: float, preset: str = "wide", warmup: int = 3) -> dict:
    """Device samples per second of a backend's haptic loop, over at least min_seconds (and 5 samples)."""
    traj = _trajectory(system, 1 << 20)
    with connect(system, backend, preset) as sim:
        for s in range(warmup):
            sim.step(traj[s])
        n, t0 = 0, time.perf_counter()
        while True:
            sim.step(traj[warmup + n])
            n += 1
            el = time.perf_counter() - t0
            if el >= min_seconds and n >= 5:
                break
    return dict(samples=n, seconds=el, samples_per_s=n / el, steps_per_s=n * system.probe.k / el)


def haptic_rates(system: System, backend: str = "cpu", samples: int = 10_000, min_seconds: float = 1.0,
                 preset: str = "wide") -> dict:
    """The figures of `rheo bench --haptic`: the latency distribution of `backend` and the golden and
    bit-true loop rates on the same scene, in one run."""
    if system.probe is None:
        raise ValueError(f"scene '{system.name}' has no [probe] table: the haptic benchmark pokes it")
    k, dt = system.probe.k, system.dt
    period = k * dt
    t = sample_times(system, backend, samples, preset)
    q = lambda p: float(np.percentile(t, p)) * 1e6
    row = dict(backend=backend, scene=system.name, elements=system.n_elements, nodes=system.n_nodes, k=k, dt=dt,
               device_period_us=period * 1e6, device_rate_hz=1.0 / period, samples=samples,
               median_us=q(50), p99_us=q(99), p999_us=q(99.9), max_us=float(t.max()) * 1e6,
               mean_us=float(t.mean()) * 1e6, samples_per_s=samples / float(t.sum()),
               late_samples=int(np.count_nonzero(t > period)))
    row["meets_device_rate"] = row["p999_us"] < row["device_period_us"]
    for other, pre in (("golden", None), ("fixed", preset)):
        r = loop_rate(system, other, min_seconds, preset)
        row[f"{other}_samples_per_s"] = r["samples_per_s"]
        row[f"{other}_steps_per_s"] = r["steps_per_s"]
    row["fixed_preset"] = preset
    return row
