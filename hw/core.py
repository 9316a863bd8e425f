"""The accelerator core: memories, element / pair / node pipelines, control and the host interface.

One time step runs in two phases:

  ELEMENTS  every element lane streams its elements, one per clock (II = 1), through the element
            pipeline (hw/datapath.py `element_kernel`, built by hw/pipeline.py); every pair lane streams
            its topology pairs through the pair pipeline (`pair_kernel`), and every collision lane its
            (surface vertex, surface facet) pairs through the collision pipeline (`collision_kernel`: no
            broad phase, the static list of every pair that may touch), at the same time. Each lane
            writes its new element state and adds its forces into its own force accumulator banks.
  NODES     every node lane streams its nodes through the node pipeline (`node_kernel`: sum of the banks,
            floor, friction, loads, mass, gravity, pins), writes u and x, and clears the banks.

  cycles per step = max(ceil(E/P), ceil(pairs/P), ceil(collision pairs/P)) + drain_elements + ceil(N/Q)
                    + drain_nodes

Force accumulation without read-after-write hazards, by construction: every lane owns one accumulator
bank per role (element: node i, node j; pair: the vertex and each facet vertex), a simple dual-port
memory read, its word registered, and written back two cycles after the read (RMW_WRITE). The two items
just ahead write in the cycle of this one's read and in the next, which the read cannot see: when either
addressed the same word, the later one's sum is taken from a register instead of the word read. The read
port is not transparent (a block RAM's cross-port transparency costs soft bypass logic after its slow
output). Any element order is correct, and no two lanes ever share a bank. The node pipeline adds the banks exactly (integers wide
enough for the largest number of contributions any node receives), so the result equals the bit-true
model's exact scatter, whatever the order.

Node state (x, u per dimension) lives in memories of ceil(N/Q) words, one memory per node lane slot;
element lanes read both end nodes through their own read ports.

Host interface (`host`): the registers and address map of hw/hostmap.py (one definition, shared with the
host driver, the testbench and the manifest); writes take effect at once, reads return `r_data` with
`r_valid` exactly READ_LATENCY cycles after `r_en`. Writes to memories while busy are ignored, and memory
reads while busy return undefined words: the host shares the pipeline's read ports (block RAM). Node n
lives in memory n % Q at word n // Q, element e in lane e % P at position e // P (`HostMap.interleaved`).
"""
from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np
from amaranth.hdl import Cat, Const, Module, Mux, Shape, Signal, signed, unsigned
from amaranth.lib import wiring
from amaranth.lib.memory import Memory
from amaranth.lib.wiring import In, Out

from golden.errors import BadArgument
from .datapath import NotSupported, Params, _node_flags, collision_kernel, element_kernel, node_kernel, pair_kernel
from .hostmap import ADDR_BITS, ELEM_BASE, ID_WORD, NODE_BASE, HostMap, Reg
from .pipeline import PipeArith
from .rtl_fixed import as_shape, tree_sum

# (vertex, facet) pair kinds: lane name prefix, Params table, per-item kernel
PAIR_KINDS = (("pr", "topology", pair_kernel), ("co", "collision", collision_kernel))
SAT_COUNT_LATENCY = 2  # lane sums of saturation flags, then their sum over lanes, then sat_count
RMW_WRITE = 2          # an accumulator bank word read at stage s is written back at stage s + RMW_WRITE

HostSignature = wiring.Signature({
    "addr": Out(ADDR_BITS), "w_data": Out(32), "w_en": Out(1), "r_en": Out(1),
    "r_data": In(32), "r_valid": In(1),
})


PHASED_NO_PROBE = ("the phased core has no probe port: a scene with a [probe] runs on the streaming core "
                   "(--core stream or auto)")


