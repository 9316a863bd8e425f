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

from golden.model import System, simulate
from hw.bittrue import BitTrue, check_saturations
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


class AmaranthCore:
    """A core for one scene inside Amaranth's simulator, called like a HostDriver (blocking).
    `core`: "phased" (hw/core.py) or "stream" (hw/stream/core.py)."""

    def __init__(self, bt: BitTrue, lanes: int = 1, node_lanes: int = 1, core: str = "phased"):
        from hw.stream import build_core
        self.core = build_core(bt, lanes, node_lanes, core)
        self.cfg = self.core.cfg
        self.sim = Simulator(self.core)
        self.sim.add_clock(1e-8)
        self.cycles_per_step = self.core.cycles_per_step
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
        while True:
            cmd, args = self._cmd.get()
            if cmd == "stop":
                return
            try:
                self._res.put(("ok", await getattr(drv, cmd)(*args)))
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


class HardwareStepper:
    """A `simulate` stepper that runs whole output intervals on a core and reads the state back."""

    def __init__(self, bt: BitTrue, hw, preset: str):
        self.bt, self.hw, self.preset = bt, hw, preset
        self.raws = {"x_raw": [], "v_raw": [], "a_raw": [], "saturations": []}
        self.cycles = []
        self._last_sat = 0
        self._last_step = 0

    def initial_state(self):
        st = self.bt.initial_state()
        self.hw.call("load", st.X, st.U, st.A, 0)
        return st

    def advance(self, st, n):
        self.cycles.append((n, self.hw.call("run", n)))
        X, U, A, step, sat, _ = self.hw.call("read_state")
        st.X, st.U, st.A = X, U, A
        st.step += n
        if step != st.step:
            raise RuntimeError(f"the core's step counter reads {step}, expected {st.step}")
        self.sat = sat

    def step(self, st):
        self.advance(st, 1)

    def frame(self, st):
        sat = getattr(self, "sat", 0)
        self.bt.sat.clear()
        self.bt.sat["hardware"] = sat
        check_saturations(self.bt, st.step - self._last_step, sat - self._last_sat, self.preset)
        self._last_sat, self._last_step = sat, st.step
        x, u, a = self.bt.raw(st)
        self.raws["x_raw"].append(x)
        self.raws["v_raw"].append(u)
        self.raws["a_raw"].append(a)
        self.raws["saturations"].append(sat)
        return self.bt.frame(st)


def simulate_amaranth(sys: System, preset="wide", steps=None, every=None, progress=False, lanes=1,
                      node_lanes=1, bittrue: BitTrue | None = None, core: str = "phased"):
    """Run the core in Amaranth's simulator; returns (Run, raw frames, BitTrue, info)."""
    bt = bittrue or BitTrue(sys, preset, range_steps=max(sys.n_steps, steps or 0))
    hw = AmaranthCore(bt, lanes, node_lanes, core)
    try:
        stepper = HardwareStepper(bt, hw, preset)
        run = simulate(sys, steps=steps, every=every, progress=progress, stepper=stepper)
    finally:
        hw.close()
    info = {"cycles_per_step": hw.cycles_per_step, "measured": stepper.cycles}
    return run, {k: np.asarray(v) for k, v in stepper.raws.items()}, bt, info
