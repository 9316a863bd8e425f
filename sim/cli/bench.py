"""`rheo bench --backend golden|cpu|fixed|fpga`: steps per second on generated squares or a scene, every
figure measured in the same run as the cpu backend it is compared with; `--haptic --scene poke-...`: the
haptic loop's time per device sample (sim/hapticbench.py)."""
from __future__ import annotations

import json

from .common import (PRESET_CHOICES, UsageError, check_backend_fits, check_square_fits, lane_arguments, load_system,
                     place_and_route_arguments, place_and_route_chosen, positive_float, positive_int,
                     spare_lane_notes)

NAME, HELP = "bench", "measure steps/s and element-updates/s on generated meshes"
BENCH_BACKENDS = ("golden", "cpu", "fixed", "fpga")


def add_arguments(parser) -> None:
    parser.add_argument("--backend", default="golden", help="model to measure (default: golden)")
    parser.add_argument("--json", action="store_true", help="print JSON")
    parser.add_argument("--sizes", type=positive_int, nargs="+",
                        help="approximate element counts of generated squares (default: 1000 10000 100000; fpga: 10000)")
    parser.add_argument("--scene", help="measure this scene instead of generated squares (golden, cpu, fpga)")
    parser.add_argument("--seconds", type=positive_float, default=1.0, help="minimum measuring time per size (default 1)")
    parser.add_argument("--preset", choices=PRESET_CHOICES,
                        help="fpga: number-format preset (default auto: the narrowest whose bit-true run stays "
                             "within 1e-3 of the object size of golden over the scene's steps; the error is reported)")
    lane_arguments(parser)
    parser.add_argument("--simulator", choices=["verilator", "icarus"], default="verilator",
                        help="fpga: HDL simulator that measures cycles per step (default verilator)")
    parser.add_argument("--hdl-steps", type=positive_int, default=2,
                        help="fpga: steps the simulated core runs to measure cycles per step (default 2)")
    parser.add_argument("--fmax-mhz", type=positive_float,
                        help="fpga: clock to model with, instead of placing and routing the core (minutes to an hour)")
    parser.add_argument("--device", default="ecp5-85k", help="fpga: device for place and route (default ecp5-85k)")
    place_and_route_arguments(parser, "fpga, place and route: ")
    parser.add_argument("--synth", metavar="DIR",
                        help="fpga: the Fmax and resources of `rheo synth`'s place and route in DIR instead of placing "
                             "and routing again (its Verilog must be this core's, byte for byte: checked)")
    parser.add_argument("--haptic", action="store_true",
                        help="the haptic loop of a --scene with a [probe]: time per device sample of --backend "
                             "(median, 99.9th percentile) and the golden and bit-true loop rates, same run")
    parser.add_argument("--samples", type=positive_int, default=10_000,
                        help="--haptic: device samples timed one by one (default 10000)")


