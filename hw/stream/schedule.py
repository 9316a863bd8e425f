"""The streaming core's static schedule: every cycle the hardware relies on, computed and checked at
construction (plain Python and NumPy, no Amaranth).

Time. Step k's items issue at slots c = 0 .. C - 1, one per lane and cycle, at run cycle
A0 + k T + c (T: the period, A0: the prologue). Everything else is given relative to the start of its
step's issue (a cycle may be negative: before the step starts, or beyond T: in the next period). Nodes
go in *groups* of Q consecutive nodes (node n in group n // Q, bank n % Q, one node per node lane):
the fill reads a group from the node store, a node lane retires one node of a group, all in one cycle.

  issue      slot c: the lane's ROM (and its a word) is read; ROM data at c + M (M = MEMORY = 2)
  ring read  c + M: the lane forms the node's window slot and registers it (SLOT_REG), presenting it at
             c + M + 1; registered in front of the copy (R = READ_FANOUT), which reads it at c + M + 1 + R;
             x, u at c + M + 1 + R + 3 (the pipeline's stage 7: the bank's multiplexer registered,
             hw/stream/window.py)
  contrib.   c + s: the pipeline's force (stage s: `Latencies.element` / `.pair`) reads its force ring;
             the sum is written at c + s + RMW (RMW = 3), readable from c + s + RMW + 1
  fill       t_f[g]: the control presents group g to the node store, which registers it in each bank
             and reads it (STORE_READ_FANOUT); registered in front of each window copy (FILL_FANOUT; F =
             STORE_READ_FANOUT + FILL_FANOUT), written into every copy at t_f[g] + M + F, readable by a read
             presented from t_f[g] + M + F + 1
  retire     t_r[g]: the node lanes present group g's window and force ring addresses; results at
             t_r[g] + `Latencies.node`, written into the node store S = STORE_WRITE cycles later (the control retires
             at t_r[g] - RETIRE_FANOUT: the node lanes, the rings and the window register the retirement)

Rules (a read presented in the cycle of a write to the same word sees neither value for sure, so every
read the data path uses is strictly before or after the write it depends on):

  fill       t_f[g] = min(first read of g (by a copy) - M - F - 1, t_f[g + 1] - 1): as late as possible, one group a cycle
  retire     t_r[g] = max(last contribution write of g + 1, t_f[g] + M + F + 1, t_r[g - 1] + 1): as early as
             possible, in group order, one group a cycle
  period     T = max(C, a write stage + 1 (an element's a is written before the next step reads it),
             fill span, retirement span (each at most one period), max_g t_r[g] + node + S + 1 - t_f[g]
             (a node is written into the store before the next step's fill reads it))
  rings      Wr groups (a power of two): the smallest with, for every group g and the virtual group g + Wr
             that takes its ring word next (in this step or a later one): the retirement of g < the
             first force-ring write of g + Wr (so no ring is ever cleared: a lane's first contribution to a
             node in a step counts the old word as 0). A word lives from a node's first contribution to its
             retirement, which the element pipeline's latency does not lengthen
  window     Wg groups (W = Wg Q nodes, a power of two, at least Wr): the smallest with the last read of
             g (items' window reads, the node lane's at retirement) < the fill write of g + Wg. A ring's slot
             is the window's slot mod Wr (Wr divides Wg): the rings' node copies, LUT RAM when the block
             RAMs run out, stay Wr deep as a longer pipeline doubles the window (1e4 square, P = 6: Wr = 64,
             Wg = 128 up to an element latency of 76 stages, 256 beyond)
  run        fill, issue and retirement each run n periods from their own start (A0 + t_f[0], A0,
             A0 + t_r[0], all beyond LOOKAHEAD so that their phase ROMs can be read ahead); the run
             ends `drain` cycles after the last retirement starts: RUN n takes run_cycles(n) cycles.

Window slots run on across steps: group g of step k is virtual group v = k Gs + g (Gs groups a step) in
slot v mod Wg (ring word v mod Wr), so each unit keeps a base register that adds Gs mod Wg at its step
boundary.

A scene whose window would exceed `max_window_groups` is refused with `BandwidthError`.
"""
from __future__ import annotations

