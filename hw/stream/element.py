"""`ElementLane`: one element lane of the streaming core: its ROM, a memory and pipeline.

Item k of the element stream runs in lane k % P at slot k // P of every step (hw/stream/order.py).

  stage 0    `issue`: slot c (and the step's window base): the lane's ROM and its a memory are read
  stage 2    ROM fields (the window slots of nodes i and j: (base + g) mod Wg for their groups g, their
             banks; whether i is the higher node; "first contribution of this lane to this node in this
             step" for the lower and the higher node, "last" for the higher; the per-element parameters)
             and the a memory's word
  stage 3    a, registered (nextpnr had the memory's output, 4.8 ns of routing and the damper's first
             operation in one cycle); the slots and banks, registered, at the window read ports `ring_i`,
             `ring_j` (hw/stream/window.py `present_read`)
  stage 7    x, u of nodes i and j from the window (the slots registered in front of its copies at 4)
  ...        hw/datapath.py `element_kernel` through PipeArith (hw/stream/kernels.py), one stage per
             operation; the new a is written back A_WRITE cycles after its stage (`state_stage`:
             registered beside the a memory, hw/stream/schedule.py)
  `stage`    contributions: +fe to node i, -fe to node j, presented by node: the lower node's to the
             lane's ForceRing (`contrib_lo`), the higher node's to its RunSum (`contrib_hi`: the stream is
             sorted by higher node, so a lane's contributions to it come in runs; hw/stream/forcering.py),
             each at its ring slot: the window slot mod Wr

The function units' ROMs are the lane's own, or shared with the next lane (`tables`, a side of a
hw/stream/tables.py TablePair that the core assigns; the lane of side 0 holds them and lists them in its
`rams()`). II = 1, no stalls; the stages are known at construction (a dry run) and checked at
elaboration. While idle, the host reads or writes a word of the a memory (`host_*`, `host_rdata` two
cycles later). `sats`: the lane's saturation counts per quantity (`quantities`), PipeArith's
`saturation_events`.
"""
from __future__ import annotations

import numpy as np
from amaranth.hdl import Module, Mux, Signal, unsigned
from amaranth.lib import wiring
from amaranth.lib.wiring import In, Out

from ..rtl_fixed import as_shape
from .bram import BlockRam, ram_record
from .forcering import ContributionSignature
from .kernels import A_STAGE, ROM_STAGE, SLOT_STAGE, build_element, first_flags, last_flags
from .tables import records as table_records
from .lanerom import LaneRom
from .nodeword import bits_for, delay
from .schedule import A_WRITE
from .window import NodeReadSignature, present_read

SAT_BITS = 8


def IssueSignature(slots: int, window_groups: int):
    return wiring.Signature({"valid": Out(1), "slot": Out(bits_for(slots)), "base": Out(bits_for(window_groups))})