@dataclass
class CoreConfig:
    """Everything the core is built from: the scene's datapath parameters, formats, function units,
    lane counts and the static mapping of elements, pairs and nodes onto lanes and memory words."""
    params: Params
    formats: object
    units: dict
    lanes: int = 1             # P: element lanes (and pair lanes)
    node_lanes: int = 1        # Q: node lanes (nodes per memory word)
    init: dict = field(default_factory=dict)     # initial raw state: X, U (lists), A

    def __post_init__(self):
        for name, v in (("lanes", self.lanes), ("node_lanes", self.node_lanes)):
            if isinstance(v, bool) or not isinstance(v, int) or not 1 <= v <= 64:
                raise BadArgument(f"{name} must be an integer in 1..64, got {v!r}")
        if self.params.probe is not None:
            raise NotSupported(PHASED_NO_PROBE)

    @classmethod
    def of(cls, bt, lanes=1, node_lanes=1) -> "CoreConfig":
        st = bt.initial_state()
        return cls(bt.params, bt.formats, bt.ar.units, lanes, node_lanes,
                   {"X": st.X, "U": st.U, "A": st.A})

    # ---- static mapping
    @property
    def dim(self):
        return self.params.dim

    @property
    def n_nodes(self):
        return self.params.n_nodes

    @property
    def n_elements(self):
        return len(self.params.i)

    def pairs(self, kind: str) -> np.ndarray:
        """The (vertex, facet) pairs of one kind ("topology" or "collision"), (n, D + 1); empty if absent."""
        table = getattr(self.params, kind)
        return np.zeros((0, self.dim + 1), np.int64) if table is None else table["pairs"]

    @property
    def n_pairs(self):
        """Topology preservation pairs."""
        return len(self.pairs("topology"))

    @property
    def n_collision_pairs(self):
        """Collision pairs (every surface vertex with every surface facet it may touch)."""
        return len(self.pairs("collision"))

    @property
    def node_words(self):
        return -(-self.n_nodes // self.node_lanes)

    @property
    def element_slots(self):
        """Elements per lane (the longest lane): element e runs in lane e % P at position e // P."""
        return -(-self.n_elements // self.lanes)

    @property
    def pair_slots(self):
        return -(-self.n_pairs // self.lanes)

    @property
    def collision_slots(self):
        return -(-self.n_collision_pairs // self.lanes)

    def lane_items(self, n_items, lane):
        return np.arange(lane, n_items, self.lanes)

    # ---- host addresses (hw/hostmap.py; no division in hardware: fields are bit ranges)
    @functools.cached_property
    def host_map(self) -> HostMap:
        return HostMap.interleaved(self.dim, self.n_nodes, self.node_lanes, self.n_elements, self.lanes)

    @property
    def word_bits(self):
        return self.host_map.word_bits

    @property
    def slot_bits(self):
        return self.host_map.slot_bits

    @property
    def pos_bits(self):
        return self.host_map.pos_bits

    @property
    def lane_bits(self):
        return self.host_map.lane_bits

    def features(self):
        return self.params.features()


def schedule(cfg: CoreConfig) -> dict:
    """The core's static timing (known when it is constructed): cycles per step and the pipeline drains."""
    core = Core(cfg)
    core._MustUse__used = True               # built for its facts only (no UnusedElaboratable warning)
    return {"cycles_per_step": core.cycles_per_step, "drain_elements": core.drain_elements,
            "drain_nodes": core.drain_nodes, "lanes": cfg.lanes, "node_lanes": cfg.node_lanes}


def _discard(m: Module) -> None:
    """Mark a module built only to learn its schedule, and its submodules, as used: they are never
    elaborated, and Amaranth would warn that they were "created but never used"."""
    for sub in [m] + [s for s, _ in m._named_submodules.values()] + [s for s, _ in m._anon_submodules]:
        sub._MustUse__used = True


def _bits(n):
    return max(1, int(n - 1).bit_length()) if n > 1 else 1


def _registered(m, value, name):
    """value one cycle later, in a register: memory read data goes through one before any arithmetic (a
    block RAM's clock-to-output delay is about half a 100 MHz cycle)."""
    r = Signal.like(value, name=name)
    m.d.sync += r.eq(value)
    return r


class Core(wiring.Component):
    """The specialised accelerator for one scene (see the module docstring for phases and registers).

    Known at construction (the pipelines are built once on a scratch module to learn their depths):
    `cycles_per_step`, `drain_elements`, `drain_nodes`, `sat_quantities` (the saturation flags' order),
    `const_saturations`, `units_present` and `memories`, every memory of the hierarchy (name, depth,
    width): the core's own and those of its function units (the 1/sqrt seed ROMs, the Phi / Psi table
    ROMs), the latter named by their place in the hierarchy.
    """

    def __init__(self, cfg: CoreConfig):
        if not isinstance(cfg, CoreConfig):
            raise TypeError(f"Core needs a CoreConfig, got {type(cfg).__name__}")
        self.cfg = cfg
        super().__init__({"host": In(HostSignature)})
        _discard(self._build())           # a dry build: the schedule and the inventory, known now
        self._facts = self._schedule_facts()

    def _schedule_facts(self):
        return (self.cycles_per_step, self.drain_elements, self.drain_nodes, list(self.sat_quantities),
                [dict(m) for m in self.memories])

    def elaborate(self, platform):
        m = self._build()
        if self._schedule_facts() != self._facts:
            raise AssertionError("the core elaborated differently from its construction")
        return m

    def _build(self):
        cfg, p, fmt = self.cfg, self.cfg.params, self.cfg.formats
        D, P, Q = cfg.dim, cfg.lanes, cfg.node_lanes
        W = cfg.node_words
        m = Module()
        host = self.host
        self.memories = []
        self._own_memories = []

        def add_mem(name, mem):
            m.submodules[name] = mem
            self._own_memories.append(mem)
            self.memories.append({"name": name, "depth": mem.depth, "width": Shape.cast(mem.shape).width})

        busy = Signal()
        phase = Signal(2)                 # 0 elements, 1 element drain, 2 nodes, 3 node drain
        cnt = Signal(32)
        steps_left = Signal(32)
        step_no = Signal(32)
        cycles = Signal(32)
        self.const_saturations = {}

        # ---------------------------------------------------------------- node state memories
        xs, us = as_shape(fmt["x"]), as_shape(fmt["u"])
        init = cfg.init
        def node_init(arr, q):
            a = np.zeros(W, np.int64)
            vals = np.asarray(arr)[q::Q]
            a[:len(vals)] = vals
            return [int(v) for v in a]
        Xm = [[Memory(shape=xs, depth=W, init=node_init(init["X"][k], q)) for q in range(Q)] for k in range(D)]
        Um = [[Memory(shape=us, depth=W, init=node_init(init["U"][k], q)) for q in range(Q)] for k in range(D)]
        for k in range(D):
            for q in range(Q):
                add_mem(f"x{k}_{q}", Xm[k][q])
                add_mem(f"u{k}_{q}", Um[k][q])
        node_fields = [Xm[k] for k in range(D)] + [Um[k] for k in range(D)]

        def read_node(word, slot, name):
            """Read ports on every node field for a node (word, slot); data two cycles later (registered)."""
            outs = []
            slot_d = Signal.like(slot, name=f"{name}_slot_d")
            m.d.sync += slot_d.eq(slot)
            for fi, mems in enumerate(node_fields):
                datas = []
                for q in range(Q):
                    rp = mems[q].read_port(domain="sync")
                    m.d.comb += rp.addr.eq(word)
                    datas.append(rp.data)
                if Q == 1:
                    outs.append(_registered(m, datas[0], f"{name}_f{fi}_r"))
                else:
                    sel = Signal(mems[0].shape, name=f"{name}_f{fi}")
                    with m.Switch(slot_d):
                        for q in range(Q):
                            with m.Case(q):
                                m.d.comb += sel.eq(datas[q])
                    outs.append(_registered(m, sel, f"{name}_f{fi}_r"))
            return outs[:D], outs[D:]

        # ---------------------------------------------------------------- accumulator banks
        banks = []        # (lane, role name, [k][q] memories, width)

        def make_bank(name, width):
            mems = [[Memory(shape=signed(width), depth=W, init=[]) for q in range(Q)] for k in range(D)]
            for k in range(D):
                for q in range(Q):
                    add_mem(f"acc_{name}_{k}_{q}", mems[k][q])
            ports = [[None] * Q for _ in range(D)]
            for k in range(D):
                for q in range(Q):
                    wp = mems[k][q].write_port()
                    rp = mems[k][q].read_port(domain="sync")
                    ports[k][q] = (rp, wp, _registered(m, rp.data, f"acc_{name}_{k}_{q}_r"))
            banks.append((name, ports, width))
            return ports

        def acc_width(nodes_of_role):
            cnt_max = int(np.bincount(nodes_of_role, minlength=1).max()) if len(nodes_of_role) else 1
            return fmt["fe"].width + cnt_max.bit_length() + 1

        # the element / pair pipelines' RMW requests: (ports, word, slot, [fe per k], enable, stage, arith)
        rmw = []

        # ---------------------------------------------------------------- element lanes
        elem_phase_valid = Signal()
        m.d.comb += elem_phase_valid.eq(busy & (phase == 0))
        S = cfg.element_slots
        drains = []
        all_arith = []
        self.elem_state_mems = []
        for lane in range(P):
            items = cfg.lane_items(cfg.n_elements, lane)
            valid0 = Signal(name=f"el{lane}_valid0")
            m.d.comb += valid0.eq(elem_phase_valid & (cnt < len(items)))
            rom_fields = []
            def src(q, raw, shape, items=items, rom_fields=rom_fields, lane=lane):
                sig = Signal(shape, name=f"el{lane}_prm_{q}")
                vals = np.zeros(S, np.int64)
                vals[:len(items)] = np.asarray(raw)[items]
                rom_fields.append((sig, vals))
                return _registered(m, sig, f"el{lane}_prm_{q}_r")
            # stage 0: ROM and element state read; 2: ROM data (parameters, node addresses, which then read
            # the node memories) and element state registered; 4: node x, u registered
            ar = PipeArith(m, fmt, cfg.units, valid0, f"el{lane}", src, param_stage=2)
            all_arith.append(ar)
            iw, jw = (Signal(_bits(W), name=f"el{lane}_{n}") for n in ("iw", "jw"))
            is_, js = (Signal(_bits(Q), name=f"el{lane}_{n}") for n in ("is", "js"))
            ni, nj = p.i[items], p.j[items]
            for sig, arr in ((iw, ni // Q), (is_, ni % Q), (jw, nj // Q), (js, nj % Q)):
                vals = np.zeros(S, np.int64)
                vals[:len(items)] = arr
                rom_fields.append((sig, vals))
            iw, is_, jw, js = (_registered(m, v, f"{v.name}_r") for v in (iw, is_, jw, js))
            Xi, Ui = read_node(iw, is_, f"el{lane}_ni")
            Xj, Uj = read_node(jw, js, f"el{lane}_nj")
            # element state: a only (the damper is solved exactly each step, no |T| of the previous step)
            a_shape = as_shape(fmt["a"])
            has_a = not p.fixed_a
            a_vals = np.zeros(S, np.int64)
            a_vals[:len(items)] = np.asarray(init["A"])[items]
            A_mem = Memory(shape=a_shape, depth=S, init=[int(v) for v in a_vals])
            add_mem(f"el{lane}_a", A_mem)
            A_wp = A_mem.write_port() if has_a else None
            A_rp = A_mem.read_port(domain="sync")
            m.d.comb += A_rp.addr.eq(cnt)
            with ar:
                A_r = _registered(m, A_rp.data, f"el{lane}_a_r")
                A = ar.input(A_r, "a", 2)
                fe, newA = element_kernel(
                    ar, p, [ar.input(v, "x", 4) for v in Xi], [ar.input(v, "x", 4) for v in Xj],
                    [ar.input(v, "u", 4) for v in Ui], [ar.input(v, "u", 4) for v in Uj], A)
                fe_neg = [ar.neg(v) for v in fe]          # node j's word (saturating, as the model)
                outs = fe + fe_neg + ([newA] if newA is not None else [])
                s_out = max(v.stage for v in outs)
            slot_at = ar.delay(cnt[:_bits(S) + 1], 0, s_out)
            en = ar.valid_at(s_out)
            if has_a:
                m.d.comb += [A_wp.addr.eq(slot_at), A_wp.data.eq(ar.at(newA, s_out)), A_wp.en.eq(en)]
            # (memory, pipeline write port or None, read port, registered read data)
            self.elem_state_mems.append((A_mem, A_wp, A_rp, A_r))
            # the ROM of this lane: node words/slots and per-element parameters
            self._rom(m, add_mem, f"el{lane}_rom", rom_fields, S, cnt)
            fe_out = [ar.at(v, s_out) for v in fe]
            neg = [ar.at(v, s_out) for v in fe_neg]
            rmw.append((make_bank(f"el{lane}_i", acc_width(ni)), ar.delay(iw, 2, s_out), ar.delay(is_, 2, s_out),
                        fe_out, en, s_out, ar))
            rmw.append((make_bank(f"el{lane}_j", acc_width(nj)), ar.delay(jw, 2, s_out), ar.delay(js, 2, s_out),
                        neg, en, s_out, ar))
            drains.append(s_out + RMW_WRITE + 1)

        # ---------------------------------------------------------------- pair lanes (topology, collisions)
        for prefix, kind, kernel in PAIR_KINDS:
            pairs = cfg.pairs(kind)
            if not len(pairs):
                continue
            SP = -(-len(pairs) // P)
            for lane in range(P):
                items = cfg.lane_items(len(pairs), lane)
                valid0 = Signal(name=f"{prefix}{lane}_valid0")
                m.d.comb += valid0.eq(elem_phase_valid & (cnt < len(items)))
                rom_fields = []
                ar = PipeArith(m, fmt, cfg.units, valid0, f"{prefix}{lane}", None, param_stage=1)
                all_arith.append(ar)
                X_roles, U_roles, words, slots = [], [], [], []
                for r in range(D + 1):
                    nodes = pairs[items, r]
                    w_ = Signal(_bits(W), name=f"{prefix}{lane}_w{r}")
                    s_ = Signal(_bits(Q), name=f"{prefix}{lane}_s{r}")
                    for sig, arr in ((w_, nodes // Q), (s_, nodes % Q)):
                        vals = np.zeros(SP, np.int64)
                        vals[:len(items)] = arr
                        rom_fields.append((sig, vals))
                    # stage 2: the ROM's node address registered; 4: node x, u registered
                    w_, s_ = _registered(m, w_, f"{w_.name}_r"), _registered(m, s_, f"{s_.name}_r")
                    Xr, Ur = read_node(w_, s_, f"{prefix}{lane}_n{r}")
                    X_roles.append(Xr)
                    U_roles.append(Ur)
                    words.append(w_)
                    slots.append(s_)
                self._rom(m, add_mem, f"{prefix}{lane}_rom", rom_fields, SP, cnt)
                with ar:
                    ins = [[ar.input(v, "x", 4) for v in X_roles[r]] for r in range(D + 1)]
                    ins += [[ar.input(v, "u", 4) for v in U_roles[r]] for r in range(D + 1)]
                    gate, contribs = kernel(ar, p, *ins)
                    s_out = max(v.stage for _, v, _ in contribs)
                    cond = ar.delay(gate.cond.sig, gate.cond.stage, s_out)
                en = ar.valid_at(s_out) & cond
                for r in range(D + 1):
                    per_k = [None] * D
                    for k, v, role in contribs:
                        if role == r:
                            per_k[k] = ar.at(v, s_out)
                    rmw.append((make_bank(f"{prefix}{lane}_r{r}", acc_width(pairs[items, r])),
                                ar.delay(words[r], 2, s_out), ar.delay(slots[r], 2, s_out), per_k, en, s_out, ar))
                drains.append(s_out + RMW_WRITE + 1)

        # ---------------------------------------------------------------- RMW into the banks
        node_phase_valid = Signal()
        m.d.comb += node_phase_valid.eq(busy & (phase == 2))
        clear_en = Signal()
        clear_addr = Signal(_bits(W) + 1)
        m.d.sync += [clear_en.eq(node_phase_valid & (cnt < W)), clear_addr.eq(cnt)]
        for ports, word, slot, vals, en, s_out, ar in rmw:
            # element phase: read at s_out, the word registered at s_out + 1, added and written at
            # s_out + 2 (RMW_WRITE); node phase: read, clear
            word1 = ar.delay(word, s_out, s_out + 1)
            word2 = ar.delay(word, s_out, s_out + RMW_WRITE)
            word3 = ar.delay(word, s_out, s_out + RMW_WRITE + 1)
            slot2 = ar.delay(slot, s_out, s_out + RMW_WRITE)
            en2 = ar.delay(en, s_out, s_out + RMW_WRITE)
            for k in range(D):
                v2 = ar.delay(vals[k], s_out, s_out + RMW_WRITE)
                for q in range(Q):
                    rp, wp, rd = ports[k][q]
                    wen = en2 & (slot2 == q)
                    # the item one behind (at s_out + 1 now) and the one two behind (at s_out + 2 next
                    # cycle, when this write is a cycle old) read before this write: the flags, decided a
                    # cycle ahead, make them add to this sum (a register) instead of what they read
                    wen3 = Signal(name=f"{ar.name}_wen3_{k}_{q}")
                    fwd1 = Signal(name=f"{ar.name}_fwd1_{k}_{q}")
                    fwd2 = Signal(name=f"{ar.name}_fwd2_{k}_{q}")
                    last1 = Signal.like(wp.data, name=f"{ar.name}_last1_{k}_{q}")
                    last2 = Signal.like(wp.data, name=f"{ar.name}_last2_{k}_{q}")
                    m.d.sync += [wen3.eq(wen), fwd1.eq(wen & (word1 == word2)), fwd2.eq(wen3 & (word1 == word3)),
                                 last1.eq(wp.data), last2.eq(last1)]
                    m.d.comb += rp.addr.eq(Mux(phase[1], cnt, word))
                    m.d.comb += [
                        wp.addr.eq(Mux(phase[1], clear_addr, word2)),
                        wp.data.eq(Mux(phase[1], 0, Mux(fwd1, last1, Mux(fwd2, last2, rd)) + v2)),
                        wp.en.eq(Mux(phase[1], clear_en, wen)),
                    ]

        # ---------------------------------------------------------------- node lanes
        flags = _node_flags(p)
        node_outs = []
        node_lane_reads = {}          # (node field, slot): the node lane's read port, shared with host reads
        n_drain = 0
        last_fill = cfg.n_nodes - (W - 1) * Q
        for q in range(Q):
            valid0 = Signal(name=f"nd{q}_valid0")
            exists = (cnt < W - 1) | Const(int(q < last_fill), 1) if W > 1 else Const(int(q < last_fill), 1)
            m.d.comb += valid0.eq(node_phase_valid & (cnt < W) & exists)
            rom_fields = []
            def src(name, raw, shape, q=q, rom_fields=rom_fields):
                sig = Signal(shape, name=f"nd{q}_prm_{name}")
                vals = np.zeros(W, np.int64)
                arr = np.asarray(raw)[q::Q]
                vals[:len(arr)] = arr
                rom_fields.append((sig, vals))
                return _registered(m, sig, f"nd{q}_prm_{name}_r")
            # stage 0: memories and ROM read; 2: x, u, parameters and bank words registered; 3: sum of the banks
            ar = PipeArith(m, fmt, cfg.units, valid0, f"nd{q}", src, param_stage=2)
            all_arith.append(ar)
            Xq, Uq = [], []
            for k in range(D):
                for mems, out in ((Xm, Xq), (Um, Uq)):
                    rp = mems[k][q].read_port(domain="sync")
                    m.d.comb += rp.addr.eq(cnt)
                    out.append(_registered(m, rp.data, f"nd{q}_{'x' if mems is Xm else 'u'}{k}_r"))
                    node_lane_reads[k + D * (mems is Um), q] = (rp, out[-1])
            # exact sum of the banks' slot q (their words registered first), registered: valid at stage 3
            F_elem = []
            for k in range(D):
                total = tree_sum([ports[k][q][2] for _, ports, _ in banks])
                r = Signal(signed(max(w for _, _, w in banks) + _bits(len(banks)) + 1), name=f"nd{q}_facc{k}")
                m.d.sync += r.eq(total)
                F_elem.append(r)
            with ar:
                X = [ar.input(v, "x", 2) for v in Xq]
                U = [ar.input(v, "u", 2) for v in Uq]
                Fe = [ar.input(v, "fe", 3) for v in F_elem]
                newX, newU = node_kernel(ar, p, X, U, Fe, step_no, flags)
                s_out = max(v.stage for v in newX + newU)
            self._rom(m, add_mem, f"nd{q}_rom", rom_fields, W, cnt)
            word_at = ar.delay(cnt[:_bits(W) + 1], 0, s_out)
            node_outs.append((q, word_at, [ar.at(v, s_out) for v in newX], [ar.at(v, s_out) for v in newU],
                              ar.valid_at(s_out)))
            n_drain = max(n_drain, s_out + 1)

        # ---------------------------------------------------------------- host access to node / element memories
        h_addr = host.addr
        h_node = (h_addr >= NODE_BASE) & (h_addr < ELEM_BASE)
        h_elem = h_addr >= ELEM_BASE
        node_off = h_addr - NODE_BASE
        wbits, sbits = cfg.word_bits, cfg.slot_bits
        h_field = node_off >> (wbits + sbits)
        h_word, h_slot = node_off[:wbits], node_off[wbits:wbits + sbits]
        host_w_node = host.w_en & h_node & ~busy
        for fi, mems in enumerate(node_fields):
            k, is_u = fi % D, fi >= D
            for q in range(Q):
                wp = mems[q].write_port()
                hit = host_w_node & (h_field == fi) & (h_slot == q)
                pipe = [o for o in node_outs if o[0] == q][0]
                _, word_at, nx, nu, nvalid = pipe
                m.d.comb += [
                    wp.addr.eq(Mux(busy, word_at, h_word)),
                    wp.data.eq(Mux(busy, (nu if is_u else nx)[k], host.w_data)),
                    wp.en.eq(Mux(busy, nvalid, hit)),
                ]
        # host reads: the address goes to the (shared) read ports, whose data the pipeline registers; the
        # address, registered twice, selects among those registers; the answer is registered once more
        r_en1, r_addr1, r_en2, r_addr2 = Signal(), Signal(ADDR_BITS), Signal(), Signal(ADDR_BITS)
        m.d.sync += [r_en1.eq(host.r_en), r_addr1.eq(h_addr), r_en2.eq(r_en1), r_addr2.eq(r_addr1)]
        node_read = []
        for (fi, q), (rp, data_r) in node_lane_reads.items():
            with m.If(~busy):               # node lane q's read port, the host's while idle
                m.d.comb += rp.addr.eq(h_word)
            node_read.append((fi, q, data_r))
        e_off = h_addr - ELEM_BASE
        pbits, lbits = cfg.pos_bits, cfg.lane_bits
        e_field = e_off >> (pbits + lbits)
        e_pos, e_lane = e_off[:pbits], e_off[pbits:pbits + lbits]
        elem_read = []
        for lane, (mem, wp, rp, data_r) in enumerate(self.elem_state_mems):
            fi = 0                          # field 0: a
            with m.If(~busy):               # the element lane's read port, the host's while idle
                m.d.comb += rp.addr.eq(e_pos)
            elem_read.append((fi, lane, data_r))
            if wp is None:                  # no a-state in the pipeline: the host still loads a
                wp = mem.write_port()
                m.d.comb += [wp.addr.eq(e_pos), wp.data.eq(host.w_data),
                             wp.en.eq(host.w_en & h_elem & ~busy & (e_field == fi) & (e_lane == lane))]
        # (element state write ports: the pipeline drives them while busy, the host while idle)
        self._host_elem_writes(m, busy, host, h_elem, e_field, e_lane, e_pos)

        # ---------------------------------------------------------------- saturation accounting
        events = []
        for ar in all_arith:
            events += ar.saturation_events()
            for k, n in ar.const_sat.items():
                self.const_saturations[k] = self.const_saturations.get(k, 0) + n
        quantities = sorted({q for q, _ in events})
        self.sat_quantities = quantities
        sat_count = Signal(32)
        sat_flags = Signal(max(1, len(quantities)))
        if events:
            per_cycle = Signal(16)
            m.d.sync += per_cycle.eq(tree_sum([c for _, c in events]))
            hits = Cat(*[Cat(*[(c != 0) for qq, c in events if qq == q]).any() for q in quantities])
            new_count = sat_count + per_cycle
            with m.If(host.w_en & (h_addr == Reg.SATURATIONS)):
                m.d.sync += [sat_count.eq(0), sat_flags.eq(0)]
            with m.Else():
                m.d.sync += [sat_count.eq(Mux(new_count >> 32 != 0, 0xFFFFFFFF, new_count[:32])),
                             sat_flags.eq(sat_flags | hits)]

        # ---------------------------------------------------------------- control
        drain_e = max(drains)
        # the last node's saturation counts reach sat_count SAT_COUNT_LATENCY cycles after its flags: the
        # run ends (busy falls) only when every counter is final
        drain_n = n_drain + 1 + SAT_COUNT_LATENCY
        C_E = max(cfg.element_slots, cfg.pair_slots, cfg.collision_slots)
        self.drain_elements, self.drain_nodes = drain_e, drain_n
        self.cycles_per_step = C_E + drain_e + W + drain_n
        with m.If(busy):
            m.d.sync += cycles.eq(cycles + 1)
            with m.Switch(phase):
                with m.Case(0):
                    with m.If(cnt == C_E - 1):
                        m.d.sync += [cnt.eq(0), phase.eq(1)]
                    with m.Else():
                        m.d.sync += cnt.eq(cnt + 1)
                with m.Case(1):
                    with m.If(cnt == drain_e - 1):
                        m.d.sync += [cnt.eq(0), phase.eq(2)]
                    with m.Else():
                        m.d.sync += cnt.eq(cnt + 1)
                with m.Case(2):
                    with m.If(cnt == W - 1):
                        m.d.sync += [cnt.eq(0), phase.eq(3)]
                    with m.Else():
                        m.d.sync += cnt.eq(cnt + 1)
                with m.Case(3):
                    with m.If(cnt == drain_n - 1):
                        m.d.sync += [cnt.eq(0), phase.eq(0), step_no.eq(step_no + 1),
                                     steps_left.eq(steps_left - 1)]
                        with m.If(steps_left == 1):
                            m.d.sync += busy.eq(0)
                    with m.Else():
                        m.d.sync += cnt.eq(cnt + 1)
        with m.Elif(host.w_en):
            with m.If(h_addr == Reg.RUN):
                with m.If(host.w_data != 0):
                    m.d.sync += [busy.eq(1), steps_left.eq(host.w_data), phase.eq(0), cnt.eq(0)]
            with m.If(h_addr == Reg.STEP):
                m.d.sync += step_no.eq(host.w_data)

        # register reads: decode the address registered twice with r_en, answer one cycle later
        r_data = Signal(32)
        with m.Switch(r_addr2):
            with m.Case(Reg.ID):
                m.d.comb += r_data.eq(ID_WORD)
            with m.Case(Reg.RUN):
                m.d.comb += r_data.eq(steps_left)
            with m.Case(Reg.STATUS):
                m.d.comb += r_data.eq(Cat(busy, sat_flags.any()))
            with m.Case(Reg.STEP):
                m.d.comb += r_data.eq(step_no)
            with m.Case(Reg.SATURATIONS):
                m.d.comb += r_data.eq(sat_count)
            with m.Case(Reg.SATURATION_FLAGS):
                m.d.comb += r_data.eq(sat_flags)
            with m.Case(Reg.CYCLES):
                m.d.comb += r_data.eq(cycles)
            with m.Default():
                r_off = r_addr2 - NODE_BASE
                r_field, r_slot = r_off >> (wbits + sbits), r_off[wbits:wbits + sbits]
                re_off = r_addr2 - ELEM_BASE
                re_field, re_lane = re_off >> (pbits + lbits), re_off[pbits:pbits + lbits]
                with m.If((r_addr2 >= NODE_BASE) & (r_addr2 < ELEM_BASE)):
                    for fi, q, data in node_read:
                        with m.If((r_field == fi) & (r_slot == q)):
                            m.d.comb += r_data.eq(data.as_signed())
                with m.Elif(r_addr2 >= ELEM_BASE):
                    for fi, lane, data in elem_read:
                        with m.If((re_field == fi) & (re_lane == lane)):
                            m.d.comb += r_data.eq(data.as_signed())
        m.d.sync += [host.r_data.eq(r_data), host.r_valid.eq(r_en2)]
        for ar in all_arith:                 # the function units' memories, after the core's own
            self.memories += ar.memories
        self.units_present = self.cfg.features()
        return m

    def _host_elem_writes(self, m, busy, host, h_elem, e_field, e_lane, e_pos):
        """Element state write ports: the pipeline while busy, the host while idle."""
        for lane, (_, wp, *_) in enumerate(self.elem_state_mems):
            if wp is None:
                continue
            # the pipeline's assignments were made first in comb; override them when idle
            hit = host.w_en & h_elem & (e_field == 0) & (e_lane == lane)
            with m.If(~busy):
                m.d.comb += [wp.addr.eq(e_pos), wp.data.eq(host.w_data), wp.en.eq(hit)]

    @staticmethod
    def _rom(m, add_mem, name, fields, depth, addr):
        """One ROM holding every per-item field of a lane, read at stage 0, fields valid at stage 1."""
        if not fields:
            return
        widths = [f[0].shape().width for f in fields]
        words = []
        for n in range(depth):
            w, off = 0, 0
            for (sig, vals), width in zip(fields, widths):
                w |= (int(vals[n]) & ((1 << width) - 1)) << off
                off += width
            words.append(w)
        rom = Memory(shape=unsigned(sum(widths)), depth=max(depth, 1), init=words)
        add_mem(name, rom)
        rp = rom.read_port(domain="sync")
        m.d.comb += rp.addr.eq(addr)
        off = 0
        for (sig, _), width in zip(fields, widths):
            m.d.comb += sig.eq(rp.data[off:off + width])
            off += width