from ..datapath import NotSupported

from dataclasses import dataclass, field

import numpy as np

from .order import StreamOrder

MEMORY = 2            # block RAM: address presented in cycle t, data (from its output register) in t + 2
FILL_FANOUT = 4       # the fill's registers on its way to each window copy (hw/stream/window.py): two for all
                      # copies behind the store's output (one for the slot and enable), one per lane pair's
                      # copies, one per copy (the slot and enable), one in front of each copy's blocks. The root
                      # into every copy was a long route (the 1e4 square at P = 6, floorplanned: 13.5 ns of
                      # routing, 71.7 MHz; a register per copy instead: 71.3 MHz); a lane pair's slot into its
                      # copies' 24 blocks, 10.5 ns
STORE_READ_FANOUT = 1  # the fill's group registered in each store bank, kept apart, before its host multiplexer
                      # (hw/stream/store.py): the control's counter into the banks' block RAMs in two gaps of
                      # the floorplan arrived at 11.8 ns (the 1e4 square at P = 6)
SLOT_REG = 1          # a lane's window slot (base + group) registered in the lane before its read port
                      # (hw/stream/window.py `present_read`): the adder and the route into the copy's blocks'
                      # registers were one cycle (the 1e4 square: 10.3 ns)
READ_FANOUT = 1       # a node read's slot registered in front of its window copy (hw/stream/window.py): the
                      # lane's slot adder and the route to a far copy were one cycle (1e3 poke: 12.6 ns)
RETIRE_FANOUT = 1     # the retirement registered in each node lane, ring and the window's group port: the
                      # control retires this many cycles early (1e3 poke: 11.2 ns into a far ring's copy)
RMW = 3               # a force ring word read at stage s is written back at stage s + RMW (its sum
                      # registered before the block RAM's write port: hw/stream/forcering.py)
LOOKAHEAD = 3         # the phase ROMs are read this many cycles ahead of their process (read latency 2,
                      # then the event bit registered)
ISSUE_FANOUT = 1      # the issue registered in each lane (hw/stream/core.py): the control issues this many
                      # cycles early. One register fed every lane's ROM and a-memory address across the die
                      # (the 1e4 square at P = 6: 15.8 ns of routing, 49.4 MHz)
BUSY_FANOUT = 1       # the control's busy registered in the store and each element lane (hw/stream/core.py),
                      # which switch their memories' ports to the host while idle: they switch a cycle late,
                      # and the host sees the core busy that cycle longer. The first use of a port is
                      # LOOKAHEAD + 1 cycles after the start (the 1e4 square: 14 ns into far a memories)
ELEM_FANOUT = 1       # the host's element access (position, data, write strobe) registered in each element lane
                      # (hw/stream/core.py), each copy kept apart; the host port delays its other answers to
                      # match (hw/stream/hostport.py). One register fed every lane's a memory (the 1e4 square at
                      # f6412ba: the host's write data into a far lane's a memory, 14.6 ns of routing, 61.9 MHz)
NODE_FANOUT = 1       # the host's node access (address, bank, field, data, write strobe) registered in front of the
                      # node store (hw/stream/core.py); the host port delays its other answers to match. The
                      # host's decoding, the store's bank and field enables and its pipeline/host multiplexer
                      # were one cycle
A_WRITE = 1           # an element lane's new a registered before its a memory's pipeline/host multiplexer
                      # (hw/stream/element.py): written A_WRITE cycles after its stage (`Latencies.element_state`
                      # counts them). The pipeline's register and the multiplexer into a far block RAM were one
                      # cycle (the 1e4 square at f6412ba: 73 late pins on the a memories' ports)
STORE_WRITE = 1       # the node lanes' store write registered in each bank before its pipeline/host multiplexer
                      # (hw/stream/store.py): a node lands in the store STORE_WRITE cycles after its result
                      # (the square at f6412ba: 57 late pins on the store's write)
SAT_TAIL = 9          # from a node's last result stage to the core's saturation count register (lane
                      # register 2, SaturationCounter.LATENCY 7)
