"""Where the streaming core's hard blocks go on the die: each lane's block RAMs and multipliers together.

A floorplan is a list of regions in die order, left to right. A region is a list of regular expressions
matched (`re.match`) against the Yosys cell names, which are the core's submodule paths (`el3.`,
`ring_el3_r0.`, `window.copy7.`: hw/stream/core.py names them), or None: a share of the cells no region
names (the node store, the node lanes' group copy and ROMs, the control's phase ROMs), split in name order
among the None regions. `sim.synth.floorplan_bels` gives each region's DP16KD consecutive sites across the
die and its MULT18X18D the free sites nearest them; nextpnr keeps those and places the logic around them.

Lanes go in pairs of one kind (element lanes, then pair lanes): lane a, the tables the pair shares (hw/stream/tables.py
`shared_*`, in lane a's module), lane b; the rest between pairs. A lane's region: its module, its force
rings and its window copies (2 per element lane, D + 1 per pair lane, in that order: NodeWindow's reads).
Why: on the 1e4-element square at P = 6 every die-wide placement of session 19 and 20 ground in router2;
with this floorplan the same netlist routed in 100 iterations (docs/streaming-core.md, session 20).
"""
from __future__ import annotations


def lane_floorplan(element_lanes: int, pair_lanes: int, dim: int) -> list[list[str] | None]:
    """The regions (see the module docstring) of a streaming core with these lanes, in die order."""
    for name, v in (("element_lanes", element_lanes), ("pair_lanes", pair_lanes), ("dim", dim)):
        if not isinstance(v, int) or v < 0:
            raise ValueError(f"{name} must be a count (an int >= 0), got {v!r}")
    pairs = [[(f"{kind}{k}", [rf"{kind}{k}\.(?!.*\.shared_)", rf"ring_{kind}{k}_r\d+\.",
                              rf"window\.copy({'|'.join(map(str, copies))})\."]) for kind, k, copies in pair]
             for pair in _lane_pairs(element_lanes, pair_lanes, dim)]
    regions: list[list[str] | None] = []
    for i, pair in enumerate(pairs):
        if i:
            regions.append(None)
        regions.append(pair[0][1])
        if len(pair) == 2:
            regions += [[rf"{pair[0][0]}\..*\.shared_"], pair[1][1]]
    if len(pairs) < 2:
        regions.append(None)
    return regions


def _lane_pairs(element_lanes: int, pair_lanes: int, dim: int) -> list[list[tuple[str, int, range]]]:
    """The lanes in die order, in pairs of one kind (lanes 2j and 2j + 1 share tables), each as (kind, index,
    its window copies: NodeWindow's reads, 2 per element lane, then D + 1 per pair lane)."""
    pairs, first = [], 0
    for kind, count, reads in (("el", element_lanes, 2), ("pr", pair_lanes, dim + 1)):
        lanes = [(kind, k, range(first + k * reads, first + (k + 1) * reads)) for k in range(count)]
        first += count * reads
        pairs += [lanes[i:i + 2] for i in range(0, count, 2)]
    return pairs


def lane_pair_copies(element_lanes: int, pair_lanes: int, dim: int) -> list[list[int]]:
    """The window copies of each floorplan lane pair (lanes 2j and 2j + 1 of one kind, whose copies sit in
    one stripe of the die), in copy order: the fill's relay registers serve one group each
    (hw/stream/window.py)."""
    return [[c for _, _, copies in pair for c in copies] for pair in _lane_pairs(element_lanes, pair_lanes, dim)]
