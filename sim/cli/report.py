"""`rheo report SCENE --out DIR`: error against run time (quantisation per preset, discretisation per dt)."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .common import FORMAT_PRESETS, UsageError, check_backend_fits, load_system, positive_float, scene_argument

NAME, HELP = "report", "error against run time: quantisation and discretisation errors"


def add_arguments(parser) -> None:
    scene_argument(parser)
    parser.add_argument("--out", required=True, help="output directory")
    parser.add_argument("--presets", nargs="+", choices=FORMAT_PRESETS, default=list(FORMAT_PRESETS),
                        help="format presets")
    parser.add_argument("--clock-mhz", type=positive_float, default=50.0,
                        help="FPGA clock for the FPGA run time (default: 50 MHz, about the measured Fmax of narrow cores)")
    parser.add_argument("--synth", default=None, help="take the clock from this synth.json (rheo synth's measured Fmax)")


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
    clock, source = args.clock_mhz, "assumed (--clock-mhz)"
    if args.synth is not None:
        try:
            fmax = json.loads(Path(args.synth).read_text())["fmax_mhz"]
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise UsageError(f"--synth {args.synth}: not a synth.json of `rheo synth` ({exc})") from None
        if not fmax:
            raise UsageError(f"--synth {args.synth}: it holds no Fmax")
        clock, source = float(fmax), f"measured Fmax ({args.synth})"
    with np.errstate(over="ignore", invalid="ignore"):
        summary = report.build(system, args.out, presets=args.presets, log=lambda m: print(f"  {m}", flush=True),
                               clock_mhz=clock, clock_source=source, progress=True)
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