MAX_WINDOW_GROUPS = 512      # the largest window: one 512 x 36 DP16KD column per 36 bits of a group
NONE = np.iinfo(np.int64).max // 4
assert BUSY_FANOUT <= LOOKAHEAD, "a unit's busy copy must be set before its memories' first pipeline use"
assert max(ELEM_FANOUT, NODE_FANOUT) <= BUSY_FANOUT, "a host write accepted while idle must land before busy rises"
assert STORE_WRITE < SAT_TAIL, "the last node must land in the store before the run ends (its drain)"


class BandwidthError(NotSupported):
    """The scene's node numbering spans more nodes than the largest window holds."""


@dataclass(frozen=True)
class Latencies:
    """Pipeline stages the schedule relies on (each measured by a dry run of its pipeline)."""
    element: int          # stage of the element pipeline's force contributions (issue = stage 0)
    element_state: int    # cycle (from issue) at which the element lane's new a lands in its a memory
    node: int             # stage of the node pipeline's results (retirement = stage 0)
    pair: int = 0         # stage of the pair pipeline's force contributions (0: no pairs)


@dataclass(frozen=True, eq=False)
class StreamSchedule:
    """The static schedule of one core (see the module docstring for the rules).

    Per group g (arrays of Gs): fill[g], retire[g]. Per node n (new numbering, arrays of N):
    first_read[n], last_read[n] (cycles a window copy reads the node), first_write[n],
    last_write[n] (force ring writes); NONE where a node has none. Cycles are relative to the start of
    the step's issue. `binding` names what sets T.
    """
    n_nodes: int
    lanes: int                 # P: element lanes
    node_lanes: int            # Q
    groups: int                # Gs = ceil(N / Q)
    slots: int                 # C: item slots a step
    element_slots: int         # ceil(E / P)
    pair_slots: int            # ceil(pairs / Pp)
    period: int                # T
    window_groups: int         # Wg
    ring_groups: int           # Wr: the force rings' slots (the window's slot mod Wr)
    latencies: Latencies
    fill: np.ndarray
    retire: np.ndarray
    first_read: np.ndarray
    last_read: np.ndarray
    first_write: np.ndarray
    last_write: np.ndarray
    bandwidth: int
    binding: str
    bounds: dict = field(default_factory=dict)
    pair_lanes: int = 0        # Pp: topology-pair lanes (0: no pairs)

    # ---- derived figures
    @property
    def window_nodes(self) -> int:
        return self.window_groups * self.node_lanes

    @property
    def base_step(self) -> int:
        """What a window base register adds at a step boundary: Gs mod Wg."""
        return self.groups % self.window_groups

    @property
    def issue_start(self) -> int:
        """A0: run cycle of step 0's slot 0 (the prologue: the fills that precede it)."""
        return max(LOOKAHEAD + 1 + ISSUE_FANOUT, LOOKAHEAD + 1 - int(self.fill[0]))

    @property
    def fill_start(self) -> int:
        return self.issue_start + int(self.fill[0])

    @property
    def retire_start(self) -> int:
        return self.issue_start + int(self.retire[0])

    @property
    def drain(self) -> int:
        """Cycles from the start of the last step's issue to the run's end (busy falls after it)."""
        return int(self.retire[-1]) + self.latencies.node + SAT_TAIL

    def run_cycles(self, steps: int) -> int:
        """Cycles RUN `steps` keeps the core busy: prologue, steps - 1 periods, the last step's drain."""
        return self.issue_start + (steps - 1) * self.period + self.drain + 1

    def fill_phases(self) -> np.ndarray:
        """(T,) bits: the fill process reads a group at this phase of its period."""
        bits = np.zeros(self.period, np.int64)
        bits[self.fill - self.fill[0]] = 1
        return bits

    def retire_phases(self) -> np.ndarray:
        bits = np.zeros(self.period, np.int64)
        bits[self.retire - self.retire[0]] = 1
        return bits

    def to_dict(self) -> dict:
        """The manifest's view."""
        lat = self.latencies
        return {
            "period_T": self.period, "item_slots_C": self.slots, "element_slots": self.element_slots,
            "pair_slots": self.pair_slots, "binding": self.binding, "bounds": dict(self.bounds),
            "groups_Gs": self.groups, "node_lanes_Q": self.node_lanes, "lanes_P": self.lanes,
            "pair_lanes_Pp": self.pair_lanes,
            "window_groups_Wg": self.window_groups, "window_nodes_W": self.window_nodes,
            "ring_groups_Wr": self.ring_groups,
            "bandwidth": self.bandwidth, "prologue_A0": self.issue_start,
            "fill_start": self.fill_start, "retire_start": self.retire_start, "drain": self.drain,
            "run_cycles": "A0 + (n - 1) T + drain + 1",
            "latencies": {"memory": MEMORY, "fill_fanout": FILL_FANOUT,
                          "store_read_fanout": STORE_READ_FANOUT, "slot_register": SLOT_REG,
                          "read_fanout": READ_FANOUT,
                          "retire_fanout": RETIRE_FANOUT, "rmw_write": RMW, "a_write": A_WRITE, "store_write": STORE_WRITE,
                          "lookahead": LOOKAHEAD, "saturation_tail": SAT_TAIL,
                          "element": lat.element, "element_state": lat.element_state, "pair": lat.pair,
                          "node": lat.node},
        }


