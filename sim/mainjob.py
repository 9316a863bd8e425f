"""The main job (`make run`, `rheo run`): one scene from physics to hardware, every claim checked.

  1. the golden run (float64), its pictures, animation and ParaView series;
  2. the number formats of a preset (range analysis), the Verilog of the scene's core and its manifest;
     Yosys starts in the background on the core of the narrowest preset within 1e-3 of golden (bit-true runs
     of the scene, narrowest first: sim.backends.narrowest_preset);
  3. the Verilog simulated (Verilator where installed, else Icarus Verilog) and checked bit for bit
     against the bit-true model over the first steps;
  4. the error-against-run-time report: the bit-true run of every preset against golden, and golden at
     dt, 2 dt, 4 dt against a converged reference;
  5. the synthesis: resources from Yosys; Fmax from nextpnr only when asked (`place_and_route`: tens of
     minutes), both cached by the Verilog's hash in build/synth/;
and a summary of all of it (printed, and DIR/summary.json). Outputs go to the output directory only
(plus the build/ caches).
"""
from __future__ import annotations

import json
import shutil
import threading
import time
from pathlib import Path

import numpy as np

from golden.system import System



def hdl_simulator(prefer: str | None = None) -> tuple[str, str | None]:
    """(simulator, note): Verilator where it is installed (about 40x faster than Icarus here), else Icarus
    Verilog with a note saying why."""
    from .simulators import SimulatorMissing, locate_verilator
    if prefer is not None:
        return prefer, None
    try:
        locate_verilator()
        return "verilator", None
    except SimulatorMissing as exc:
        return "icarus", f"Verilator is not available ({exc}): checking on Icarus Verilog, about 40x slower"


def _bar(total: int, desc: str, unit: str):
    from tqdm import tqdm
    return tqdm(total=total, desc=f"      {desc}", unit=unit, unit_scale=True, delay=1.0, mininterval=0.5,
                leave=False)


def _peak_frame(system: System, run) -> int:
    """Frame of the largest displacement of the loaded nodes (or of all nodes without loads)."""
    nodes = np.concatenate([ld.nodes for ld in system.loads]) if system.loads else np.arange(system.n_nodes)
    disp = np.linalg.norm(run.x[:, nodes] - run.x[0, nodes], axis=2).mean(1)
    return int(np.argmax(disp))


class _Background:
    """A call run in a thread (the synthesis, a subprocess, overlaps the rest of the job)."""

    def __init__(self, fn, *args, **kw):
        self.result, self.error = None, None

        def target():
            try:
                self.result = fn(*args, **kw)
            except BaseException as exc:        # re-raised in the job's thread by get()
                self.error = exc
        self.thread = threading.Thread(target=target, daemon=True)
        self.thread.start()

    def get(self):
        self.thread.join()
        if self.error is not None:
            raise self.error
        return self.result


def main_job(system: System, out, preset: str = "wide", hdl_steps: int = 200, synth: bool = True,
             place_and_route: bool = False, simulator: str | None = None, log=print) -> dict:
    """Run the whole job on `system` into directory `out`; returns the summary (also out/summary.json).
    `out` is written whole or not at all (sim.runfile.output_directory): the job writes into a temporary
    sibling that becomes `out` when every stage has passed."""
    from sim.runfile import output_directory
    final = Path(out)
    with output_directory(final) as tmp:
        def shown(p) -> Path:                 # the path a file will have once the job is done
            return final / Path(p).relative_to(tmp)
        return _job(system, tmp, shown, preset, hdl_steps, synth, place_and_route, simulator, log)


