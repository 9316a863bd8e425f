"""`NodeLane`: node lane q integrates node q of every retired group (hw/datapath.py `node_kernel`).

Nodes retire in index order, a whole group (Q nodes, one per lane) at a time, at most one group a cycle,
when the stream has passed the group's last contribution (hw/stream/schedule.py):

  stage 0    `retire`: the group g, its step number; the window's group port and every force ring's
             node copy are read at the group's slot (by the core), the lane's ROM at g
  stage 2    `node`: this lane's node of the group word, registered beside the lane (x, u at stage 3);
             the ROM fields (whether the node exists: the last group may be short; per force ring "this
             ring holds contributions to this node", which masks the stale words of rings that do not;
             the kernel's flags and parameters)
  stage 5    the exact sum of the masked force ring words (`forces`): each masked word registered at
             stage 3 (only routing and one LUT after a ring's block RAM, which nextpnr may place far from
             the lane: 3.9 ns of routing measured), sums of up to FORCE_CHUNK of them registered at stage 4,
             their sum at stage 5
  ...        `node_kernel` through PipeArith: loads by the retirement's own step number (retirement
             runs into the next period, so two steps share the pipeline), floor, friction, mass, gravity
  `stage`    `store`: x, u written into the node store (bank q, word g)

With a probe (the scene has one), the kernel reads the probe's registers (`probe_P`, `probe_Pdot`,
`probe_Lo`, `probe_Hi`: constant during a run, hw/stream/probeport.py) and yields, at `probe_stage`, the
node's probe force `probe_f` (pfe words, zero unless `probe_touch`), `probe_valid` (a node is there) and
`probe_first` (its group is the step's first: the port's sum restarts).

II = 1, no stalls; stages known at construction (a dry run), checked at elaboration.
"""
from __future__ import annotations

import numpy as np
from amaranth.hdl import Cat, Module, Mux, Signal, signed, unsigned
from amaranth.lib import wiring
from amaranth.lib.wiring import In, Out

from ..datapath import ProbeInputs
from ..rtl_fixed import as_shape, tree_sum
from .element import SAT_BITS
from .kernels import FORCE_STAGE, PROBE_REGS, build_node
from .lanerom import LaneRom
from .nodeword import bits_for, split_words

FORCE_CHUNK = 4


def RetireSignature(groups: int):
    return wiring.Signature({"valid": Out(1), "group": Out(bits_for(groups)), "step": Out(32)})