def _node_extremes(n_nodes, nodes_per_item, cycles_per_item):
    """Per node: (min, max) of the cycles of the items touching it (NONE / -NONE where none)."""
    lo = np.full(n_nodes, NONE, np.int64)
    hi = np.full(n_nodes, -NONE, np.int64)
    for nodes, cyc in zip(nodes_per_item, cycles_per_item):
        if len(nodes):
            np.minimum.at(lo, nodes, cyc)
            np.maximum.at(hi, nodes, cyc)
    return lo, hi


def _by_group(arr, Q, Gs, fill, reduce):
    pad = np.full(Gs * Q, fill, np.int64)
    pad[:len(arr)] = arr
    return reduce(pad.reshape(Gs, Q), axis=1)


def build_schedule(order: StreamOrder, lanes: int, node_lanes: int, lat: Latencies,
                   max_window_groups: int = MAX_WINDOW_GROUPS, pair_lanes: int | None = None) -> StreamSchedule:
    """The schedule of a core streaming `order` on P = lanes element lanes, Pp = pair_lanes topology-pair
    lanes (default P) and Q = node_lanes node lanes with these pipeline latencies; raises BandwidthError
    when no window up to `max_window_groups` groups satisfies the rules."""
    P, Q, N = int(lanes), int(node_lanes), order.n_nodes
    Pp = P if pair_lanes is None else int(pair_lanes)
    if P < 1 or Q < 1 or Pp < 1:
        raise ValueError(f"lanes, pair lanes and node lanes must be at least 1, got P = {P}, Pp = {Pp}, Q = {Q}")
    if N < 1:
        raise ValueError("a scene without nodes has no schedule")
    E, Pn = len(order.ei), len(order.pair_nodes)
    if Pn and lat.pair <= 0:
        raise ValueError("pairs in the stream but no pair pipeline latency")
    M, F = MEMORY, STORE_READ_FANOUT + FILL_FANOUT
    Ce, Cp = -(-E // P), -(-Pn // Pp)
    C = max(Ce, Cp, 1)
    Gs = -(-N // Q)
    se, sp = np.arange(E) // P, np.arange(Pn) // Pp
    nodes = [order.ei, order.ej] + [order.pair_nodes[:, r] for r in range(order.pair_nodes.shape[1] if Pn else 0)]
    slots = [se, se] + [sp] * (len(nodes) - 2)
    stage = [lat.element, lat.element] + [lat.pair] * (len(nodes) - 2)
    first_read, last_read = _node_extremes(N, nodes, [c + M + SLOT_REG + READ_FANOUT for c in slots])
    first_write, last_write = _node_extremes(N, nodes, [c + s + RMW for c, s in zip(slots, stage)])

    rd_first = _by_group(first_read, Q, Gs, NONE, np.min)
    rd_last = _by_group(last_read, Q, Gs, -NONE, np.max)
    wr_first = _by_group(first_write, Q, Gs, NONE, np.min)
    wr_last = _by_group(last_write, Q, Gs, -NONE, np.max)

    # fill: as late as possible, one group a cycle, in group order (a group nobody reads is filled just
    # after the stream, before its retirement)
    fill = np.zeros(Gs, np.int64)
    nxt = NONE
    for g in range(Gs - 1, -1, -1):
        want = rd_first[g] - M - F - 1 if rd_first[g] < NONE else C + 1
        fill[g] = min(want, nxt - 1)
        nxt = fill[g]
    # retirement: as early as possible, one group a cycle, in group order
    retire = np.zeros(Gs, np.int64)
    prev = -NONE
    for g in range(Gs):
        retire[g] = max(wr_last[g] + 1, fill[g] + M + F + 1, prev + 1)
        prev = retire[g]

    bounds = {
        "items": C,
        "a_state": lat.element_state + 1 if E else 1,
        "fill_span": int(fill[-1] - fill[0] + 1),
        "retire_span": int(retire[-1] - retire[0] + 1),
        "node_store": int(np.max(retire + lat.node + STORE_WRITE + 1 - fill)),
    }
    T = max(bounds.values())
    binding = max(bounds, key=lambda k: (bounds[k], k == "items"))

    # the rings, then the window: the smallest powers of two groups whose slot reuse is safe
    last_window_read = np.maximum(rd_last, retire)
    g = np.arange(Gs)

    def next_group(W):
        v = g + W
        return v // Gs, v % Gs                            # the step and group that take g's slot next

    def rings_safe(W):
        s, g2 = next_group(W)
        return np.all(retire <= np.where(wr_first[g2] < NONE, s * T + wr_first[g2], NONE) - 1)

    def window_safe(W):
        s, g2 = next_group(W)
        return np.all(last_window_read <= s * T + fill[g2] + M + F - 1)     # before the fill write

    Wr = 1
    while Wr <= max_window_groups and not rings_safe(Wr):
        Wr *= 2
    Wg = Wr
    while Wg <= max_window_groups and not window_safe(Wg):
        Wg *= 2
    if Wg > max_window_groups:
        raise BandwidthError(
            f"the scene's node numbering has bandwidth {order.bandwidth} (after reverse Cuthill-McKee): "
            f"its live nodes do not fit the largest window the streaming core allows, {max_window_groups} "
            f"groups of {Q} nodes ({max_window_groups * Q} nodes); use more node lanes (--node-lanes), "
            f"or the phased core (--core phased)")
    return StreamSchedule(N, P, Q, Gs, C, Ce, Cp, int(T), int(Wg), int(Wr), lat, fill, retire, first_read, last_read,
                          first_write, last_write, order.bandwidth, binding, bounds, Pp if Pn else 0)


SPARE_LANE_KINDS = ("element_lanes_P", "pair_lanes", "node_lanes_Q")


def spare_lanes(order: StreamOrder, sch: StreamSchedule, max_window_groups: int = MAX_WINDOW_GROUPS) -> list[dict]:
    """The lane kinds of schedule `sch` (of `order`) of which one fewer keeps its period T or shortens it
    (fewer node lanes can: the retirement runs a group a cycle; each lane costs multipliers and logic for
    nothing then): for each, its manifest name, the lane counts with one fewer
    of it, their command-line options and T. Pair lanes count only in a scene with pairs; a fewer count
    whose window would not fit is no spare."""
    pairs = len(order.pair_nodes) > 0
    counts = {"element_lanes_P": sch.lanes, "pair_lanes": sch.pair_lanes if pairs else 1,
              "node_lanes_Q": sch.node_lanes}
    out = []
    for kind in SPARE_LANE_KINDS:
        if counts[kind] < 2:
            continue
        fewer = dict(counts, **{kind: counts[kind] - 1})
        P, Pp, Q = fewer["element_lanes_P"], fewer["pair_lanes"], fewer["node_lanes_Q"]
        try:
            t = build_schedule(order, P, Q, sch.latencies, max_window_groups, Pp).period
        except BandwidthError:
            continue
        if t <= sch.period:
            options = f"--lanes {P} " + (f"--pair-lanes {Pp} " if pairs else "") + f"--node-lanes {Q}"
            out.append({"lanes": kind, "fewer": fewer[kind], "options": options, "period_T": int(t)})
    return out
