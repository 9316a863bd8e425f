"""`HostPort`: the host interface of the streaming core (hw/hostmap.py: one register map for every core).

Word addresses, 32-bit data; writes act at once, a read answers READ_LATENCY = 3 cycles after its
request: the request cycle presents the decoded address to the memories (block RAMs, data two cycles
later) while the address is registered twice; the answer (a register, or the memory word sign-extended
from its format) is selected then and registered once more. Node state: field f of the node in store
bank `slot`, word `word` (the renumbering's placement, StreamConfig.host_map); element state: field 0
(a) of item `pos` of element lane `lane`. Memory writes while busy are ignored and memory reads while
busy answer undefined words (the pipeline owns the ports). RUN n > 0 starts a run when idle; STEP is
written when idle; writing SATURATIONS clears the count and the flags.
"""
from __future__ import annotations

from amaranth.hdl import Cat, Module, Signal
from amaranth.lib import wiring
from amaranth.lib.wiring import In, Out

from ..hostmap import ADDR_BITS, ELEM_BASE, ID_WORD, NODE_BASE, Reg


HostSignature = wiring.Signature({
    "addr": Out(ADDR_BITS), "w_data": Out(32), "w_en": Out(1), "r_en": Out(1),
    "r_data": In(32), "r_valid": In(1),
})


class HostPort(wiring.Component):
    def __init__(self, host_map, node_fields: list, a_shape, sat_flags: int):
        """node_fields: the hw.fixed.Shape of each node field (x_0 .. u_{D-1}); a_shape: that of a."""
        self.map, self.node_fields, self.a_shape = host_map, list(node_fields), a_shape
        hm = host_map
        fbits = max(s.width for s in node_fields)
        self.P = hm.lanes
        super().__init__({
            "bus": In(HostSignature),
            "busy": In(1), "steps_left": In(32), "step": In(32), "sat_count": In(32),
            "sat_flags": In(max(1, sat_flags)), "cycles": In(32),
            "run_start": Out(1), "run_steps": Out(32), "step_we": Out(1), "step_wdata": Out(32), "sat_clear": Out(1),
            "node_addr": Out(hm.word_bits), "node_bank": Out(hm.slot_bits), "node_field": Out(max(1, (len(node_fields) - 1).bit_length())),
            "node_wdata": Out(fbits), "node_we": Out(1), "node_rdata": In(fbits),
            "elem_pos": Out(hm.pos_bits), "elem_wdata": Out(a_shape.width), "elem_we": Out(hm.lanes),
            "elem_rdata": In(a_shape.width).array(hm.lanes),
        })

    def elaborate(self, platform):
        m = Module()
        hm, bus = self.map, self.bus
        wb, sb, pb, lb = hm.word_bits, hm.slot_bits, hm.pos_bits, hm.lane_bits
        addr = bus.addr
        in_node = (addr >= NODE_BASE) & (addr < ELEM_BASE)
        in_elem = addr >= ELEM_BASE
        noff, eoff = addr - NODE_BASE, addr - ELEM_BASE
        idle = ~self.busy
        m.d.comb += [
            self.node_addr.eq(noff[:wb]), self.node_bank.eq(noff[wb:wb + sb]), self.node_field.eq(noff >> (wb + sb)),
            self.node_wdata.eq(bus.w_data), self.node_we.eq(bus.w_en & in_node & idle),
            self.elem_pos.eq(eoff[:pb]), self.elem_wdata.eq(bus.w_data),
            self.elem_we.eq(Cat(*[bus.w_en & in_elem & idle & ((eoff >> (pb + lb)) == 0) & (eoff[pb:pb + lb] == l)
                                  for l in range(self.P)])),
            self.run_start.eq(bus.w_en & (addr == Reg.RUN) & idle), self.run_steps.eq(bus.w_data),
            self.step_we.eq(bus.w_en & (addr == Reg.STEP) & idle), self.step_wdata.eq(bus.w_data),
            self.sat_clear.eq(bus.w_en & (addr == Reg.SATURATIONS)),
        ]
        # reads: the address registered twice, the answer selected then and registered
        r_en1, r_en2 = Signal(), Signal()
        a1, a2 = Signal(ADDR_BITS), Signal(ADDR_BITS)
        m.d.sync += [r_en1.eq(bus.r_en), a1.eq(addr), r_en2.eq(r_en1), a2.eq(a1)]
        r_data = Signal(32)
        regs = {Reg.ID: ID_WORD, Reg.RUN: self.steps_left, Reg.STATUS: Cat(self.busy, self.sat_flags.any()),
                Reg.STEP: self.step, Reg.SATURATIONS: self.sat_count, Reg.SATURATION_FLAGS: self.sat_flags,
                Reg.CYCLES: self.cycles}
        with m.Switch(a2):
            for reg, value in regs.items():
                with m.Case(reg):
                    m.d.comb += r_data.eq(value)
            with m.Default():
                n2, e2 = a2 - NODE_BASE, a2 - ELEM_BASE
                with m.If((a2 >= NODE_BASE) & (a2 < ELEM_BASE)):
                    field = n2 >> (wb + sb)
                    for f, shape in enumerate(self.node_fields):
                        raw = self.node_rdata[:shape.width]
                        with m.If(field == f):
                            m.d.comb += r_data.eq(raw.as_signed() if shape.signed else raw)
                with m.Elif(a2 >= ELEM_BASE):
                    lane = e2[pb:pb + lb]
                    for l in range(self.P):
                        raw = self.elem_rdata[l]
                        with m.If(((e2 >> (pb + lb)) == 0) & (lane == l)):
                            m.d.comb += r_data.eq(raw.as_signed() if self.a_shape.signed else raw)
        m.d.sync += [bus.r_data.eq(r_data), bus.r_valid.eq(r_en2)]
        return m
