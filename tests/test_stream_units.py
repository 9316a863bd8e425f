"""The streaming core's storage and control components, each against a small pure-Python reference in
Amaranth's simulator: NodeStore, NodeWindow, ForceRing (read-modify-write with forwarding and the
first-contribution flag), RunSum, SaturationCounter, HostPort and Control (against the schedule's event
cycles). The lanes are in tests/test_stream_lanes.py.
"""
from __future__ import annotations

import numpy as np
import pytest
from amaranth.hdl._ast import SignalDict
from amaranth.sim import Simulator

from hw.fixed import SQ
from hw.hostmap import ELEM_BASE, ID_WORD, NODE_BASE, HostMap, Reg
from hw.stream.control import Control
from hw.stream.forcering import ForceRing, RunSum
from hw.stream.hostport import HostPort
from hw.stream.nodeword import NodeWord
from hw.stream.order import stream_order
from hw.stream.saturation import SaturationCounter
from hw.stream.schedule import Latencies, build_schedule
from hw.stream.store import NodeStore
from hw.stream.window import NodeWindow

pytestmark = pytest.mark.hdl      # Amaranth's simulator or HDL simulators: `make test-fast` leaves these out


def sd(mapping):
    """A {signal: value} table (Amaranth signals are not hashable: a SignalDict)."""
    out = SignalDict()
    for k, v in mapping:
        out[k] = v
    return out


def simulate(dut, cycles, drive, sample):
    """Each cycle t: inputs from drive(t, get) (signal -> value pairs; `get` reads the design), then
    sample(t, get) with those inputs applied (combinational outputs of cycle t), then the clock edge."""
    sim = Simulator(dut)
    sim.add_clock(1e-8)

    async def bench(ctx):
        for t in range(cycles):
            for sig, v in drive(t, ctx.get).items():
                ctx.set(sig, int(v))
            sample(t, ctx.get)
            await ctx.tick()
    sim.add_testbench(bench)
    sim.run()


