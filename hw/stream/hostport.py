"""`HostPort`: the host interface of the streaming core (hw/hostmap.py: one register map for every core).

Word addresses, 32-bit data. The bus is registered on entry (address, data, strobes: the decoding
and its fan-out to the control's counters and every lane's memory then start at flip-flops, not at the
host's logic); a write acts a cycle after its request (an element write `elem_fanout` cycles later, a node
write `node_fanout` cycles later: each element lane and the node store register the host's access,
hw/stream/core.py; a RUN or STEP write a cycle later: `run_*` and `step_*` are registered once more,
beside the control's counters, and the port stays busy while a start is in that register), a read answers
`read_latency` = READ_LATENCY + 2 + max(elem_fanout, node_fanout) cycles after it, `r_valid` marking the
answer: the registered request presents the decoded address to the memories
(block RAMs, data two cycles later; a cycle later per register in front of them) while the address is
registered, decoded into one select per answer and the selects registered; the memories' words and the
registers' values are registered on entry (the selects with them, each answer held until the latest
memory's, so that every answer is sampled in the same cycle), the answer (a register, or the memory word
sign-extended from its format) is selected then and registered once more. Requests keep their order: a read sees
every write requested before it. Node state: field f of the node in store
bank `slot`, word `word` (the renumbering's placement, StreamConfig.host_map); element state: field 0
(a) of item `pos` of element lane `lane`. Memory writes while busy are ignored and memory reads while
busy answer undefined words (the pipeline owns the ports). RUN n > 0 starts a run when idle; STEP is
written when idle; writing SATURATIONS clears the count and the flags.
"""
from __future__ import annotations

import functools
import operator

from amaranth.hdl import Cat, Module, Mux, Signal
from amaranth.lib import wiring
from amaranth.lib.wiring import In, Out

from ..hostmap import ADDR_BITS, ELEM_BASE, ID_WORD, NODE_BASE, READ_LATENCY, Reg
from .nodeword import delay


HostSignature = wiring.Signature({
    "addr": Out(ADDR_BITS), "w_data": Out(32), "w_en": Out(1), "r_en": Out(1),
    "r_data": In(32), "r_valid": In(1),
})


