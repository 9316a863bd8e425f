"""`rheo`: the command line. Every user error is one line on stderr and exit code 2, never a traceback."""
from __future__ import annotations

import argparse
import json
import os
import signal
import sys
from pathlib import Path

import numpy as np

DEFAULT_SCENE = "press-2d-rheological"
BACKENDS = ("golden", "cpu", "fixed", "amaranth", "icarus", "verilator")
BENCH_BACKENDS = ("golden", "cpu", "fixed", "fpga")
PRESETS = ("narrow", "medium", "wide")


class UsageError(Exception):
    """A problem with the user's input; printed as one line, exit code 2."""


def _positive_float(text: str) -> float:
    try:
        val = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got '{text}'") from None
    if not (val > 0 and np.isfinite(val)):
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text}")
    return val


def _positive_int(text: str) -> int:
    try:
        val = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got '{text}'") from None
    if val < 1:
        raise argparse.ArgumentTypeError(f"expected a whole number >= 1, got {val}")
    return val


def _load_system(ref: str):
    """A built-in scene by name, a scene file by path, `square:N`: the benchmark's generated square of
    about N elements, or `box:N`: its 3D counterpart (sim/bench.py)."""
    from golden.scene import compile_scene, load_scene
    for kind in ("square", "box"):
        if ref.startswith(kind + ":"):
            from sim import bench
            try:
                n = int(ref[len(kind) + 1:])
            except ValueError:
                n = 0
            if not 10 <= n <= 10_000_000:
                raise UsageError(f"'{ref}': {kind}:N takes a whole number of elements N in 10..10000000")
            _check_square_fits(n)
            return bench.square_system(n) if kind == "square" else bench.box_system(n)
    return compile_scene(load_scene(ref))


def _check_frames_fit(sys_, steps, every) -> None:
    """A run records every frame in memory: refuse, before running, what this machine cannot hold."""
    from golden.limits import over_memory
    steps = sys_.n_steps if steps is None else steps
    every = max(1, sys_.every if every is None else every)
    frames = steps // every + 2
    need = frames * (2 * sys_.n_nodes * sys_.dim + sys_.n_elements) * 8.0
    if (why := over_memory(need, f"recording {frames:.3g} frames ({steps} steps, every {every})")) is not None:
        raise UsageError(f"{why}: record fewer frames (a larger --every or fewer --steps)")


def _check_square_fits(n_elements: int) -> None:
    from golden.limits import mesh_nodes_fit
    if (why := mesh_nodes_fit(n_elements / 3, f"a generated square of {n_elements} elements")) is not None:
        raise UsageError(why)


def _simulate(sys_, backend: str, steps, every, progress=True, preset="wide", lanes=1, node_lanes=1, core="auto"):
    """Run a backend; returns (Run, extra run-file arrays)."""
    from golden.model import simulate
    if backend not in BACKENDS:
        raise UsageError(f"backend '{backend}' is not available (available: {', '.join(BACKENDS)})")
    with np.errstate(over="ignore", invalid="ignore"):
        if backend == "golden":
            return simulate(sys_, steps=steps, every=every, progress=progress), {}
        if backend == "cpu":
            from sim.cpu import Cpu
            return simulate(sys_, steps=steps, every=every, progress=progress, stepper=Cpu(sys_)), {}
        from hw.bittrue import simulate_fixed
        if backend == "amaranth":
            from sim.hwsim import simulate_amaranth
            run, raws, bt, info = simulate_amaranth(sys_, preset, steps=steps, every=every, progress=progress,
                                                    lanes=lanes, node_lanes=node_lanes, core=core)
        elif backend in ("icarus", "verilator"):
            from sim.hdlsim import simulate_hdl
            run, raws, bt, info = simulate_hdl(sys_, backend, preset, steps=steps, every=every, progress=progress,
                                               lanes=lanes, node_lanes=node_lanes, core=core)
        else:
            run, raws, bt = simulate_fixed(sys_, preset, steps=steps, every=every, progress=progress)
        warn_stagnation(bt)
        names = sorted(bt.sat)
        extra = dict(raws, preset=np.str_(preset), formats=np.str_(json.dumps(bt.formats.to_dict())),
                     stagnation=np.str_(json.dumps(bt.formats.stagnation())),
                     saturation_names=np.array(names, dtype=str),
                     saturation_counts=np.array([bt.sat[n] for n in names], np.int64),
                     constant_saturations=np.str_(json.dumps(dict(bt.const_sat))),
                     units=np.str_(json.dumps(bt.units.to_dict())))
        return run, extra


