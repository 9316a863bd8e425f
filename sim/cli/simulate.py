"""`rheo simulate SCENE --backend B --out run.npz`: run a scene on any backend and write its run file."""
from __future__ import annotations

from .common import (FORMAT_PRESETS, UsageError, check_backend_fits, check_frames_fit, lane_arguments, load_system, positive_int,
                     scene_argument, warn_stagnation)

NAME, HELP = "simulate", "run a scene and write its frames to an NPZ file"


def add_arguments(parser) -> None:
    from sim.backends import BACKENDS
    scene_argument(parser)
    parser.add_argument("--backend", default="golden", choices=BACKENDS, help="model to run (default: golden)")
    parser.add_argument("--steps", type=positive_int, help="number of steps (default: the scene's duration / dt)")
    parser.add_argument("--every", type=positive_int, help="record every K-th step (default: the scene's output_every)")
    parser.add_argument("--preset", default="wide", choices=FORMAT_PRESETS,
                        help="number-format preset of the fixed and hardware backends (default: wide)")
    parser.add_argument("--out", required=True, help="output .npz file")
    parser.add_argument("--force", action="store_true", help="run even when dt exceeds the predicted stable limit")
    lane_arguments(parser)


def run(args) -> int:
    from sim import runfile
    from sim.backends import FIXED_POINT, bit_true_model, run_backend
    from .stability import refuse_if_unstable
    if not args.out.endswith(".npz"):
        raise UsageError(f"--out must name a .npz file, got '{args.out}'")
    runfile.check_output_file(args.out)            # every argument before any work
    if args.backend in ("icarus", "verilator"):
        from sim.simulators import check_simulator
        check_simulator(args.backend)
    system = load_system(args.scene)
    if args.backend in ("amaranth", "icarus", "verilator"):
        from hw.stream import check_pair_lanes, resolve_core    # a core the scene cannot have: refused first
        check_pair_lanes(resolve_core(system, args.core), args.pair_lanes)
    refuse_if_unstable(system, args.force)
    check_frames_fit(system, args.steps, args.every)
    check_backend_fits(system, args.backend, args.steps)
    bt = None
    if args.backend in FIXED_POINT:
        bt = bit_true_model(system, args.preset, args.steps)
        warn_stagnation(bt)
    run = run_backend(system, args.backend, args.steps, args.every, progress=True, preset=args.preset,
                      lanes=args.lanes, node_lanes=args.node_lanes, bittrue=bt, core=args.core,
                      pair_lanes=args.pair_lanes)
    runfile.save(args.out, runfile.run_arrays(system, run, args.backend))
    steps = int(round(run.t[-1] / system.dt))
    print(f"{system.name}: {steps} steps of {system.dt:g} s "
          f"({run.t[-1]:g} s simulated) in {run.wall_seconds:.2f} s wall, {len(run.t)} frames -> {args.out}")
    return 0
