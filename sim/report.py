"""Error against run time: what accuracy each word width and each time step costs, for one scene.

- Quantisation error: the bit-true model of every format preset against the golden model at the scene's
  dt (max and RMS position error over nodes, absolute and relative to the object size), per frame; and
  each preset's sensitivity floor: the golden model with only its states rounded to the preset's grid
  (hw/sensitivity.py). Where the floor is as high as the quantisation error, the scene itself (a
  clamp of a or a contact switching a step earlier) parts the trajectories, not the datapath.
- Discretisation error: the golden model at dt, 2 dt and 4 dt against a converged reference, the golden
  model at dt / 16 (dt / 4 when that would exceed `max_ref_steps` steps; the summary says which).
- Run time per simulated second: golden and bit-true measured on this machine; the FPGA core of each
  preset from its schedule (cycles per step of the core `rheo verilog` builds) at a clock per preset
  (`clock_mhz`: an assumption unless taken from `rheo synth`'s measured Fmax; `measured_clock` puts a
  place-and-route result in afterwards, as `rheo run --pnr` does for the preset it synthesises; the
  summary says which, per preset).
Writes DIR/error.csv, DIR/summary.json, DIR/error_vs_time.png and DIR/cost_vs_accuracy.png.
"""
from __future__ import annotations

import csv
import dataclasses
import json
import time
from pathlib import Path

import numpy as np

from golden.errors import SimulationDiverged
from golden.system import State, System
from golden.model import simulate

FRAMES = 100


def _scaled(system: System, factor: float) -> System:
    """The same scene with dt multiplied by factor (same duration)."""
    return dataclasses.replace(system, dt=system.dt * factor, n_steps=int(round(system.n_steps / factor)))


def _errors(x, ref, size):
    diff = np.linalg.norm(x - ref, axis=2)                 # (F, N) position error per node
    return diff.max(1), np.sqrt((diff ** 2).mean(1)), diff.max(1) / size


DEFAULT_CLOCK_MHZ = 50.0     # about the Fmax rheo synth measures for narrow 2D cores on an ECP5-85k