class HostPort(wiring.Component):
    def __init__(self, host_map, node_fields: list, a_shape, sat_flags: int, elem_fanout: int = 0,
                 node_fanout: int = 0):
        """node_fields: the hw.fixed.Shape of each node field (x_0 .. u_{D-1}); a_shape: that of a;
        elem_fanout, node_fanout: the registers between `elem_*` and the element lanes' a memories, between
        `node_*` and the node store (both ways)."""
        for name, v in (("elem_fanout", elem_fanout), ("node_fanout", node_fanout)):
            if not isinstance(v, int) or v < 0:
                raise ValueError(f"{name} must be a count of registers (an int >= 0), got {v!r}")
        self.map, self.node_fields, self.a_shape = host_map, list(node_fields), a_shape
        self.elem_fanout, self.node_fanout = elem_fanout, node_fanout
        hm = host_map
        fbits = max(s.width for s in node_fields)
        self.P = hm.lanes
        self.read_latency = READ_LATENCY + 2 + max(elem_fanout, node_fanout)
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
        addr, w_data, w_en, r_en = (Signal.like(v, name=f"bus_{n}") for v, n in
                                    ((bus.addr, "addr"), (bus.w_data, "w_data"), (bus.w_en, "w_en"), (bus.r_en, "r_en")))
        m.d.sync += [addr.eq(bus.addr), w_data.eq(bus.w_data), w_en.eq(bus.w_en), r_en.eq(bus.r_en)]
        in_node = (addr >= NODE_BASE) & (addr < ELEM_BASE)
        in_elem = addr >= ELEM_BASE
        noff, eoff = addr - NODE_BASE, addr - ELEM_BASE
        idle = ~self.busy & ~self.run_start      # a start on its way to the control: busy from the next cycle
        m.d.comb += [
            self.node_addr.eq(noff[:wb]), self.node_bank.eq(noff[wb:wb + sb]), self.node_field.eq(noff >> (wb + sb)),
            self.node_wdata.eq(w_data), self.node_we.eq(w_en & in_node & idle),
            self.elem_pos.eq(eoff[:pb]), self.elem_wdata.eq(w_data),
            self.elem_we.eq(Cat(*[w_en & in_elem & idle & ((eoff >> (pb + lb)) == 0) & (eoff[pb:pb + lb] == l)
                                  for l in range(self.P)])),
        ]
        # the control's writes and the saturation clear registered once more (the write word, its decoding,
        # the start's `steps != 0` and the control's counters were one cycle across the die: the 1e4
        # square's critical path, 13.9 ns; the clear's decoding into the saturation flags' resets, 11.8 ns)
        m.d.sync += [self.run_start.eq(w_en & (addr == Reg.RUN) & idle), self.run_steps.eq(w_data),
                     self.step_we.eq(w_en & (addr == Reg.STEP) & idle), self.step_wdata.eq(w_data),
                     self.sat_clear.eq(w_en & (addr == Reg.SATURATIONS))]
        # reads: the address registered, decoded and the decoding registered (so that the answer's
        # multiplexer has registered selects: nextpnr had the address arithmetic and the multiplexer of
        # the element lanes' words in one cycle), the answer selected then and registered
        r_en1, r_en2, r_en3 = Signal(), Signal(), Signal()
        a1 = Signal(ADDR_BITS)
        m.d.sync += [r_en1.eq(r_en), a1.eq(addr), r_en2.eq(r_en1), r_en3.eq(r_en2)]
        regs = {Reg.ID: ID_WORD, Reg.RUN: self.steps_left,
                Reg.STATUS: Cat(self.busy | self.run_start, self.sat_flags.any()),
                Reg.STEP: self.step, Reg.SATURATIONS: self.sat_count, Reg.SATURATION_FLAGS: self.sat_flags,
                Reg.CYCLES: self.cycles}
        n1, e1 = a1 - NODE_BASE, a1 - ELEM_BASE
        is_reg = [Signal(name=f"is_{reg.name.lower()}") for reg in regs]
        is_field = [Signal(name=f"is_field{f}") for f in range(len(self.node_fields))]
        is_lane = [Signal(name=f"is_lane{l}") for l in range(self.P)]
        m.d.sync += [sel.eq(a1 == reg) for sel, reg in zip(is_reg, regs)]
        m.d.sync += [sel.eq((a1 >= NODE_BASE) & (a1 < ELEM_BASE) & ((n1 >> (wb + sb)) == f))
                     for f, sel in enumerate(is_field)]
        m.d.sync += [sel.eq((a1 >= ELEM_BASE) & ((e1 >> (pb + lb)) == 0) & (e1[pb:pb + lb] == l))
                     for l, sel in enumerate(is_lane)]
        # the memories' words (from block RAMs all over the die) and the registers registered on entry,
        # the selects a cycle later with them: the store's bank and field multiplexers, the route and the
        # answer's multiplexer were one cycle (the 1e4 square at speed grade 8: 11.6 ns, its critical path)
        # (each held until the latest memory's word: a memory's left a cycle later per register on its way)
        f = max(self.elem_fanout, self.node_fanout)

        def entered(v, name, cycles=1 + f):
            return delay(m, v, cycles, f"{name}_in")
        regs = {reg: entered(v, reg.name.lower()) if not isinstance(v, int) else v for reg, v in regs.items()}
        node_rdata = entered(self.node_rdata, "node_rdata", 1 + f - self.node_fanout)
        elem_rdata = [entered(v, f"elem_rdata{l}", 1 + f - self.elem_fanout) for l, v in enumerate(self.elem_rdata)]
        is_reg, is_field, is_lane = ([entered(sel, sel.name) for sel in sels] for sels in (is_reg, is_field, is_lane))
        # the answer: an OR of the selected words (the selects are one-hot; an If per answer was a chain of
        # 17 multiplexers on the square, 12.7 ns)
        answers = list(zip(is_reg, regs.values()))
        answers += [(sel, node_rdata[:shape.width].as_signed() if shape.signed else node_rdata[:shape.width])
                    for sel, shape in zip(is_field, self.node_fields)]
        answers += [(sel, raw.as_signed() if self.a_shape.signed else raw) for sel, raw in zip(is_lane, elem_rdata)]
        words = []
        for k, (sel, value) in enumerate(answers):
            word = Signal(32, name=f"answer{k}")
            m.d.comb += word.eq(value)
            words.append(Mux(sel, word, 0))
        r_data = Signal(32)
        m.d.comb += r_data.eq(functools.reduce(operator.or_, words))
        m.d.sync += [bus.r_data.eq(r_data), bus.r_valid.eq(delay(m, r_en3, f, "r_en_fanout"))]
        return m