# ---------------------------------------------------------------- commands

def cmd_scenes(args) -> int:
    from golden.scene import builtin_names, load_scene
    for name in builtin_names():
        sc = load_scene(name)
        print(f"{name:26s} {sc.description}")
    return 0


def cmd_simulate(args) -> int:
    from sim import runfile
    if not args.out.endswith(".npz"):
        raise UsageError(f"--out must name a .npz file, got '{args.out}'")
    from sim.stability_cmd import refuse_if_unstable
    sys_ = _load_system(args.scene)
    refuse_if_unstable(sys_, args.force)
    _check_frames_fit(sys_, args.steps, args.every)
    run, extra = _simulate(sys_, args.backend, args.steps, args.every, preset=args.preset,
                           lanes=args.lanes, node_lanes=args.node_lanes, core=args.core)
    runfile.save(args.out, {**runfile.run_arrays(sys_, run, args.backend), **extra})
    steps = int(round(run.t[-1] / sys_.dt))
    print(f"{sys_.name}: {steps} steps of {sys_.dt:g} s "
          f"({run.t[-1]:g} s simulated) in {run.wall_seconds:.2f} s wall, {len(run.t)} frames -> {args.out}")
    return 0


def cmd_verilog(args) -> int:
    """Emit the scene's specialised core as Verilog plus manifest.json."""
    from hw import emit
    bt = _hardware_model(args)
    man = emit.write(bt, args.out, lanes=args.lanes, node_lanes=args.node_lanes, core=args.core)
    cps = man["cycles_per_step"]
    print(f"wrote {args.out}/{man['verilog']} ({len(man['verilog_modules'])} modules, {man['core']} core) and manifest.json")
    print(f"  units: {', '.join(u['unit'] for u in man['units_present'])}")
    print(f"  left out: {', '.join(u['unit'] for u in man['units_left_out']) or 'nothing'}")
    print(f"  {cps['value']} cycles per step = {cps['formula']} (P = {cps['P']}, Q = {cps['Q']}); "
          f"{len(man['memories'])} memories, {man['memory_bits']} bits")
    return 0


def _hardware_model(args):
    """The bit-true model (formats) of the scene a hardware command builds: the scene, or with --full its
    full-featured variant (every optional unit)."""
    from hw import emit
    from hw.bittrue import BitTrue
    sys_ = _load_system(args.scene)
    if args.full:
        sys_ = emit.full_featured(sys_)
    if getattr(args, "core", "auto") == "stream" and sys_.collision is not None:
        from hw.stream import resolve_core          # refused before the range analysis
        resolve_core(sys_, "stream")
    print(f"{sys_.name}: range analysis and formats (preset {args.preset})", flush=True)
    with np.errstate(over="ignore", invalid="ignore"):
        bt = BitTrue(sys_, args.preset)
    warn_stagnation(bt)
    return bt


def warn_stagnation(bt) -> None:
    """A warning line on stderr for every state that stagnates under the bit-true model's formats."""
    for msg in bt.stagnation_messages():
        print(f"warning: {msg}", file=sys.stderr, flush=True)


