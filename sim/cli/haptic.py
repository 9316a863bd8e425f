"""`rheo haptic SCENE --trajectory traj.csv --backend golden|cpu|fixed|amaranth|icarus|verilator --out run.npz`:
drive a scene's probe along a trajectory, one device sample per CSV row (sim/haptic.py; the core backends
through the streaming core's probe port), and write a run file with the probe's position and force per
sample."""
from __future__ import annotations

from .common import FORMAT_PRESETS, UsageError, check_frames_fit, load_system, positive_int, scene_argument

NAME, HELP = "haptic", "drive a scene's probe along a trajectory (the haptic loop) and write a run file"
DESCRIPTION = ("Move the probe of a scene with a [probe] table along a trajectory, one device sample per row "
               "of a CSV file (header x,y[,z] for absolute positions in metres, or dx,dy[,dz] for offsets from "
               "the probe's initial position); each sample holds the position for the scene's k steps. The run "
               "file adds, per sample, the probe's position (probe_p), the force on it (probe_force, N) and how "
               "many nodes touch it (probe_contacts).")


def add_arguments(parser) -> None:
    from sim.haptic import HAPTIC_BACKENDS
    scene_argument(parser)
    parser.add_argument("--trajectory", required=True, help="CSV file: a header, then one row per device sample")
    parser.add_argument("--backend", default="golden", choices=HAPTIC_BACKENDS, help="model to run (default: golden)")
    parser.add_argument("--preset", default="wide", choices=FORMAT_PRESETS,
                        help="number-format preset of the fixed and core backends (default: wide)")
    parser.add_argument("--every", type=positive_int,
                        help="record the state every N device samples (default: about 200 frames)")
    parser.add_argument("--out", required=True, help="output .npz file")
    parser.add_argument("--force", action="store_true", help="run even when dt exceeds the predicted stable limit")


def run(args) -> int:
    import numpy as np
    from sim import runfile
    from sim.haptic import connect, read_trajectory, run_trajectory
    from .common import warn_stagnation
    from .stability import refuse_if_unstable
    if not args.out.endswith(".npz"):
        raise UsageError(f"--out must name a .npz file, got '{args.out}'")
    system = load_system(args.scene)
    if system.probe is None:
        raise UsageError(f"scene '{system.name}' has no [probe] table: nothing to move along {args.trajectory}")
    positions = read_trajectory(args.trajectory, system)
    refuse_if_unstable(system, args.force)
    S = len(positions)
    every = args.every if args.every is not None else max(1, S // 200)
    check_frames_fit(system, S, every)
    with connect(system, args.backend, args.preset) as sim:
        fixed_point = args.backend not in ("golden", "cpu")      # the bit-true model, or a core it converts for
        if args.backend == "fixed":
            warn_stagnation(sim.stepper)
        bar = _progress(S, system.name)
        try:
            arrays = run_trajectory(sim, positions, every, bar.update if bar is not None else None)
        finally:
            if bar is not None:
                bar.close()
        extra = {}
        if fixed_point:
            extra = {k: v for k, v in sim.stepper.run_info().items()}
            bt = getattr(sim.stepper, "bt", sim.stepper)
            extra["probe_force_format"] = np.str_(str(bt.formats["fprobe"]))
            if args.backend != "fixed":                          # the probe port's cycles per sample
                extra["probe_latency_cycles"] = np.array(sim.stepper.latency, np.int64)
    runfile.save(args.out, runfile.haptic_arrays(system, arrays, args.backend, extra))
    F = arrays["probe_force"]
    peak = float(np.linalg.norm(F, axis=1).max()) if S else 0.0
    wall = float(arrays["wall_seconds"])
    print(f"{system.name}: {S} device samples ({S * system.probe.k} steps, {S * system.probe.k * system.dt:g} s) on "
          f"{args.backend} in {wall:.2f} s wall ({S / wall:.0f} samples/s); peak force on the probe "
          f"{peak:.4g} N, at most {int(arrays['probe_contacts'].max())} node(s) touching -> {args.out}")
    return 0


def _progress(total: int, name: str):
    from tqdm import tqdm
    return tqdm(total=total, desc=name, unit="sample", delay=2.0, mininterval=0.5, leave=False)
