"""What several subcommands share: argument types, the scene argument (a built-in name, a file, or the
benchmark square `square:N`), memory checks before anything is allocated, and the bit-true model a
hardware command builds."""
from __future__ import annotations

import argparse
import sys

import numpy as np

from golden.errors import RheoError

FORMAT_PRESETS = ("narrow", "medium", "wide")       # hw/formats.py FORMAT_PRESETS (tested equal)
PRESET_CHOICES = FORMAT_PRESETS + ("auto",)        # auto: the narrowest within 1e-3 of golden (sim.backends)


class UsageError(RheoError, ValueError):
    """A problem with the user's input; printed as one line, exit code 2."""


def positive_float(text: str) -> float:
    try:
        val = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got '{text}'") from None
    if not (val > 0 and np.isfinite(val)):
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text}")
    return val


def _int_at_least(text: str, low: int) -> int:
    try:
        val = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got '{text}'") from None
    if val < low:
        raise argparse.ArgumentTypeError(f"expected a whole number >= {low}, got {val}")
    return val


def whole_number(text: str) -> int:
    return _int_at_least(text, 0)


def positive_int(text: str) -> int:
    return _int_at_least(text, 1)


MAX_LANES = 64                                      # hw/core.py CoreConfig


def lane_count(text: str) -> int:
    val = positive_int(text)
    if val > MAX_LANES:
        raise argparse.ArgumentTypeError(f"expected a lane count in 1..{MAX_LANES}, got {val}")
    return val


def scene_argument(parser) -> None:
    parser.add_argument("scene", help="built-in scene name, path to a scene .toml, square:N (the benchmark "
                                      "square of about N elements) or box:N (its 3D counterpart)")


def lane_arguments(parser) -> None:
    parser.add_argument("--lanes", type=lane_count, default=1,
                        help=f"hardware: element (and pair) lanes P in 1..{MAX_LANES} (default 1)")
    parser.add_argument("--node-lanes", type=lane_count, default=1,
                        help=f"hardware: node lanes Q in 1..{MAX_LANES} (default 1)")
    parser.add_argument("--pair-lanes", type=lane_count, default=None,
                        help=f"hardware: the streaming core's topology-pair lanes in 1..{MAX_LANES} (default: as "
                             f"many as --lanes; scenes with more pairs than elements run faster with more)")
    parser.add_argument("--core", choices=("auto", "phased", "stream"), default="auto",
                        help="hardware: the streaming core (hw/stream/) or the phased one (hw/core.py); default "
                             "auto: streaming unless the scene has collisions")


# block_rams None: all the device has
PLACE_AND_ROUTE_DEFAULTS = {"router": "router1", "placer": "heap", "seed": 1, "speed_grade": 6, "block_rams": None,
                            "floorplan": "auto"}


def place_and_route_arguments(parser, what: str = "") -> None:
    """nextpnr's router, placer, seed and speed grade, the floorplan and the streaming core's DP16KD budget (`rheo synth`,
    `rheo bench --backend fpga`); `what` prefixes the help (e.g. "fpga: ")."""
    from sim.synth import FLOORPLANS, PLACERS, ROUTERS, SPEED_GRADES
    d = PLACE_AND_ROUTE_DEFAULTS
    parser.add_argument("--router", choices=ROUTERS, default=d["router"],
                        help=f"{what}nextpnr's router (default router1, nextpnr's own; router2 gets through congested "
                             "designs sooner)")
    parser.add_argument("--placer", choices=PLACERS, default=d["placer"],
                        help=f"{what}nextpnr's placer (default heap, nextpnr's own; static, its electrostatic one, "
                             "leaves less wire and less congestion on large cores)")
    parser.add_argument("--seed", type=positive_int, default=d["seed"],
                        help=f"{what}nextpnr's placement seed (default 1); Fmax moves by a few MHz from seed to seed")
    parser.add_argument("--speed-grade", type=int, choices=SPEED_GRADES, default=d["speed_grade"],
                        help=f"{what}the ECP5 part's speed grade, for nextpnr's timing (default 6, the slowest: "
                             "the LFE5U-85F-6 of common boards; 8 is the fastest part)")
    parser.add_argument("--floorplan", choices=FLOORPLANS, default=d["floorplan"],
                        help=f"{what}where nextpnr puts the block RAMs and multipliers: lanes, each lane's own in a "
                             "stripe of the die beside its logic (hw/stream/floorplan.py; the 1e4 square routes with "
                             "it); none, wherever nextpnr likes; auto (default): lanes for the streaming core on a "
                             "device whose sites are known (ecp5-85k), else none")
    parser.add_argument("--block-rams", type=whole_number, default=d["block_rams"], metavar="N",
                        help=f"{what}the streaming core's DP16KD budget (default: all the device has); fewer moves "
                             "more shallow copies into LUT RAM: block RAM, and the routing into it, traded for LUTs")


