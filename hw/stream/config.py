"""`StreamConfig`: everything a streaming core is built from, decided at construction.

From a bit-true model (its Params, formats and function units) and the lane counts: the stream order
(hw/stream/order.py), the pipelines' stages (dry runs, hw/stream/kernels.py), the schedule
(hw/stream/schedule.py), the node word layout, the force rings (one per lane role) with their
accumulator widths, and the host address map of the renumbering (hw/hostmap.py). A scene with a [probe]
adds the probe port's sample kernel (`probe_dry`).
"""
from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np

from ..datapath import NotSupported
from ..hostmap import HostMap
from .kernels import dry_run_element, dry_run_node, dry_run_pair, dry_run_probe_sample, max_count
from .nodeword import NodeWord, bits_for
from .order import lane_items, stream_order
from .schedule import A_WRITE, Latencies, build_schedule, spare_lanes


class NotStreamable(NotSupported):
    """A scene the streaming core does not take (collisions: their pairs are not local)."""


@dataclass(frozen=True)
class RingInfo:
    """One force ring: lane kind ("el" or "pr"), lane, role, accumulator bits, and its items' nodes.
    Element lanes' roles are 0: the lower node, 1: the higher node of each element, whose contributions
    come in runs (`runs`: a RunSum instead of a ForceRing); pair lanes' are the pair's roles."""
    kind: str
    lane: int
    role: int
    acc_bits: int
    nodes: np.ndarray = field(repr=False)       # new node numbers of the lane's items, in slot order
    runs: bool = False

    @property
    def name(self) -> str:
        return f"{self.kind}{self.lane}_r{self.role}"