def run(args) -> int:
    from sim import bench
    if args.backend not in BENCH_BACKENDS:
        raise UsageError(f"backend '{args.backend}' has no benchmark (available: {', '.join(BENCH_BACKENDS)})")
    if args.backend == "fpga":                      # every argument and tool before any work
        from sim.simulators import check_simulator
        from sim.synth import check_block_rams, check_device, check_floorplan_device, check_tools
        check_simulator(args.simulator)
        check_device(args.device)
        check_block_rams(args.block_rams, args.device)
        check_floorplan_device(args.floorplan, args.device)
        if args.synth is not None:
            _check_synth(args)
        elif args.fmax_mhz is None:
            check_tools(place_and_route=True)
        elif place_and_route_chosen(args):
            raise UsageError("--router, --placer, --seed, --speed-grade, --floorplan and --block-rams choose how the core "
                             "is placed and routed: not with --fmax-mhz (no place and route)")
    elif place_and_route_chosen(args):
        raise UsageError("--router, --placer, --seed, --speed-grade, --floorplan and --block-rams belong to --backend fpga")
    elif (any(v is not None for v in (args.preset, args.fmax_mhz, args.pair_lanes, args.synth)) or args.lanes != 1
          or args.node_lanes != 1 or args.core != "auto"):
        raise UsageError("--preset, --lanes, --node-lanes, --pair-lanes, --core, --fmax-mhz and --synth belong to "
                         "--backend fpga")
    sizes = args.sizes or ([10_000] if args.backend == "fpga" else list(bench.SIZES))
    for n in sizes:
        check_square_fits(n, args.backend)
    scene = load_system(args.scene) if args.scene else None
    if scene is not None:
        check_backend_fits(scene, args.backend)
    if args.haptic:
        return _haptic(args, scene)
    fpga = {}
    if args.backend == "fpga":
        fpga = dict(preset=args.preset or "auto", lanes=args.lanes, node_lanes=args.node_lanes, core=args.core,
                    pair_lanes=args.pair_lanes,
                    simulator=args.simulator, steps=args.hdl_steps, fmax_mhz=args.fmax_mhz, device=args.device,
                    router=args.router, placer=args.placer, seed=args.seed, speed_grade=args.speed_grade,
                    floorplan=args.floorplan,
                    block_rams=args.block_rams, synth=args.synth,
                    log=None if args.json else (lambda m: print(f"  {m}", flush=True)))
    rows = bench.run(args.backend, sizes=sizes, min_seconds=args.seconds, scene=scene, **fpga)
    if args.json:
        print(json.dumps({"backend": args.backend, "results": rows}, indent=2))
    elif args.backend == "fpga":
        _print_fpga(rows)
    elif args.backend == "cpu":
        _print_cpu(rows)
    else:
        print(f"{'elements':>9} {'nodes':>8} {'steps/s':>10} {'element-updates/s':>18}")
        for r in rows:
            print(f"{r['elements']:9d} {r['nodes']:8d} {r['steps_per_s']:10.1f} {r['element_updates_per_s']:18.3e}")
    return 0


def _check_synth(args) -> None:
    """`--synth DIR`: one placed core, whose device, router, placer, seed, speed grade and DP16KD budget are DIR's."""
    from sim.synth import read_placed
    if args.fmax_mhz is not None or place_and_route_chosen(args):
        raise UsageError("--synth takes the Fmax, router, placer, seed, speed grade, floorplan and block RAM budget of "
                         "its place and route: not with --fmax-mhz, --router, --placer, --seed, --speed-grade, "
                         "--floorplan or --block-rams")
    if args.scene is None and args.sizes is not None and len(args.sizes) > 1:
        raise UsageError("--synth DIR holds one core: give one --scene or one --sizes value")
    placed, _ = read_placed(args.synth)
    if placed.get("device") != args.device:
        raise UsageError(f"--synth {args.synth}: placed for {placed.get('device')}, not --device {args.device}")


HAPTIC_BACKENDS = ("golden", "cpu", "fixed")


