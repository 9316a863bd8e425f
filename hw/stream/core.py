"""`StreamCore`: the streaming accelerator core (issue 15), composed of its components.

Node state is stored once (`NodeStore`, Q banks). The element and topology-pair streams run in a
bandwidth-reducing order (reverse Cuthill-McKee, hw/stream/order.py) on P element lanes (`ElementLane`)
and Pp pair lanes (`PairLane`, Pp = P unless asked), which read their nodes from a sliding window (`NodeWindow`, one ring copy
per read port, filled from the store just ahead of the first read) and add their forces into their own
rings (`ForceRing`, one per lane role). A node retires as soon as the stream has passed its last
contribution: Q node lanes (`NodeLane`) integrate it and write the store. There is no node phase and no
drain between steps: steps run back to back, one period T apart, on the static schedule
(hw/stream/schedule.py) that `Control` follows. `HostPort` speaks the register map of hw/hostmap.py,
with the node and element placement of the renumbering (`cfg.host_map`).

  cycles per step  T = max(ceil(E / P), ceil(pairs / Pp), the read-after-write bounds of the schedule)
  a run of n steps run_cycles(n) = A0 + (n - 1) T + drain + 1 (prologue, periods, epilogue)

Hazards are impossible by construction: the schedule is checked at construction against every
read-after-write rule, and the pipelines' stages it relies on come from dry runs of the kernels (each
lane asserts at elaboration that its pipeline has the same stages). The bit-true model's force sums are
exact integers, so the streaming order gives its bits exactly.

A scene with a [probe] adds `ProbePort` (hw/stream/probeport.py): the top's `probe_in` stream of device
samples and `force_out` stream of probe forces; each sample runs k steps, `probe_latency` cycles from
sample to force.

Block RAM fit (`cfg.dp16kd_budget`, the device's DP16KD; None: no fit): when the core's blocks
(`block_rams()`) exceed it, the shallow copies (the force rings' node copies, then the window's copies,
Wg words each in blocks 512 deep) move into LUT RAM one by one, the fewest LUT RAMs per block saved
first, until the rest fits (`lut_memories`). Same ports and latencies: the schedule and the bits do not
change.

Everything is known at construction: `cycles_per_step`, `schedule`, `sat_quantities`, `memories()`,
`block_rams()`, `lut_memories`, `probe_latency`.
"""
from __future__ import annotations

from amaranth.hdl import Cat, Module, Mux
from amaranth.lib import stream, wiring
from amaranth.lib.wiring import In, Out

from ..rtl_fixed import KEEP_APART_TAG
from .bram import LATENCY, lut_rams, plan_blocks, ram_record
from .config import StreamConfig
from .control import Control
from .element import ElementLane
from .floorplan import lane_pair_copies
from .forcering import ForceRing, RunSum
from .hostport import HostPort, HostSignature
from .node import NodeLane
from .nodeword import delay, segment
from .pair import PairLane
from .probeport import ProbePort
from .saturation import LATENCY as SAT_LATENCY
from .saturation import SaturationCounter
from .schedule import BUSY_FANOUT, ELEM_FANOUT, ISSUE_FANOUT, NODE_FANOUT, RETIRE_FANOUT, SAT_TAIL
from .store import NodeStore
from .tables import share as share_tables
from .window import NodeWindow

# a run's drain waits for a node's last saturation report: the node lane's 2 registers, then the counter's
assert SAT_TAIL == 2 + SAT_LATENCY, (SAT_TAIL, SAT_LATENCY)