def rbits(rng, n):
    """A random n-bit integer (n may exceed 63)."""
    return int.from_bytes(rng.bytes((n + 7) // 8), "little") & ((1 << n) - 1)


def signed(v, bits):
    v &= (1 << bits) - 1
    return v - (1 << bits) if v >> (bits - 1) else v


# ------------------------------------------------------------------------------------------ NodeStore

def test_node_store_groups_and_host_fields():
    word = NodeWord(2, SQ(4, 14), SQ(-2, 20))           # 18-bit fields
    Q, G = 3, 7
    dut = NodeStore(word, Q, G)
    rng = np.random.default_rng(1)
    mem = [[0] * G for _ in range(Q)]                   # reference: node words per bank
    fb, nb = word.field_bits, word.bits
    log, expect = [], {}
    plan = []
    for t in range(200):                                # idle (host) for 60 cycles, then busy
        busy = t >= 60
        plan.append(dict(busy=busy, rd=int(rng.integers(G)), wr=int(rng.integers(G)),
                         wdata=rbits(rng, Q * nb), wen=int(rng.integers(1 << Q)),
                         h_addr=int(rng.integers(G)), h_bank=int(rng.integers(Q)), h_field=int(rng.integers(4)),
                         h_wdata=int(rng.integers(1 << fb)), h_we=int(rng.random() < 0.5)))

    def drive(t, get):
        p = plan[t]
        return sd([(dut.busy, (1 << Q) - 1 if p["busy"] else 0), (dut.rd_addr, p["rd"]), (dut.wr_addr, p["wr"]), (dut.wr_data, p["wdata"]), (dut.wr_en, p["wen"]), (dut.h_addr, p["h_addr"]), (dut.h_bank, p["h_bank"]), (dut.h_field, p["h_field"]), (dut.h_wdata, p["h_wdata"]), (dut.h_we, p["h_we"])])

    def sample(t, get):
        log.append((get(dut.rd_data), get(dut.h_rdata)))
        p = plan[t]
        # reference: the fill's read presented in t - 1 (registered in each bank: STORE_READ_FANOUT = 1) and the
        # host's presented now answer in t + 2 (from the words as they are now); the node lanes' write
        # presented in t - 1 lands now (STORE_WRITE = 1: registered in each bank, busy or not)
        if p["busy"]:
            rd = plan[t - 1]["rd"]
            expect[t + 2] = ("rd", sum(mem[q][rd] << (q * nb) for q in range(Q)))
            w = plan[t - 1]
            writes = [(q, w["wr"], (w["wdata"] >> (q * nb)) & ((1 << nb) - 1)) for q in range(Q) if w["wen"] >> q & 1]
            collide = any(a == rd for _, a, _ in writes)
        else:
            expect[t + 2] = ("h", (mem[p["h_bank"]][p["h_addr"]] >> (p["h_field"] * fb)) & ((1 << fb) - 1))
            writes = []
            if p["h_we"]:
                q, a, f = p["h_bank"], p["h_addr"], p["h_field"]
                w = mem[q][a] & ~(((1 << fb) - 1) << (f * fb)) | (p["h_wdata"] << (f * fb))
                writes = [(q, a, w)]
            collide = p["h_we"] and True
        if collide:
            expect[t + 2] = None
        for q, a, w in writes:
            mem[q][a] = w

    simulate(dut, len(plan), drive, sample)
    checked = 0
    for t, e in expect.items():
        if e is None or t >= len(log):
            continue
        kind, v = e
        assert log[t][0 if kind == "rd" else 1] == v, f"cycle {t} {kind}"
        checked += 1
    assert checked > 120


# ------------------------------------------------------------------------------------------ NodeWindow

@pytest.mark.parametrize("fill_groups", [[[0, 1]], [[0, 1], [1, 2, 3]], [[0, 1, 2], [], [3]], [[0, 1, 2, 3, 4]]])
def test_node_window_refuses_fill_groups_that_do_not_split_its_copies(fill_groups):
    with pytest.raises(ValueError, match="fill_groups must split the 4 copies"):
        NodeWindow(NodeWord(2, SQ(4, 14), SQ(4, 14)), 2, 8, node_reads=3, group_reads=1, fill_groups=fill_groups)


@pytest.mark.parametrize("fill_groups", [None, [[0, 1], [2, 3]], [[0, 2, 3], [1]]])
def test_node_window_copies_read_the_filled_groups(fill_groups):
    """Every copy reads what the fill wrote F cycles after it was presented, whichever copies share a relay
    register of the fill (one each, the group port's with a node port's, three of four together)."""
    word = NodeWord(2, SQ(4, 14), SQ(4, 14))
    Q, Wg = 2, 8
    dut = NodeWindow(word, Q, Wg, node_reads=3, group_reads=1, fill_groups=fill_groups)
    rng = np.random.default_rng(2)
    ring = [0] * Wg
    nb = word.bits
    plan = [dict(fa=int(rng.integers(Wg)), fd=rbits(rng, Q * nb), fe=int(rng.random() < 0.6),
                 reads=[(int(rng.integers(Wg)), int(rng.integers(Q))) for _ in range(4)]) for _ in range(150)]
    log, expect = [], {}

    def drive(t, get):
        p = plan[t]
        d = sd([(dut.fill_addr, p["fa"]), (dut.fill_data, p["fd"]), (dut.fill_en, p["fe"]), (dut.groups[0].addr, p["reads"][3][0])])
        for k in range(3):
            d[dut.reads[k].addr], d[dut.reads[k].bank] = p["reads"][k]
        return d

    F = 4          # a fill presented in cycle t is written at the end of cycle t + F (the register tree)
    R = 1          # a node read's slot presented in cycle t is read in cycle t + R (registered in front of its copy)

    def sample(t, get):
        log.append([get(dut.reads[k].data) for k in range(3)] + [get(dut.groups[0].data)])
        w = plan[t - F] if t >= F else dict(fe=0)      # the fill written in this cycle
        # the reads of this cycle: the node reads presented R cycles ago, the group read presented now
        reads = [(k, plan[t - R]["reads"][k], t - R) for k in range(3) if t >= R] + [(3, plan[t]["reads"][3], t)]
        for k, (a, b), t0 in reads:                 # node words 4 cycles after their slot, the group word 2
            if w["fe"] and a == w["fa"]:
                e = None
            else:
                e = (ring[a] >> (b * nb)) & ((1 << nb) - 1) if k < 3 else ring[a]
            expect.setdefault(t0 + (dut.node_latency if k < 3 else dut.latency), [None] * 4)[k] = e
        if w["fe"]:
            ring[w["fa"]] = w["fd"]

    simulate(dut, len(plan), drive, sample)
    n = 0
    for t, exp in expect.items():
        if t < len(log):
            for k, e in enumerate(exp):
                if e is not None:
                    assert log[t][k] == e, (t, k)
                    n += 1
    assert n > 400


# ------------------------------------------------------------------------------------------ ForceRing

def _contributions(rng, cycles, Q, Wg, D, fe_bits, runs=False):
    """A lane role's items: nodes that repeat close together (forwarding), slots reused after the node
    lane read them, gaps; with `runs`, each node's contributions are consecutive."""
    items, t, v = [], 0, 0
    while t < cycles:
        if runs:
            n_rep = int(rng.integers(1, 5))
            seq = [v] * n_rep
            v += int(rng.integers(1, 3))
        else:
            seq = list(v + rng.integers(0, 3, int(rng.integers(1, 6))))
            v += int(rng.integers(1, 4))
        for node in seq:
            if rng.random() < 0.15:
                items.append(None)                    # a bubble
                t += 1
            vals = [int(rng.integers(-(1 << (fe_bits - 1)), 1 << (fe_bits - 1))) for _ in range(D)]
            items.append((int(node), vals))
            t += 1
    return items


@pytest.mark.parametrize("kind", ["ring", "runs"])
def test_force_ring_sums_exactly_with_forwarding_and_first_flags(kind):
    D, fe_bits, acc_bits, Q, Wg = 2, 8, 12, 2, 4
    cls = ForceRing if kind == "ring" else RunSum
    dut = cls(D, fe_bits, acc_bits, Q, Wg)
    rng = np.random.default_rng(3)
    items = _contributions(rng, 300, Q, Wg, D, fe_bits, runs=kind == "runs")
    nodes = [it[0] for it in items if it is not None]
    first = {}
    last = {}
    for k, it in enumerate(items):
        if it is not None:
            first.setdefault(it[0], k)
            last[it[0]] = k
    totals = {}
    for it in items:
        if it is not None:
            totals.setdefault(it[0], [0] * D)
            totals[it[0]] = [a + b for a, b in zip(totals[it[0]], it[1])]
    # the node lanes read a node's sums after its last write (last + RMW + 1) and before its slot's next
    # node writes: read every node at its last item + RMW + 1 (nodes W apart are far enough in this stream)
    reads = {last[n] + dut.rmw + 1: n for n in totals}
    got = {}
    log = []

    def drive(t, get):
        d = sd([(dut.node_addr, 0)])
        it = items[t] if t < len(items) else None
        if it is None:
            d[dut.add.valid] = 0
        else:
            n, vals = it
            for sig, val in ((dut.add.valid, 1), (dut.add.slot, (n // Q) % Wg), (dut.add.bank, n % Q),
                             (dut.add.first, int(first[n] == t)), (dut.add.last, int(last[n] == t)),
                             (dut.add.value, sum((v & ((1 << fe_bits) - 1)) << (k * fe_bits) for k, v in enumerate(vals)))):
                d[sig] = val
        if t in reads:
            d[dut.node_addr] = (reads[t] // Q) % Wg
        return d

    def sample(t, get):
        log.append(get(dut.node_data))

    simulate(dut, len(items) + 8, drive, sample)
    for t, n in reads.items():
        word = log[t + 2]
        seg = (word >> ((n % Q) * D * acc_bits)) & ((1 << (D * acc_bits)) - 1)
        sums = [signed(seg >> (k * acc_bits), acc_bits) for k in range(D)]
        assert sums == totals[n], f"node {n}: {sums} != {totals[n]}"
    assert len(reads) > 40
    assert len(set(nodes)) < len(nodes)           # nodes repeat: sums of several items were checked


# ------------------------------------------------------------------------------------------ SaturationCounter

def test_saturation_counter_counts_and_flags():
    events = ["x", "u", "x", "fe"] * 17          # 68 reports: 17 sums of 4, then 5, 2, 1, 1
    n = len(events)
    dut = SaturationCounter(events)
    rng = np.random.default_rng(4)
    plan = [[int(v) for v in rng.integers(0, 3, n) * (rng.random(n) < 0.3)] for _ in range(60)]
    clear_at = 30
    count, flags, log = 0, 0, []
    expect = {}

    def drive(t, get):
        d = sd([(getattr(dut, f"ev{k}"), plan[t][k] if t < len(plan) else 0) for k in range(n)])
        d[dut.clear] = int(t == clear_at)
        return d

    def sample(t, get):
        log.append((get(dut.count), get(dut.flags)))

    simulate(dut, len(plan) + 6, drive, sample)
    # reference: an event of cycle s is in `count` from cycle s + L (L = 7: entry register, five summing
    # levels, count), in `flags` from s + 3 (registered on entry, then in parts); a clear in cycle c zeroes
    # both from c + 1 on, and then only events from cycle c - L + 2 on (count: the ones not yet summed) or
    # c - 1 on (flags) are in them
    L = 7
    ev = lambda s_: plan[s_] if 0 <= s_ < len(plan) else [0] * n
    qs = sorted(set(events))
    for t in range(len(plan) + 4):
        lo_c, lo_f = (clear_at - L + 2, clear_at - 1) if t >= clear_at + 1 else (0, 0)
        count = sum(sum(ev(s_)) for s_ in range(lo_c, t - L + 1))
        flags = 0
        for s_ in range(lo_f, t - 2):
            for k, q in enumerate(events):
                if ev(s_)[k]:
                    flags |= 1 << qs.index(q)
        expect[t] = (count, flags)
    for t in range(4, len(plan) + 4):
        assert log[t][0] == expect[t][0], (t, log[t], expect[t])
        assert log[t][1] == expect[t][1], (t, log[t], expect[t])


def test_saturation_counter_sums_every_report_at_its_most_without_wrapping():
    """1024 reports of 255 events in one cycle: 261,120 in `count`, beyond 16 bits."""
    dut = SaturationCounter(["x"] * 1024)
    log = []
    simulate(dut, 10, lambda t, get: sd([(getattr(dut, f"ev{k}"), 255 if t == 0 else 0) for k in range(1024)]),
             lambda t, get: log.append(get(dut.count)))
    assert log[-1] == 1024 * 255 == 261_120


def test_saturation_counter_refuses_more_reports_than_its_levels_sum():
    SaturationCounter(["x"] * 1024)
    with pytest.raises(ValueError, match="1025 saturation reports; the counter sums at most 1024"):
        SaturationCounter(["x"] * 1025)


# ------------------------------------------------------------------------------------------ HostPort

@pytest.mark.parametrize("elem_fanout, node_fanout", [(0, 0), (1, 0), (0, 1), (1, 1)])
def test_host_port_decodes_registers_and_memories(elem_fanout, node_fanout):
    """The memories answer MEMORY = 2 cycles after the port presents an address (a cycle later per register
    in front of them: the element lanes', the store's): each word is driven in that cycle only, junk
    otherwise."""
    hm = HostMap(2, np.array([0, 1, 0, 1]), np.array([0, 0, 1, 1]), 2, 2,
                 np.array([0, 1, 0]), np.array([0, 0, 1]), 2, 2)
    fields = [SQ(4, 14)] * 2 + [SQ(-2, 20)] * 2
    dut = HostPort(hm, fields, SQ(2, 16), 3, elem_fanout, node_fanout)
    lag = max(elem_fanout, node_fanout)
    node_word = 0x3FFFF        # an 18-bit field of all ones: -1
    a_word = 0x3FFFE
    reads = [Reg.ID, Reg.RUN, Reg.STATUS, Reg.STEP, Reg.SATURATIONS, Reg.SATURATION_FLAGS, Reg.CYCLES,
             int(hm.node_addr(3, 2)), int(hm.elem_addr(0, 1))]
    writes = [(Reg.STEP, 11), (Reg.RUN, 7), (int(hm.node_addr(1, 3)), 5), (Reg.SATURATIONS, 0),
              (int(hm.node_addr(1, 3)), 5), (int(hm.elem_addr(0, 2)), 9)]
    seq = [("w", a, d) for a, d in writes] + [("r", a, 0) for a in reads] + [("n", 0, 0)] * 6
    strobes, answers = [], []

    t_node = seq.index(("r", reads[-2], 0)) + 1 + node_fanout + 2       # registered on entry, then MEMORY
    t_elem = seq.index(("r", reads[-1], 0)) + 1 + elem_fanout + 2
    junk = 0x15555

    def drive(t, get):
        kind, a, d = seq[t]
        return sd([(dut.bus.addr, a), (dut.bus.w_data, d), (dut.bus.w_en, int(kind == "w")), (dut.bus.r_en, int(kind == "r")), (dut.busy, 0), (dut.steps_left, 3), (dut.step, 12), (dut.sat_count, 13), (dut.sat_flags, 5), (dut.cycles, 99),
                   (dut.node_rdata, node_word if t == t_node else junk), (dut.elem_rdata[0], junk),
                   (dut.elem_rdata[1], a_word if t == t_elem else junk)])

    def sample(t, get):
        strobes.append({k: get(getattr(dut, k)) for k in ("run_start", "run_steps", "step_we", "step_wdata", "sat_clear",
                                                          "node_addr", "node_bank", "node_field", "node_we", "elem_pos", "elem_we")})
        if get(dut.bus.r_valid):
            answers.append(get(dut.bus.r_data))
            valid_at.append(t)

    valid_at = []
    simulate(dut, len(seq), drive, sample)
    # the bus is registered on entry: a write's strobes a cycle after its request (the control's, RUN and
    # STEP, and the saturation clear, two cycles after), answers 5 cycles after; a write while a start is
    # on its way is ignored
    assert strobes[2]["step_we"] == 1 and strobes[2]["step_wdata"] == 11 and strobes[1]["step_we"] == 0
    assert strobes[3]["run_start"] == 1 and strobes[3]["run_steps"] == 7 and strobes[2]["run_start"] == 0
    assert strobes[3]["node_we"] == 0 and strobes[4]["run_start"] == 0
    assert strobes[5]["sat_clear"] == 1 and strobes[4]["sat_clear"] == 0
    assert (strobes[5]["node_we"], strobes[5]["node_field"], strobes[5]["node_bank"], strobes[5]["node_addr"]) == (1, 1, 1, 1)
    assert (strobes[6]["elem_we"], strobes[6]["elem_pos"]) == (0b01, 1)
    m32 = 0xFFFFFFFF
    assert answers == [ID_WORD, 3, 2, 12, 13, 5, 99, (-1) & m32, (-2) & m32]
    assert dut.read_latency == 5 + lag
    assert valid_at == [len(writes) + k + 5 + lag for k in range(len(reads))]


# ------------------------------------------------------------------------------------------ Control

@pytest.mark.parametrize("P,Q,steps", [(1, 1, 2), (2, 3, 3)])
def test_control_follows_the_schedule(P, Q, steps):
    from golden import mesh as meshlib
    m = meshlib.rectangle(1.0, 1.0, 3, 3)
    order = stream_order(len(m.nodes), m.edges, meshlib.topology_pairs(m.cells, m.nodes))
    sch = build_schedule(order, P, Q, Latencies(element=20, element_state=15, node=6, pair=25))
    dut = Control(sch)
    T, Gs, Wg = sch.period, sch.groups, sch.window_groups
    got = {"fill": [], "issue": [], "retire": [], "busy": [], "step": []}
    start = 3

    def drive(t, get):
        return sd([(dut.start, int(t == start)), (dut.steps, steps), (dut.step_we, int(t == 1)), (dut.step_wdata, 40)])

    def sample(t, get):
        a = t - start - 1                                # run cycle (busy from start + 1)
        if get(dut.fill.valid):
            got["fill"].append((a, get(dut.fill.group), get(dut.fill.slot)))
        if get(dut.issue.valid):
            got["issue"].append((a, get(dut.issue.slot), get(dut.issue.base)))
        if get(dut.retire.valid):
            got["retire"].append((a, get(dut.retire.group), get(dut.retire.slot), get(dut.retire.step), get(dut.retire.last)))
        got["busy"].append(get(dut.busy))
        got["step"].append(get(dut.step))

    n_cycles = start + 1 + sch.run_cycles(steps) + 5
    simulate(dut, n_cycles, drive, sample)
    A0 = sch.issue_start
    ref_fill = [(A0 + k * T + int(sch.fill[g]), g, (k * Gs + g) % Wg) for k in range(steps) for g in range(Gs)]
    # the control issues ISSUE_FANOUT = 1 cycle early: each lane registers the issue (hw/stream/core.py)
    ref_issue = [(A0 - 1 + k * T + c, c, (k * Gs) % Wg) for k in range(steps) for c in range(sch.slots)]
    # and retires RETIRE_FANOUT = 1 cycle early: the node lanes, rings and window register the retirement
    ref_ret = [(A0 - 1 + k * T + int(sch.retire[g]), g, (k * Gs + g) % Wg, 40 + k, int(g == Gs - 1))
               for k in range(steps) for g in range(Gs)]
    assert got["fill"] == ref_fill
    assert got["issue"] == ref_issue
    assert got["retire"] == ref_ret
    busy = np.flatnonzero(got["busy"])
    assert busy[0] == start + 1 and len(busy) == sch.run_cycles(steps)
    assert got["step"][-1] == 40 + steps
