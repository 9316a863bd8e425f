"""Block RAM budget of the streaming core against mesh size (a model from the cores' own memory
inventories, StreamCore.memories(), which include the function-unit tables that pairs of element lanes
share, plus each lane's own unit ROMs that Yosys infers, planned as hw/stream/bram.py plans a BlockRam:
the two Phi tables, 2 DP16KD a lane under medium; unshared, all tables take 12 a lane under medium, 6
under narrow): which squares and boxes fit the 208 DP16KD of an LFE5U-85F. Checked against Yosys on
square:1000, P = Q = 2, medium: 74 modelled, 74 synthesised. Formats come from the 1e4-element mesh (they
hardly depend on its size), so no range analysis of the large meshes is needed.

    python tools/stream_fit.py square 6 2 narrow 10000 20000 30000 ...
"""
from __future__ import annotations

import sys
import warnings

warnings.filterwarnings("ignore")


def unit_rom_blocks(lane) -> int:
    """DP16KD of a lane's own function-unit ROMs (1/sqrt tables, Phi and Psi tables, from its kernel's dry
    run), those it does not share with another lane (hw/stream/tables.py)."""
    from hw.stream.bram import plan_blocks
    from hw.stream.tables import shares
    own = [mem for mem in lane.unit_memories() if lane.tables is None or not shares(mem["width"], mem["depth"])]
    return sum(rows * cols for *_, rows, cols in (plan_blocks(mem["width"], mem["depth"]) for mem in own))


def inventory(kind, n, P, Q, preset, fmt_cache={}):
    from hw.bittrue import BitTrue
    from hw.stream.config import StreamConfig
    from hw.stream.core import StreamCore
    from sim.bench import box_system, square_system
    make = square_system if kind == "square" else box_system
    if (kind, preset) not in fmt_cache:
        fmt_cache[(kind, preset)] = BitTrue(make(10_000), preset).formats
    system = make(n)
    bt = BitTrue(system, preset, formats=fmt_cache[(kind, preset)])
    core = StreamCore(StreamConfig.of(bt, P, Q))
    mems = core.memories()
    units = sum(unit_rom_blocks(lane) for lane in core.elements + core.pairs)
    blocks = sum(m["dp16kd"] for m in mems) + units
    sch = core.schedule
    return dict(elements=system.n_elements, nodes=system.n_nodes, bandwidth=sch.bandwidth, T=sch.period,
                C=sch.slots, window_groups=sch.window_groups, dp16kd=blocks,
                by_kind={**{k: sum(m["dp16kd"] for m in mems if m["name"].startswith(k) and "_tables." not in m["name"])
                            for k in ("store", "window", "ring", "runsum", "el", "nd", "fill", "retire")},
                         "tables": units + sum(m["dp16kd"] for m in mems if "_tables." in m["name"])})


if __name__ == "__main__":
    kind, P, Q, preset = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
    for n in sys.argv[5:]:
        try:
            r = inventory(kind, int(n), P, Q, preset)
            print(f"{kind}:{n} E {r['elements']} N {r['nodes']} bw {r['bandwidth']} T {r['T']} (C {r['C']}, "
                  f"+{100 * (r['T'] / r['C'] - 1):.1f} %) Wg {r['window_groups']} DP16KD {r['dp16kd']} {r['by_kind']}",
                  flush=True)
        except ValueError as exc:
            print(f"{kind}:{n} refused: {exc}", flush=True)
