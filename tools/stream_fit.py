"""Block RAM budget of the streaming core against mesh size (a model from the cores' own memory
inventories, StreamCore.block_rams(): its BlockRams, which include the function-unit tables that pairs
of element lanes share, plus each lane's own unit ROMs that Yosys infers, planned as hw/stream/bram.py
plans a BlockRam: the two Phi tables, 2 DP16KD a lane under medium; unshared, all tables take 12 a lane
under medium, 6 under narrow): which squares and boxes fit the 208 DP16KD of an LFE5U-85F. Checked
against Yosys on square:1000, P = Q = 2, medium: 74 modelled, 74 synthesised. Formats come from the
1e4-element mesh (they hardly depend on its size), so no range analysis of the large meshes is needed.
With `--fit N` the core fits N DP16KD as `rheo synth` builds it (shallow copies into LUT RAM,
hw/stream/core.py): the memories moved and their TRELLIS_DPR16X4 are printed.

    python tools/stream_fit.py square 6 2 narrow 10000 20000 30000 ... [--fit 208]
"""
from __future__ import annotations

import sys
import warnings

warnings.filterwarnings("ignore")


def inventory(kind, n, P, Q, preset, budget=None, fmt_cache={}):
    from hw.bittrue import BitTrue
    from hw.stream.config import StreamConfig
    from hw.stream.core import StreamCore
    from sim.bench import box_system, square_system
    make = square_system if kind == "square" else box_system
    if (kind, preset) not in fmt_cache:
        fmt_cache[(kind, preset)] = BitTrue(make(10_000), preset).formats
    system = make(n)
    bt = BitTrue(system, preset, formats=fmt_cache[(kind, preset)])
    core = StreamCore(StreamConfig.of(bt, P, Q, dp16kd_budget=budget))
    mems = core.memories()
    blocks = core.block_rams()
    units = blocks - sum(m["dp16kd"] for m in mems)
    sch = core.schedule
    return dict(elements=system.n_elements, nodes=system.n_nodes, bandwidth=sch.bandwidth, T=sch.period,
                C=sch.slots, window_groups=sch.window_groups, dp16kd=blocks, lut_ram=core.lut_memories,
                dpr16x4=sum(m.get("dpr16x4", 0) for m in mems),
                by_kind={**{k: sum(m["dp16kd"] for m in mems if m["name"].startswith(k) and "_tables." not in m["name"])
                            for k in ("store", "window", "ring", "runsum", "el", "nd", "fill", "retire")},
                         "tables": units + sum(m["dp16kd"] for m in mems if "_tables." in m["name"])})


if __name__ == "__main__":
    args = sys.argv[1:]
    budget = None
    if "--fit" in args:
        k = args.index("--fit")
        budget = int(args[k + 1])
        del args[k:k + 2]
    kind, P, Q, preset = args[0], int(args[1]), int(args[2]), args[3]
    for n in args[4:]:
        try:
            r = inventory(kind, int(n), P, Q, preset, budget)
            moved = (f" LUT RAM: {len(r['lut_ram'])} memories, {r['dpr16x4']} DPR16X4 ({', '.join(r['lut_ram'])})"
                     if r["lut_ram"] else "")
            print(f"{kind}:{n} E {r['elements']} N {r['nodes']} bw {r['bandwidth']} T {r['T']} (C {r['C']}, "
                  f"+{100 * (r['T'] / r['C'] - 1):.1f} %) Wg {r['window_groups']} DP16KD {r['dp16kd']} {r['by_kind']}"
                  + moved, flush=True)
        except ValueError as exc:
            print(f"{kind}:{n} refused: {exc}", flush=True)
