"""The streaming core (issue 15, design C of docs hw-architecture review): node state stored once, the
element and pair streams in a bandwidth-reducing order reading their nodes from a sliding window, node
integration fused into the stream, steps back to back on a static schedule.

Modules, one concept each (no Amaranth in the first two):

  order.py      scene-compile-time order: reverse Cuthill-McKee renumbering, sorted streams, lanes
  schedule.py   StreamSchedule: every fill, read, contribution and retirement cycle, the window, the
                period T, checked against every read-after-write constraint at construction
  bram.py       BlockRam: a simple dual-port block RAM with its output register (Amaranth Memory, or
                ECP5 DP16KD instances with REGMODE_B = "OUTREG"), and the DP16KD model for simulators
  nodeword.py   how a node's x, u words pack into memory words
  store.py      NodeStore: node state, stored once in Q banks
  window.py     NodeWindow: the ring of nodes, one copy per read port, written by the fill
  forcering.py  ForceRing: a lane role's force accumulator (read-modify-write with forwarding)
  element.py    ElementLane, pair.py PairLane, node.py NodeLane: the per-item kernels of hw/datapath.py
  control.py    Control: the run, its prologue, periods and epilogue; hostport.py HostPort
  core.py       StreamCore: the top, composing the components; config.py StreamConfig
"""

CORES = ("phased", "stream")


def resolve_core(params, core: str = "auto") -> str:
    """The core a scene gets: "auto" is the streaming core unless the scene has collisions (their pairs
    are not local), which the phased core (hw/core.py) runs; asking for "stream" on such a scene fails
    with NotStreamable."""
    if core not in ("auto",) + CORES:
        raise ValueError(f"unknown core {core!r} (known: auto, {', '.join(CORES)})")
    if core == "auto":
        return "phased" if params.collision is not None else "stream"
    if core == "stream" and params.collision is not None:
        from .config import NotStreamable
        raise NotStreamable("the streaming core does not take scenes with collisions (collision pairs are not "
                            "local to the node numbering): use --core phased")
    return core


def build_core(bt, lanes: int = 1, node_lanes: int = 1, core: str = "phased", ram: str = "sim"):
    """The core (an Amaranth component with `cfg`, `host`, `cycles_per_step`) for a bit-true model."""
    core = resolve_core(bt.params, core)
    if core == "phased":
        from ..core import Core, CoreConfig
        return Core(CoreConfig.of(bt, lanes, node_lanes))
    from .config import StreamConfig
    from .core import StreamCore
    return StreamCore(StreamConfig.of(bt, lanes, node_lanes, ram=ram))