class NodeLane(wiring.Component):
    def __init__(self, cfg, q: int):
        self.cfg, self.q = cfg, q
        self.tables = None               # node lanes share no function-unit ROM (hw/stream/tables.py)
        sch = cfg.schedule
        self.groups = sch.groups
        self.stage = cfg.node_dry.stage
        self.quantities = cfg.node_dry.quantities
        self.rings = cfg.rings
        self.force_bits = [ring.acc_bits for ring in self.rings]
        self.sum_bits = cfg.force_sum_bits
        word = cfg.word
        members = {
            "retire": In(RetireSignature(sch.groups)),
            "node": In(word.bits),
            "forces": In(cfg.dim * sum(self.force_bits)),
            "store_en": Out(1), "store_group": Out(bits_for(sch.groups)), "store_data": Out(word.bits),
        }
        for k, _ in enumerate(self.quantities):
            members[f"sat{k}"] = Out(SAT_BITS)
        self.probe_stage = cfg.node_dry.outputs.get("probe_stage")
        if self.probe_stage is not None:
            fmt, D = cfg.formats, cfg.dim
            for reg, q in PROBE_REGS:
                members[f"probe_{reg}"] = In(D * fmt[q].width)
            members.update({"probe_valid": Out(1), "probe_first": Out(1), "probe_touch": Out(1),
                            "probe_f": Out(D * fmt["pfe"].width)})
        super().__init__(members)

    @property
    def prefix(self) -> str:
        """The lane's name in the Verilog and the manifest ("nd0")."""
        return f"nd{self.q}"

    def unit_memories(self) -> list[dict]:
        """The function units' memories (the probe's 1/sqrt seeds), from the dry run."""
        return self.cfg.node_dry.ar.memories

    def nodes(self) -> np.ndarray:
        """The new numbers of this lane's nodes, by group (-1: none, past the last node)."""
        n = np.arange(self.groups) * self.cfg.node_lanes + self.q
        return np.where(n < self.cfg.n_nodes, n, -1)

    def elaborate(self, platform):
        m = Module()
        cfg, p, fmt, D = self.cfg, self.cfg.params, self.cfg.formats, self.cfg.dim
        name = f"nd{self.q}"
        nodes = self.nodes()
        exists = nodes >= 0
        orig = cfg.order.inv[np.where(exists, nodes, 0)]          # original node numbers
        valid0 = Signal(name=f"{name}_valid0")
        last = cfg.n_nodes - (self.groups - 1) * cfg.node_lanes   # nodes in the last group
        if self.q < last:
            m.d.comb += valid0.eq(self.retire.valid)
        else:
            m.d.comb += valid0.eq(self.retire.valid & (self.retire.group != self.groups - 1))
        rom = LaneRom(self.groups, cfg.ram)
        masks = cfg.ring_masks()[np.where(exists, nodes, 0)] * exists[:, None]
        mask_bits = [rom.add(f"{name}_mask{r}", unsigned(1), masks[:, r]) for r in range(len(self.rings))]

        def src(qty, raw, shape):
            arr = np.asarray(raw)
            return rom.add(f"{name}_prm_{qty}", shape, np.where(exists, arr[orig], 0))

        # stages 3 to 5: the masked force ring words registered, then their exact sum, per dimension
        F = []
        off = 0
        words = []
        for bits in self.force_bits:
            words.append([self.forces[off + k * bits:off + (k + 1) * bits].as_signed() for k in range(D)])
            off += D * bits
        R = len(self.rings)
        for k in range(D):
            parts = []
            for c in range(0, R, FORCE_CHUNK):
                part = Signal(signed(self.sum_bits), name=f"{name}_force{k}_{c // FORCE_CHUNK}", reset_less=True)
                masked = []
                for r in range(c, min(R, c + FORCE_CHUNK)):
                    w = Signal(signed(self.force_bits[r]), name=f"{name}_ring{r}_f{k}", reset_less=True)
                    m.d.sync += w.eq(Mux(mask_bits[r], words[r][k], 0))
                    masked.append(w)
                m.d.sync += part.eq(tree_sum(masked))
                parts.append(part)
            f = Signal(signed(self.sum_bits), name=f"{name}_force{k}", reset_less=True)
            m.d.sync += f.eq(tree_sum(parts))
            F.append(f)
        # x, u: the window's group word registered beside the lane (nextpnr on the 1e3 poke: 4.1 ns of
        # routing from the window copy, the floor test's carry chain and 4.5 ns more in one cycle)
        node = Signal.like(self.node, name=f"{name}_node", reset_less=True)
        m.d.sync += node.eq(self.node)
        X, U = cfg.word.unpack(node)
        probe = None
        if self.probe_stage is not None:
            probe = ProbeInputs(*[split_words(getattr(self, f"probe_{reg}"), D, as_shape(fmt[q]))
                                  for reg, q in PROBE_REGS])
        built = build_node(m, p, fmt, cfg.units, valid0, name, src, X, U, F, self.retire.step, probe, cfg.ram)
        assert built.stage == self.stage, f"{name}: pipeline stage {built.stage}, the schedule has {self.stage}"
        ar, s = built.ar, built.stage
        if probe is not None:
            ps = built.outputs["probe_stage"]
            assert ps == self.probe_stage, f"{name}: probe stage {ps}, the dry run has {self.probe_stage}"
            first = Signal(name=f"{name}_first0")
            m.d.comb += first.eq(self.retire.group == 0)
            gate = built.outputs["probe_gate"]
            touch = ar.delay(gate.sig, gate.stage, ps) & ar.valid_at(ps)
            m.d.comb += [self.probe_valid.eq(ar.valid_at(ps)), self.probe_first.eq(ar.delay(first, 0, ps)),
                         self.probe_touch.eq(touch),
                         self.probe_f.eq(Cat(*[Mux(touch, ar.at(f, ps), 0) for f in built.outputs["probe_f"]]))]
        rom.build(m, f"{name}_rom", self.retire.group)
        m.d.comb += [self.store_en.eq(ar.valid_at(s)),
                     self.store_group.eq(ar.delay(self.retire.group, 0, s)),
                     self.store_data.eq(cfg.word.pack([ar.at(v, s) for v in built.outputs["x"]],
                                                      [ar.at(v, s) for v in built.outputs["u"]]))]
        events = dict(ar.saturation_events())
        assert sorted(events) == self.quantities
        for k, qty in enumerate(self.quantities):
            m.d.comb += getattr(self, f"sat{k}").eq(events[qty])
        return m
