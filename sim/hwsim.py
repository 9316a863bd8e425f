"""Run the generated core in Amaranth's simulator through its host interface (`--backend amaranth`).

The simulation runs in a worker thread; its one testbench executes host commands (load, run, read
back: sim/host.py) that `simulate` hands it frame by frame, so the run loop, divergence checks and run
files are the same as for every other backend.
"""
from __future__ import annotations

import queue
import threading

import numpy as np
from amaranth.sim import Simulator

from golden.model import Stepper, simulate
from golden.system import Run, System
from hw.bittrue import BitTrue, RunawayWatch
from .host import HostDriver


class AmaranthBus:
    """The host bus of hw/core.py driven from an Amaranth async testbench."""

    def __init__(self, ctx, host):
        self.ctx, self.host = ctx, host

    async def write(self, addr, data):
        c, h = self.ctx, self.host
        c.set(h.addr, int(addr))
        c.set(h.w_data, data & 0xFFFFFFFF)
        c.set(h.w_en, 1)
        await c.tick()
        c.set(h.w_en, 0)

    async def read_many(self, addrs):
        c, h = self.ctx, self.host
        out = []
        for a in addrs:                      # one read issued per cycle, answers READ_LATENCY cycles later
            c.set(h.addr, int(a))
            c.set(h.r_en, 1)
            await c.tick()
            if c.get(h.r_valid):
                out.append(c.get(h.r_data))
        c.set(h.r_en, 0)
        while len(out) < len(addrs):
            await c.tick()
            if c.get(h.r_valid):
                out.append(c.get(h.r_data))
        return out

    async def wait(self, cycles):
        await self.ctx.tick().repeat(cycles)


class AmaranthProbe:
    """The streaming core's probe port (hw/stream/probeport.py) driven from an Amaranth async testbench."""

    def __init__(self, ctx, core):
        self.ctx, self.core = ctx, core

    async def sample(self, words):
        """One device sample (x words): offered until taken, then its force taken at once; returns (fprobe
        words, contacts, latency in cycles from the sample's handshake to its force)."""
        from hw.stream.nodeword import pack_ints, unpack_ints
        c, pp, pi, fo = self.ctx, self.core.probe, self.core.probe_in, self.core.force_out
        c.set(pi.payload, pack_ints(words, pp.x_bits))
        c.set(pi.valid, 1)
        while not c.get(pi.ready):
            await c.tick()
        await c.tick()
        c.set(pi.valid, 0)
        cycles = 1
        while not c.get(fo.valid):
            await c.tick()
            cycles += 1
        w = int(c.get(fo.payload))
        c.set(fo.ready, 1)
        await c.tick()
        c.set(fo.ready, 0)
        D = self.core.cfg.dim
        return unpack_ints(w, D, pp.f_bits), w >> (D * pp.f_bits), cycles


class AmaranthCore:
    """A core for one scene inside Amaranth's simulator, called like a HostDriver (blocking).
    `core`: "phased" (hw/core.py), "stream" (hw/stream/core.py) or "auto"."""

    def __init__(self, bt: BitTrue, lanes: int = 1, node_lanes: int = 1, core: str = "phased",
                 pair_lanes: int | None = None):
        from hw.stream import build_core
        self.core = build_core(bt, lanes, node_lanes, core, pair_lanes=pair_lanes)
        self.cfg = self.core.cfg
        self.sim = Simulator(self.core)
        self.sim.add_clock(1e-8)
        self.cycles_per_step = self.core.cycles_per_step
        self.probe_latency = getattr(self.core, "probe_latency", None)
        self._cmd, self._res = queue.Queue(), queue.Queue()
        self.sim.add_testbench(self._testbench)
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self):
        try:
            self.sim.run()
        except BaseException as exc:            # report to the caller instead of dying silently
            self._res.put(("err", exc))

    async def _testbench(self, ctx):
        drv = HostDriver.for_map(self.cfg.host_map, self.core.cycles_per_step, AmaranthBus(ctx, self.core.host))
        probe = AmaranthProbe(ctx, self.core) if getattr(self.core, "probe", None) is not None else None
        while True:
            cmd, args = self._cmd.get()
            if cmd == "stop":
                return
            try:
                self._res.put(("ok", await getattr(probe if cmd == "sample" else drv, cmd)(*args)))
            except Exception as exc:
                self._res.put(("err", exc))

    def call(self, cmd, *args):
        if not self._thread.is_alive():
            raise RuntimeError("the Amaranth simulation has stopped")
        self._cmd.put((cmd, args))
        kind, res = self._res.get()
        if kind == "err":
            raise res
        return res

    def close(self):
        if self._thread.is_alive():
            self._cmd.put(("stop", ()))
            self._thread.join(timeout=10)


