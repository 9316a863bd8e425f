"""`rheo report SCENE --out DIR`: error against run time (quantisation per preset, discretisation per dt)."""
from __future__ import annotations

import numpy as np

from golden.errors import RheoError

from .common import FORMAT_PRESETS, UsageError, check_backend_fits, load_system, positive_float, scene_argument

NAME, HELP = "report", "error against run time: quantisation and discretisation errors"


def add_arguments(parser) -> None:
    scene_argument(parser)
    parser.add_argument("--out", required=True, help="output directory")
    parser.add_argument("--presets", nargs="+", choices=FORMAT_PRESETS, default=list(FORMAT_PRESETS),
                        help="format presets")
    parser.add_argument("--clock-mhz", type=positive_float, default=None,
                        help="FPGA clock for the FPGA run time (default: 50 MHz, about the measured Fmax of narrow cores)")
    parser.add_argument("--synth", default=None, metavar="DIR",
                        help="the measured Fmax of `rheo synth`'s place and route in DIR (or DIR/synth.json) for its "
                             "preset's FPGA point; the scene's core as the report builds it (one lane of each kind)")


def run(args) -> int:
    from sim import report
    from sim.runfile import check_output_dir
    check_output_dir(args.out)                     # before the minutes of runs
    system = load_system(args.scene)
    check_backend_fits(system, "fixed")
    if system.probe is not None:        # a device sample is k steps: at 2 dt, 4 dt and dt/16, another device rate
        raise UsageError(f"scene '{system.name}' has a probe: the report's runs at 2 dt, 4 dt and dt/16 would hold "
                         f"each device sample for k = {system.probe.k} steps of their own dt, another device rate, "
                         f"and their discretisation error would be mostly the rate's; use rheo haptic and rheo simulate")
    placed = _check_synth(args, system) if args.synth is not None else None
    clock = report.DEFAULT_CLOCK_MHZ if args.clock_mhz is None else args.clock_mhz
    source = "assumed (default)" if args.clock_mhz is None else "assumed (--clock-mhz)"
    with np.errstate(over="ignore", invalid="ignore"):
        summary = report.build(system, args.out, presets=args.presets, log=lambda m: print(f"  {m}", flush=True),
                               clock_mhz=clock, clock_source=source, progress=True)
    if placed is not None:                   # the one preset whose core was placed and routed
        preset, fmax, placed_cycles = placed
        cycles = summary["fpga"]["cycles_per_step"].get(preset)       # None: the preset's run was skipped
        if cycles == placed_cycles:
            summary = report.measured_clock(args.out, preset, fmax, f"measured Fmax ({args.synth})")
        else:                                # another core of the scene (--core phased, say): its clock is not ours
            print(f"  warning: --synth {args.synth} placed a core of {placed_cycles} cycles a step, the report's "
                  f"{preset} core takes {cycles}: its {fmax:g} MHz not used", flush=True)
    print(f"wrote {args.out}/error.csv, summary.json, error_vs_time.png, cost_vs_accuracy.png")
    for preset, q in summary["quantisation"].items():
        print(f"  quantisation {preset:7s}: " + (f"max {q['max_relative']:.2e} of the object size, "
              f"{sum(q['saturations'].values())} saturations" if "max_relative" in q else q["skipped"]))
    for label, d in summary["discretisation"].items():
        if isinstance(d, dict):
            print(f"  discretisation {label:4s}: " + (f"max {d['max_relative']:.2e} of the object size"
                  if "max_relative" in d else "diverged"))
    rt, fp = summary["run_time_per_simulated_second"], summary["fpga"]
    print(f"  wall seconds per simulated second: golden {rt['golden']:.3g}, cpu backend {rt['cpu']:.3g}" + "".join(
        f", bit-true {p} {rt['fixed-' + p]:.3g}" for p in fp["cycles_per_step"]))
    for p, c in fp["cycles_per_step"].items():
        print(f"  FPGA {p:7s}: {c} cycles/step at {fp['clock_mhz_by_preset'][p]:g} MHz "
              f"({fp['clock_source_by_preset'][p]}): "
              f"{rt['fpga-' + p]:.3g} s per simulated second")
    return 0


def _check_synth(args, system) -> tuple[str, float, int]:
    """`--synth DIR`: (its preset, its measured Fmax, its core's cycles a step), refused before any run unless
    DIR placed this scene's core with one lane of each kind (the core whose cycles a step the report counts)
    in one of --presets."""
    from sim.synth import read_placed
    if args.clock_mhz is not None:
        raise UsageError("--synth takes the clock from its place and route: not with --clock-mhz")
    try:
        placed, manifest = read_placed(args.synth)
    except RheoError as exc:
        raise UsageError(str(exc)) from None
    lanes = manifest.get("lanes", {})
    wanted = {"scene": system.name, "element_lanes_P": 1, "node_lanes_Q": 1}
    got = {"scene": manifest.get("scene"), **{k: lanes.get(k) for k in ("element_lanes_P", "node_lanes_Q")}}
    if got != wanted:
        raise UsageError(f"--synth {args.synth}: it placed another core (scene {got['scene']}, P = "
                         f"{got['element_lanes_P']}, Q = {got['node_lanes_Q']}); the report counts scene "
                         f"{system.name}'s core with one lane of each kind (rheo synth without --lanes)")
    if manifest.get("preset") not in args.presets:
        raise UsageError(f"--synth {args.synth}: preset {manifest.get('preset')}, not among --presets "
                         f"{' '.join(args.presets)}")
    return manifest["preset"], float(placed["fmax_mhz"]), int(manifest["cycles_per_step"]["value"])
