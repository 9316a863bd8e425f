"""Shared helpers of the streaming core's tests (tests/test_stream_*.py)."""
from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np
from amaranth.back import verilog
from amaranth.sim import Simulator

from hw.emit import primitive_models

TESTS = Path(__file__).resolve().parent
BUILD = Path(os.environ.get("RHEO_BUILD", "build")) / "stream-tests"


def run_amaranth(dut, inputs: list[str], values, outputs: list[str]) -> np.ndarray:
    """Amaranth's simulator with the vector convention of tests/cocotb_vectors.py: row t of `values`
    drives the inputs during cycle t, outputs are read after the clock edge that ends it."""
    sim = Simulator(dut)
    sim.add_clock(1e-8)
    res = np.zeros((len(values), len(outputs)), np.int64)

    async def bench(ctx):
        for t, row in enumerate(values):
            for name, v in zip(inputs, row):
                ctx.set(_port(dut, name), int(v))
            await ctx.tick()
            for k, name in enumerate(outputs):
                res[t, k] = ctx.get(_port(dut, name))
    sim.add_testbench(bench)
    sim.run()
    return res


def _port(dut, name):
    obj = dut
    for part in name.split("__"):
        obj = obj[int(part)] if part.isdigit() else getattr(obj, part)
    return obj


def run_verilog(dut, inputs: list[str], values, outputs: list[str], simulator: str = "icarus",
                tag: str = "dut", extra_sources=tuple(primitive_models())) -> np.ndarray:
    """The same on Icarus or Verilator through cocotb (tests/cocotb_vectors.py); the top's ports are the
    Amaranth names with "__" for the hierarchy separator."""
    from sim.simulators import run_cocotb
    text = verilog.convert(dut, name="top", emit_src=False)
    d = BUILD / tag
    d.mkdir(parents=True, exist_ok=True)
    (d / "top.v").write_text(text)
    with tempfile.TemporaryDirectory(prefix="rheo-vec-") as tmp:
        job, result = Path(tmp) / "job.npz", Path(tmp) / "result.npz"
        np.savez(job, inputs=np.array(inputs), values=np.asarray(values, np.int64), outputs=np.array(outputs))
        run_cocotb(simulator=simulator, verilog_sources=[d / "top.v", *extra_sources], toplevel="top",
                   test_module="cocotb_vectors", test_dir=TESTS, build_dir=d / simulator,
                   extra_env={"RHEO_VECTORS": str(job), "RHEO_RESULT": str(result)}, timeout_s=600)
        return np.load(result)["out"]