class StreamCore(wiring.Component):
    def __init__(self, cfg: StreamConfig):
        if not isinstance(cfg, StreamConfig):
            raise TypeError(f"StreamCore needs a StreamConfig, got {type(cfg).__name__}")
        self.cfg = cfg
        sch, word, ram = cfg.schedule, cfg.word, cfg.ram
        P, Q, D = cfg.lanes, cfg.node_lanes, cfg.dim
        self.schedule = sch
        self.cycles_per_step = sch.period
        self.control = Control(sch, ram)
        self.store = NodeStore(word, Q, sch.groups, self._store_init(), ram)
        self.elements = [ElementLane(cfg, lane) for lane in range(P)]
        share_tables(self.elements, ram)           # lanes 2k and 2k + 1 share the function units' tables
        self.pairs = [PairLane(cfg, lane) for lane in range(cfg.pair_lanes)] if cfg.n_pairs else []
        share_tables(self.pairs, ram)
        reads = 2 * P + (D + 1) * len(self.pairs)
        pair_copies = lane_pair_copies(P, len(self.pairs), D)
        self.window = NodeWindow(word, Q, sch.window_groups, reads, 1, ram, fill_groups=pair_copies + [[reads]])
        fe = cfg.formats["fe"].width
        self.rings = [(RunSum if ring.runs else ForceRing)(D, fe, ring.acc_bits, Q, sch.ring_groups, ram)
                      for ring in cfg.rings]
        self.nodes = [NodeLane(cfg, q) for q in range(Q)]
        self.lut_memories = self._fit_block_ram(cfg.dp16kd_budget)
        self.probe = ProbePort(cfg) if cfg.params.probe is not None else None
        self.probe_latency = self.probe.latency if self.probe is not None else None
        lanes = self.elements + self.pairs + self.nodes + ([self.probe] if self.probe is not None else [])
        self.saturation = SaturationCounter([q for lane in lanes for q in lane.quantities])
        self.sat_quantities = self.saturation.quantities
        fields = [cfg.formats["x"]] * D + [cfg.formats["u"]] * D
        self.hostport = HostPort(cfg.host_map, fields, cfg.formats["a"], len(self.sat_quantities), ELEM_FANOUT,
                                 NODE_FANOUT)
        self.const_saturations = {}
        for dry in (cfg.element_dry, cfg.pair_dry, cfg.node_dry):
            for k, n in (dry.ar.const_sat.items() if dry is not None else ()):
                self.const_saturations[k] = self.const_saturations.get(k, 0) + n
        members = {"host": In(HostSignature)}
        if self.probe is not None:       # the top's probe_in__valid/ready/payload, force_out__valid/ready/payload
            pp = self.probe
            members.update({"probe_in": In(stream.Signature(pp.samples.payload.shape())),
                            "force_out": Out(stream.Signature(pp.forces.payload.shape()))})
        super().__init__(members)

    def _store_init(self):
        """The initial node words per bank (the scene's initial state; the host loads it anyway)."""
        cfg = self.cfg
        if "X" not in cfg.init:
            return None
        Q, Gs, word = cfg.node_lanes, cfg.schedule.groups, cfg.word
        banks = [[0] * Gs for _ in range(Q)]
        for n in range(cfg.n_nodes):
            o = cfg.order.inv[n]
            banks[n % Q][n // Q] = word.pack_int([x[o] for x in cfg.init["X"]], [u[o] for u in cfg.init["U"]])
        return banks

    def memories(self) -> list[dict]:
        """Every BlockRam of the core: name, depth, width, DP16KD blocks of the ECP5 variant."""
        out = self.store.rams() + self.window.rams()
        for ring, info in zip(self.rings, self.cfg.rings):
            out += ring.rams(info.name)
        for lane in self.elements + self.pairs:
            out += lane.rams()
        return out + self._roms()

    def block_rams(self) -> int:
        """DP16KD of the "ecp5" variant: the BlockRams of `memories()` and the lanes' own function-unit
        ROMs (those a lane does not share, hw/stream/tables.py), which Yosys infers."""
        own = self.own_unit_memories()
        units = sum(rows * cols for *_, rows, cols in (plan_blocks(mem["width"], mem["depth"]) for mem in own))
        return sum(mem["dp16kd"] for mem in self.memories()) + units

    def own_unit_memories(self) -> list[dict]:
        """The lanes' function-unit ROMs (1/sqrt seeds, damper tables) that no other lane shares: inferred,
        not BlockRams (hw/stream/tables.py). Names as in the Verilog ("el0.el0_inverse_phi_80.rom_0")."""
        from .tables import shares
        out = []
        for lane in self.elements + self.pairs + self.nodes:
            name = lane.prefix
            for mem in lane.unit_memories():
                if lane.tables is None or not shares(mem["width"], mem["depth"]):
                    unit = mem["name"].replace(f"dry_{name[:2]}", name, 1)
                    out.append({"name": f"{name}.{unit}", "depth": mem["depth"], "width": mem["width"]})
        return out

    def _fit_block_ram(self, budget: int | None) -> list[str]:
        """Move shallow copies into LUT RAM until block_rams() <= budget (module docstring); their names."""
        if budget is None:
            return []
        names = [info.name for info in self.cfg.rings]
        candidates = []                    # (its record, a LUT RAM's cost, mark it distributed)
        for ring, name in zip(self.rings, names):
            rec = ring.rams(name)[-1]
            cost = lut_rams(rec["width"], rec["depth"], self.cfg.node_lanes)     # a segment per node lane
            candidates.append((rec, cost, lambda ring=ring: setattr(ring, "lut_copy", True)))
        for k, rec in enumerate(self.window.rams()):
            candidates.append((rec, lut_rams(rec["width"], rec["depth"]), lambda k=k: self.window.lut_copies.add(k)))
        candidates.sort(key=lambda c: c[1] / c[0]["dp16kd"])     # fewest DPR16X4 per block saved first
        moved, excess = [], self.block_rams() - budget
        for rec, _, mark in candidates:
            if excess <= 0:
                break
            mark()
            moved.append(rec["name"])
            excess -= rec["dp16kd"]
        return moved

    def _roms(self) -> list[dict]:
        """The node lanes' and the control's ROMs (node lanes: widths from the dry run's per-item fields;
        the element and pair lanes' ROMs are in their rams())."""
        cfg, sch = self.cfg, self.schedule
        nd_bits = len(cfg.rings) + sum(b for _, b in cfg.node_dry.params)
        out = [ram_record(f"nd{lane.q}_rom", max(1, nd_bits), sch.groups) for lane in self.nodes]
        return out + [ram_record("fill_phases", 1, sch.period), ram_record("retire_phases", 1, sch.period)]

    def elaborate(self, platform):
        m = Module()
        cfg, sch = self.cfg, self.schedule
        Q, D, word = cfg.node_lanes, cfg.dim, cfg.word
        ctl, store, win, hp, sat = self.control, self.store, self.window, self.hostport, self.saturation
        m.submodules.control, m.submodules.store, m.submodules.window = ctl, store, win
        m.submodules.hostport, m.submodules.saturation = hp, sat
        wiring.connect(m, wiring.flipped(self.host), hp.bus)

        # control <-> host port (and the probe port, whose runs the host's cannot interrupt)
        pp = self.probe
        if pp is None:
            m.d.comb += [ctl.start.eq(hp.run_start), ctl.steps.eq(hp.run_steps)]
        else:
            m.submodules.probe = pp
            wiring.connect(m, wiring.flipped(self.probe_in), pp.samples)
            wiring.connect(m, pp.forces, wiring.flipped(self.force_out))
            m.d.comb += [pp.busy.eq(ctl.busy), pp.host_start.eq(hp.run_start),
                         ctl.start.eq(pp.start | (hp.run_start & ~pp.active)),
                         ctl.steps.eq(Mux(pp.start, pp.steps, hp.run_steps))]
            for lane in self.nodes:
                for name in ("P", "Pdot", "Lo", "Hi"):
                    m.d.comb += getattr(lane, f"probe_{name}").eq(getattr(pp, f"reg_{name}"))
                m.d.comb += [pp.lanes[lane.q].valid.eq(lane.probe_valid), pp.lanes[lane.q].first.eq(lane.probe_first),
                             pp.lanes[lane.q].touch.eq(lane.probe_touch), pp.lanes[lane.q].f.eq(lane.probe_f)]
        # `busy` registered where it selects between the pipeline and the host (BUSY_FANOUT: the store and
        # each element lane, each copy kept apart: the control's register fed every lane's a memory ports
        # across the die, 14 ns on the 1e4 square); the host sees the core busy until every copy is idle
        def busy_at(name):
            return delay(m, ctl.busy, BUSY_FANOUT, f"{name}_busy{KEEP_APART_TAG}")
        m.d.comb += [ctl.step_we.eq(hp.step_we),
                     ctl.step_wdata.eq(hp.step_wdata),
                     hp.busy.eq(ctl.busy | busy_at("host")), hp.steps_left.eq(ctl.steps_left), hp.step.eq(ctl.step),
                     hp.cycles.eq(ctl.cycles), hp.sat_count.eq(sat.count), hp.sat_flags.eq(sat.flags),
                     sat.clear.eq(hp.sat_clear)]

        # node store: the fill reads, the node lanes write, the host while idle (its access registered in
        # front of the store, NODE_FANOUT, kept apart: Yosys merged it with an element lane's copy of the
        # same bus; the host port expects the store's word that much later)
        def node_host(what, data=True):
            return delay(m, getattr(hp, f"node_{what}"), NODE_FANOUT, f"store_host_{what}{KEEP_APART_TAG}",
                         data=data)
        m.d.comb += [store.busy.eq(Cat(*[busy_at(f"store{q}") for q in range(Q)])), store.rd_addr.eq(ctl.fill.group),
                     store.h_addr.eq(node_host("addr")), store.h_bank.eq(node_host("bank")),
                     store.h_field.eq(node_host("field")), store.h_wdata.eq(node_host("wdata")),
                     store.h_we.eq(node_host("we", data=False)), hp.node_rdata.eq(store.h_rdata)]
        # the fill: the store's group, `fill_latency` cycles after the control presents it, into every window copy
        m.d.comb += [win.fill_addr.eq(delay(m, ctl.fill.slot, store.fill_latency, "fill_slot", data=True)),
                     win.fill_en.eq(delay(m, ctl.fill.valid, store.fill_latency, "fill_valid")),
                     win.fill_data.eq(store.rd_data)]

        # element and pair lanes: issue, window reads, contributions into their rings
        # each element lane registers the host's access (ELEM_FANOUT, its copy kept apart: one register fed
        # every lane's a memory); the host port expects the lanes' words that much later
        def host_at(lane, what, value, data=True):
            return delay(m, value, ELEM_FANOUT, f"{lane.prefix}_host_{what}{KEEP_APART_TAG}", data=data)
        ports = []
        for lane in self.elements:
            m.submodules[f"el{lane.lane}"] = lane
            m.d.comb += [lane.busy.eq(busy_at(lane.prefix)), lane.host_pos.eq(host_at(lane, "pos", hp.elem_pos)),
                         lane.host_wdata.eq(host_at(lane, "wdata", hp.elem_wdata)),
                         lane.host_we.eq(host_at(lane, "we", hp.elem_we[lane.lane], data=False)),
                         hp.elem_rdata[lane.lane].eq(lane.host_rdata)]
            ports += [(lane.ring_i, lane.contrib_lo), (lane.ring_j, lane.contrib_hi)]
        for lane in self.pairs:
            m.submodules[f"pr{lane.lane}"] = lane
            ports += [(lane.rings[r], lane.contribs[r]) for r in range(D + 1)]
        # each lane registers the issue (ISSUE_FANOUT: the control issues that much earlier), its copy kept
        # apart from the others' in Yosys: one register fed every lane's ROM and a-memory address
        for lane in self.elements + self.pairs:
            for f in ("valid", "slot", "base"):
                m.d.comb += getattr(lane.issue, f).eq(delay(m, getattr(ctl.issue, f), ISSUE_FANOUT,
                                                            f"{lane.prefix}_issue_{f}{KEEP_APART_TAG}",
                                                            data=f != "valid"))
        for (read, contrib), window_port, ring, info in zip(ports, win.reads, self.rings, cfg.rings):
            m.submodules[f"ring_{info.name}"] = ring
            wiring.connect(m, read, window_port)
            wiring.connect(m, contrib, ring.add)

        # retirement: the window's group port and every ring's node copy at the group's slot; each registers
        # the retirement (RETIRE_FANOUT: the control retires that much earlier), as each node lane does,
        # its copy kept apart: one register fed every ring across the die
        def retired(what, name):
            return delay(m, getattr(ctl.retire, what), RETIRE_FANOUT, f"{name}_retire_{what}{KEEP_APART_TAG}",
                         data=what not in ("valid", "last"))
        m.d.comb += win.groups[0].addr.eq(retired("slot", "window"))
        for ring, info in zip(self.rings, cfg.rings):
            m.d.comb += ring.node_addr.eq(retired("slot", f"ring_{info.name}")[:len(ring.node_addr)])   # mod Wr
        for lane in self.nodes:
            q = lane.q
            m.submodules[f"nd{q}"] = lane
            m.d.comb += [lane.retire.valid.eq(retired("valid", f"nd{q}")), lane.retire.group.eq(retired("group", f"nd{q}")),
                         lane.retire.step.eq(retired("step", f"nd{q}")),
                         lane.node.eq(segment(win.groups[0].data, q, word.bits, Q)),
                         lane.forces.eq(Cat(*[segment(ring.node_data, q, D * ring.acc_bits, Q) for ring in self.rings]))]
        m.d.comb += [store.wr_addr.eq(self.nodes[0].store_group),
                     store.wr_en.eq(Cat(*[lane.store_en for lane in self.nodes])),
                     store.wr_data.eq(Cat(*[lane.store_data for lane in self.nodes]))]

        # saturation events, in the order the counter was built with
        evs = [getattr(lane, f"sat{k}") for lane in self.elements + self.pairs + self.nodes + ([pp] if pp else [])
               for k in range(len(lane.quantities))]
        for k, ev in enumerate(evs):
            m.d.comb += getattr(sat, f"ev{k}").eq(ev)
        return m