class StreamConfig:
    """The static description of one streaming core (see the module docstring)."""

    def __init__(self, params, formats, units, lanes: int = 1, node_lanes: int = 1, init: dict | None = None,
                 ram: str = "sim", max_window_groups: int | None = None, pair_lanes: int | None = None,
                 dp16kd_budget: int | None = None):
        pair_lanes = lanes if pair_lanes is None else pair_lanes
        for name, v in (("lanes", lanes), ("node_lanes", node_lanes), ("pair_lanes", pair_lanes)):
            if isinstance(v, bool) or not isinstance(v, int) or not 1 <= v <= 64:
                raise ValueError(f"{name} must be an integer in 1..64, got {v!r}")
        if params.collision is not None:
            raise NotStreamable("the streaming core does not take scenes with collisions (collision pairs are "
                                "not local to the node numbering): use the phased core (--core phased)")
        self.params, self.formats, self.units = params, formats, units
        self.lanes, self.node_lanes, self.ram = lanes, node_lanes, ram
        # ram: "sim" (Amaranth memories and products, for every simulator) or "ecp5" (`rheo synth`: the
        # ECP5's DP16KD block RAMs, hw/stream/bram.py, and MULT18X18D multipliers, hw/mult18x18d.py,
        # instantiated with their registers; simulators need their models beside the core)
        if dp16kd_budget is not None and (isinstance(dp16kd_budget, bool) or not isinstance(dp16kd_budget, int)
                                          or dp16kd_budget < 0):
            raise ValueError(f"dp16kd_budget must be an integer >= 0 or None, got {dp16kd_budget!r}")
        self.dp16kd_budget = dp16kd_budget    # the device's DP16KD: shallow copies move into LUT RAM to fit
                                              # (StreamCore; None: every memory a block RAM)
        self.pair_lanes = pair_lanes          # Pp: topology-pair lanes (P unless asked; scenes whose pairs
                                              # outnumber their elements run faster with more)
        self.init = init or {}
        p = params
        pairs = p.topology["pairs"] if p.topology is not None else np.zeros((0, p.dim + 1), np.int64)
        self.order = stream_order(p.n_nodes, np.stack([p.i, p.j], 1), pairs)
        self.element_dry = dry_run_element(p, formats, units)
        self.pair_dry = dry_run_pair(p, formats, units) if len(pairs) else None
        self.node_dry = dry_run_node(p, formats, units, self.force_sum_bits)   # its stages follow the widths
        self.probe_dry = dry_run_probe_sample(p, formats, units) if p.probe is not None else None
        self.latencies = Latencies(element=self.element_dry.stage,
                                   element_state=self.element_dry.outputs["state_stage"] + A_WRITE,
                                   node=self.node_dry.stage,
                                   pair=self.pair_dry.stage if self.pair_dry is not None else 0)
        self._window_kw = {} if max_window_groups is None else {"max_window_groups": max_window_groups}
        self.schedule = build_schedule(self.order, lanes, node_lanes, self.latencies, pair_lanes=pair_lanes,
                                       **self._window_kw)
        self.word = NodeWord.of(formats, p.dim)

    @classmethod
    def of(cls, bt, lanes: int = 1, node_lanes: int = 1, ram: str = "sim", **kw) -> "StreamConfig":
        st = bt.initial_state()
        return cls(bt.params, bt.formats, bt.ar.units, lanes, node_lanes, {"X": st.X, "U": st.U, "A": st.A},
                   ram, **kw)

    def spare_lanes(self) -> list[dict]:
        """Lane kinds of which one fewer keeps the period (hw/stream/schedule.py `spare_lanes`)."""
        return spare_lanes(self.order, self.schedule, **self._window_kw)

    # ---- sizes
    @property
    def dim(self) -> int:
        return self.params.dim

    @property
    def n_nodes(self) -> int:
        return self.params.n_nodes

    @property
    def n_elements(self) -> int:
        return len(self.order.ei)

    @property
    def n_pairs(self) -> int:
        return len(self.order.pair_nodes)

    def element_items(self, lane: int) -> np.ndarray:
        """Stream positions of the elements lane `lane` runs, in slot order."""
        return lane_items(self.n_elements, self.lanes, lane)

    def pair_items(self, lane: int) -> np.ndarray:
        return lane_items(self.n_pairs, self.pair_lanes, lane)

    # ---- force rings, in the order of the node lanes' mask bits
    @functools.cached_property
    def rings(self) -> list[RingInfo]:
        fe = self.formats["fe"].width
        out = []
        for lane in range(self.lanes):
            items = self.element_items(lane)
            ei, ej = self.order.ei[items], self.order.ej[items]
            for role, nodes in enumerate((np.minimum(ei, ej), np.maximum(ei, ej))):
                out.append(RingInfo("el", lane, role, fe + max_count(nodes).bit_length() + 1, nodes, role == 1))
        if self.n_pairs:
            for lane in range(self.pair_lanes):
                items = self.pair_items(lane)
                for role in range(self.dim + 1):
                    nodes = self.order.pair_nodes[items, role]
                    out.append(RingInfo("pr", lane, role, fe + max_count(nodes).bit_length() + 1, nodes))
        return out

    @property
    def force_sum_bits(self) -> int:
        """Bits of a node lane's exact sum of its force ring words (hw/stream/node.py)."""
        return max(ring.acc_bits for ring in self.rings) + bits_for(len(self.rings)) + 1

    def ring_masks(self) -> np.ndarray:
        """(N, rings) bits: ring r holds contributions to node n (new numbering)."""
        mask = np.zeros((self.n_nodes, len(self.rings)), np.int64)
        for r, ring in enumerate(self.rings):
            mask[np.unique(ring.nodes).astype(np.int64), r] = 1
        return mask

    # ---- host addresses of the renumbering
    @functools.cached_property
    def host_map(self) -> HostMap:
        Q, P = self.node_lanes, self.lanes
        perm, pos = self.order.perm, self.order.element_position()
        return HostMap(self.dim, perm % Q, perm // Q, Q, self.schedule.groups, pos % P, pos // P, P,
                       max(self.schedule.element_slots, 1))

    def features(self):
        return self.params.features()
