"""`PairLane`: one topology-pair lane of the streaming core (hw/datapath.py `pair_kernel`).

Item k of the pair stream (sorted by its highest node, hw/stream/order.py) runs in lane k % P at slot
k // P. Like an element lane with D + 1 roles (the vertex, then the facet's vertices) and no state:

  stage 0    `issue`: slot c; the ROM is read
  stage 2    per role: window slot, bank, "first contribution of this lane to this node in this step"
             (the ROM's fields, dictionary-encoded: hw/stream/lanerom.py)
  stage 3    the slots and banks, registered, at the roles' window read ports `rings[r]`
  stage 7    x, u of the D + 1 nodes
  `stage`    per role the pair force (zero where the pair's gate, d <= eps, is closed: the item still
             counts as the lane's contribution, so that a ring word's first contribution always writes),
             presented to the role's force ring (`contribs[r]`, at its ring slot: the window slot mod Wr)

The function units' tables are shared by pairs of pair lanes as by element lanes (hw/stream/tables.py).
II = 1, no stalls; stages known at construction (a dry run), checked at elaboration.
"""
from __future__ import annotations

from amaranth.hdl import Module, Signal, unsigned
from amaranth.lib import wiring
from amaranth.lib.wiring import In, Out

from ..datapath import pair_kernel
from .element import SAT_BITS, IssueSignature
from .forcering import ContributionSignature
from .kernels import ROM_STAGE, SLOT_STAGE, build_pair, first_flags
from .tables import records as table_records
from .lanerom import LaneRom
from .nodeword import bits_for, delay
from .window import NodeReadSignature, present_read


class PairLane(wiring.Component):
    def __init__(self, cfg, lane: int):
        self.cfg, self.lane = cfg, lane
        sch = cfg.schedule
        self.items = cfg.pair_items(lane)
        self.depth = max(1, sch.pair_slots)
        self.stage = cfg.pair_dry.stage
        self.quantities = cfg.pair_dry.quantities
        D, Q, Wg = cfg.dim, cfg.node_lanes, sch.window_groups
        self.pbits = bits_for(self.depth)
        members = {
            "issue": In(IssueSignature(sch.slots, Wg)),
            "rings": Out(NodeReadSignature(cfg.word, Q, Wg)).array(D + 1),
            "contribs": Out(ContributionSignature(D, cfg.formats["fe"].width, Q, sch.ring_groups)).array(D + 1),
        }
        for k, _ in enumerate(self.quantities):
            members[f"sat{k}"] = Out(SAT_BITS)
        super().__init__(members)
        self.rom = self._rom()
        self.tables = None               # the function units' ROMs: the lane's own, or a TablePair side

    def rams(self) -> list[dict]:
        return self.rom.records(f"{self.prefix}_rom") + table_records(self, f"{self.prefix}_tables")

    @property
    def prefix(self) -> str:
        """The lane's name in the Verilog and the manifest ("pr0")."""
        return f"pr{self.lane}"

    def unit_memories(self) -> list[dict]:
        """The function units' memories (name, depth, width), from the dry run."""
        return self.cfg.pair_dry.ar.memories

    def _rom(self) -> LaneRom:
        """Per role the window group, bank and first flag of its node; the kernel's per-pair parameters."""
        cfg, name = self.cfg, self.prefix
        Q, Wg = cfg.node_lanes, cfg.schedule.window_groups
        rom = LaneRom(self.depth, cfg.ram, dictionary=True)
        for r in range(cfg.dim + 1):
            nodes = cfg.order.pair_nodes[self.items, r]
            rom.add(f"{name}_g{r}", unsigned(bits_for(Wg)), (nodes // Q) % Wg)
            rom.add(f"{name}_b{r}", unsigned(bits_for(Q)), nodes % Q)
            rom.add(f"{name}_first{r}", unsigned(1), first_flags(nodes))
        pairs = cfg.order.pairs[self.items]
        for q, (shape, raw) in cfg.pair_dry.param_values.items():
            rom.add(f"{name}_prm_{q}", shape, raw[pairs])
        return rom

    def elaborate(self, platform):
        m = Module()
        cfg, p, fmt = self.cfg, self.cfg.params, self.cfg.formats
        D, word = cfg.dim, cfg.word
        name = self.prefix
        slot = self.issue.slot[:self.pbits]
        valid0 = Signal(name=f"{name}_valid0")
        m.d.comb += valid0.eq(self.issue.valid & (self.issue.slot < len(self.items)))
        rom = self.rom
        base2 = delay(m, self.issue.base, ROM_STAGE, f"{name}_base", data=True)
        roles, X, U = [], [], []
        for r in range(D + 1):
            g, b, f = [rom.signal(f"{name}_{what}{r}") for what in ("g", "b", "first")]
            roles.append((present_read(m, self.rings[r], base2, g, b, f"{name}_read{r}"), b, f))
            Xr, Ur = word.unpack(self.rings[r].data)
            X.append(Xr)
            U.append(Ur)

        def src(q, raw, shape):
            sig = rom.signal(f"{name}_prm_{q}")
            assert len(sig) == len(Signal(shape)), (q, len(sig), shape)
            return sig

        if self.tables is not None:
            self.tables.reset()
        built = build_pair(m, p, fmt, cfg.units, valid0, name, src, pair_kernel, X, U, self.tables, cfg.ram)
        assert built.stage == self.stage, f"{name}: pipeline stage {built.stage}, the schedule has {self.stage}"
        ar, s = built.ar, built.stage
        rom.build(m, f"{name}_rom", slot)
        fb = fmt["fe"].width
        for r, ((s3, b, f), vals) in enumerate(zip(roles, built.outputs["roles"])):
            port = self.contribs[r]
            m.d.comb += [port.valid.eq(ar.valid_at(s)), port.slot.eq(ar.delay(s3[:len(port.slot)], SLOT_STAGE, s)),
                         port.bank.eq(ar.delay(b, ROM_STAGE, s)), port.first.eq(ar.delay(f, ROM_STAGE, s))]
            for k, v in enumerate(vals):
                m.d.comb += port.value[k * fb:(k + 1) * fb].eq(v)
        events = dict(ar.saturation_events())
        assert sorted(events) == self.quantities
        for k, q in enumerate(self.quantities):
            m.d.comb += getattr(self, f"sat{k}").eq(events[q])
        return m
