"""Run the emitted Verilog on Icarus Verilog or Verilator through cocotb (`--backend icarus|verilator`).

Builds once per scene configuration: the build directory is named after a hash of the Verilog, so
runs of the same core reuse the compiled simulator. The whole run is one cocotb job (sim/cocotb_core.py);
its read-backs are decoded here and replayed through `simulate` so that run files and divergence checks
are those of every other backend.
"""
from __future__ import annotations

import hashlib
import os
import tempfile
from pathlib import Path

import numpy as np

from golden.model import System, frame_steps, simulate
from golden.scene import file_stem
from hw import emit
from hw.bittrue import BitTrue
from .host import HostDriver
from .hwsim import HardwareStepper

SIMULATORS = ("icarus", "verilator")
SIM_DIR = Path(__file__).resolve().parent


def build_root() -> Path:
    return Path(os.environ.get("RHEO_BUILD", "build")) / "hdl"


def emit_core(bt: BitTrue, lanes=1, node_lanes=1, root: Path | None = None, core: str = "phased",
              ram: str = "sim"):
    """Emit the core's Verilog into a directory named after its hash; returns (dir, manifest, driver).
    A core with DP16KD instances (ram "ecp5") gets the DP16KD model beside it (simulators need it)."""
    core, text, man = emit.build(bt, lanes, node_lanes, core, ram)
    digest = hashlib.sha256(text.encode()).hexdigest()[:16]
    d = (root or build_root()) / f"{file_stem(bt.sys.name)}-{digest}"
    d.mkdir(parents=True, exist_ok=True)
    v = d / f"{emit.TOP}.v"
    if not v.exists() or v.read_text() != text:
        v.write_text(text)
    if ram == "ecp5":
        from hw.stream.bram import DP16KD_MODEL
        (d / DP16KD_MODEL.name).write_text(DP16KD_MODEL.read_text())
    drv = HostDriver.for_map(core.cfg.host_map, core.cycles_per_step)
    return d, man, drv


def run_job(simulator: str, core_dir: Path, drv: HostDriver, load_words, frames, reset_after: int = 0,
            timeout_s: float | None = None) -> dict:
    """One cocotb run: load, run each frame's steps, read back; returns decoded frames and cycles."""
    from .simulators import run_cocotb
    if simulator not in SIMULATORS:
        raise ValueError(f"unknown simulator '{simulator}' (known: {', '.join(SIMULATORS)})")
    with tempfile.TemporaryDirectory(prefix="rheo-job-") as tmp:
        job = Path(tmp) / "job.npz"
        result = Path(tmp) / "result.npz"
        np.savez(job, **drv.to_job(), load_words=np.array(load_words, np.int64),
                 frames=np.array(frames, np.int64), reset_after=reset_after)
        models = [p for p in [core_dir / "dp16kd.v"] if p.is_file()]
        run_cocotb(simulator=simulator, verilog_sources=[core_dir / f"{emit.TOP}.v", *models], toplevel=emit.TOP,
                   test_module="sim.cocotb_core", test_dir=SIM_DIR.parent, build_dir=core_dir / simulator,
                   extra_env={"RHEO_JOB": str(job), "RHEO_RESULT": str(result),
                              "PYTHONPATH": os.pathsep.join([str(SIM_DIR.parent), os.environ.get("PYTHONPATH", "")])},
                   timeout_s=timeout_s)
        res = np.load(result)
        return {"frames": [drv.decode(r) for r in res["reads"]], "cycles": res["cycles"].tolist(),
                "wall_s": float(res["wall"])}


class _Replay:
    """Plays back the frames the simulator produced, as a HardwareStepper's core would."""

    def __init__(self, frames, cycles):
        self.frames, self.cycles = list(frames), list(cycles)

    def call(self, cmd, *args):
        if cmd == "load":
            return None
        if cmd == "run":
            return self.cycles.pop(0)
        if cmd == "read_state":
            return self.frames.pop(0)
        raise ValueError(cmd)


def simulate_hdl(sys: System, simulator: str, preset="wide", steps=None, every=None, progress=False,
                 lanes=1, node_lanes=1, bittrue: BitTrue | None = None, core: str = "phased"):
    """Run the scene's Verilog on a simulator; returns (Run, raw frames, BitTrue, info)."""
    bt = bittrue or BitTrue(sys, preset, range_steps=max(sys.n_steps, steps or 0))
    core_dir, man, drv = emit_core(bt, lanes, node_lanes, core=core)
    n_steps = sys.n_steps if steps is None else int(steps)
    at = frame_steps(n_steps, max(1, sys.every if every is None else int(every)))
    runs = np.diff(np.concatenate([[0], at])).astype(int)
    st = bt.initial_state()
    runs = [int(n) for n in runs if n > 0]
    out = run_job(simulator, core_dir, drv, drv.load_words(st.X, st.U, st.A, 0), runs)
    stepper = HardwareStepper(BitTrue(sys, preset, formats=bt.formats), _Replay(out["frames"], out["cycles"]), preset)
    run = simulate(sys, steps=steps, every=every, progress=progress, stepper=stepper)
    info = {"cycles_per_step": man["cycles_per_step"]["value"], "measured": out["cycles"],
            "sim_wall_s": out["wall_s"], "core_dir": str(core_dir)}
    return run, {k: np.asarray(v) for k, v in stepper.raws.items()}, stepper.bt, info