def cmd_synth(args) -> int:
    """Synthesise the scene's core for an ECP5 (Yosys + nextpnr from PyPI): resources and Fmax."""
    from hw import emit
    from sim.synth import synthesize
    out = Path(args.out)
    bt = _hardware_model(args)
    man = emit.write(bt, out, lanes=args.lanes, node_lanes=args.node_lanes, core=args.core, ram="ecp5")
    r = synthesize(out / man["verilog"], man["top"], out, device=args.device, clock_mhz=args.clock_mhz,
                   progress=True, place_and_route=args.pnr)
    r.update(scene=man["scene"], preset=man["preset"], full_featured=args.full, lanes=man["lanes"],
             elements=man["elements"], nodes=man["nodes"], units_present=[u["unit"] for u in man["units_present"]])
    cps = man["cycles_per_step"]["value"]
    r["cycles_per_step"] = cps
    if r.get("fmax_mhz"):
        r["modelled_steps_per_s"] = r["fmax_mhz"] * 1e6 / cps
        r["modelled_element_updates_per_s"] = r["modelled_steps_per_s"] * man["elements"]
    (out / "synth.json").write_text(json.dumps(r, indent=2, default=str))
    print(f"wrote {out}/synth.json, report.md, {man['verilog']}, manifest.json")
    timing = (f"Fmax {r['fmax_mhz']:.1f} MHz (constraint {args.clock_mhz} MHz, {'met' if r['timing_met'] else 'NOT met'})"
              if args.pnr and r.get("fmax_mhz") is not None else
              "no place and route (--no-pnr): no Fmax" if not args.pnr else "no Fmax: see nextpnr.log")
    print(f"  {r['luts']} LUTs, {r['flip_flops']} FFs, {r['mult18x18']} 18x18 multipliers, {r['block_rams']} block RAMs; "
          + timing)
    if r.get("fmax_mhz"):
        print(f"  {cps} cycles per step -> {r['modelled_steps_per_s']:.0f} steps/s modelled at Fmax")
    return 0


def cmd_show(args) -> int:
    from sim.render import render
    out = render(args.run, args.out, frames=args.frames)
    print(f"wrote {out}")
    return 0


def cmd_export(args) -> int:
    from sim.vtk_export import export_vtk
    files = export_vtk(args.run, args.vtk)
    print(f"wrote {len(files)} VTK frames and run.pvd to {args.vtk}")
    return 0


def cmd_bench(args) -> int:
    from sim import bench
    if args.backend not in BENCH_BACKENDS:
        raise UsageError(f"backend '{args.backend}' has no benchmark (available: {', '.join(BENCH_BACKENDS)})")
    scene = _load_system(args.scene) if args.scene else None
    fpga = {}
    if args.backend == "fpga":
        fpga = dict(preset=args.preset or "narrow", lanes=args.lanes, node_lanes=args.node_lanes, core=args.core,
                    simulator=args.simulator, steps=args.hdl_steps, fmax_mhz=args.fmax_mhz, device=args.device,
                    log=None if args.json else (lambda m: print(f"  {m}", flush=True)))
    elif any(v is not None for v in (args.preset, args.fmax_mhz)) or args.lanes != 1 or args.node_lanes != 1:
        raise UsageError("--preset, --lanes, --node-lanes and --fmax-mhz belong to --backend fpga")
    sizes = args.sizes or ([10_000] if args.backend == "fpga" else list(bench.SIZES))
    for n in sizes:
        _check_square_fits(n)
    try:
        rows = bench.run(args.backend, sizes=sizes, min_seconds=args.seconds, scene=scene, **fpga)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    if args.json:
        print(json.dumps({"backend": args.backend, "results": rows}, indent=2))
    elif args.backend == "fpga":
        for r in rows:
            print(f"{r['scene']}: {r['elements']} elements, {r['nodes']} nodes, preset {r['preset']}, "
                  f"P = {r['lanes']}, Q = {r['node_lanes']}: {r['cycles_per_step']:.0f} cycles/step ({r['simulator']}: "
                  f"{r['simulator_cycles_per_s']:.0f} cycles/s, host interface included)")
            print(f"  Fmax {r['fmax_mhz']:.1f} MHz ({r['fmax_source']}) -> {r['steps_per_s']:.0f} steps/s, "
                  f"{r['element_updates_per_s']:.3e} element-updates/s")
            print(f"  on this machine, same run: cpu backend ({r['cpu_threads']} thread(s)) "
                  f"{r['cpu_steps_per_s']:.1f} steps/s, golden model {r['golden_steps_per_s']:.1f} steps/s; "
                  f"FPGA / cpu = {r['ratio_to_cpu']:.2f}x, FPGA / golden = {r['ratio_to_golden']:.1f}x")
    elif args.backend == "cpu":
        print(f"{'elements':>9} {'nodes':>8} {'golden':>10} {'cpu 1 thr':>10} {'cpu 2 thr':>10} {'cpu/golden':>10} "
              f"{'C loop':>10} {'cpu/C':>6}   (steps/s, same trajectory segment)")
        for r in rows:
            c = r.get("c_reference_steps_per_s")
            print(f"{r['elements']:9d} {r['nodes']:8d} {r['golden_steps_per_s']:10.1f} "
                  f"{r.get('cpu_1_threads_steps_per_s', float('nan')):10.1f} "
                  f"{r.get('cpu_2_threads_steps_per_s', float('nan')):10.1f} {r['cpu_ratio_to_golden']:9.1f}x "
                  + (f"{c:10.1f} {r['cpu_ratio_to_c_reference']:5.2f}x" if c else f"{'-':>10} {'-':>6}")
                  + f"   chosen: {r['cpu_threads']} thread(s)")
    else:
        print(f"{'elements':>9} {'nodes':>8} {'steps/s':>10} {'element-updates/s':>18}")
        for r in rows:
            print(f"{r['elements']:9d} {r['nodes']:8d} {r['steps_per_s']:10.1f} {r['element_updates_per_s']:18.3e}")
    return 0