class HardwareStepper(Stepper):
    """Runs whole output intervals on a core (`hw`: anything with `call(cmd, *args)` of the HostDriver's
    commands) and reads the state back; the bit-true model `bt` converts the raw words."""

    def __init__(self, bt: BitTrue, hw):
        self.system, self.bt, self.hw = bt.system, bt, hw
        self.cycles = []                  # (steps, cycles) of every run
        self.sat = 0                      # the hardware's saturation count at the last read-back
        self.runaway = RunawayWatch(bt.system, bt.preset)

    def initial_state(self):
        st = self.bt.initial_state()
        self.hw.call("load", st.X, st.U, st.A, 0)      # clears the core's saturation count
        self.sat = 0
        self.runaway.start(0)
        return st

    def advance(self, st, n, progress=None):
        end = st.step + n
        while st.step < end:         # runs never cross a window of the runaway test (RunawayWatch)
            k = min(end, RunawayWatch.window_end(st.step)) - st.step
            self.cycles.append((k, self.hw.call("run", k)))
            last = self.sat
            X, U, A, step, self.sat, _ = self.hw.call("read_state")
            st.X, st.U, st.A = X, U, A
            st.step += k
            if step != st.step:
                raise RuntimeError(f"the core's step counter reads {step}, expected {st.step}")
            self.runaway.add(st.step, self.sat - last, steps=k)
            if progress is not None:
                progress(k)

    def step(self, st):
        self.advance(st, 1)

    def frame(self, st):
        return self.bt.frame(st)

    def record(self, st) -> dict:
        x, u, a = self.bt.raw(st)
        return {"x_raw": x, "v_raw": u, "a_raw": a, "saturations": self.sat}

    def run_info(self) -> dict:
        """The bit-true model's metadata with the hardware's own saturation count (the core counts them all
        together), and the cycles the core took."""
        return {**self.bt.run_info(), "saturation_names": np.array(["hardware"], dtype=str),
                "saturation_counts": np.array([self.sat], np.int64),
                "cycles": np.array(self.cycles, np.int64).reshape(-1, 2)}


class PortStepper(HardwareStepper):
    """A haptic session's stepper on a core with a probe port (sim/haptic.py `connect(..., "amaranth")`): each
    device sample goes through the port (k steps on the core); the bit-true model `bt` converts the host's
    position into the x words the port takes (`hold_probe`) and the force words into newtons. The state is
    read back only when a frame is asked for."""

    takes_probe = True

    def __init__(self, bt: BitTrue, hw):
        super().__init__(bt, hw)
        self.k = bt.params.probe["k"]
        self.latency = []                 # cycles from sample to force, per sample
        self._words, self._stale = None, False

    def hold_probe(self, st, p) -> None:
        self.bt.hold_probe(st, p)
        self._words = [int(v) for v in st.probe.P]

    def advance(self, st, n, progress=None):
        if n != self.k or self._words is None:
            raise RuntimeError(f"the probe port runs one held sample's {self.k} steps at a time, asked for {n}")
        F, contacts, cycles = self.hw.call("sample", self._words)
        self._words, self._stale = None, True
        st.probe.F, st.probe.contacts = F, contacts
        st.step += n
        self.latency.append(cycles)
        if progress is not None:
            progress(n)

    def _sync(self, st):
        if self._stale:
            X, U, A, step, self.sat, _ = self.hw.call("read_state")
            if step != st.step:
                raise RuntimeError(f"the core's step counter reads {step}, expected {st.step}")
            st.X, st.U, st.A = X, U, A
            self._stale = False

    def frame(self, st):
        self._sync(st)
        return self.bt.frame(st)

    def record(self, st) -> dict:
        self._sync(st)
        return super().record(st)

    def probe_reading(self, st):
        return self.bt.probe_reading(st)

    def probe_raw(self, st):
        return self.bt.probe_raw(st)

    def probe_position(self, st):
        return self.bt.probe_position(st)

    def close(self) -> None:
        self.hw.close()


def simulate_amaranth(system: System, preset="wide", steps=None, every=None, progress=False, lanes=1,
                      node_lanes=1, bittrue: BitTrue | None = None, core: str = "phased",
                      pair_lanes: int | None = None) -> Run:
    """Run the core in Amaranth's simulator (a Run with the raw words, formats and cycles)."""
    bt = bittrue or BitTrue(system, preset, range_steps=max(system.n_steps, steps or 0))
    hw = AmaranthCore(bt, lanes, node_lanes, core, pair_lanes)
    try:
        run = simulate(system, steps=steps, every=every, progress=progress, stepper=HardwareStepper(bt, hw))
    finally:
        hw.close()
    run.info["cycles_per_step"] = np.int64(hw.cycles_per_step)
    return run
