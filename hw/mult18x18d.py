"""`mult18x18d`: an instantiated ECP5 MULT18X18D with its own input, pipeline and output registers.

Yosys maps a product onto a MULT18X18D with every register off (synth_ecp5: `$__MUL18X18` in
techlibs/ecp5/dsp_map.v), so nextpnr times the block as logic between fabric flip-flops, and those land
tens of tiles from it (the streaming core's critical path: operand register -> 3.9 ns multiplier ->
product register, about 3 ns of routing on each side). With REG_INPUTA_CLK, REG_INPUTB_CLK and
REG_OUTPUT_CLK set the block is timed register to register (nextpnr's MULT18X18D_REGS_ALL: measured
alone, the worst path was a flip-flop to the A port, 1.95 ns).

Latency: 2 (input and output registers) or 3 (with the pipeline register too), operands presented in
cycle t give their product in cycle t + latency. Throughput one product a cycle. CE0 is high and RST0 low:
like the fabric registers it replaces (hw/rtl_fixed.py `registered_product`), the block's registers are
loaded every cycle and never reset.

Operands are 18-bit values, both signed or both unsigned (SIGNEDA = SIGNEDB, constant); P holds the
36-bit product. Simulators need `MULT18X18D_MODEL` (hw/mult18x18d.v) beside the core's Verilog: Yosys
ships the cell as a blackbox.
"""
from __future__ import annotations

from pathlib import Path

from amaranth.hdl import ClockSignal, Const, Instance, Module, Signal, Value

__all__ = ["mult18x18d", "MULT18X18D_MODEL", "OPERAND_BITS"]

MULT18X18D_MODEL = Path(__file__).resolve().parent / "mult18x18d.v"
OPERAND_BITS = 18


def mult18x18d(m: Module, a: Value, b: Value, is_signed: bool, pipeline: bool, name: str) -> Signal:
    """The registered product of `a` and `b` (each at most 18 bits, as `is_signed` reads them; extended
    to 18 bits here) from a MULT18X18D in module `m`: a 36-bit signal, `2 + pipeline` cycles later."""
    a, b = Value.cast(a), Value.cast(b)
    for v in (a, b):
        # an unsigned operand of a signed product needs a zero bit above it; a signed one, a signed product
        bits = len(v) + int(is_signed and not v.shape().signed)
        if bits > OPERAND_BITS or (v.shape().signed and not is_signed):
            raise ValueError(f"{name}: operand {v.shape()} does not fit a MULT18X18D "
                             f"{'signed' if is_signed else 'unsigned'} product")
    a18, b18 = Signal(OPERAND_BITS, name=f"{name}_a"), Signal(OPERAND_BITS, name=f"{name}_b")
    p = Signal(36, name=f"{name}_p")
    clock = "CLK0"
    params = {"p_REG_INPUTA_CLK": clock, "p_REG_INPUTB_CLK": clock,
              "p_REG_PIPELINE_CLK": clock if pipeline else "NONE", "p_REG_OUTPUT_CLK": clock,
              "p_SOURCEB_MODE": "B_SHIFT", "p_RESETMODE": "SYNC", "p_GSR": "DISABLED"}
    ports = {"i_CLK0": ClockSignal("sync"), "i_CE0": Const(1, 1), "i_RST0": Const(0, 1),
             "i_SIGNEDA": Const(int(is_signed), 1), "i_SIGNEDB": Const(int(is_signed), 1),
             "i_SOURCEA": Const(0, 1), "i_SOURCEB": Const(0, 1)}
    for k in range(OPERAND_BITS):
        ports[f"i_A{k}"] = a18[k]
        ports[f"i_B{k}"] = b18[k]
        ports[f"i_C{k}"] = Const(0, 1)
    for k in range(36):
        ports[f"o_P{k}"] = p[k]
    m.d.comb += [a18.eq(a), b18.eq(b)]          # sign- or zero-extended as the operand's shape says
    m.submodules[name] = Instance("MULT18X18D", **params, **ports)
    return p