class ElementLane(wiring.Component):
    def __init__(self, cfg, lane: int):
        self.cfg, self.lane = cfg, lane
        sch = cfg.schedule
        self.items = cfg.element_items(lane)
        self.depth = max(1, sch.element_slots)
        self.stage = cfg.element_dry.stage
        self.state_stage = cfg.element_dry.outputs["state_stage"]
        self.quantities = cfg.element_dry.quantities
        fmt, Q, Wg, Wr = cfg.formats, cfg.node_lanes, sch.window_groups, sch.ring_groups
        self.a_bits = fmt["a"].width
        self.has_a = not cfg.params.fixed_a
        self.pbits = bits_for(self.depth)
        members = {
            "busy": In(1),
            "issue": In(IssueSignature(sch.slots, Wg)),
            "ring_i": Out(NodeReadSignature(cfg.word, Q, Wg)),
            "ring_j": Out(NodeReadSignature(cfg.word, Q, Wg)),
            "contrib_lo": Out(ContributionSignature(cfg.dim, fmt["fe"].width, Q, Wr)),
            "contrib_hi": Out(ContributionSignature(cfg.dim, fmt["fe"].width, Q, Wr)),
            "host_pos": In(self.pbits), "host_wdata": In(self.a_bits), "host_we": In(1),
            "host_rdata": Out(self.a_bits),
        }
        for k, _ in enumerate(self.quantities):
            members[f"sat{k}"] = Out(SAT_BITS)
        super().__init__(members)
        self.rom = self._rom()
        self.tables = None               # the function units' ROMs: the lane's own, or a TablePair side

    def rams(self) -> list[dict]:
        return ([ram_record(f"{self.prefix}_a", self.a_bits, self.depth)] + self.rom.records(f"{self.prefix}_rom")
                + table_records(self, f"{self.prefix}_tables"))

    @property
    def prefix(self) -> str:
        """The lane's name in the Verilog and the manifest ("el0")."""
        return f"el{self.lane}"

    def unit_memories(self) -> list[dict]:
        """The function units' memories (name, depth, width), from the dry run."""
        return self.cfg.element_dry.ar.memories

    def _rom(self) -> LaneRom:
        """The lane's ROM (dictionary-encoded, hw/stream/lanerom.py): the window groups and banks of nodes
        i and j, whether i is the higher node, the first and last flags, the kernel's per-element
        parameters (from the dry run)."""
        cfg, name = self.cfg, self.prefix
        Q, Wg = cfg.node_lanes, cfg.schedule.window_groups
        rom = LaneRom(self.depth, cfg.ram, dictionary=True)
        ni, nj = cfg.order.ei[self.items], cfg.order.ej[self.items]
        for r, nodes in enumerate((ni, nj)):
            rom.add(f"{name}_g{r}", unsigned(bits_for(Wg)), (nodes // Q) % Wg)
            rom.add(f"{name}_b{r}", unsigned(bits_for(Q)), nodes % Q)
        rom.add(f"{name}_i_high", unsigned(1), ni > nj)          # node i is the higher node
        lo, hi = np.minimum(ni, nj), np.maximum(ni, nj)
        rom.add(f"{name}_first_lo", unsigned(1), first_flags(lo))
        rom.add(f"{name}_first_hi", unsigned(1), first_flags(hi))
        rom.add(f"{name}_last_hi", unsigned(1), last_flags(hi))
        elements = cfg.order.elements[self.items]
        for q, (shape, raw) in cfg.element_dry.param_values.items():
            rom.add(f"{name}_prm_{q}", shape, raw[elements])
        return rom

    def a_memory(self):
        init = np.asarray(self.cfg.init.get("A", np.zeros(self.cfg.n_elements)))
        vals = init[self.cfg.order.elements[self.items]] if len(self.items) else []
        mask = (1 << self.a_bits) - 1
        return BlockRam(self.a_bits, self.depth, init=[int(v) & mask for v in vals], ram=self.cfg.ram)

    def elaborate(self, platform):
        m = Module()
        cfg, p, fmt = self.cfg, self.cfg.params, self.cfg.formats
        word = cfg.word
        name = self.prefix
        slot = self.issue.slot[:self.pbits]
        valid0 = Signal(name=f"{name}_valid0")
        m.d.comb += valid0.eq(self.issue.valid & (self.issue.slot < len(self.items)))

        rom = self.rom
        roles = [(rom.signal(f"{name}_g{r}"), rom.signal(f"{name}_b{r}")) for r in range(2)]
        swap, first_lo, first_hi, last_hi = [rom.signal(f"{name}_{f}")
                                             for f in ("i_high", "first_lo", "first_hi", "last_hi")]

        def src(q, raw, shape):
            sig = rom.signal(f"{name}_prm_{q}")
            assert len(sig) == len(Signal(shape)), (q, len(sig), shape)
            return sig

        # stage 2: window slots from the ROM and the step's base, presented at stage 3
        base2 = delay(m, self.issue.base, ROM_STAGE, f"{name}_base", data=True)
        slots3 = [present_read(m, port, base2, g, b, f"{name}_read{k}")
                  for k, ((g, b), port) in enumerate(zip(roles, (self.ring_i, self.ring_j)))]
        a_mem = self.a_memory()
        m.submodules[f"{name}_a"] = a_mem
        (Xi, Ui), (Xj, Uj) = word.unpack(self.ring_i.data), word.unpack(self.ring_j.data)
        a_shape = as_shape(fmt["a"])
        a_raw = delay(m, a_mem.r_data.as_signed() if a_shape.signed else a_mem.r_data, A_STAGE - ROM_STAGE,
                      f"{name}_a_word", data=True)
        if self.tables is not None:
            self.tables.reset()
        built = build_element(m, p, fmt, cfg.units, valid0, name, src, a_raw, Xi, Xj, Ui, Uj, self.tables, cfg.ram)
        assert built.stage == self.stage, f"{name}: pipeline stage {built.stage}, the schedule has {self.stage}"
        assert built.outputs["state_stage"] == self.state_stage
        ar, s = built.ar, built.stage
        rom.build(m, f"{name}_rom", slot)

        # contributions at stage s, by node: +fe to i, -fe to j; the lower one's to the ForceRing, the
        # higher one's to the RunSum
        at = lambda v: ar.delay(v, ROM_STAGE, s)
        sw = at(swap)
        rb = len(self.contrib_lo.slot)                    # a ring's slot: the window's mod Wr
        slot_i, slot_j = [ar.delay(v[:rb], SLOT_STAGE, s) for v in slots3]
        b_i, b_j = [at(b) for _, b in roles]
        fb = fmt["fe"].width
        fe_i = [ar.at(v, s) for v in built.outputs["fe"]]
        fe_j = [ar.at(v, s) for v in built.outputs["fe_neg"]]
        for port, high, first, last in ((self.contrib_lo, False, first_lo, None), (self.contrib_hi, True, first_hi, last_hi)):
            take_j = ~sw if high else sw                 # the higher node is j unless i is higher
            m.d.comb += [port.valid.eq(ar.valid_at(s)), port.slot.eq(Mux(take_j, slot_j, slot_i)),
                         port.bank.eq(Mux(take_j, b_j, b_i)), port.first.eq(at(first)),
                         port.last.eq(at(last) if last is not None else 0)]
            for k in range(cfg.dim):
                m.d.comb += port.value[k * fb:(k + 1) * fb].eq(Mux(take_j, fe_j[k], fe_i[k]))

        # the a memory: read at issue, written A_WRITE cycles after its stage (registered beside the memory,
        # before the multiplexer); the host's while idle
        new_a = built.outputs["a"]
        m.d.comb += a_mem.r_addr.eq(Mux(self.busy, slot, self.host_pos))
        if self.has_a and new_a is not None:
            sa = self.state_stage
            w_addr = delay(m, ar.delay(slot, 0, sa), A_WRITE, f"{name}_a_waddr", data=True)
            w_data = delay(m, ar.at(new_a, sa), A_WRITE, f"{name}_a_wdata", data=True)
            w_en = delay(m, ar.valid_at(sa), A_WRITE, f"{name}_a_wen")
            m.d.comb += [a_mem.w_addr.eq(Mux(self.busy, w_addr, self.host_pos)),
                         a_mem.w_data.eq(Mux(self.busy, w_data, self.host_wdata)),
                         a_mem.w_en.eq(Mux(self.busy, w_en, self.host_we))]
        else:
            m.d.comb += [a_mem.w_addr.eq(self.host_pos), a_mem.w_data.eq(self.host_wdata),
                         a_mem.w_en.eq(self.host_we & ~self.busy)]
        m.d.comb += self.host_rdata.eq(a_mem.r_data)
        self._saturations(m, ar)
        return m

    def _saturations(self, m, ar):
        events = dict(ar.saturation_events())
        assert sorted(events) == self.quantities, (sorted(events), self.quantities)
        for k, q in enumerate(self.quantities):
            m.d.comb += getattr(self, f"sat{k}").eq(events[q])
