"""The streaming core's lanes against the bit-true kernels (hw/datapath.py on FixedArith), in Amaranth's
simulator: an ElementLane, a PairLane and the NodeLanes, each fed the node states a window and force
rings would give them, one step of items, checked item by item (contributions with their window slot,
bank and first / last flags, new a, node results) and in their saturation counts.

The scene: press-2d-rheological (nonlinear damper, topology pairs, floor, a load), narrow formats from
its range analysis, P = 2, Q = 2, from a state 40 steps in.
"""
from __future__ import annotations

import dataclasses
import functools

import numpy as np
import pytest
from amaranth.hdl import Module
from amaranth.sim import Simulator

from hw.arith import FixedArith
from hw.datapath import _node_flags, element_kernel, node_kernel, pair_kernel
from hw.fixed import Saturations
from hw.stream.config import StreamConfig
from hw.stream.element import ElementLane
from hw.stream.kernels import NODE_STAGE, SLOT_STAGE
from hw.stream.node import NodeLane
from hw.stream.pair import PairLane

from conftest import bittrue
from test_stream_units import sd, signed

pytestmark = pytest.mark.hdl      # Amaranth's simulator or HDL simulators: `make test-fast` leaves these out

P, Q, BASE = 2, 2, 5


@functools.lru_cache(maxsize=None)
def setup():
    bt = bittrue("press-2d-rheological", "narrow")
    st = bt.initial_state()
    for _ in range(40):
        bt.step(st)
    cfg = StreamConfig.of(bt, P, Q)
    return bt, st, cfg


def run(dut, cycles, drive, sample):
    sim = Simulator(dut)
    sim.add_clock(1e-8)

    async def bench(ctx):
        for t in range(cycles):
            for sig, v in drive(t).items():
                ctx.set(sig, int(v))
            sample(t, ctx.get)
            await ctx.tick()
    sim.add_testbench(bench)
    sim.run()


def subset(p, idx, n):
    """Params restricted to items idx (fields that are per-item arrays of length n)."""
    repl = {f.name: getattr(p, f.name)[idx] for f in dataclasses.fields(p)
            if isinstance(getattr(p, f.name), np.ndarray) and getattr(p, f.name).shape[:1] == (n,)}
    return dataclasses.replace(p, **repl)


def node_word(cfg, X, U, n):
    o = cfg.order.inv[n]
    return cfg.word.pack_int([x[o] for x in X], [u[o] for u in U])


def fields(value, bits, count):
    return [signed(value >> (k * bits), bits) for k in range(count)]


