"""The streaming core's static schedule (hw/stream/schedule.py), checked by an independent event replay.

The replay below knows only the hardware's timing conventions (restated here, not imported): item k of
a stream runs in lane k % P at slot k // P, its window slot is formed 2 cycles after issue (block RAM
latency), registered in the lane (SLOT) and read by the copy a cycle later (READ: registered in front of
the copy), a filled group
is written into the window STORE_RD + MEM + FILL = 7 cycles after the control presents it to the store
(the group registered in each bank, the block RAM's latency, then the register tree in front of the
window copies), its contribution is written
RMW = 3 cycles after its pipeline stage; a read presented in the
cycle of a write to the same word is undefined. It takes from the schedule only its decisions (the fill
and retirement cycle of every group, the period T, the window Wg, the rings' Wr, the prologue A0), replays a few steps
of every memory's writes and reads, and checks: every window read (items', node lanes') sees the group
of its own step, every store read sees the previous step's result, every element's a its previous
step's value, every contribution is written before its node retires and no other node's write lands in
its ring word in between (so a ring needs no clearing; a node's result lands in the store STORE = 1 cycle after
its result stage), one fill, one retirement and one item per lane
per cycle. T - 1, Wr / 2 (or Wg / 2, when the window is larger than the rings) must break something: the
schedule's T, rings and window are the smallest.
"""
from __future__ import annotations

import math
from collections import defaultdict

import numpy as np
import pytest

from golden import mesh as meshlib
from golden.scene import builtin_names
from hw.stream.order import stream_order
from hw.stream.schedule import BandwidthError, Latencies, build_schedule, spare_lanes

from conftest import scene_system

STORE_RD = 1                        # the fill's group registered in each store bank
MEM, FILL, READ, RMW = 2, 4, 1, 3   # block RAM read latency; the fill's registers before the window copies;
                                    # an item's window slot registered before its copy; a force ring word is
                                    # written RMW cycles after its read
SLOT = 1                            # an item's window slot registered in its lane
STORE = 1                           # a node lane's result lands in the store a cycle later (registered in the bank)


class Violation(AssertionError):
    pass


def _latest(log, cycle):
    """The tag of the last write before `cycle` in a sorted [(cycle, tag)] log (None: none); a write in
    `cycle` itself makes the read undefined."""
    tag = None
    for c, t in log:
        if c == cycle:
            raise Violation(f"read in cycle {cycle} of a word written in that cycle")
        if c > cycle:
            break
        tag = t
    return tag


