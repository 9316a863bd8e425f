"""Run the emitted Verilog on Icarus Verilog or Verilator through cocotb (`--backend icarus|verilator`).

Builds once per scene configuration: the build directory is named after a hash of the Verilog, so
runs of the same core reuse the compiled simulator. The whole run is one cocotb job (sim/cocotb_core.py);
its read-backs are decoded here into the frames of a Run, with the divergence checks and run-file arrays
of every other backend.
"""
from __future__ import annotations

import contextlib
import hashlib
import os
import tempfile
import threading
from pathlib import Path

import numpy as np

from golden.errors import BadArgument
from golden.model import FrameRecorder
from golden.system import Run, System, frame_steps
from golden.scene import file_stem
from hw import emit
from hw.bittrue import RUNAWAY_WINDOW, BitTrue, RunawayWatch
from hw.datapath import HwState
from .host import HostDriver
from .hwsim import HardwareStepper

SIMULATORS = ("icarus", "verilator")
SIM_DIR = Path(__file__).resolve().parent


def build_root() -> Path:
    return Path(os.environ.get("RHEO_BUILD", "build")) / "hdl"


def emit_core(bt: BitTrue, lanes=1, node_lanes=1, root: Path | None = None, core: str = "phased",
              ram: str = "sim", pair_lanes: int | None = None, dp16kd_budget: int | None = None):
    """Emit the core's Verilog into a directory named after its hash; returns (dir, manifest, driver).
    A core with ECP5 primitives (ram "ecp5") gets their models beside it (simulators need them);
    `dp16kd_budget`: the streaming core's block RAM fit (copies in LUT RAM, hw/stream/core.py)."""
    core, text, man = emit.build(bt, lanes, node_lanes, core, ram, pair_lanes, dp16kd_budget)
    digest = hashlib.sha256(text.encode()).hexdigest()[:16]
    d = (root or build_root()) / f"{file_stem(bt.system.name)}-{digest}"
    d.mkdir(parents=True, exist_ok=True)
    v = d / f"{emit.TOP}.v"
    if not v.exists() or v.read_text() != text:
        v.write_text(text)
    if ram == "ecp5":
        for model in emit.primitive_models():
            (d / model.name).write_text(model.read_text())
    drv = HostDriver.for_map(core.cfg.host_map, core.cycles_per_step)
    return d, man, drv


def run_job(simulator: str, core_dir: Path, drv: HostDriver, load_words, frames, reset_after: int = 0,
            timeout_s: float | None = None, progress=None, probe: dict | None = None) -> dict:
    """One cocotb run: load, run each frame's steps, read back; returns decoded frames and cycles.
    `progress(done, total)` hears the simulated cycles while the simulation runs (polled twice a second).
    `probe` (a core with a probe port): {"words": (S, D) x words, "x_bits", "f_bits", "seed"}: the samples
    are then streamed through the port (sim/cocotb_core.py) and "forces", "contacts", "latency" returned,
    with the state read back after them as the last frame."""
    from .simulators import run_cocotb
    if simulator not in SIMULATORS:
        raise BadArgument(f"unknown simulator '{simulator}' (known: {', '.join(SIMULATORS)})")
    with tempfile.TemporaryDirectory(prefix="rheo-job-") as tmp:
        job = Path(tmp) / "job.npz"
        result = Path(tmp) / "result.npz"
        progress_file = Path(tmp) / "progress"
        extra = {} if probe is None else {
            "probe_words": np.array(probe["words"], np.int64).reshape(len(probe["words"]), -1),
            "probe_x_bits": probe["x_bits"], "probe_f_bits": probe["f_bits"], "probe_seed": probe["seed"]}
        np.savez(job, **drv.to_job(), load_words=np.array(load_words, np.int64),
                 frames=np.array(frames, np.int64), reset_after=reset_after, **extra)
        env = {"RHEO_JOB": str(job), "RHEO_RESULT": str(result),
               "PYTHONPATH": os.pathsep.join([str(SIM_DIR.parent), os.environ.get("PYTHONPATH", "")])}
        if progress is not None:
            env["RHEO_PROGRESS"] = str(progress_file)
        with _polling(progress_file, progress):
            models = [p for p in (core_dir / m.name for m in emit.primitive_models()) if p.is_file()]
            run_cocotb(simulator=simulator, verilog_sources=[core_dir / f"{emit.TOP}.v", *models], toplevel=emit.TOP,
                       test_module="sim.cocotb_core", test_dir=SIM_DIR.parent, build_dir=core_dir / simulator,
                       extra_env=env, timeout_s=timeout_s)
        res = np.load(result)
        out = {"frames": [drv.decode(r) for r in res["reads"]], "cycles": res["cycles"].tolist(),
               "wall_s": float(res["wall"])}
        for key in ("forces", "contacts", "latency"):
            if key in res:
                out[key] = res[key].tolist()
        return out


@contextlib.contextmanager
def _polling(path: Path, progress):
    """While the block runs, pass the "done total" numbers in `path` to progress(done, total)."""
    if progress is None:
        yield
        return
    stop = threading.Event()

    def poll():
        while not stop.wait(0.5):
            try:
                done, total = (int(v) for v in path.read_text().split())
            except (OSError, ValueError):
                continue
            progress(done, total)
    thread = threading.Thread(target=poll, daemon=True)
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join()


