"""`NodeStore`: the node state (x, u), stored once, in Q banks.

Node n (of the streaming order) lives in bank n % Q at word n // Q, its group: one word of every bank
holds one group of Q nodes. Each bank is a `BlockRam` of Gs words (read latency 2) whose word has one
segment per node field, so that the host can write a single x_k or u_k.

While busy, the fill reads group `rd_addr` (all banks, `rd_data` STORE_READ_FANOUT + 2 cycles later: each
bank registers the group, kept apart, before its host multiplexer) and the node lanes
write group `wr_addr` (bank q when `wr_en[q]`), which lands STORE_WRITE cycles later: each bank registers
the write before its pipeline/host multiplexer (hw/stream/schedule.py). While idle, the host reads or writes field `h_field`
of the node in bank `h_bank`, word `h_addr`; `h_rdata` (the field, raw) two cycles after the address.
`busy` has a bit per bank (the core registers a copy of the control's busy beside each: one copy into
both banks' block RAMs, in two gaps of the floorplan, arrived at 14.1 ns on the 1e4 square).
One read and one write per bank and cycle: the fill reads group by group and the node lanes retire
group by group, each at most one a cycle (hw/stream/schedule.py).
"""
from __future__ import annotations

from amaranth.hdl import Cat, Module, Mux, Signal
from amaranth.lib import wiring
from amaranth.lib.wiring import In, Out

from ..rtl_fixed import KEEP_APART_TAG
from .bram import LATENCY, BlockRam, ram_record
from .nodeword import NodeWord, bits_for, delay, segment
from .schedule import STORE_READ_FANOUT, STORE_WRITE


class NodeStore(wiring.Component):
    def __init__(self, word: NodeWord, node_lanes: int, groups: int, init_words=None, ram: str = "sim"):
        self.word, self.Q, self.groups, self.ram = word, node_lanes, groups, ram
        self.latency = LATENCY                                  # a host read's
        self.fill_latency = STORE_READ_FANOUT + LATENCY          # the fill's
        self.gbits, self.qbits, self.fbits = bits_for(groups), bits_for(node_lanes), bits_for(word.fields)
        self.init_words = init_words          # per bank: list of node words (ints), or None
        super().__init__({
            "busy": In(node_lanes),              # per bank: each its own copy of the control's busy
            "rd_addr": In(self.gbits), "rd_data": Out(node_lanes * word.bits),
            "wr_addr": In(self.gbits), "wr_data": In(node_lanes * word.bits), "wr_en": In(node_lanes),
            "h_addr": In(self.gbits), "h_bank": In(self.qbits), "h_field": In(self.fbits),
            "h_wdata": In(word.field_bits), "h_we": In(1), "h_rdata": Out(word.field_bits),
        })

    def rams(self) -> list[dict]:
        return [ram_record(f"store_bank{q}", self.word.bits, self.groups, self.word.fields) for q in range(self.Q)]

    def banks(self):
        return [BlockRam(self.word.bits, self.groups, segments=self.word.fields, ram=self.ram,
                         init=None if self.init_words is None else self.init_words[q]) for q in range(self.Q)]

    def elaborate(self, platform):
        m = Module()
        w, Q = self.word, self.Q
        rdata = []
        for q, bank in enumerate(self.banks()):
            m.submodules[f"bank{q}"] = bank
            host_hit = self.h_we & (self.h_bank == q)
            field_en = Cat(*[host_hit & (self.h_field == f) for f in range(w.fields)])
            # the node lanes' write registered in each bank (STORE_WRITE), its address kept apart
            wr_addr = delay(m, self.wr_addr, STORE_WRITE, f"bank{q}_wr_addr{KEEP_APART_TAG}", data=True)
            wr_data = delay(m, segment(self.wr_data, q, w.bits, Q), STORE_WRITE, f"bank{q}_wr_data", data=True)
            wr_en = delay(m, self.wr_en[q], STORE_WRITE, f"bank{q}_wr_en")
            rd_addr = delay(m, self.rd_addr, STORE_READ_FANOUT, f"bank{q}_rd_addr{KEEP_APART_TAG}", data=True)
            busy = self.busy[q]
            m.d.comb += [
                bank.r_addr.eq(Mux(busy, rd_addr, self.h_addr)),
                bank.w_addr.eq(Mux(busy, wr_addr, self.h_addr)),
                bank.w_data.eq(Mux(busy, wr_data, self.h_wdata.replicate(w.fields))),
                bank.w_en.eq(Mux(busy, wr_en.replicate(w.fields), field_en)),
            ]
            rdata.append(bank.r_data)
        m.d.comb += self.rd_data.eq(Cat(*rdata))
        bank_d = delay(m, self.h_bank, LATENCY, "h_bank", data=True)
        field_d = delay(m, self.h_field, LATENCY, "h_field", data=True)
        node = segment(self.rd_data, bank_d, w.bits, Q)
        m.d.comb += self.h_rdata.eq(segment(node, field_d, w.field_bits, w.fields))
        return m