def replay(order, P, Q, lat, T, Wg, Wr, fill, retire, A0, steps=3, Pp=None, rings_as_one=False):
    """Replay `steps` steps (P element lanes, Pp pair lanes: P unless given); raises Violation naming the
    first broken rule. `rings_as_one`: every ring's word (bank, slot) is one word, written by any lane or
    role (stricter than the hardware, whose rings are apart)."""
    Pp = P if Pp is None else Pp
    N, D1 = order.n_nodes, order.pair_nodes.shape[1] if len(order.pair_nodes) else 0
    Gs = -(-N // Q)
    t0 = lambda k: A0 + k * T
    # one fill and one retirement a cycle, in group order within a step
    for name, times in (("fill", fill), ("retire", retire)):
        cycles = [t0(k) + int(times[g]) for k in range(steps) for g in range(Gs)]
        if len(set(cycles)) != len(cycles) or cycles != sorted(cycles):
            raise Violation(f"{name}: not one group a cycle in order")
    # streams: (stage, [(lane, slot, nodes per role)])
    # element lanes accumulate by node: ring 0 the lower node of each element, ring 1 the higher
    streams = [("el", lat.element, list(np.sort(np.stack([order.ei, order.ej], 1), axis=1)), P)]
    if D1:
        streams.append(("pr", lat.pair, list(order.pair_nodes), Pp))
    for name, _, items, L in streams:
        for lane in range(L):
            cyc = [t0(k) + i // L for k in range(steps) for i in range(lane, len(items), L)]
            if len(set(cyc)) != len(cyc):
                raise Violation(f"{name} lane {lane}: two items in one cycle")
    # the window
    win = defaultdict(list)
    for k in range(steps):
        for g in range(Gs):
            win[(k * Gs + g) % Wg].append((t0(k) + int(fill[g]) + STORE_RD + MEM + FILL, (k, g)))
    for log in win.values():
        log.sort()

    def window_read(k, n, cycle, who):
        g = n // Q
        got = _latest(win[(k * Gs + g) % Wg], cycle)
        if got != (k, g):
            raise Violation(f"{who} of node {n} in step {k} (cycle {cycle}) sees group {got}, not {(k, g)}")

    # force rings: per (stream, lane, role) and word: [(write cycle, (step, node))]
    rings = defaultdict(list)
    for name, stage, items, L in streams:
        for k in range(steps):
            for i, nodes in enumerate(items):
                lane, c = i % L, i // L
                for role, n in enumerate(nodes):
                    n = int(n)
                    window_read(k, n, t0(k) + c + MEM + SLOT + READ, f"{name} item {i} role {role}")
                    word = (n % Q, (k * Gs + n // Q) % Wr)
                    key = word if rings_as_one else (name, lane, role, word)
                    rings[key].append((t0(k) + c + stage + RMW, (k, n)))
    for log in rings.values():
        log.sort()
    by_owner = defaultdict(list)
    for key, log in rings.items():
        for c, owner in log:
            by_owner[owner].append((key, c))
    # retirement: window read, every contribution in, no foreign write in between
    for k in range(steps):
        for n in range(N):
            R = t0(k) + int(retire[n // Q])
            window_read(k, n, R, "node lane read")
            for key in {key for key, _ in by_owner[(k, n)]}:
                log = rings[key]
                mine = [c for c, o in log if o == (k, n)]
                if max(mine) >= R:
                    raise Violation(f"node {n} step {k} retires in cycle {R}, a contribution lands in {max(mine)}")
                foreign = [(c, o) for c, o in log if min(mine) <= c <= R and o != (k, n)]
                if foreign:
                    raise Violation(f"ring {key}: node {n} step {k}'s word is overwritten by {foreign[0]}")
    # node store: the fill of step k reads what step k - 1 retired
    for g in range(Gs):
        writes = sorted((t0(k) + int(retire[g]) + lat.node + STORE, k) for k in range(steps))
        for k in range(steps):
            got = _latest(writes, t0(k) + int(fill[g]))
            if got != (k - 1 if k else None):
                raise Violation(f"fill of group {g} step {k} reads the store version {got}")
    # a: read at issue of step k, written at the state stage of step k - 1
    if len(order.ei):
        for k in range(1, steps):
            if t0(k - 1) + lat.element_state >= t0(k):
                raise Violation("an element's a is read before the previous step wrote it")
    return True


def check(order, P, Q, lat, steps=3, Pp=None):
    sch = build_schedule(order, P, Q, lat, pair_lanes=Pp)
    args = (order, P, Q, lat)
    Wg, Wr = sch.window_groups, sch.ring_groups
    assert Wg % Wr == 0                              # a ring's slot is the window's mod Wr
    replay(*args, sch.period, Wg, Wr, sch.fill, sch.retire, sch.issue_start, steps, Pp)
    replay(*args, sch.period, Wg, Wr, sch.fill, sch.retire, sch.issue_start, steps, Pp, rings_as_one=True)
    C = max(-(-len(order.ei) // P), -(-len(order.pair_nodes) // (P if Pp is None else Pp)), 1)
    assert sch.period >= C and sch.slots == C
    # the period, the rings and the window are the smallest these fill / retirement cycles allow
    with pytest.raises(Violation):
        replay(*args, sch.period - 1, Wg, Wr, sch.fill, sch.retire, sch.issue_start, steps, Pp)
    if Wr > 1:      # the rule judges a group's ring words over all its rings at once: so does this replay
        with pytest.raises(Violation, match="overwritten|retires"):
            replay(*args, sch.period, Wg, Wr // 2, sch.fill, sch.retire, sch.issue_start, steps, Pp,
                   rings_as_one=True)
    if Wg > Wr:
        with pytest.raises(Violation, match="sees group|written in that cycle"):
            replay(*args, sch.period, Wg // 2, Wr, sch.fill, sch.retire, sch.issue_start, steps, Pp)
    return sch


LATENCIES = [Latencies(element=76, element_state=68, node=16, pair=62),     # the wide preset's pipelines
             Latencies(element=9, element_state=3, node=4, pair=11),
             Latencies(element=140, element_state=140, node=40, pair=150)]


def _random_mesh(rng, dim):
    if dim == 2:
        m = meshlib.rectangle(1.0, 1.0, int(rng.integers(2, 9)), int(rng.integers(2, 9)))
    else:
        m = meshlib.box((1.0, 1.0, 1.0), tuple(int(v) for v in rng.integers(1, 4, 3)))
    shuffle = rng.permutation(len(m.nodes))                 # a scrambled numbering: RCM must undo it
    edges = shuffle[m.edges]
    pairs = shuffle[meshlib.topology_pairs(m.cells, m.nodes)] if rng.random() < 0.7 else None
    return len(m.nodes), edges, pairs


@pytest.mark.parametrize("seed", range(6))
def test_random_meshes(seed):
    rng = np.random.default_rng(seed)
    dim = 2 if seed % 3 else 3
    N, edges, pairs = _random_mesh(rng, dim)
    order = stream_order(N, edges, pairs)
    P, Q = int(rng.choice([1, 2, 3, 5])), int(rng.integers(1, 4))
    check(order, P, Q, LATENCIES[seed % len(LATENCIES)])
    check(order, P, Q, LATENCIES[seed % len(LATENCIES)], Pp=int(rng.choice([1, 2, 4, 7])))   # pair lanes apart


SCENES = [n for n in builtin_names() if scene_system(n).collision is None]


@pytest.mark.parametrize("name", SCENES)
def test_builtin_scenes(name):
    system = scene_system(name)
    pairs = system.topology.pairs if system.topology is not None else None
    order = stream_order(system.n_nodes, system.edges, pairs)
    for P, Q, Pp in ((1, 1, None), (2, 2, None), (3, 1, None), (2, 2, 3)):
        check(order, P, Q, LATENCIES[0], Pp=Pp)


@pytest.mark.parametrize("Q", [2, 3])
def test_benchmark_square(Q):
    from sim.bench import square_system
    system = square_system(10_000)
    order = stream_order(system.n_nodes, system.edges)
    assert order.bandwidth == 87                       # reverse Cuthill-McKee (the review's figure)
    sch = check(order, 6, Q, Latencies(element=76, element_state=68, node=16), steps=2)
    assert sch.period <= 1.05 * math.ceil(system.n_elements / 6)


def test_bandwidth_beyond_the_window_is_refused():
    from sim.bench import square_system
    system = square_system(10_000)
    order = stream_order(system.n_nodes, system.edges)
    with pytest.raises(BandwidthError, match=r"bandwidth 87 .*largest window .* 16 groups of 2 nodes \(32 nodes\)"):
        build_schedule(order, 6, 2, LATENCIES[0], max_window_groups=16)
    assert issubclass(BandwidthError, ValueError)


def test_replay_catches_a_broken_schedule():
    """The checker itself: a fill one cycle late, a retirement one cycle early are caught."""
    system = scene_system("gravity-2d-nonlinear")
    order = stream_order(system.n_nodes, system.edges, system.topology.pairs)
    lat = LATENCIES[0]
    sch = build_schedule(order, 2, 2, lat)
    args = (order, 2, 2, lat, sch.period, sch.window_groups, sch.ring_groups)
    late = sch.fill.copy()
    g = int(np.argmax(sch.fill))                       # the last group is filled just in time
    late[g] += 1
    with pytest.raises(Violation, match="sees group|written in that cycle"):
        replay(*args, late, sch.retire, sch.issue_start)
    early = sch.retire.copy()
    early[0] -= 1
    with pytest.raises(Violation):
        replay(*args, sch.fill, early, sch.issue_start)


def test_spare_lanes_named_when_one_fewer_keeps_the_period():
    """A lane that leaves T unchanged is named with the options of one fewer; a lane that sets T is not."""
    m = meshlib.rectangle(1.0, 1.0, 8, 8)                 # 81 nodes, 208 edges: items, not nodes, set T at P = 1
    order = stream_order(len(m.nodes), m.edges, meshlib.topology_pairs(m.cells, m.nodes))
    n_pairs = len(order.pair_nodes)
    assert len(m.nodes) < len(m.edges) // 2 and n_pairs > 0
    lat = LATENCIES[0]
    sch = build_schedule(order, 1, 2, lat, pair_lanes=1)
    spare = spare_lanes(order, sch)
    assert [s["lanes"] for s in spare] == ["node_lanes_Q"]
    assert spare[0]["fewer"] == 1 and spare[0]["options"] == "--lanes 1 --pair-lanes 1 --node-lanes 1"
    assert spare[0]["period_T"] == sch.period == max(len(m.edges), n_pairs)
    assert spare_lanes(order, build_schedule(order, 1, 1, lat, pair_lanes=1)) == []
    # far more pair lanes than the pairs need beside one element lane: pair lanes are spare, elements not
    sch = build_schedule(order, 1, 1, lat, pair_lanes=n_pairs)
    assert [s["lanes"] for s in spare_lanes(order, sch)] == ["pair_lanes"]


def test_spare_lanes_of_the_benchmark_square():
    """At P = 6 the square's 1e4 elements take fewer slots than one node lane's retirement of every node,
    so a second node lane is not spare; at P = 1 it is."""
    from sim.bench import square_system
    system = square_system(10_000)
    order = stream_order(system.n_nodes, system.edges)
    lat = Latencies(element=76, element_state=68, node=16)
    assert math.ceil(system.n_elements / 6) < system.n_nodes < system.n_elements
    assert spare_lanes(order, build_schedule(order, 6, 2, lat)) == []
    assert [s["lanes"] for s in spare_lanes(order, build_schedule(order, 1, 2, lat))] == ["node_lanes_Q"]