def simulate_hdl(system: System, simulator: str, preset="wide", steps=None, every=None, progress=False,
                 lanes=1, node_lanes=1, bittrue: BitTrue | None = None, core: str = "phased",
                 pair_lanes: int | None = None) -> Run:
    """Run the scene's Verilog on a simulator: one cocotb job runs every output interval and reads the state
    back after each; the read-backs become the Run's frames (checked by the divergence watchdog, with the
    raw words, the hardware's saturation count and the cycles measured)."""
    bt = bittrue or BitTrue(system, preset, range_steps=max(system.n_steps, steps or 0))
    core_dir, man, drv = emit_core(bt, lanes, node_lanes, core=core, pair_lanes=pair_lanes)
    n_steps = system.n_steps if steps is None else int(steps)
    at = frame_steps(n_steps, max(1, system.every if every is None else int(every)))
    st = bt.initial_state()
    ends = sorted(set(int(k) for k in at[1:]) | set(range(RunawayWatch.window_end(0), int(at[-1]), RUNAWAY_WINDOW)))
    runs = [int(n) for n in np.diff([0] + ends)]      # read back at every frame and every runaway window's end
    out = run_job(simulator, core_dir, drv, drv.load_words(st.X, st.U, st.A, 0), runs)
    hw = HardwareStepper(bt, hw=None)                # converts and records the read-backs
    frames = FrameRecorder(system, hw, len(at))
    frames.add(st)
    wanted = set(int(k) for k in at[1:])
    for n, (X, U, A, step, sat, _), cycles in zip(runs, out["frames"], out["cycles"]):
        st = HwState(X, U, A, step)
        hw.runaway.add(step, sat - hw.sat, steps=n)
        hw.sat = sat
        hw.cycles.append((n, cycles))
        if step in wanted:
            frames.add(st)
    run = frames.run(at * system.dt, out["wall_s"])
    run.info["cycles_per_step"] = np.int64(man["cycles_per_step"]["value"])
    return run


class HdlCore:
    """A core's Verilog on a simulator driven command by command (a haptic session): the cocotb testbench
    (sim/cocotb_core.py `serve_session`) runs in a worker thread and reads JSON commands from a FIFO, so
    `call(cmd, *args)` works as AmaranthCore's: "load", "sample" (the probe port), "read_state"."""

    OPEN_TIMEOUT_S = 1800         # the build comes first (minutes for Verilator)

    def __init__(self, bt: BitTrue, simulator: str, lanes: int = 1, node_lanes: int = 1):
        import time
        from .simulators import run_cocotb
        if simulator not in SIMULATORS:
            raise BadArgument(f"unknown simulator '{simulator}' (known: {', '.join(SIMULATORS)})")
        self.dir, man, self.drv = emit_core(bt, lanes, node_lanes, core="stream")
        self.probe_latency = (man.get("probe_port") or {}).get("latency_cycles")
        self._tmp = tempfile.TemporaryDirectory(prefix="rheo-session-")
        tmp = Path(self._tmp.name)
        for name in ("cmd", "ans"):
            os.mkfifo(tmp / name)
        job = tmp / "job.npz"
        np.savez(job, **self.drv.to_job(), load_words=np.zeros((0, 2), np.int64), frames=np.zeros(0, np.int64),
                 probe_x_bits=bt.formats["x"].width, probe_f_bits=bt.formats["fprobe"].width)
        env = {"RHEO_JOB": str(job), "RHEO_RESULT": str(tmp / "result.npz"), "RHEO_SESSION": str(tmp),
               "PYTHONPATH": os.pathsep.join([str(SIM_DIR.parent), os.environ.get("PYTHONPATH", "")])}
        self._error = None

        def run():
            try:
                run_cocotb(simulator=simulator, verilog_sources=[self.dir / f"{emit.TOP}.v"], toplevel=emit.TOP,
                           test_module="sim.cocotb_core", test_dir=SIM_DIR.parent, build_dir=self.dir / simulator,
                           extra_env=env)
            except BaseException as exc:          # reported to the caller
                self._error = exc
        self._thread = threading.Thread(target=run, daemon=True)
        self._thread.start()
        t0 = time.monotonic()
        while True:                               # the testbench opens cmd once the simulation runs
            try:
                fd = os.open(tmp / "cmd", os.O_WRONLY | os.O_NONBLOCK)
                break
            except OSError:
                if not self._thread.is_alive() or time.monotonic() - t0 > self.OPEN_TIMEOUT_S:
                    raise RuntimeError(f"the {simulator} session did not start: {self._error}")
                time.sleep(0.2)
        os.set_blocking(fd, True)
        self._cmd = os.fdopen(fd, "w")
        self._ans = open(tmp / "ans")

    def call(self, cmd, *args):
        import json
        conv = lambda v: np.asarray(v).tolist() if isinstance(v, (list, tuple, np.ndarray)) else v
        self._cmd.write(json.dumps([cmd, *[[conv(a) for a in v] if isinstance(v, list) else conv(v)
                                           for v in args]]) + "\n")
        self._cmd.flush()
        line = self._ans.readline()
        if not line:
            raise RuntimeError(f"the simulation has stopped: {self._error}")
        kind, out = json.loads(line)
        if kind == "err":
            raise RuntimeError(out)
        return self.drv.decode(out) if cmd == "read_state" else out

    def close(self):
        if self._thread.is_alive():
            try:
                self._cmd.write('["stop"]\n')
                self._cmd.flush()
            except OSError:
                pass
            self._thread.join(timeout=60)
        for f in (self._cmd, self._ans):
            f.close()
        self._tmp.cleanup()
