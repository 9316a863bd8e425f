"""cocotb testbench for `rheo_core` (the Verilog of `rheo verilog`), on Icarus Verilog and Verilator.

It executes a job prepared by sim/hdlsim.py (a .npz named by RHEO_JOB): reset, load a state through the
host interface, run the frames' steps with the core running whole steps on its own (Python only writes
RUN, waits the predicted cycles and polls STATUS), read every state word back after each frame, and
store the raw read-backs and the measured cycles in RHEO_RESULT. With RHEO_PROGRESS set, it keeps that file
holding "cycles waited, cycles planned" for the host's progress bar. Comparison with the bit-true model
happens on the host side, on the decoded words (sim/host.py).

Optional: `reset_after` > 0 starts a run and asserts reset after that many cycles, checks the core
is idle with its step counter at 0, then carries on with the job (a reset in the middle of a run).
With `probe_words` (a scene with a [probe]: one row of x words per device sample), after the frames the
samples go through the probe port (`probe_in`) with seeded random gaps while `force_out` sees random
back-pressure; each force's words and contact count and its latency in cycles (from the sample's
handshake cycle to the first cycle its force is valid, from the simulation time) join the result, and
the state is read back once more at the end. With RHEO_SESSION (a folder with the FIFOs cmd and ans), it
serves a host's commands one by one instead (`serve_session`: a haptic session, sim/hdlsim.py `HdlCore`).
"""
from __future__ import annotations

import os
import time

import cocotb
import numpy as np
from cocotb.clock import Clock
from cocotb.triggers import ClockCycles, FallingEdge, RisingEdge
from cocotb.utils import get_sim_time

from hw.hostmap import ID_WORD, STATUS_BUSY, Reg
from sim.host import HostDriver


class CocotbBus:
    """The core's host bus, driven between clock edges (inputs change on the falling edge)."""

    def __init__(self, dut):
        self.dut = dut

    async def write(self, addr, data):
        d = self.dut
        d.host__addr.value = int(addr)
        d.host__w_data.value = data & 0xFFFFFFFF
        d.host__w_en.value = 1
        await FallingEdge(d.clk)
        d.host__w_en.value = 0

    async def read_many(self, addrs):
        d = self.dut
        out = []
        for a in addrs:
            d.host__addr.value = int(a)
            d.host__r_en.value = 1
            await FallingEdge(d.clk)
            if int(d.host__r_valid.value):
                out.append(int(d.host__r_data.value))
        d.host__r_en.value = 0
        while len(out) < len(addrs):
            await FallingEdge(d.clk)
            if int(d.host__r_valid.value):
                out.append(int(d.host__r_data.value))
        return out

    async def wait(self, cycles):
        await ClockCycles(self.dut.clk, cycles, rising=False)


async def _reset(dut):
    dut.rst.value = 1
    for name in ("host__addr", "host__w_data", "host__w_en", "host__r_en", "probe_in__valid", "force_out__ready"):
        if hasattr(dut, name):                            # the probe port's: scenes with a [probe]
            getattr(dut, name).value = 0
    await ClockCycles(dut.clk, 2)
    await FallingEdge(dut.clk)
    dut.rst.value = 0


@cocotb.test()
async def run_job(dut):
    job = dict(np.load(os.environ["RHEO_JOB"]))
    cocotb.start_soon(Clock(dut.clk, 10, unit="ns").start())
    await _reset(dut)
    bus = CocotbBus(dut)
    drv = HostDriver.from_job(job, bus)
    ident = (await bus.read_many([Reg.ID]))[0]
    assert ident == ID_WORD, hex(ident)
    if os.environ.get("RHEO_SESSION"):                    # a host drives the core command by command
        await serve_session(dut, drv, os.environ["RHEO_SESSION"], int(job["probe_x_bits"]), int(job["probe_f_bits"]))
        return
    load = [tuple(w) for w in job["load_words"]]
    reset_after = int(job.get("reset_after", 0))
    if reset_after > 0:                                   # a reset in the middle of a run
        await drv.write_words(load)
        await bus.write(Reg.RUN, 5)
        await ClockCycles(dut.clk, reset_after, rising=False)
        dut.rst.value = 1
        await FallingEdge(dut.clk)
        dut.rst.value = 0
        status, step = await bus.read_many([Reg.STATUS, Reg.STEP])
        assert status & STATUS_BUSY == 0 and step == 0, (status, step)
    await drv.write_words(load)
    reads, cycles = [], []
    progress = os.environ.get("RHEO_PROGRESS")
    if progress:                                          # cycles waited so far / planned, for the host's bar
        total = int(sum(int(n) for n in job["frames"])) * drv.cycles_per_step
        done = [0]

        def report(n):
            done[0] += n
            with open(progress + ".tmp", "w") as f:
                f.write(f"{done[0]} {total}\n")
            os.replace(progress + ".tmp", progress)
        drv.on_cycles = report
    t0 = time.perf_counter()
    for n in job["frames"]:
        cycles.append(await drv.run(int(n)))
        reads.append(await drv.read_raw())
    probe = {}
    if "probe_words" in job:
        probe = await stream_probe(dut, job)
        reads.append(await drv.read_raw())
    wall = time.perf_counter() - t0
    np.savez(os.environ["RHEO_RESULT"], reads=np.array(reads, np.int64), cycles=np.array(cycles, np.int64),
             wall=wall, **probe)


