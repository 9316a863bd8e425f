"""The backends a scene can run on, by name: each returns a `golden.system.Run` (frames in SI units; the
fixed-point and hardware backends add their raw words, formats and saturation counts in `Run.raw` and
`Run.info`, the simulated cores the cycles they took).

  golden     the float64 reference model (golden/model.py)
  cpu        the golden physics compiled (sim/cpu.py)
  fixed      the bit-true fixed-point model (hw/bittrue.py)
  amaranth   the core in Amaranth's simulator (sim/hwsim.py)
  icarus     the core's Verilog on Icarus Verilog through cocotb (sim/hdlsim.py)
  verilator  the same on Verilator
"""
from __future__ import annotations

import numpy as np

from golden.errors import BadArgument
from golden.model import simulate
from golden.system import Run, System

BACKENDS = ("golden", "cpu", "fixed", "amaranth", "icarus", "verilator")
FIXED_POINT = ("fixed", "amaranth", "icarus", "verilator")      # the backends that need number formats


def bit_true_model(system: System, preset: str, steps: int | None = None):
    """The bit-true model of a scene for a run of `steps` steps (its range analysis covers them)."""
    from hw.bittrue import BitTrue
    return BitTrue(system, preset, range_steps=max(system.n_steps, steps or 0))


PRESET_BUDGET = 1e-3       # of the object size: a default preset's largest position error against golden
PRESET_ORDER = ("narrow", "medium", "wide")      # narrowest first: fewer bits, fewer multipliers


def preset_error(system: System, preset: str, steps: int | None = None, gold: Run | None = None,
                 ranges=None) -> tuple[float | None, str]:
    """The bit-true run of `preset` against golden over `steps` (default the scene's): (largest position
    error on any recorded frame / object size, or None when the preset cannot run the scene; a note)."""
    from golden.errors import RheoError
    from hw.bittrue import BitTrue, scene_ranges
    n = system.n_steps if steps is None else int(steps)
    every = max(1, n // 50)
    gold = gold if gold is not None else simulate(system, steps=n, every=every)
    try:
        with np.errstate(over="ignore", invalid="ignore"):
            ranges = ranges or scene_ranges(system, n)
            run = simulate(system, steps=n, every=every, stepper=BitTrue(system, preset, ranges=ranges))
    except RheoError as exc:                 # no formats, or a runaway of saturations
        return None, str(exc)
    size = float(np.ptp(system.x0, axis=0).max()) or 1.0
    return float(np.abs(run.x - gold.x).max()) / size, f"over {n} steps"


def narrowest_preset(system: System, steps: int | None = None, budget: float = PRESET_BUDGET, log=None):
    """The narrowest format preset whose bit-true run of the scene (`steps`, default the scene's) stays
    within `budget` x the object size of golden on every recorded frame, without a runaway of saturations
    (issue 15: defaults do not trade accuracy for speed silently). Returns (preset, error, why): why is one
    line with each tried preset's error; when none is within the budget, "wide" and a line saying so."""
    from hw.bittrue import scene_ranges
    say = log or (lambda m: None)
    n = system.n_steps if steps is None else int(steps)
    gold = simulate(system, steps=n, every=max(1, n // 50))
    with np.errstate(over="ignore", invalid="ignore"):
        ranges = scene_ranges(system, n)
    tried, err = [], None
    for preset in PRESET_ORDER:
        err, note = preset_error(system, preset, n, gold, ranges)
        tried.append(f"{preset} {err:.1e}" if err is not None else f"{preset} cannot run it")
        say(f"preset {preset}: " + (f"{err:.1e} of the object size against golden {note}" if err is not None
                                    else note))
        if err is not None and err <= budget:
            return preset, err, (f"preset {preset}: the narrowest within {budget:g} of the object size of golden "
                                 f"over {n} steps ({', '.join(tried)})")
    return "wide", err, (f"preset wide: no preset is within {budget:g} of the object size of golden over {n} "
                         f"steps ({', '.join(tried)}); wide is the most accurate")


def run_backend(system: System, backend: str, steps=None, every=None, progress=False, preset="wide",
                lanes=1, node_lanes=1, bittrue=None, core="auto", pair_lanes=None) -> Run:
    """Run `system` on `backend` (BACKENDS); `bittrue`: the bit-true model to use (formats) for a
    fixed-point backend, else one is built for the preset."""
    if backend not in BACKENDS:
        raise BadArgument(f"unknown backend '{backend}' (known: {', '.join(BACKENDS)})")
    with np.errstate(over="ignore", invalid="ignore"):
        if backend == "golden":
            return simulate(system, steps=steps, every=every, progress=progress)
        if backend == "cpu":
            from sim.cpu import Cpu
            return simulate(system, steps=steps, every=every, progress=progress, stepper=Cpu(system))
        if backend != "fixed" and system.probe is not None:
            from hw.datapath import NotSupported
            raise NotSupported(f"scene '{system.name}' has a probe: on the core its samples come through the probe "
                               f"port, which a scripted run does not drive; use --backend fixed (bit for bit the "
                               f"same), or sim.haptic.connect(scene, backend=\"amaranth\") to drive the port")
        bt = bittrue or bit_true_model(system, preset, steps)
        if backend == "fixed":
            return simulate(system, steps=steps, every=every, progress=progress, stepper=bt)
        if backend == "amaranth":
            from sim.hwsim import simulate_amaranth
            return simulate_amaranth(system, preset, steps=steps, every=every, progress=progress, lanes=lanes,
                                     node_lanes=node_lanes, bittrue=bt, core=core, pair_lanes=pair_lanes)
        from sim.hdlsim import simulate_hdl
        return simulate_hdl(system, backend, preset, steps=steps, every=every, progress=progress, lanes=lanes,
                            node_lanes=node_lanes, bittrue=bt, core=core, pair_lanes=pair_lanes)