def _haptic(args, scene) -> int:
    from sim.hapticbench import haptic_rates
    if scene is None:
        raise UsageError("--haptic needs --scene: a scene with a [probe] table (e.g. poke-2d-1000-elements)")
    if scene.probe is None:
        raise UsageError(f"scene '{scene.name}' has no [probe] table: --haptic pokes it")
    if args.backend not in HAPTIC_BACKENDS:
        raise UsageError(f"--haptic measures {', '.join(HAPTIC_BACKENDS)}, not '{args.backend}' (the FPGA's probe "
                         f"port: --backend fpga --scene with a [probe], without --haptic)")
    if args.sizes or args.fmax_mhz is not None or args.lanes != 1 or args.node_lanes != 1 or args.pair_lanes:
        raise UsageError("--haptic takes --scene, --backend, --samples, --seconds and --preset")
    r = haptic_rates(scene, args.backend, args.samples, args.seconds, args.preset or "wide")
    if args.json:
        print(json.dumps({"backend": args.backend, "haptic": True, "results": [r]}, indent=2))
        return 0
    print(f"{r['scene']}: {r['elements']} elements, {r['nodes']} nodes, k = {r['k']} steps of {r['dt']:g} s per "
          f"device sample ({r['device_rate_hz']:.0f} Hz device, {r['device_period_us']:.0f} us period)")
    print(f"  {r['backend']}: {r['samples']} samples, median {r['median_us']:.1f} us, 99th percentile "
          f"{r['p99_us']:.1f} us, 99.9th {r['p999_us']:.1f} us, max {r['max_us']:.1f} us; {r['late_samples']} "
          f"late; {'meets' if r['meets_device_rate'] else 'misses'} the device rate at the 99.9th percentile")
    print(f"  same run: golden {r['golden_samples_per_s']:.1f} samples/s, bit-true ({r['fixed_preset']}) "
          f"{r['fixed_samples_per_s']:.1f} samples/s")
    return 0


def _print_fpga(rows) -> None:
    for r in rows:
        print(f"{r['scene']}: {r['elements']} elements, {r['nodes']} nodes, preset {r['preset']}, "
              f"P = {r['lanes']}, " + (f"Pp = {r['pair_lanes']}, " if r.get("pair_lanes") else "")
              + f"Q = {r['node_lanes']}: {r['cycles_per_step']:.0f} cycles/step ({r['simulator']}: "
              f"{r['simulator_cycles_per_s']:.0f} cycles/s, host interface included)")
        for line in spare_lane_notes(r.get("spare_lanes"), r["cycles_per_step_schedule"]):
            print(f"  {line}")
        err = r.get("error_vs_golden")
        print(f"  {r['preset_why']}; its position error against golden: "
              + (f"{err:.1e} of the object size over {r['error_steps']} steps" if err is not None else "no run"))
        print(f"  Fmax {r['fmax_mhz']:.1f} MHz ({r['fmax_source']}) -> {r['steps_per_s']:.0f} steps/s, "
              f"{r['element_updates_per_s']:.3e} element-updates/s")
        if "probe_latency_cycles" in r:
            print(f"  probe port, k = {r['probe_k']}: {r['device_samples_per_s']:.0f} device samples/s, sample-in to "
                  f"force-out {r['probe_latency_us']:.1f} us ({r['probe_latency_cycles']} cycles, measured "
                  f"{', '.join(str(v) for v in r['probe_latency_measured'])})")
        print(f"  on this machine, same run: cpu backend ({r['cpu_threads']} thread(s)) "
              f"{r['cpu_steps_per_s']:.1f} steps/s, golden model {r['golden_steps_per_s']:.1f} steps/s; "
              f"FPGA / cpu = {r['ratio_to_cpu']:.2f}x, FPGA / golden = {r['ratio_to_golden']:.1f}x")


def _print_cpu(rows) -> None:
    print(f"{'elements':>9} {'nodes':>8} {'golden':>10} {'cpu 1 thr':>10} {'cpu 2 thr':>10} {'cpu/golden':>10} "
          f"{'C loop':>10} {'cpu/C':>6}   (steps/s, same trajectory segment)")
    for r in rows:
        c = r.get("c_reference_steps_per_s")
        print(f"{r['elements']:9d} {r['nodes']:8d} {r['golden_steps_per_s']:10.1f} "
              f"{r.get('cpu_1_threads_steps_per_s', float('nan')):10.1f} "
              f"{r.get('cpu_2_threads_steps_per_s', float('nan')):10.1f} {r['cpu_ratio_to_golden']:9.1f}x "
              + (f"{c:10.1f} {r['cpu_ratio_to_c_reference']:5.2f}x" if c else f"{'-':>10} {'-':>6}")
              + f"   chosen: {r['cpu_threads']} thread(s)")