def build(system: System, out_dir, presets=("narrow", "medium", "wide"), max_ref_steps=2_000_000,
          log=print, clock_mhz: float = DEFAULT_CLOCK_MHZ, clock_source: str = "assumed",
          progress: bool = False) -> dict:
    """Write the report of `system` into out_dir; returns its summary. `progress`: a bar on the long runs."""
    from hw.bittrue import BitTrue, scene_ranges
    from hw.stream import cycles_per_step
    from hw.datapath import NotSupported
    from hw.sensitivity import rounded_golden
    from .runfile import check_output_dir, output_directory
    final = check_output_dir(out_dir)              # before the minutes of runs, not after
    size = float(np.ptp(system.x0, axis=0).max())
    every = 4 * max(1, -(-system.n_steps // (4 * FRAMES)))     # a multiple of 4: frames shared by all dts
    n = (system.n_steps // every) * every
    T = n * system.dt
    sysn = dataclasses.replace(system, n_steps=n)
    summary = {"scene": system.name, "dt": system.dt, "duration": T, "object_size_m": size, "frames": n // every + 1,
               "quantisation": {}, "discretisation": {}, "run_time_per_simulated_second": {},
               "fpga": {"clock_mhz": clock_mhz, "clock_source": clock_source, "cycles_per_step": {},
                        "clock_mhz_by_preset": {}, "clock_source_by_preset": {}}}
    cols = {}

    log(f"golden at dt = {system.dt:g} s ({n} steps)")
    gold = simulate(sysn, every=every, progress=progress)
    t = gold.t
    cols["t"] = t
    summary["run_time_per_simulated_second"]["golden"] = gold.wall_seconds / T

    ranges = None
    for preset in presets:
        log(f"bit-true model, preset {preset}")
        try:
            if ranges is None:          # the range analysis is the same for every preset: once
                ranges = scene_ranges(sysn)
            bt = BitTrue(sysn, preset, ranges=ranges)
            t0 = time.perf_counter()
            run = simulate(sysn, every=every, stepper=bt, progress=progress)
            wall = time.perf_counter() - t0
        except NotSupported as exc:
            summary["quantisation"][preset] = {"skipped": str(exc)}
            continue
        mx, rms, rel = _errors(run.x, gold.x, size)
        cols[f"quant_max_m_{preset}"], cols[f"quant_rms_m_{preset}"], cols[f"quant_max_rel_{preset}"] = mx, rms, rel
        floor = _errors(rounded_golden(sysn, bt.formats, bt.units, every=every), gold.x, size)[2]
        cols[f"floor_max_rel_{preset}"] = floor
        summary["quantisation"][preset] = {"max_m": float(mx.max()), "rms_m": float(rms.max()),
                                           "max_relative": float(rel.max()),
                                           "sensitivity_floor_relative": float(floor.max()),
                                           "saturations": dict(bt.sat), "constant_saturations": dict(bt.const_sat),
                                           "stagnation": bt.formats.stagnation(), "wall_s": wall}
        for msg in bt.stagnation_messages():
            log(f"warning: {msg}")
        summary["run_time_per_simulated_second"][f"fixed-{preset}"] = wall / T
        _, cycles = cycles_per_step(bt)          # the core `rheo verilog` builds (--core auto)
        summary["fpga"]["cycles_per_step"][preset] = cycles
        _set_clock(summary, preset, clock_mhz, clock_source)

    from sim.cpu import Cpu
    log("cpu backend (compiled golden physics) at dt")
    Cpu(sysn).advance(State.initial(sysn), 1)                   # compile (or load the cache) outside the timing
    cpu = simulate(sysn, every=every, stepper=Cpu(sysn))
    summary["run_time_per_simulated_second"]["cpu"] = cpu.wall_seconds / T
    summary["cpu"] = {"max_relative_vs_golden": float(_errors(cpu.x, gold.x, size)[2].max()), "discretisation": {}}

    factor_ref = 16 if n * 16 <= max_ref_steps else 4
    log(f"golden reference at dt / {factor_ref} (on the cpu backend, equal to golden to 1e-12)")
    sys_ref = _scaled(sysn, 1 / factor_ref)
    ref = simulate(sys_ref, every=every * factor_ref, stepper=Cpu(sys_ref), progress=progress)
    summary["discretisation"]["reference"] = f"golden physics at dt/{factor_ref} (cpu backend)"
    for factor in (1, 2, 4):
        label = "dt" if factor == 1 else f"{factor}dt"
        scaled = _scaled(sysn, factor)
        try:
            run = gold if factor == 1 else simulate(scaled, every=every // factor)
            fast = cpu if factor == 1 else simulate(scaled, every=every // factor, stepper=Cpu(scaled))
        except SimulationDiverged as exc:
            summary["discretisation"][label] = {"diverged": str(exc)}
            continue
        mx, rms, rel = _errors(run.x, ref.x, size)
        cols[f"disc_max_m_{label}"], cols[f"disc_max_rel_{label}"] = mx, rel
        summary["discretisation"][label] = {"dt": system.dt * factor, "max_m": float(mx.max()),
                                            "max_relative": float(rel.max()),
                                            "run_time_per_simulated_second": run.wall_seconds / T}
        summary["cpu"]["discretisation"][label] = {"max_relative": float(_errors(fast.x, ref.x, size)[2].max()),
                                                   "run_time_per_simulated_second": fast.wall_seconds / T}

    with output_directory(final) as out:            # whole or not at all
        with open(out / "error.csv", "w", newline="") as f:
            w = csv.writer(f)
            keys = list(cols)
            w.writerow(keys)
            for row in zip(*(cols[k] for k in keys)):
                w.writerow([f"{v:.9g}" for v in row])
        (out / "summary.json").write_text(json.dumps(summary, indent=2))
        _plots(out, cols, summary)
    return summary


def _set_clock(summary: dict, preset: str, mhz: float, source: str) -> None:
    """The FPGA point of `preset`: its cycles per step at `mhz` (the summary keeps the clock and its source)."""
    fp = summary["fpga"]
    fp["clock_mhz_by_preset"][preset], fp["clock_source_by_preset"][preset] = float(mhz), source
    summary["run_time_per_simulated_second"][f"fpga-{preset}"] = (
        fp["cycles_per_step"][preset] / (float(mhz) * 1e6 * summary["dt"]))


def measured_clock(out_dir, preset: str, fmax_mhz: float, source: str) -> dict:
    """Put a measured Fmax (place and route of `preset`'s core) into the report written in out_dir: its
    summary.json and cost_vs_accuracy.png are rewritten with that preset's FPGA point at the new clock.
    Returns the new summary."""
    out = Path(out_dir)
    summary = json.loads((out / "summary.json").read_text())
    if preset not in summary["fpga"]["cycles_per_step"]:
        raise KeyError(f"the report in {out} has no FPGA point for preset {preset!r}")
    _set_clock(summary, preset, fmax_mhz, source)
    with open(out / "error.csv", newline="") as f:
        rows = list(csv.reader(f))
    cols = {k: np.array([float(r[i]) for r in rows[1:]]) for i, k in enumerate(rows[0])}
    tmp = out / ".summary.json.tmp"
    tmp.write_text(json.dumps(summary, indent=2))
    tmp.replace(out / "summary.json")
    _plots(out, cols, summary)
    return summary


def _plots(out: Path, cols: dict, summary: dict) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    t = cols["t"]
    fig, ax = plt.subplots(figsize=(8, 4.5))
    floor = 1e-11          # exact zeros (before anything moves) are drawn at the bottom of the plot
    for key in [c for c in cols if c.startswith("quant_max_rel_")]:
        preset = key[len("quant_max_rel_"):]
        line, = ax.semilogy(t, np.maximum(cols[key], floor), "-", label=f"quantisation, {preset}")
        ax.semilogy(t, np.maximum(cols[f"floor_max_rel_{preset}"], floor), ":", color=line.get_color(), lw=1,
                    label=f"sensitivity floor, {preset} (golden, states rounded)")
    for key in [c for c in cols if c.startswith("disc_max_rel_")]:
        ax.semilogy(t, np.maximum(cols[key], floor), "--", label="discretisation, " + key[len("disc_max_rel_"):])
    ax.axhline(1e-4, color="grey", lw=0.8, ls="-.", label="budget 1e-4 (wide)")
    ax.set_ylim(bottom=floor)
    _finish(fig, ax, "simulated time [s]", f"{summary['scene']}: error against simulated time",
            out / "error_vs_time.png")

    fig, ax = plt.subplots(figsize=(6, 4.5))
    floor = 1e-11
    rt = summary["run_time_per_simulated_second"]
    clocks = summary["fpga"]["clock_mhz_by_preset"]
    for preset, q in summary["quantisation"].items():
        if "max_relative" in q:
            err = max(q["max_relative"], floor)
            line, = ax.loglog(rt[f"fixed-{preset}"], err, "o", label=f"bit-true {preset} (NumPy)")
            ax.loglog(rt[f"fpga-{preset}"], err, "*", ms=11, color=line.get_color(),
                      label=f"FPGA {preset} ({summary['fpga']['cycles_per_step'][preset]} cycles/step, "
                            f"{clocks[preset]:.4g} MHz)")
    for label, d in summary["discretisation"].items():
        if isinstance(d, dict) and "max_relative" in d:
            ax.loglog(d["run_time_per_simulated_second"], max(d["max_relative"], floor), "s", label=f"golden {label}")
    for label, d in summary.get("cpu", {}).get("discretisation", {}).items():
        ax.loglog(d["run_time_per_simulated_second"], max(d["max_relative"], floor), "^",
                  label=f"cpu backend {label} (Numba)")
    _finish(fig, ax, "wall seconds per simulated second (this machine)",
            f"{summary['scene']}: accuracy against cost", out / "cost_vs_accuracy.png")


def _finish(fig, ax, xlabel: str, title: str, path: Path) -> None:
    import matplotlib.pyplot as plt
    ax.set_xlabel(xlabel)
    ax.set_ylabel("max position error / object size")
    ax.set_title(title)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