SPARE_LANE_NAMES = {"element_lanes_P": "element lane", "pair_lanes": "pair lane", "node_lanes_Q": "node lane"}


def spare_lane_notes(spare, period: int) -> list[str]:
    """One line per lane kind of which one fewer keeps the period `period` or shortens it (a manifest's
    "spare_lanes")."""
    return [f"note: one {SPARE_LANE_NAMES[s['lanes']]} fewer ({s['options']}) "
            + (f"keeps T = {period}" if s["period_T"] == period else f"gives T = {s['period_T']}, not {period},")
            + " cycles a step: that lane costs multipliers and logic for no speed" for s in spare or []]


def place_and_route_chosen(args) -> bool:
    """Whether any option of place_and_route_arguments differs from its default."""
    return any(getattr(args, k) != v for k, v in PLACE_AND_ROUTE_DEFAULTS.items())


def load_system(ref: str):
    """A built-in scene by name, a scene file by path, `square:N`: the benchmark's generated square of about
    N elements, or `box:N`: its 3D counterpart (sim/bench.py)."""
    from golden.scene import load_scene
    for kind in ("square", "box"):
        if ref.startswith(kind + ":"):
            from sim import bench
            try:
                n = int(ref[len(kind) + 1:])
            except ValueError:
                n = 0
            if not 10 <= n <= 10_000_000:
                raise UsageError(f"'{ref}': {kind}:N takes a whole number of elements N in 10..10000000")
            check_square_fits(n)
            return bench.square_system(n) if kind == "square" else bench.box_system(n)
    from hw.formats import check_scene_formats       # [formats] belongs to the hardware: checked up front
    system = load_scene(ref)
    check_scene_formats(system)
    return system


def check_frames_fit(system, steps, every) -> None:
    """A run records every frame in memory: refuse, before running, what this machine cannot hold."""
    from golden.limits import over_memory
    steps = system.n_steps if steps is None else steps
    every = max(1, system.every if every is None else every)
    frames = steps // every + 2
    need = frames * (2 * system.n_nodes * system.dim + system.n_elements) * 8.0
    if (why := over_memory(need, f"recording {frames:.3g} frames ({steps} steps, every {every})")) is not None:
        raise UsageError(f"{why}: record fewer frames (a larger --every or fewer --steps)")


def check_square_fits(n_elements: int, backend: str = "golden") -> None:
    from golden.limits import mesh_nodes_fit
    if (why := mesh_nodes_fit(n_elements / 3, f"a generated square of {n_elements} elements", backend)) is not None:
        raise UsageError(why)


def check_backend_fits(system, backend: str, steps=None) -> None:
    """The scene on `backend` (the bit-true model and the simulated cores need more than golden, which the
    scene's loading already checked): refused before anything is built when this machine cannot hold it."""
    from golden.limits import mesh_nodes_fit
    if (why := mesh_nodes_fit(system.n_nodes, f"scene '{system.name}'", backend)) is not None:
        raise UsageError(why)


def warn_stagnation(bt) -> None:
    """A warning line on stderr for every state that stagnates under the bit-true model's formats."""
    for msg in bt.stagnation_messages():
        print(f"warning: {msg}", file=sys.stderr, flush=True)


def choose_preset(system, steps=None) -> str:
    """--preset auto: the narrowest preset within 1e-3 of the object size of golden over the scene's run,
    said on stdout with the errors that decided it."""
    from sim.backends import narrowest_preset
    print(f"{system.name}: choosing the preset (bit-true runs against golden, narrowest first)", flush=True)
    preset, _, why = narrowest_preset(system, steps)
    print(f"  {why}", flush=True)
    return preset


def hardware_model(args):
    """The bit-true model (formats) of the scene a hardware command builds: the scene, or with --full its
    full-featured variant (every optional unit)."""
    from hw import emit
    from hw.bittrue import BitTrue
    system = load_system(args.scene)
    if args.full:
        system = emit.full_featured(system)
    from hw.stream import check_pair_lanes, resolve_core    # a core the scene cannot have: refused before the range analysis
    check_pair_lanes(resolve_core(system, getattr(args, "core", "auto")), getattr(args, "pair_lanes", None))
    check_backend_fits(system, "amaranth")           # the core is elaborated: before the range analysis
    if args.preset == "auto":
        args.preset = choose_preset(system)
    print(f"{system.name}: range analysis and formats (preset {args.preset})", flush=True)
    with np.errstate(over="ignore", invalid="ignore"):
        bt = BitTrue(system, args.preset)
    warn_stagnation(bt)
    return bt