def test_element_lane_equals_element_kernel():
    bt, st, cfg = setup()
    lane = 1
    dut = ElementLane(cfg, lane)
    p, fmt, D = cfg.params, cfg.formats, cfg.dim
    items = cfg.element_items(lane)
    elems = cfg.order.elements[items]
    ni, nj = cfg.order.ei[items], cfg.order.ej[items]
    Wg, Wr = cfg.schedule.window_groups, cfg.schedule.ring_groups
    # reference
    sat = Saturations()
    ar = FixedArith(bt.formats, bt.ar.units, sat)
    X = [ar.state("x", x) for x in st.X]
    U = [ar.state("u", u) for u in st.U]
    oi, oj = cfg.order.inv[ni], cfg.order.inv[nj]
    take = lambda vs, idx: [ar.take(v, idx) for v in vs]
    fe, new_a = element_kernel(ar, subset(p, elems, len(p.i)), take(X, oi), take(X, oj), take(U, oi), take(U, oj),
                               ar.state("a", st.A[elems]))
    fe_neg = [ar.neg(v).x for v in fe]
    fe = [v.x for v in fe]
    S, n_items, s = dut.depth, len(items), dut.stage
    a_bits, fb = fmt["a"].width, fmt["fe"].width
    # plan: host writes a (cycles 0 .. S-1), issue (S + 2 ..), host reads a after the pipeline drained
    t_issue = S + 2
    t_read = t_issue + S + s + 6
    cycles = t_read + S + 4
    words = {}
    for c in range(n_items):
        words[(t_issue + c + NODE_STAGE, 0)] = node_word(cfg, st.X, st.U, ni[c])   # the window's word
        words[(t_issue + c + NODE_STAGE, 1)] = node_word(cfg, st.X, st.U, nj[c])
    contribs, addrs, a_read, sats = [], [], {}, np.zeros(len(dut.quantities), np.int64)

    def drive(t):
        busy = t_issue <= t < t_read
        d = sd([(dut.busy, busy), (dut.issue.valid, t_issue <= t < t_issue + S), (dut.issue.slot, t - t_issue),
                (dut.issue.base, BASE), (dut.ring_i.data, words.get((t, 0), 0)), (dut.ring_j.data, words.get((t, 1), 0)),
                (dut.host_we, t < n_items), (dut.host_pos, t if t < S else (t - t_read) % S),
                (dut.host_wdata, int(st.A[elems[t]]) & ((1 << a_bits) - 1) if t < n_items else 0)])
        return d

    def sample(t, get):
        if t_issue <= t < t_issue + S + s + 4:
            c = t - t_issue - SLOT_STAGE
            if 0 <= c < n_items:
                addrs.append((get(dut.ring_i.addr), get(dut.ring_i.bank), get(dut.ring_j.addr), get(dut.ring_j.bank)))
            for port in (dut.contrib_lo, dut.contrib_hi):
                if get(port.valid):
                    contribs.append((t, get(port.slot), get(port.bank), get(port.first), get(port.last),
                                     fields(get(port.value), fb, D)))
            for k in range(len(dut.quantities)):
                sats[k] += get(getattr(dut, f"sat{k}"))
        if t >= t_read + 2 and t - t_read - 2 < n_items:
            a_read[t - t_read - 2] = signed(get(dut.host_rdata), a_bits)

    run(dut, cycles, drive, sample)
    assert addrs == [((BASE + a // Q) % Wg, a % Q, (BASE + b // Q) % Wg, b % Q) for a, b in zip(ni, nj)]
    lo, hi = np.minimum(ni, nj), np.maximum(ni, nj)
    ref = []
    for c in range(n_items):
        v_i = [int(fe[k][c]) for k in range(D)]
        v_j = [int(fe_neg[k][c]) for k in range(D)]
        for node, val, flags in ((lo[c], v_i if ni[c] < nj[c] else v_j, (lo, None)), (hi[c], v_j if ni[c] < nj[c] else v_i, (hi, hi))):
            seq, seq_last = flags
            first = int(c == int(np.flatnonzero(seq == node)[0]))
            last = int(c == int(np.flatnonzero(seq == node)[-1])) if seq_last is not None else 0
            ref.append((t_issue + c + s, (BASE + node // Q) % Wr, node % Q, first, last, val))   # its ring slot
    assert contribs == ref
    if not p.fixed_a:
        assert [a_read[c] for c in range(n_items)] == [int(v) for v in new_a.x]
    assert dict(zip(dut.quantities, sats.tolist())) == {q: sat[q] for q in dut.quantities}


def test_pair_lane_equals_pair_kernel():
    bt, st, cfg = setup()
    lane = 0
    dut = PairLane(cfg, lane)
    p, fmt, D = cfg.params, cfg.formats, cfg.dim
    items = cfg.pair_items(lane)
    nodes = cfg.order.pair_nodes[items]
    Wr, S, s, fb = cfg.schedule.ring_groups, dut.depth, dut.stage, fmt["fe"].width
    # nodes shaken by up to about half a cell, so that some pairs' gates (d <= eps) open
    rng = np.random.default_rng(5)
    edge = np.hypot(*[x[p.j] - x[p.i] for x in st.X]).mean()              # raw units
    st = dataclasses.replace(st, X=[x + rng.integers(-1, 2, x.shape) * int(0.5 * edge) for x in st.X])
    sat = Saturations()
    ar = FixedArith(bt.formats, bt.ar.units, sat)
    X = [ar.state("x", x) for x in st.X]
    U = [ar.state("u", u) for u in st.U]
    orig = cfg.order.inv[nodes]
    roles = [orig[:, r] for r in range(D + 1)]
    gate, contribs_ref = pair_kernel(ar, p, *[[ar.take(v, r) for v in X] for r in roles],
                                     *[[ar.take(v, r) for v in U] for r in roles])
    ref_val = np.zeros((D + 1, D, len(items)), np.int64)
    for k, v, role in contribs_ref:
        ref_val[role, k, gate.full_idx] = v.x
    words = {}
    t0 = 2
    for c in range(len(items)):
        for r in range(D + 1):
            words[(t0 + c + NODE_STAGE, r)] = node_word(cfg, st.X, st.U, nodes[c, r])
    got, sats = [], np.zeros(len(dut.quantities), np.int64)

    def drive(t):
        d = sd([(dut.issue.valid, t0 <= t < t0 + S), (dut.issue.slot, t - t0), (dut.issue.base, BASE)])
        for r in range(D + 1):
            d[dut.rings[r].data] = words.get((t, r), 0)
        return d

    def sample(t, get):
        for r in range(D + 1):
            port = dut.contribs[r]
            if get(port.valid):
                got.append((t, r, get(port.slot), get(port.bank), get(port.first), fields(get(port.value), fb, D)))
        for k in range(len(dut.quantities)):
            sats[k] += get(getattr(dut, f"sat{k}"))

    run(dut, t0 + S + s + 6, drive, sample)
    ref = []
    for c in range(len(items)):
        for r in range(D + 1):
            n = nodes[c, r]
            first = int(c == int(np.flatnonzero(nodes[:, r] == n)[0]))
            ref.append((t0 + c + s, r, (BASE + n // Q) % Wr, n % Q, first, [int(ref_val[r, k, c]) for k in range(D)]))
    assert sorted(got) == sorted(ref)
    assert any(any(v) for *_, v in ref) and any(not any(v) for *_, v in ref)     # gates open and closed
    assert dict(zip(dut.quantities, sats.tolist())) == {q: sat[q] for q in dut.quantities}


def test_node_lanes_equal_node_kernel():
    bt, st, cfg = setup()
    p, fmt, D = cfg.params, cfg.formats, cfg.dim
    lanes = [NodeLane(cfg, q) for q in range(Q)]
    top = Module()
    for q, lane in enumerate(lanes):
        top.submodules[f"nd{q}"] = lane
    Gs, s = cfg.schedule.groups, lanes[0].stage
    rng = np.random.default_rng(7)
    bits = lanes[0].force_bits
    # force ring words: random sums (a ring that does not touch a node holds garbage, which must be masked)
    words = [[[int(rng.integers(-(1 << (b - 3)), 1 << (b - 3))) for _ in range(D)] for b in bits] for _ in range(cfg.n_nodes)]
    mask = cfg.ring_masks()
    F = np.zeros((D, cfg.n_nodes), np.int64)
    for n in range(cfg.n_nodes):
        for r in range(len(bits)):
            if mask[n, r]:
                F[:, n] += words[n][r]
    step_no = 7                                      # the scene's load acts from step 0 on
    sat = Saturations()
    ar = FixedArith(bt.formats, bt.ar.units, sat)
    inv = cfg.order.inv
    Fo = np.zeros_like(F)
    Fo[:, inv] = F
    new_x, new_u = node_kernel(ar, p, [ar.state("x", x) for x in st.X], [ar.state("u", u) for u in st.U],
                               [ar.state("fe", f) for f in Fo], step_no, _node_flags(p))
    t0 = 2
    got, sats = [], 0

    def forces(n):
        return sum((v & ((1 << b) - 1)) << int(off + k * b) for (off, b, ws) in
                   zip(np.cumsum([0] + [D * b for b in bits[:-1]]), bits, words[n]) for k, v in enumerate(ws))

    def drive(t):
        g = t - t0
        d = sd([])
        for q, lane in enumerate(lanes):
            d[lane.retire.valid] = 0 <= g < Gs
            d[lane.retire.group] = g if 0 <= g < Gs else 0
            d[lane.retire.step] = step_no
            g2, n = t - t0 - 2, (t - t0 - 2) * Q + q
            ok = 0 <= g2 < Gs and n < cfg.n_nodes
            d[lane.node] = node_word(cfg, st.X, st.U, n) if ok else 0
            d[lane.forces] = forces(n) if ok else 0
        return d

    def sample(t, get):
        nonlocal sats
        for q, lane in enumerate(lanes):
            if get(lane.store_en):
                got.append((t, get(lane.store_group), q, get(lane.store_data)))
            sats += sum(get(getattr(lane, f"sat{k}")) for k in range(len(lane.quantities)))

    run(top, t0 + Gs + s + 6, drive, sample)
    ref = []
    for n in range(cfg.n_nodes):
        o = inv[n]
        ref.append((t0 + n // Q + s, n // Q, n % Q, cfg.word.pack_int([x.x[o] for x in new_x], [u.x[o] for u in new_u])))
    assert sorted(got) == sorted(ref)
    assert sats == sat.total
