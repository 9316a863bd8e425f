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


def run_backend(system: System, backend: str, steps=None, every=None, progress=False, preset="wide",
                lanes=1, node_lanes=1, bittrue=None) -> Run:
    """Run `system` on `backend` (BACKENDS); `bittrue`: the bit-true model to use (formats) for a
    fixed-point backend, else one is built for the preset."""
    if backend not in BACKENDS:
        raise BadArgument(f"unknown backend '{backend}' (known: {', '.join(BACKENDS)})")
    with np.errstate(over="ignore", invalid="ignore"):
        if backend == "golden":
            return simulate(system, steps=steps, every=every, progress=progress)
        if backend == "cpu":
            from sim.cpu import Cpu
            cpu = Cpu(system)
            if system.probe is not None and not cpu.takes_probe:
                from golden.errors import RheoError
                raise RheoError(f"scene '{system.name}' has a probe, which the cpu backend cannot run yet; "
                                f"use --backend golden or fixed")
            return simulate(system, steps=steps, every=every, progress=progress, stepper=cpu)
        bt = bittrue or bit_true_model(system, preset, steps)
        if backend == "fixed":
            return simulate(system, steps=steps, every=every, progress=progress, stepper=bt)
        if backend == "amaranth":
            from sim.hwsim import simulate_amaranth
            return simulate_amaranth(system, preset, steps=steps, every=every, progress=progress, lanes=lanes,
                                     node_lanes=node_lanes, bittrue=bt)
        from sim.hdlsim import simulate_hdl
        return simulate_hdl(system, backend, preset, steps=steps, every=every, progress=progress, lanes=lanes,
                            node_lanes=node_lanes, bittrue=bt)
