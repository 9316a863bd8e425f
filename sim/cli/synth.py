"""`rheo synth SCENE --out DIR`: the scene's core through Yosys and nextpnr for an ECP5: resources, Fmax and
the steps per second they give."""
from __future__ import annotations

import json
from pathlib import Path

from .common import (PRESET_CHOICES, hardware_model, lane_arguments, place_and_route_arguments, positive_float,
                     scene_argument, spare_lane_notes)
from .verilog import full_argument

NAME, HELP = "synth", "synthesise the scene's core for an ECP5: resources, Fmax, steps/s"


def add_arguments(parser) -> None:
    scene_argument(parser)
    parser.add_argument("--out", required=True, metavar="DIR", help="output directory")
    parser.add_argument("--device", default="ecp5-85k", help="ecp5-85k (default), ecp5-45k, ecp5-25k, ecp5-12k")
    parser.add_argument("--clock-mhz", type=positive_float, default=100.0, help="clock constraint (default 100 MHz)")
    parser.add_argument("--preset", default="auto", choices=PRESET_CHOICES,
                        help="number-format preset (default auto: the narrowest whose bit-true run stays within 1e-3 "
                             "of the object size of golden on the scene; narrow's products fit 18x18 multipliers)")
    place_and_route_arguments(parser)
    full_argument(parser)
    parser.add_argument("--no-pnr", dest="pnr", action="store_false",
                        help="Yosys only: resources in minutes, no place and route and no Fmax")
    parser.add_argument("--netlist-from", type=Path, metavar="DIR",
                        help="place and route the Yosys netlist of an earlier `rheo synth` output directory of the "
                             "same core (its Verilog byte for byte) instead of running Yosys again: another --seed, "
                             "--router or --speed-grade in minutes less (make it once with --no-pnr)")
    lane_arguments(parser)


def run(args) -> int:
    from hw import emit
    from sim.runfile import check_output_dir, output_directory
    from sim.synth import check_block_rams, check_device, check_tools, synthesize
    out = check_output_dir(args.out)              # every argument before the range analysis and the tools
    check_device(args.device)
    check_block_rams(args.block_rams, args.device)
    check_tools(args.pnr)
    check_netlist_from(args)
    check_floorplan(args)
    bt = hardware_model(args)
    with output_directory(out) as tmp:             # whole or not at all
        r, man = _synthesize(args, bt, tmp, emit, synthesize)
    print(f"wrote {out}/synth.json, report.md, {man['verilog']}, manifest.json")
    moved = man.get("block_ram_fit", {}).get("lut_ram_memories")
    if moved:
        print(f"  {len(moved)} shallow copies in LUT RAM to fit {args.device}'s "
              f"{man['block_ram_fit']['dp16kd_budget']} DP16KD: {', '.join(moved)}")
    timing = (f"Fmax {r['fmax_mhz']:.1f} MHz (constraint {args.clock_mhz} MHz, {'met' if r['timing_met'] else 'NOT met'}; "
              f"seed {r['seed']}, speed grade {args.speed_grade})"
              + (f"; netlist of {r['netlist_from']}" if r.get("netlist_from") else "")
              + (f"; floorplan: {r['floorplan']['cells_placed']} block RAMs and multipliers in "
                 f"{r['floorplan']['regions']} regions" if r.get("floorplan") else "")
              + (f"; router2 stalled with seed {', '.join(str(st['seed']) for st in r['stalled_seeds'])}"
                 if r.get("stalled_seeds") else "")
              if args.pnr and r.get("fmax_mhz") is not None else
              "no place and route (--no-pnr): no Fmax" if not args.pnr else "no Fmax: see nextpnr.log")
    print(f"  {r['luts']} LUTs, {r['flip_flops']} FFs, {r['mult18x18']} 18x18 multipliers, {r['block_rams']} block RAMs; "
          + timing)
    cp, late = r.get("critical_path"), r.get("late_endpoints")
    if cp:
        print(f"  critical path {cp['from']} -> {cp['to']}: {cp['delay_ns']:.2f} ns, {cp['routing_ns']:.2f} of it routing"
              + (f"; {late['late']} of {late['endpoints']} endpoint pins late (report.md lists them by register)"
                 if late and late["late"] else ""))
    for line in spare_lane_notes(man.get("spare_lanes"), man["cycles_per_step"]["value"]):
        print(f"  {line}")
    if r.get("fmax_mhz"):
        print(f"  {r['cycles_per_step']} cycles per step -> {r['modelled_steps_per_s']:.0f} steps/s modelled at Fmax")
    return 0


def check_netlist_from(args) -> None:
    """`--netlist-from DIR`, before any work: a directory holding a netlist, with place and route to use it.
    Whether its netlist is this core's is known after the Verilog is emitted (sim/synth.py reuse_netlist)."""
    from golden.errors import BadArgument
    src = args.netlist_from
    if src is None:
        return
    if not args.pnr:
        raise BadArgument("--netlist-from reuses a netlist for place and route; with --no-pnr there is nothing to do")
    if not src.is_dir() or not (src / "synth.ys").is_file():
        raise BadArgument(f"--netlist-from {src}: not an output directory of `rheo synth` (no synth.ys there)")


def check_floorplan(args) -> None:
    """`--floorplan lanes`, before any work: place and route, a device whose block sites are known, the
    streaming core (with --core auto the scene decides: sim.synth.floorplan_for)."""
    from golden.errors import BadArgument
    from sim.synth import check_floorplan_device
    if args.floorplan != "lanes":
        return
    if not args.pnr:
        raise BadArgument("--floorplan places blocks for place and route; with --no-pnr there is nothing to place")
    check_floorplan_device(args.floorplan, args.device)
    if args.core == "phased":
        raise BadArgument("--floorplan lanes places the streaming core's lanes, not the phased core's")


def _synthesize(args, bt, out: Path, emit, synthesize):
    from sim.synth import block_ram_capacity, floorplan_for
    man = emit.write(bt, out, lanes=args.lanes, node_lanes=args.node_lanes, core=args.core, ram="ecp5",
                     pair_lanes=args.pair_lanes,
                     dp16kd_budget=block_ram_capacity(args.device) if args.block_rams is None else args.block_rams)
    r = synthesize(out / man["verilog"], man["top"], out, device=args.device, clock_mhz=args.clock_mhz,
                   seed=args.seed, progress=True, place_and_route=args.pnr, router=args.router,
                   placer=args.placer, speed_grade=args.speed_grade,
                   netlist_from=getattr(args, "netlist_from", None),
                   floorplan=floorplan_for(man, args.device, args.floorplan) if args.pnr else None)
    r.update(scene=man["scene"], preset=man["preset"], full_featured=args.full, lanes=man["lanes"],
             elements=man["elements"], nodes=man["nodes"], units_present=[u["unit"] for u in man["units_present"]])
    cps = man["cycles_per_step"]["value"]
    r["cycles_per_step"] = cps
    if r.get("fmax_mhz"):
        r["modelled_steps_per_s"] = r["fmax_mhz"] * 1e6 / cps
        r["modelled_element_updates_per_s"] = r["modelled_steps_per_s"] * man["elements"]
    (out / "synth.json").write_text(json.dumps(r, indent=2, default=str))
    return r, man
