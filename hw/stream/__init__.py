"""The streaming core (issue 15, design C of the hardware architecture review): node state stored once,
the element and pair streams in a bandwidth-reducing order reading their nodes from a sliding window,
node integration fused into the stream, steps back to back on a static schedule. docs/streaming-core.md
has the design and the measured figures.

Modules, one concept each (the first two without Amaranth):

  order.py       scene-compile-time order: reverse Cuthill-McKee renumbering, sorted streams, lanes
  schedule.py    StreamSchedule: every fill, read, contribution and retirement cycle, the window, the
                 period T, checked against every read-after-write rule at construction
  config.py      StreamConfig: order, pipeline stages (dry runs), schedule, force rings, host map
  bram.py        BlockRam: simple dual-port block RAM with its output register (Amaranth Memory, or
                 ECP5 DP16KD instances with REGMODE_B = "OUTREG"), a ROM with one or two read ports;
                 dp16kd.v: the DP16KD model
  nodeword.py    how a node's x, u words pack into memory words; small gateware helpers
  store.py       NodeStore: node state, stored once in Q banks
  window.py      NodeWindow: the ring of nodes, one copy per read port, written by the fill
  forcering.py   ForceRing (read-modify-write with forwarding) and RunSum (runs summed in a register)
  kernels.py     the kernels of hw/datapath.py on PipeArith for each lane kind, and their dry runs
  lanerom.py     LaneRom: a lane's per-item fields in one ROM, dictionary-encoded where they take few values
  tables.py      TablePair: function-unit tables shared by two element lanes (two ROM ports)
  element.py     ElementLane; pair.py PairLane; node.py NodeLane
  control.py     Control: the run, its prologue, periods and epilogue
  hostport.py    HostPort: the register map of hw/hostmap.py; saturation.py SaturationCounter
  probeport.py   ProbePort: a scene's haptic probe, samples in and forces out as streams (scenes with a [probe])
  core.py        StreamCore: the top, composing the components; manifest.py: its manifest
"""

from golden.errors import BadArgument

CORES = ("phased", "stream")
def resolve_core(params, core: str = "auto") -> str:
    """The core a scene gets: "auto" is the streaming core unless the scene has collisions (their pairs
    are not local), which the phased core (hw/core.py) runs; asking for "stream" on such a scene fails
    with NotStreamable. A scene with a [probe] gets the streaming core (its probe port); "phased" fails."""
    if core not in ("auto",) + CORES:
        raise BadArgument(f"unknown core {core!r} (known: auto, {', '.join(CORES)})")
    if params.probe is not None:
        from ..datapath import NotSupported
        if params.collision is not None:
            raise NotSupported("a scene with a [probe] and collisions runs on no core: the probe port is the "
                               "streaming core's, collisions the phased core's")
        if core == "phased":
            from ..core import PHASED_NO_PROBE
            raise NotSupported(PHASED_NO_PROBE)
        return "stream"
    if core == "auto":
        return "phased" if params.collision is not None else "stream"
    if core == "stream" and params.collision is not None:
        from .config import NotStreamable
        raise NotStreamable("the streaming core does not take scenes with collisions (collision pairs are not "
                            "local to the node numbering): use --core phased")
    return core


def check_pair_lanes(kind: str, pair_lanes: int | None) -> None:
    """Pair lanes apart from element lanes are the streaming core's: the phased core runs its pairs on
    its P lanes."""
    if pair_lanes is not None and kind == "phased":
        raise BadArgument("--pair-lanes is the streaming core's: the phased core runs its topology pairs on "
                          "its element lanes (--lanes)")


def cycles_per_step(bt, lanes: int = 1, node_lanes: int = 1, core: str = "auto",
                    pair_lanes: int | None = None) -> tuple[str, int]:
    """(the core `core` resolves to, its cycles per step), from the schedule known at construction:
    nothing is elaborated."""
    kind = resolve_core(bt.params, core)
    check_pair_lanes(kind, pair_lanes)
    if kind == "phased":
        from ..core import CoreConfig, schedule
        return kind, schedule(CoreConfig.of(bt, lanes, node_lanes))["cycles_per_step"]
    from .config import StreamConfig
    return kind, StreamConfig.of(bt, lanes, node_lanes, pair_lanes=pair_lanes).schedule.period


def build_core(bt, lanes: int = 1, node_lanes: int = 1, core: str = "phased", ram: str = "sim",
               pair_lanes: int | None = None, dp16kd_budget: int | None = None):
    """The core (an Amaranth component with `cfg`, `host`, `cycles_per_step`) for a bit-true model;
    pair_lanes (the streaming core's topology-pair lanes) defaults to lanes; dp16kd_budget: the streaming
    core's block RAM fit (hw/stream/core.py; the phased core has none)."""
    core = resolve_core(bt.params, core)
    check_pair_lanes(core, pair_lanes)
    if core == "phased":
        from ..core import Core, CoreConfig
        return Core(CoreConfig.of(bt, lanes, node_lanes))
    from .config import StreamConfig
    from .core import StreamCore
    return StreamCore(StreamConfig.of(bt, lanes, node_lanes, ram=ram, pair_lanes=pair_lanes,
                                      dp16kd_budget=dp16kd_budget))