def cmd_run(args) -> int:
    """The main job: golden and bit-true runs, the Verilog checked bit for bit on Icarus, the error
    report, the synthesis summary, pictures and VTK; prints where everything went."""
    from golden.model import frame_steps
    from golden.scene import file_stem
    from hw import emit
    from hw.bittrue import BitTrue, simulate_fixed
    from sim import report, runfile
    from sim.hdlsim import emit_core, run_job
    from sim.render import render, render_before_after
    from sim.vtk_export import export_vtk
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    sys_ = _load_system(args.scene)
    n = 8 if args.synth else 7
    print(f"[1/{n}] golden run of {sys_.name}: {sys_.n_nodes} nodes, {sys_.n_elements} elements, "
          f"{sys_.n_steps} steps of {sys_.dt:g} s (float64)", flush=True)
    run, _ = _simulate(sys_, "golden", None, None)
    stem = file_stem(sys_.name)      # no output path from inside the scene file
    npz = runfile.save(out / f"{stem}.npz", runfile.run_arrays(sys_, run, "golden"))
    print(f"      {run.wall_seconds:.2f} s wall -> {npz}")
    print(f"[2/{n}] pictures, animation, VTK", flush=True)
    png = render(npz, out / f"{stem}.png")
    peak = _peak_frame(sys_, run)
    ba = render_before_after(npz, out / f"{stem}-before-after.png", [0, peak, len(run.t) - 1],
                             ["before", f"loaded (t = {run.t[peak]:.2f} s)", f"after release (t = {run.t[-1]:.2f} s)"])
    gif = render(npz, out / f"{stem}.gif")
    files = export_vtk(npz, out / "vtk")
    print(f"      {png}\n      {ba}\n      {gif}\n      {len(files)} frames -> {out / 'vtk' / 'run.pvd'}")
    print(f"[3/{n}] bit-true run (preset {args.preset})", flush=True)
    with np.errstate(over="ignore", invalid="ignore"):
        bt = BitTrue(sys_, args.preset)
        frun, raws, _ = simulate_fixed(sys_, args.preset, bittrue=BitTrue(sys_, args.preset, formats=bt.formats))
    warn_stagnation(bt)
    size = float(np.ptp(sys_.x0, axis=0).max())
    err = float(np.abs(frun.x - run.x).max() / size)
    print(f"      max position error against golden: {err:.2e} of the object size, "
          f"{int(raws['saturations'][-1])} saturations")
    print(f"[4/{n}] Verilog and manifest", flush=True)
    man = emit.write(bt, out / "verilog", core="auto")
    print(f"      {out / 'verilog' / man['verilog']}: {man['cycles_per_step']['value']} cycles per step, "
          f"left out: {', '.join(u['unit'] for u in man['units_left_out']) or 'nothing'}")
    steps = min(args.hdl_steps, sys_.n_steps)
    print(f"[5/{n}] Icarus Verilog (cocotb): the first {steps} steps, checked bit for bit", flush=True)
    core_dir, _, drv = emit_core(bt, core="auto")
    st = bt.initial_state()
    every = max(1, steps // 4)
    at = frame_steps(steps, every)
    res = run_job("icarus", core_dir, drv, drv.load_words(st.X, st.U, st.A, 0),
                  [int(k) for k in np.diff(at)])
    ref = BitTrue(sys_, args.preset, formats=bt.formats)
    st = ref.initial_state()
    for frame, target in zip(res["frames"], at[1:]):
        while st.step < target:
            ref.step(st)
        X, U, A = frame[0], frame[1], frame[2]
        same = all(np.array_equal(a, b) for a, b in zip(X + U, st.X + st.U)) and np.array_equal(A, st.A)
        if not same:
            raise UsageError(f"Icarus run differs from the bit-true model at step {st.step}: please report")
    print(f"      {len(res['frames'])} read-backs equal the bit-true model; {res['wall_s']:.1f} s simulated wall "
          f"({sum(res['cycles']) / max(res['wall_s'], 1e-9):.0f} cycles/s)")
    print(f"[6/{n}] error against run time report", flush=True)
    with np.errstate(over="ignore", invalid="ignore"):
        summary = report.build(sys_, out / "report", presets=["narrow", "medium", "wide"], log=lambda m: None)
    for preset, q in summary["quantisation"].items():
        if "max_relative" in q:
            print(f"      {preset:7s} max {q['max_relative']:.2e} of the object size")
    if args.synth:
        from sim.synth import synthesize
        print(f"[7/{n}] synthesis for ECP5-85k (preset narrow: one 18x18 multiplier per product)", flush=True)
        with np.errstate(over="ignore", invalid="ignore"):
            nb = BitTrue(sys_, "narrow")
        nm = emit.write(nb, out / "synth", core="auto", ram="ecp5")
        r = synthesize(out / "synth" / nm["verilog"], nm["top"], out / "synth", clock_mhz=100.0)
        print(f"      {r['luts']} LUTs, {r['flip_flops']} FFs, {r['mult18x18']} multipliers, {r['block_rams']} "
              f"block RAMs, Fmax {r['fmax_mhz']:.1f} MHz -> {out / 'synth' / 'report.md'}")
    print(f"[{n}/{n}] done: {out}/ holds the runs, pictures, verilog/, report/" + (", synth/" if args.synth else ""))
    return 0


def cmd_report(args) -> int:
    from sim import report
    sys_ = _load_system(args.scene)
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
        summary = report.build(sys_, args.out, presets=args.presets, log=lambda m: print(f"  {m}", flush=True),
                               clock_mhz=clock, clock_source=source)
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
        print(f"  FPGA {p:7s}: {c} cycles/step at {fp['clock_mhz']:g} MHz ({fp['clock_source']}): "
              f"{rt['fpga-' + p]:.3g} s per simulated second")
    return 0


def _peak_frame(sys_, run) -> int:
    """Frame of the largest displacement of the loaded nodes (or of all nodes without loads)."""
    nodes = np.concatenate([ld.nodes for ld in sys_.loads]) if sys_.loads else np.arange(sys_.n_nodes)
    disp = np.linalg.norm(run.x[:, nodes] - run.x[0, nodes], axis=2).mean(1)
    return int(np.argmax(disp))


# ---------------------------------------------------------------- parser

def _lane_args(s):
    s.add_argument("--lanes", type=_positive_int, default=1, help="hardware: element (and pair) lanes P (default 1)")
    s.add_argument("--node-lanes", type=_positive_int, default=1, help="hardware: node lanes Q (default 1)")
    s.add_argument("--core", choices=("auto", "phased", "stream"), default="auto",
                   help="hardware: the streaming core (hw/stream/) or the phased one (hw/core.py); default auto: "
                        "streaming unless the scene has collisions")


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="rheo", description="Rheological soft-object simulator: golden model, "
                                "bit-true fixed point and FPGA pipeline (Kimura et al. 2002).")
    sub = p.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True

    s = sub.add_parser("scenes", help="list the built-in scenes")
    s.set_defaults(func=cmd_scenes)

    s = sub.add_parser("simulate", help="run a scene and write its frames to an NPZ file")
    s.add_argument("scene", help="built-in scene name or path to a scene .toml")
    s.add_argument("--backend", default="golden", choices=BACKENDS, help="model to run (default: golden)")
    s.add_argument("--steps", type=_positive_int, help="number of steps (default: the scene's duration / dt)")
    s.add_argument("--every", type=_positive_int, help="record every K-th step (default: the scene's output_every)")
    s.add_argument("--preset", default="wide", choices=PRESETS,
                   help="number-format preset of the fixed and hardware backends (default: wide)")
    s.add_argument("--out", required=True, help="output .npz file")
    s.add_argument("--force", action="store_true", help="run even when dt exceeds the predicted stable limit")
    _lane_args(s)
    s.set_defaults(func=cmd_simulate)

    s = sub.add_parser("verilog", help="emit the scene's specialised core as Verilog with manifest.json")
    s.add_argument("scene", help="built-in scene name or path to a scene .toml")
    s.add_argument("--out", required=True, metavar="DIR", help="output directory")
    s.add_argument("--preset", default="wide", choices=PRESETS, help="number-format preset (default: wide)")
    s.add_argument("--full", action="store_true",
                   help="every optional unit elaborated (what specialisation saves; see hw/emit.py full_featured)")
    _lane_args(s)
    s.set_defaults(func=cmd_verilog)

    s = sub.add_parser("synth", help="synthesise the scene's core for an ECP5: resources, Fmax, steps/s")
    s.add_argument("scene", help="built-in scene name or path to a scene .toml")
    s.add_argument("--out", required=True, metavar="DIR", help="output directory")
    s.add_argument("--device", default="ecp5-85k", help="ecp5-85k (default), ecp5-45k, ecp5-25k, ecp5-12k")
    s.add_argument("--clock-mhz", type=_positive_float, default=100.0, help="clock constraint (default 100 MHz)")
    s.add_argument("--preset", default="narrow", choices=PRESETS,
                   help="number-format preset (default: narrow, the one whose products fit 18x18 multipliers)")
    s.add_argument("--full", action="store_true",
                   help="every optional unit elaborated (what specialisation saves; see hw/emit.py full_featured)")
    s.add_argument("--no-pnr", dest="pnr", action="store_false",
                   help="Yosys only: resources in minutes, no place and route and no Fmax")
    _lane_args(s)
    s.set_defaults(func=cmd_synth)

    s = sub.add_parser("show", help="render a run to PNG frames or a GIF animation")
    s.add_argument("run", help="run .npz written by `rheo simulate`")
    s.add_argument("--out", required=True, help="output .png (frames side by side) or .gif (animation)")
    s.add_argument("--frames", type=_positive_int, help="number of frames in a PNG (default 4)")
    s.set_defaults(func=cmd_show)

    s = sub.add_parser("export", help="write a VTK time series (ParaView) of a run")
    s.add_argument("run", help="run .npz written by `rheo simulate`")
    s.add_argument("--vtk", required=True, metavar="DIR", help="output directory (frame_*.vtu and run.pvd)")
    s.set_defaults(func=cmd_export)

    s = sub.add_parser("bench", help="measure steps/s and element-updates/s on generated meshes")
    s.add_argument("--backend", default="golden", help="model to measure (default: golden)")
    s.add_argument("--json", action="store_true", help="print JSON")
    s.add_argument("--sizes", type=_positive_int, nargs="+",
                   help="approximate element counts of generated squares (default: 1000 10000 100000; fpga: 10000)")
    s.add_argument("--scene", help="measure this scene instead of generated squares (golden, cpu, fpga)")
    s.add_argument("--seconds", type=_positive_float, default=1.0, help="minimum measuring time per size (default 1)")
    s.add_argument("--preset", choices=PRESETS, help="fpga: number-format preset (default narrow)")
    _lane_args(s)
    s.add_argument("--simulator", choices=["verilator", "icarus"], default="verilator",
                   help="fpga: HDL simulator that measures cycles per step (default verilator)")
    s.add_argument("--hdl-steps", type=_positive_int, default=2,
                   help="fpga: steps the simulated core runs to measure cycles per step (default 2)")
    s.add_argument("--fmax-mhz", type=_positive_float,
                   help="fpga: clock to model with, instead of placing and routing the core (minutes to an hour)")
    s.add_argument("--device", default="ecp5-85k", help="fpga: device for place and route (default ecp5-85k)")
    s.set_defaults(func=cmd_bench)

    from sim import stability_cmd
    stability_cmd.add_parser(sub)

    s = sub.add_parser("report", help="error against run time: quantisation and discretisation errors")
    s.add_argument("scene", help="built-in scene name or path to a scene .toml")
    s.add_argument("--out", required=True, help="output directory")
    s.add_argument("--presets", nargs="+", choices=PRESETS, default=list(PRESETS), help="format presets")
    s.add_argument("--clock-mhz", type=_positive_float, default=50.0,
                   help="FPGA clock for the FPGA run time (default: 50 MHz, about the measured Fmax of narrow cores)")
    s.add_argument("--synth", default=None, help="take the clock from this synth.json (rheo synth's measured Fmax)")
    s.set_defaults(func=cmd_report)

    s = sub.add_parser("run", help="the main job: simulate the default scene, render it and export it")
    s.add_argument("--scene", default=DEFAULT_SCENE, help=f"scene (default: {DEFAULT_SCENE})")
    s.add_argument("--out", default="out", help="output directory (default: out)")
    s.add_argument("--preset", default="wide", choices=PRESETS, help="format preset of the bit-true run and Verilog")
    s.add_argument("--hdl-steps", type=_positive_int, default=200, help="steps run on Icarus (default 200)")
    s.add_argument("--no-synth", dest="synth", action="store_false", help="skip the synthesis (minutes)")
    s.set_defaults(func=cmd_run)
    return p


def main(argv=None) -> int:
    from golden.mesh import MeshError
    from golden.model import SimulationDiverged
    from sim.simulators import SimulatorMissing
    from sim.synth import SynthesisError
    parser = build_parser()
    args = parser.parse_args(argv)
    signal.signal(signal.SIGTERM, _terminated)       # SIGTERM like Ctrl-C: outputs are cleaned up alike
    try:
        return args.func(args)
    except BrokenPipeError:                          # `rheo scenes | head -1`: the reader left; no message
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
    except (UsageError, MeshError, SimulationDiverged, ValueError, FileNotFoundError, OSError,
            SimulatorMissing, SynthesisError) as exc:
        print(error_line(exc), file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("rheo: interrupted", file=sys.stderr)
        return 130


def error_line(exc: BaseException) -> str:
    """The one line a user error prints: its message's lines joined, so a remedy on a later line is kept."""
    text = "; ".join(line.strip() for line in str(exc).splitlines() if line.strip())
    return f"rheo: error: {text or type(exc).__name__}"


def _terminated(signum, frame):
    raise KeyboardInterrupt


if __name__ == "__main__":
    sys.exit(main())