async def probe_sample(dut, row, x_bits: int, f_bits: int, rng=None):
    """One device sample through the probe port: offered until taken, its force taken at once (or, with
    `rng`, under random back-pressure); returns (fprobe words, contacts, latency in cycles from the sample's
    handshake cycle to the first cycle its force is valid, from the simulation time)."""
    from hw.stream.nodeword import pack_ints, unpack_ints
    D, period = len(row), 10
    now = lambda: get_sim_time("ns")
    dut.probe_in__payload.value = pack_ints(row, x_bits)
    dut.probe_in__valid.value = 1
    while not int(dut.probe_in__ready.value):
        await FallingEdge(dut.clk)
    t_in = now()                          # taken at the next rising edge
    await FallingEdge(dut.clk)
    dut.probe_in__valid.value = 0
    if not int(dut.force_out__valid.value):
        await RisingEdge(dut.force_out__valid)
        await FallingEdge(dut.clk)
    latency = int(round((now() - t_in) / period))
    while True:                           # the force waits until taken
        assert int(dut.force_out__valid.value), "force_out fell without a handshake"
        w = int(dut.force_out__payload.value)
        ready = 1 if rng is None else int(rng.random() < 0.3)
        dut.force_out__ready.value = ready
        await FallingEdge(dut.clk)
        if ready:
            break
    dut.force_out__ready.value = 0
    return unpack_ints(w, D, f_bits), w >> (D * f_bits), latency


async def stream_probe(dut, job) -> dict:
    """The probe port under random gaps and back-pressure (seed `probe_seed`): forces, contacts, latencies."""
    rng = np.random.default_rng(int(job["probe_seed"]))
    xb, fb = int(job["probe_x_bits"]), int(job["probe_f_bits"])
    forces, contacts, latency = [], [], []
    dut.force_out__ready.value = 0
    for row in job["probe_words"]:
        gap = int(rng.integers(0, 40))
        if gap:
            await ClockCycles(dut.clk, gap, rising=False)
        f, c, lat = await probe_sample(dut, row, xb, fb, rng)
        forces.append(f)
        contacts.append(c)
        latency.append(lat)
    return {"forces": np.array(forces, np.int64), "contacts": np.array(contacts, np.int64),
            "latency": np.array(latency, np.int64)}


async def serve_session(dut, drv, session: str, x_bits: int, f_bits: int):
    """A host session (sim/hdlsim.py `HdlCore`): JSON commands, one a line, from the FIFO `session`/cmd,
    answers to `session`/ans: ["load", X, U, A, step], ["sample", words], ["read_state"], ["stop"]. The
    simulation stands still while a command is awaited."""
    import json
    with open(os.path.join(session, "cmd")) as cmd, open(os.path.join(session, "ans"), "w") as ans:
        for line in cmd:
            op, *args = json.loads(line)
            if op == "stop":
                return
            try:
                if op == "load":
                    await drv.load(*args)
                    out = None
                elif op == "sample":
                    out = await probe_sample(dut, args[0], x_bits, f_bits)
                elif op == "read_state":
                    out = await drv.read_raw()
                else:
                    raise ValueError(f"unknown session command {op!r}")
                ans.write(json.dumps(["ok", out]) + "\n")
            except Exception as exc:          # the host hears of it; the session goes on
                ans.write(json.dumps(["err", f"{type(exc).__name__}: {exc}"]) + "\n")
            ans.flush()