def _job(system, out: Path, shown, preset, hdl_steps, synth, place_and_route, simulator, log) -> dict:
    from golden.scene import file_stem
    from hw import emit
    from hw.bittrue import BitTrue, scene_ranges
    from hw.datapath import state_difference
    from sim import report, runfile
    from sim.backends import narrowest_preset, run_backend
    from sim.hdlsim import emit_core, run_job
    from sim.render import render, render_before_after
    from sim.synth import synthesize_cached
    from sim.vtk_export import export_vtk

    t_job = time.perf_counter()
    n = 5 if synth else 4
    stem = file_stem(system.name)      # no output path from inside the scene file
    summary: dict = {"scene": system.name, "nodes": system.n_nodes, "elements": system.n_elements,
                     "steps": system.n_steps, "dt_s": system.dt, "seconds": {}}
    seconds = summary["seconds"]

    def stage(k, text):
        log(f"[{k}/{n}] {text}")
        return time.perf_counter()

    t = stage(1, f"golden run of {system.name}: {system.n_nodes} nodes, {system.n_elements} elements, "
                 f"{system.n_steps} steps of {system.dt:g} s (float64); pictures, animation, VTK")
    run = run_backend(system, "golden", progress=True)
    npz = runfile.save(out / f"{stem}.npz", runfile.run_arrays(system, run, "golden"))
    png = render(npz, out / f"{stem}.png")
    peak = _peak_frame(system, run)
    ba = render_before_after(npz, out / f"{stem}-before-after.png", [0, peak, len(run.t) - 1],
                             ["before", f"loaded (t = {run.t[peak]:.2f} s)", f"after release (t = {run.t[-1]:.2f} s)"])
    gif = render(npz, out / f"{stem}.gif")
    files = export_vtk(npz, out / "vtk")
    log(f"      {shown(npz)}\n      {shown(png)}\n      {shown(ba)}\n      {shown(gif)}\n      {len(files)} frames -> "
        f"{shown(out / 'vtk' / 'run.pvd')}")
    seconds["golden_and_pictures"] = time.perf_counter() - t
    summary["golden_wall_s"] = run.wall_seconds

    t = stage(2, f"number formats (preset {preset}: range analysis), the Verilog and its manifest"
                 + ("; Yosys synthesis started in the background" if synth else ""))
    with np.errstate(over="ignore", invalid="ignore"):
        ranges = scene_ranges(system)                 # shared by every preset
        bt = BitTrue(system, preset, ranges=ranges)
    for msg in bt.stagnation_messages():
        log(f"warning: {msg}")
    man = emit.write(bt, out / "verilog", core="auto")
    cps = man["cycles_per_step"]["value"]
    log(f"      {shown(out / 'verilog' / man['verilog'])}: {cps} cycles per step, "
        f"left out: {', '.join(u['unit'] for u in man['units_left_out']) or 'nothing'}")
    summary["core"] = {"core": man["core"], "preset": preset, "cycles_per_step": cps,
                       "units_left_out": [u["unit"] for u in man["units_left_out"]]}
    synthesis = None
    if synth:                      # the narrowest preset within 1e-3 of golden (issue 15), said with why
        synth_preset, _, why = narrowest_preset(system)
        log(f"      synthesis: {why}")
        summary["synthesis_preset"] = {"preset": synth_preset, "why": why}
        with np.errstate(over="ignore", invalid="ignore"):
            nb = BitTrue(system, synth_preset, ranges=ranges)
        syn_dir = out / "synth"
        nm = emit.write(nb, syn_dir, core="auto", ram="ecp5")   # the streaming core with its DP16KDs
        synthesis = _Background(synthesize_cached, syn_dir / nm["verilog"], nm["top"], clock_mhz=100.0,
                                place_and_route=place_and_route)
    seconds["formats_and_verilog"] = time.perf_counter() - t

    sim_name, note = hdl_simulator(simulator)
    steps = min(hdl_steps, system.n_steps)
    t = stage(3, f"{'Verilator' if sim_name == 'verilator' else 'Icarus Verilog'} (cocotb): the first {steps} "
                 f"steps of the Verilog, checked bit for bit against the bit-true model")
    if note:
        log(f"      note: {note}")
    core_dir, _, drv = emit_core(bt, core="auto")
    log(f"      build (cached by the Verilog's hash): {core_dir / sim_name}")
    st = bt.initial_state()
    every = max(1, steps // 4)
    from golden.system import frame_steps
    at = frame_steps(steps, every)
    bar = _bar(int(steps * cps), "simulated", "cycle")
    res = run_job(sim_name, core_dir, drv, drv.load_words(st.X, st.U, st.A, 0), [int(k) for k in np.diff(at)],
                  progress=lambda done, total: bar.update(done - bar.n))
    bar.close()
    ref = BitTrue(system, preset, formats=bt.formats)
    st = ref.initial_state()
    for (X, U, A, step, *_), target in zip(res["frames"], at[1:]):
        ref.advance(st, target - st.step)
        if (why := state_difference(st, X, U, A, step)) is not None:
            raise RuntimeError(f"{sim_name} run differs from the bit-true model at step {st.step}: {why}")
    rate = sum(res["cycles"]) / max(res["wall_s"], 1e-9)
    log(f"      {len(res['frames'])} read-backs equal the bit-true model; {res['wall_s']:.1f} s simulated wall "
        f"({rate:.0f} cycles/s)")
    summary["hdl_check"] = {"simulator": sim_name, "steps": steps, "read_backs_equal": len(res["frames"]),
                            "cycles_per_s": rate}
    seconds["hdl_check"] = time.perf_counter() - t

    t = stage(4, "error against run time: the bit-true model of every preset against golden; golden at dt, "
                 "2 dt, 4 dt against a converged reference")
    with np.errstate(over="ignore", invalid="ignore"):
        rep = report.build(system, out / "report", presets=["narrow", "medium", "wide"],
                           log=lambda m: log(f"      {m}"), progress=True)
    for p, q in rep["quantisation"].items():
        if "max_relative" in q:
            log(f"      {p:7s} max {q['max_relative']:.2e} of the object size, "
                f"{sum(q['saturations'].values())} saturations")
    for label, d in rep["discretisation"].items():
        if isinstance(d, dict) and "max_relative" in d:
            log(f"      golden at {label:4s} max {d['max_relative']:.2e} of the object size from the reference")
    summary["report"] = {p: q.get("max_relative") for p, q in rep["quantisation"].items()}
    seconds["report"] = time.perf_counter() - t

    if synthesis is not None:
        what = "Yosys and nextpnr" if place_and_route else "Yosys (resources; Fmax with --pnr)"
        t = stage(5, f"synthesis for ECP5-85k, preset {synth_preset}: {what}")
        r, cache = synthesis.get()
        for name in ("synth.json", "report.md"):
            shutil.copyfile(cache / name, out / "synth" / name)
        fmax = f", Fmax {r['fmax_mhz']:.1f} MHz" if r.get("fmax_mhz") else ""
        log(f"      {r['luts']} LUTs, {r['flip_flops']} FFs, {r['mult18x18']} multipliers, {r['block_rams']} "
            f"block RAMs{fmax} -> {shown(out / 'synth' / 'report.md')} (cached in {cache})")
        summary["synthesis"] = {k: r.get(k) for k in ("luts", "flip_flops", "mult18x18", "block_rams", "fmax_mhz")}
        if r.get("fmax_mhz") and summary["report"].get(synth_preset) is not None:   # the report's FPGA point at the measured clock
            report.measured_clock(out / "report", synth_preset, r["fmax_mhz"],
                                  f"measured Fmax (place and route of this core, {cache})")
            log(f"      report: the FPGA {synth_preset} point now at the measured {r['fmax_mhz']:.1f} MHz")
        seconds["synthesis_wait"] = time.perf_counter() - t

    summary["wall_s"] = time.perf_counter() - t_job
    runfile.write_atomically(out / "summary.json",
                             lambda tmp: Path(tmp).write_text(json.dumps(summary, indent=2, default=float)))
    log(f"done in {summary['wall_s']:.0f} s: {shown(out)}/ holds the runs, pictures, vtk/, verilog/, report/"
        + (", synth/" if synth else "") + ", summary.json")
    err = summary["report"].get(preset)
    log(f"  golden: {system.n_steps} steps in {summary['golden_wall_s']:.1f} s; bit-true {preset}: "
        + (f"{err:.1e} of the object size from golden" if err is not None else "not run")
        + f"; core: {cps} cycles/step, equal to the bit-true model on {sim_name} over {steps} steps")
    if "synthesis" in summary:
        s = summary["synthesis"]
        log(f"  ECP5-85k ({synth_preset}): {s['luts']} LUT4, {s['flip_flops']} FF, {s['mult18x18']} MULT18X18D, "
            f"{s['block_rams']} DP16KD" + (f", Fmax {s['fmax_mhz']:.1f} MHz" if s.get("fmax_mhz") else
                                           " (Fmax: rheo run --pnr, or make synth)"))
    return summary
