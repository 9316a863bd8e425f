"""cocotb test module: drive a design's inputs from per-cycle vectors and record its outputs.

The job (RHEO_VECTORS, an .npz): `inputs` (names), `values` (cycles x inputs), `outputs` (names). After
reset, in each cycle t the inputs take row t (set at a falling edge, before rising edge t), and every
output is sampled at the next falling edge (after rising edge t): row t of `out` in RHEO_RESULT, with
-1 where a bit is X or Z. Used for unit tests of gateware that Amaranth's simulator cannot run (DP16KD
instances, hw/stream/bram.py).
"""
import os

import cocotb
import numpy as np
from cocotb.clock import Clock
from cocotb.triggers import ClockCycles, FallingEdge


@cocotb.test()
async def vectors(dut):
    job = np.load(os.environ["RHEO_VECTORS"])
    ins, vals, outs = list(job["inputs"]), job["values"], list(job["outputs"])
    cocotb.start_soon(Clock(dut.clk, 10, unit="ns").start())
    dut.rst.value = 1
    for name in ins:
        getattr(dut, name).value = 0
    await ClockCycles(dut.clk, 2)
    await FallingEdge(dut.clk)
    dut.rst.value = 0
    res = np.zeros((len(vals), len(outs)), np.int64)
    for t, row in enumerate(vals):
        for name, v in zip(ins, row):
            getattr(dut, name).value = int(v)
        await FallingEdge(dut.clk)
        for k, name in enumerate(outs):
            v = getattr(dut, name).value
            res[t, k] = int(v) if v.is_resolvable else -1
    np.savez(os.environ["RHEO_RESULT"], out=res)
