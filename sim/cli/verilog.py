"""`rheo verilog SCENE --out DIR`: the scene's specialised core as Verilog, with its manifest."""
from __future__ import annotations

from .common import FORMAT_PRESETS, hardware_model, lane_arguments, scene_argument, spare_lane_notes

NAME, HELP = "verilog", "emit the scene's specialised core as Verilog with manifest.json"


def full_argument(parser) -> None:
    parser.add_argument("--full", action="store_true",
                        help="every optional unit elaborated (what specialisation saves; see hw/emit.py full_featured)")


def add_arguments(parser) -> None:
    scene_argument(parser)
    parser.add_argument("--out", required=True, metavar="DIR", help="output directory")
    parser.add_argument("--preset", default="wide", choices=FORMAT_PRESETS, help="number-format preset (default: wide)")
    full_argument(parser)
    lane_arguments(parser)


def run(args) -> int:
    from hw import emit
    from sim.runfile import check_output_dir, output_directory
    check_output_dir(args.out)                     # before the range analysis
    bt = hardware_model(args)
    with output_directory(args.out) as tmp:        # whole or not at all: core.v and manifest.json together
        man = emit.write(bt, tmp, lanes=args.lanes, node_lanes=args.node_lanes, core=args.core,
                         pair_lanes=args.pair_lanes)
    cps = man["cycles_per_step"]
    print(f"wrote {args.out}/{man['verilog']} ({len(man['verilog_modules'])} modules, {man['core']} core) and manifest.json")
    print(f"  units: {', '.join(u['unit'] for u in man['units_present'])}")
    print(f"  left out: {', '.join(u['unit'] for u in man['units_left_out']) or 'nothing'}")
    print(f"  {cps['value']} cycles per step = {cps['formula']} (P = {cps['P']}, Q = {cps['Q']}); "
          f"{len(man['memories'])} memories, {man['memory_bits']} bits")
    for line in spare_lane_notes(man.get("spare_lanes"), cps["value"]):
        print(f"  {line}")
    return 0
