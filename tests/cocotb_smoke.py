"""cocotb 2.x test module for tests/test_simulators.py (8-bit counter, enable, clear).

Runs inside the simulator (icarus or verilator) via sim.simulators.run_cocotb.
Ports of the Amaranth-generated top: clk, rst (sync domain), en, clr, count.
"""

import os

import cocotb
from cocotb.clock import Clock
from cocotb.triggers import ClockCycles, FallingEdge, RisingEdge

N_CYCLES = int(os.environ.get("SMOKE_N", "37"))


async def _reset(dut):
    cocotb.start_soon(Clock(dut.clk, 10, unit="ns").start())
    dut.rst.value = 1
    dut.en.value = 0
    dut.clr.value = 0
    await ClockCycles(dut.clk, 2)
    await FallingEdge(dut.clk)
    dut.rst.value = 0
    assert int(dut.count.value) == 0, "count not 0 after reset"


@cocotb.test()
async def counts_when_enabled(dut):
    await _reset(dut)
    # Idle cycles with en=0 must not count.
    await ClockCycles(dut.clk, 5)
    await FallingEdge(dut.clk)
    assert int(dut.count.value) == 0

    dut.en.value = 1
    for _ in range(N_CYCLES):
        await RisingEdge(dut.clk)
    await FallingEdge(dut.clk)
    dut.en.value = 0
    assert int(dut.count.value) == N_CYCLES % 256, f"count={int(dut.count.value)}"

    # Holds its value while disabled.
    await ClockCycles(dut.clk, 3)
    await FallingEdge(dut.clk)
    assert int(dut.count.value) == N_CYCLES % 256


@cocotb.test()
async def clear_and_wrap(dut):
    await _reset(dut)
    dut.en.value = 1
    await ClockCycles(dut.clk, 10)
    await FallingEdge(dut.clk)
    assert int(dut.count.value) == 10

    # clr wins over en for one cycle.
    dut.clr.value = 1
    await RisingEdge(dut.clk)
    await FallingEdge(dut.clk)
    dut.clr.value = 0
    assert int(dut.count.value) == 0, f"count={int(dut.count.value)} after clear"

    # 8-bit wrap-around.
    await ClockCycles(dut.clk, 260)
    await FallingEdge(dut.clk)
    dut.en.value = 0
    assert int(dut.count.value) == 260 % 256
