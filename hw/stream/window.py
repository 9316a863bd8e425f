"""`NodeWindow`: the ring of nodes the streams read, one copy per read port, all written by the fill.

The ring holds Wg groups (W = Wg Q nodes, Wg a power of two). Virtual group v = k Gs + g (group g of
step k; the index runs on across steps) lives in slot v mod Wg. The fill writes a whole group word
(`fill`, one a cycle) into every copy through a tree of registers (FILL_FANOUT = 4 cycles: the word two
for all copies behind the store's output, the slot and enable one; one per `fill_groups` group, kept
apart in Yosys, the copies of one lane pair, which the floorplan puts in one stripe of the die; the slot
and enable one per copy (a pair's slot into its copies' 24 blocks was the 1e4 square's 10.5 ns); one in
front of each block of a node read port's copy, `BlockRam(registered=True)`, or of a group read port's
copy: the root into every copy was the 1e4 square's longest route, 13.5 ns of routing on the floorplanned
die, with or without a register per copy between), so a fill presented in cycle t is written at the end
of cycle t + 4; each read port reads its own copy. A node read port (`reads`) presents a slot and the
node's bank (n % Q) and gets that node's word NODE_READ_LATENCY = 4 cycles later: the slot registered in
front of each block of the copy (READ_FANOUT = 1, kept apart: the lane's slot adder and the route to a far
copy were the 1e3 poke's critical path; one register for a copy's six blocks, spread over the die, routed
13.6 ns on the 1e4 square), the block RAM's 2, then the bank's multiplexer into a register (nextpnr put 4.8
ns of routing between a window copy and the multiplexer, which fed an element lane's first subtraction in
the same cycle); a group read port (`groups`: the node lanes, which retire a whole group) gets the group
word LATENCY = 2 cycles later. The schedule guarantees that every read sees the
group its slot holds for that read's step (hw/stream/schedule.py).
The copies listed in `lut_copies` are LUT RAM (`BlockRam(distributed=True)`, the same latency).
"""
from __future__ import annotations

from amaranth.hdl import Module, Signal
from amaranth.lib import wiring
from amaranth.lib.wiring import In, Out

from ..rtl_fixed import KEEP_APART_TAG
from .bram import LATENCY, BlockRam, ram_record
from .nodeword import NodeWord, bits_for, delay, segment
from .schedule import FILL_FANOUT, READ_FANOUT, SLOT_REG

NODE_READ_LATENCY = READ_FANOUT + LATENCY + 1


def NodeReadSignature(word: NodeWord, node_lanes: int, window_groups: int):
    """A node read port, from the reader's side: slot and bank out, the node word in (4 cycles later)."""
    return wiring.Signature({"addr": Out(bits_for(window_groups)), "bank": Out(bits_for(node_lanes)),
                             "data": In(word.bits)})


def present_read(m: Module, port, base, group, bank, name: str):
    """A lane's read of the node in window group `group` (its slot (base + group) mod Wg) and bank `bank`
    on read port `port`: slot and bank registered in the lane (SLOT_REG = 1 cycle) before the port.
    Returns the slot's register (a ring's slot is its low bits)."""
    assert SLOT_REG == 1
    slot = Signal(len(port.addr), name=f"{name}_slot", reset_less=True)
    bank_r = Signal(len(port.bank), name=f"{name}_bank", reset_less=True)
    m.d.sync += [slot.eq(base + group), bank_r.eq(bank)]
    m.d.comb += [port.addr.eq(slot), port.bank.eq(bank_r)]
    return slot


class NodeWindow(wiring.Component):
    def __init__(self, word: NodeWord, node_lanes: int, window_groups: int, node_reads: int,
                 group_reads: int, ram: str = "sim", fill_groups: list[list[int]] | None = None):
        self.word, self.Q, self.Wg, self.ram = word, node_lanes, window_groups, ram
        copies = node_reads + group_reads
        self.fill_groups = [[k] for k in range(copies)] if fill_groups is None else [list(g) for g in fill_groups]
        if sorted(k for g in self.fill_groups for k in g) != list(range(copies)) or not all(self.fill_groups):
            raise ValueError(f"fill_groups must split the {copies} copies 0 .. {copies - 1} into non-empty groups, "
                             f"got {fill_groups!r}")
        self.latency, self.node_latency, self.fill_latency = LATENCY, NODE_READ_LATENCY, FILL_FANOUT
        self.n_reads, self.n_groups = node_reads, group_reads
        self.lut_copies: set[int] = set()      # copies in LUT RAM (StreamCore's block RAM fit)
        wb, gw = bits_for(window_groups), node_lanes * word.bits
        members = {"fill_addr": In(wb), "fill_data": In(gw), "fill_en": In(1)}
        if node_reads:
            members["reads"] = In(NodeReadSignature(word, node_lanes, window_groups)).array(node_reads)
        if group_reads:
            members["groups"] = In(wiring.Signature({"addr": Out(wb), "data": In(gw)})).array(group_reads)
        super().__init__(members)

    def copies(self) -> int:
        return self.n_reads + self.n_groups

    def rams(self) -> list[dict]:
        return [ram_record(f"window_copy{k}", self.Q * self.word.bits, self.Wg, distributed=k in self.lut_copies)
                for k in range(self.copies())]

    def copy(self, k: int):
        """Copy k: a node read port's copy registers its inputs itself (`registered`: in block RAM every
        block its own fill and read address, next to it); a group read port's keeps them here."""
        return BlockRam(self.Q * self.word.bits, self.Wg, ram=self.ram, distributed=k in self.lut_copies,
                        registered=k < self.n_reads)

    def elaborate(self, platform):
        m = Module()
        ports = [(p, True) for p in (self.reads if self.n_reads else [])]
        ports += [(p, False) for p in (self.groups if self.n_groups else [])]
        # behind the store: the word waits there for the slot and enable's register per copy
        fill = {nm: delay(m, src, FILL_FANOUT - 2 - (nm != "data"), f"fill_{nm}", data=nm != "en")
                for src, nm in ((self.fill_addr, "addr"), (self.fill_data, "data"), (self.fill_en, "en"))}
        relay = {}
        for j, group in enumerate(self.fill_groups):     # one register per group, beside its copies
            for nm, value in fill.items():
                r = delay(m, value, 1, f"fill{j}_{nm}{KEEP_APART_TAG}", data=nm != "en")
                relay.update({(k, nm): r if nm == "data" else
                              delay(m, r, 1, f"copy{k}_relay_{nm}{KEEP_APART_TAG}", data=nm != "en")
                              for k in group})
        for k, (port, single) in enumerate(ports):
            ring = self.copy(k)
            m.submodules[f"copy{k}"] = ring
            assert ring.registered == single and ring.latency == LATENCY + READ_FANOUT * single
            for dst, nm in ((ring.w_addr, "addr"), (ring.w_data, "data"), (ring.w_en, "en")):
                m.d.comb += dst.eq(relay[k, nm] if single else
                                   delay(m, relay[k, nm], 1, f"copy{k}_fill_{nm}{KEEP_APART_TAG}", data=nm != "en"))
            if single:
                m.d.comb += ring.r_addr.eq(port.addr)
                bank = delay(m, port.bank, ring.latency, f"bank{k}", data=True)
                m.d.comb += port.data.eq(delay(m, segment(ring.r_data, bank, self.word.bits, self.Q), 1,
                                               f"copy{k}_word", data=True))
            else:
                m.d.comb += [ring.r_addr.eq(port.addr), port.data.eq(ring.r_data)]
        return m
