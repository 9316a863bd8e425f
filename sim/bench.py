"""Throughput benchmark of a backend on generated meshes of about 1e3, 1e4 and 1e5 elements, or on a scene.

The benchmark scene is a square of rheological material (nonlinear damper) under gravity with its
bottom row pinned: element updates and node integration, the work every scene does. Figures are
measured on this machine: steps/s and element-updates/s (elements x steps / wall time).

The FPGA (`bench_fpga`): cycles per step measured by running the emitted Verilog in an HDL simulator
(Verilator or Icarus, through cocotb) and checked bit for bit against the bit-true model; the achieved
Fmax from place and route (`sim/synth.py`, cached next to the core's build by the Verilog's hash), or a
clock the user states; modelled steps/s = Fmax / cycles per step. The golden model's steps/s on the same
scene are measured in the same run, on this machine, for the ratio; so are the compiled cpu backend's
(`sim/cpu.py`), the yardstick a user would pick instead.

The cpu backend (`bench_cpu`, `compare_cpu`): the golden model, the cpu backend at 1 and 2 threads and,
on the benchmark square, the hand-vectorised C loop of bench/square.c, all timed on the same trajectory
segment (the damper's solve costs more as the square creeps).
"""
from __future__ import annotations

import math
import time

import numpy as np

from golden.errors import BadArgument
from golden import mesh as meshlib
from golden.model import Golden
from golden.system import State, System
from golden.builder import SystemBuilder
from golden.scene import MATERIALS

SIZES = (1_000, 10_000, 100_000)


def square_system(n_elements: int) -> System:
    """A 2D square mesh with about n_elements elements (a rectangle of n x n cells has 3 n^2 + 2 n): the
    rheological material, node mass 1e-3 kg, bottom row pinned, under gravity."""
    n = max(1, int(round((-2 + math.sqrt(4 + 12 * n_elements)) / 6)))
    m = meshlib.rectangle(1.0, 1.0, n, n)
    b = SystemBuilder(2)
    b.add_object("square", m, MATERIALS["rheological"], np.full(len(m.nodes), 1e-3), m.nodes[:, 1] == 0.0)
    # 50 steps: what a range analysis of its formats runs (the benchmarks step it for as long as they measure)
    return b.build(f"square-{len(m.edges)}", [0.0, -9.81], 1e-5, 50, 1)


def box_system(n_elements: int) -> System:
    """A 3D box of about n_elements elements (n x n x n cubes of 6 tetrahedra: 7 n^3 + 9 n^2 + 3 n edges), the
    rheological material, node mass 1e-3 kg, bottom layer pinned, under gravity: the square's 3D counterpart."""
    n = min(range(1, 200), key=lambda k: abs(7 * k ** 3 + 9 * k ** 2 + 3 * k - n_elements))
    m = meshlib.box((1.0, 1.0, 1.0), (n, n, n))
    b = SystemBuilder(3)
    b.add_object("box", m, MATERIALS["rheological"], np.full(len(m.nodes), 1e-3), m.nodes[:, 2] == 0.0)
    return b.build(f"box-{len(m.edges)}", [0.0, 0.0, -9.81], 1e-5, 50, 1)


def _timed(stepper, st, system: System, min_seconds: float, **labels) -> dict:
    """Step until at least min_seconds (and 5 steps) have passed; throughput figures."""
    for _ in range(3):                       # warm-up: caches, first-call costs
        stepper.step(st)
    steps, t0 = 0, time.perf_counter()
    while True:
        stepper.step(st)
        steps += 1
        el = time.perf_counter() - t0
        if el >= min_seconds and steps >= 5:
            break
    return dict(**labels, elements=system.n_elements, nodes=system.n_nodes, steps=steps, seconds=el,
                steps_per_s=steps / el, element_updates_per_s=steps * system.n_elements / el)


def _segment(stepper, system: System, steps: int, min_seconds: float) -> dict:
    """Steps/s over one trajectory segment: `steps` steps after 3 warm-up steps from the initial state, run
    again from the start until min_seconds have passed (so that backends of different speeds are timed on
    the same states: the damper's solve costs more as elements creep)."""
    runs, el = 0, 0.0
    while True:
        st = stepper.initial_state()
        stepper.advance(st, 3)                     # warm-up: compilation, caches
        t0 = time.perf_counter()
        stepper.advance(st, steps)
        el += time.perf_counter() - t0
        runs += 1
        if el >= min_seconds:
            return dict(steps=steps * runs, seconds=el, steps_per_s=steps * runs / el)


def compare_cpu(system: System, min_seconds: float = 1.0, threads=(1, 2), c_reference: bool = False) -> dict:
    """The golden model and the cpu backend (each thread count) on the same trajectory segment, and the
    hand-vectorised C loop of bench/square.c when asked (the benchmark square only)."""
    from sim.cpu import Cpu
    g = _timed(Golden(system), State.initial(system), system, min_seconds)
    steps = g["steps"]
    row = dict(elements=system.n_elements, nodes=system.n_nodes, segment_steps=steps + 3, golden_steps_per_s=g["steps_per_s"])
    best = None
    for n in threads:
        stepper = Cpu(system, threads=n)
        row[f"cpu_{stepper.threads}_threads_steps_per_s"] = r = _segment(stepper, system, steps, min_seconds)["steps_per_s"]
        if best is None or r > best[1]:
            best = (stepper.threads, r)
    auto = Cpu(system).threads
    row.update(cpu_threads=auto, cpu_steps_per_s=row.get(f"cpu_{auto}_threads_steps_per_s", best[1]),
               fastest_threads=best[0])
    row["cpu_ratio_to_golden"] = row["cpu_steps_per_s"] / row["golden_steps_per_s"]
    if c_reference:
        row.update(_c_reference(system, steps, min_seconds, row["cpu_steps_per_s"]))
    return row


def _c_reference(system: System, steps: int, min_seconds: float, cpu_steps_per_s: float) -> dict:
    """bench/square.c on the same segment, its result checked against the cpu backend first."""
    import importlib.util
    from pathlib import Path
    from sim.cpu import Cpu
    path = Path(__file__).resolve().parents[1] / "bench" / "square.py"
    if not path.is_file():
        return dict(c_reference=f"not available: {path} is not in this installation (a source checkout has it)")
    spec = importlib.util.spec_from_file_location("bench_square", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    try:
        c = mod.CSquare(system)
    except mod.Unavailable as exc:
        return dict(c_reference=f"not available: {exc}")
    ref, st = Cpu(system, 1), State.initial(system)
    c.advance(steps + 3)
    ref.advance(st, steps + 3)
    x, v, a = c.state()
    size = float(np.ptp(system.x0, axis=0).max())
    err = max(float(np.abs(x - st.x).max()) / size, float(np.abs(a - st.a).max()))
    if not err <= 1e-12:
        raise RuntimeError(f"bench/square.c differs from the cpu backend by {err:.3g} after {steps + 3} steps")

    class _Stepper:                                   # _segment's interface over the C state
        def initial_state(self):
            self.c = mod.CSquare(system)
            return State.initial(system)

        def advance(self, st_, n):
            self.c.advance(n)
    r = _segment(_Stepper(), system, steps, min_seconds)["steps_per_s"]
    return dict(c_reference_steps_per_s=r, c_reference_max_difference=err, cpu_ratio_to_c_reference=cpu_steps_per_s / r)


def bench_cpu(n_elements: int, min_seconds: float = 1.0) -> dict:
    system = square_system(n_elements)
    return dict(backend="cpu", scene=system.name, **compare_cpu(system, min_seconds, c_reference=True))


def bench_golden(n_elements: int, min_seconds: float = 1.0) -> dict:
    system = square_system(n_elements)
    return _timed(Golden(system), State.initial(system), system, min_seconds, backend="golden")


def bench_fixed(n_elements: int, min_seconds: float = 1.0, preset: str = "wide") -> dict:
    """The bit-true model on the same mesh (formats from a short range analysis of its first steps)."""
    from hw.bittrue import BitTrue
    system = square_system(n_elements)
    bt = BitTrue(system, preset)
    return _timed(bt, bt.initial_state(), system, min_seconds, backend="fixed", preset=preset)


def bench_fpga(system: System, preset: str = "auto", lanes: int = 1, node_lanes: int = 1,
               simulator: str = "verilator", steps: int = 2, fmax_mhz: float | None = None,
               device: str = "ecp5-85k", min_seconds: float = 1.0, range_steps: int | None = None,
               log=None, core: str = "auto", pair_lanes: int | None = None, router: str = "router1", seed: int = 1,
               block_rams: int | None = None, synth: str | None = None, placer: str = "heap",
               speed_grade: int = 6, floorplan: str = "auto") -> dict:
    """Modelled FPGA throughput of `system`'s specialised core and the golden model's measured throughput.

    The preset ("auto": the narrowest within 1e-3 of the object size of golden, sim.backends.narrowest_preset)
    and its bit-true run's error against golden over the scene's steps are part of the row.
    Cycles per step come from the HDL simulation: the core's CYCLES register over a run of 1 step and a
    run of `steps` steps after it (their difference over steps - 1: the streaming core's period, without
    its prologue and epilogue), from the initial state; each read-back must equal the bit-true model's.
    With `fmax_mhz` None the core is placed and routed for `device` at `speed_grade` with `floorplan`
    (sim.synth.floorplan_for; once per Verilog, router, placer, seed, grade and floorplan, cached
    in build/synth/; the streaming core with its DP16KD instances, fitted to `block_rams` DP16KD, default
    all the device has); with `synth` (a `rheo synth` output directory) its Fmax is taken instead, once its
    Verilog is shown to be byte for byte this core's, emitted for synthesis (checked before the simulation).
    A scene with a [probe] also streams PROBE_SAMPLES device samples through the probe port (state checked
    after them); the row adds the port's latency (the manifest's cycles, equal to the measured ones) in
    microseconds and the device samples per second at Fmax (`probe_rates`).
    """
    from hw.bittrue import BitTrue
    from hw.datapath import state_difference
    from hw.stream import check_pair_lanes, resolve_core
    from .hdlsim import emit_core, run_job
    from .synth import block_ram_capacity, floorplan_for, read_placed, same_verilog, synthesize_cached
    from .backends import narrowest_preset, preset_error
    say = log or (lambda m: None)
    check_pair_lanes(resolve_core(system, core), pair_lanes)   # a scene no core takes: refused before any run
    if floorplan == "lanes" and fmax_mhz is None and synth is None and resolve_core(system, core) != "stream":
        raise BadArgument(f"--floorplan lanes places the streaming core's lanes; scene {system.name}'s core is the "
                          f"{resolve_core(system, core)} core")
    placed = None
    if synth is not None:                      # rheo synth's place and route: its Fmax, once its Verilog is ours
        placed, placed_man = read_placed(synth)
        device, block_rams = placed["device"], placed_man.get("block_ram_fit", {}).get("dp16kd_budget")
        _check_placed_core(synth, placed_man, system, preset, lanes, node_lanes, pair_lanes)
    preset_given = preset != "auto"
    if not preset_given:
        say(f"{system.name}: choosing the preset (bit-true runs against golden over {system.n_steps} steps)")
        preset, error, chosen = narrowest_preset(system, log=say)
        say(chosen)
    else:                                # its error against golden is measured after the core's run
        chosen = f"preset {preset}: chosen (--preset)"
    say(f"{system.name}: formats (preset {preset})")
    bt = BitTrue(system, preset, range_steps=range_steps)
    kind = resolve_core(bt.params, core)
    core_dir, man, drv = emit_core(bt, lanes, node_lanes, core=kind, pair_lanes=pair_lanes)
    synth_dir = core_dir
    if fmax_mhz is None and kind == "stream":      # synthesis takes the DP16KD instances
        # fit the device's block RAM, or the budget asked (LUT RAM copies, hw/stream/core.py)
        synth_dir, _, _ = emit_core(bt, lanes, node_lanes, core=kind, ram="ecp5", pair_lanes=pair_lanes,
                                    dp16kd_budget=block_ram_capacity(device) if block_rams is None else block_rams)
    if placed is not None:
        same_verilog(synth, placed_man, synth_dir / f"{man['top']}.v")
    steps = max(2, steps)
    say(f"{simulator}: runs of 1 and {steps} steps of the {kind} core in {core_dir}")
    st = bt.initial_state()
    probe = None
    if system.probe is not None:         # runs by RUN (port off: the probe held), then PROBE_SAMPLES samples
        st.probe.driven = True
        probe = {"words": [st.probe.P] * PROBE_SAMPLES, "x_bits": bt.formats["x"].width,
                 "f_bits": bt.formats["fprobe"].width, "seed": 0}
    out = run_job(simulator, core_dir, drv, drv.load_words(st.X, st.U, st.A, 0), [1, steps], probe=probe)
    runs = [1, steps] + ([None] if probe else [])
    for n, frame in zip(runs, out["frames"]):
        if n is None:                    # after the samples through the port
            for _ in range(PROBE_SAMPLES):
                bt.hold_probe(st, system.probe.position)
                for _ in range(bt.params.probe["k"]):
                    bt.step(st)
        else:
            for _ in range(n):
                bt.step(st)
        X, U, A, step = frame[:4]
        if (why := state_difference(st, X, U, A, step)) is not None:
            raise RuntimeError(f"{simulator}: the core's state after {st.step} steps differs from the bit-true "
                               f"model: {why}")
    cycles = (out["cycles"][1] - out["cycles"][0]) / (steps - 1)
    if preset_given:
        error, note = preset_error(system, preset)
        say(f"preset {preset}: " + (f"{error:.1e} of the object size against golden {note}" if error is not None else note))
    row = dict(backend="fpga", scene=system.name, elements=system.n_elements, nodes=system.n_nodes, preset=preset,
               preset_why=chosen, error_vs_golden=error, error_steps=system.n_steps,
               lanes=lanes, node_lanes=node_lanes, pair_lanes=man["lanes"]["pair_lanes"], core=kind,
               simulator=simulator, cycles_per_step=cycles,
               cycles_per_step_schedule=man["cycles_per_step"]["value"], run_cycles=out["cycles"],
               spare_lanes=man.get("spare_lanes", []),
               ideal_cycles_per_step=-(-system.n_elements // lanes),
               simulator_cycles_per_s=(sum(out["cycles"]) + sum(out.get("latency", []))) / max(out["wall_s"], 1e-9),
               core_dir=str(core_dir))
    if fmax_mhz is None:
        if placed is not None:
            res, router, seed = placed, placed.get("router", "router1"), placed.get("seed", 1)
            placer, speed_grade = placed.get("placer", "heap"), placed.get("speed_grade", 6)
            planned = placed.get("floorplan")
            source = (f"measured: rheo synth's nextpnr-ecp5 on {device}, speed grade {speed_grade} ({synth}: the same "
                      "Verilog)")
        else:
            say(f"place and route for {device} (Yosys + nextpnr, once per Verilog; tens of minutes for large cores)")
            res, placed_dir = synthesize_cached(synth_dir / f"{man['top']}.v", man["top"], device=device,
                                                progress=log is not None, router=router, seed=seed, placer=placer,
                                                speed_grade=speed_grade, floorplan=floorplan_for(man, device, floorplan))
            planned = res.get("floorplan")
            source = f"measured: nextpnr-ecp5 on {device}, speed grade {speed_grade} ({placed_dir})"
            seed = res.get("seed", seed)               # the seed that routed (router2 moves on from a stall)
        fmax_mhz = res["fmax_mhz"]
        row["resources"] = {k: res[k] for k in ("luts", "flip_flops", "mult18x18", "block_rams")}
        row["place_and_route"] = {"router": router, "placer": placer, "seed": seed, "speed_grade": speed_grade,
                                  "floorplan": planned,
                                  "dp16kd_budget": block_ram_capacity(device) if block_rams is None else block_rams}
    else:
        source = "stated (--fmax-mhz)"
    row.update(fmax_mhz=fmax_mhz, fmax_source=source, steps_per_s=fmax_mhz * 1e6 / cycles,
               element_updates_per_s=fmax_mhz * 1e6 / cycles * system.n_elements)
    if probe is not None:
        row.update(probe_rates(man["probe_port"], out["latency"], fmax_mhz))
    say("golden model and the cpu backend on the same scene")
    cmp = compare_cpu(system, min_seconds)
    row.update(golden_steps_per_s=cmp["golden_steps_per_s"], ratio_to_golden=row["steps_per_s"] / cmp["golden_steps_per_s"],
               cpu_steps_per_s=cmp["cpu_steps_per_s"], cpu_threads=cmp["cpu_threads"],
               ratio_to_cpu=row["steps_per_s"] / cmp["cpu_steps_per_s"])
    return row


PROBE_SAMPLES = 2      # device samples through the probe port (at the initial position) to measure its latency


def _check_placed_core(synth, manifest: dict, system: System, preset: str, lanes: int, node_lanes: int,
                       pair_lanes: int | None) -> None:
    """A `--synth` directory of another scene, preset or lane count is refused before the preset's bit-true
    runs; the Verilog itself is compared once this core is emitted (sim.synth.same_verilog)."""
    from .synth import describe_core
    got = manifest.get("lanes", {})
    wanted = [(manifest.get("scene"), system.name), (got.get("element_lanes_P"), lanes),
              (got.get("node_lanes_Q"), node_lanes)]
    if preset != "auto":
        wanted.append((manifest.get("preset"), preset))
    if pair_lanes is not None and got.get("pair_lanes"):
        wanted.append((got.get("pair_lanes"), pair_lanes))
    if any(a != b for a, b in wanted):
        raise BadArgument(f"--synth {synth}: it holds {describe_core(manifest)}, not this bench's core (scene "
                          f"{system.name}, preset {preset}, P {lanes}, Q {node_lanes}"
                          + (f", Pp {pair_lanes}" if pair_lanes is not None else "") + ")")


def probe_rates(port: dict, measured: list, fmax_mhz: float) -> dict:
    """The probe port's figures at `fmax_mhz`: its latency from sample to force (the manifest's cycles, which
    the measured ones must equal) in microseconds, and the device samples per second it sustains (one per
    latency + 1 cycles: the next sample is taken the cycle after a force)."""
    L = port["latency_cycles"]
    if any(int(m) != L for m in measured):
        raise RuntimeError(f"the probe port's measured latencies {list(measured)} differ from the manifest's {L} cycles")
    return dict(probe_k=port["steps_per_sample_k"], probe_latency_cycles=L, probe_latency_measured=list(measured),
                probe_latency_us=L / fmax_mhz, device_samples_per_s=fmax_mhz * 1e6 / (L + 1))


def run(backend: str, sizes=SIZES, min_seconds: float = 1.0, scene: System | None = None, **fpga) -> list[dict]:
    """Rows of figures, one per mesh size, or one for `scene` (golden and fpga backends)."""
    if scene is not None:
        if backend == "golden":
            return [_timed(Golden(scene), State.initial(scene), scene, min_seconds, backend="golden", scene=scene.name)]
        if backend == "fpga":
            return [bench_fpga(scene, min_seconds=min_seconds, **fpga)]
        if backend == "cpu":
            return [dict(backend="cpu", scene=scene.name, **compare_cpu(scene, min_seconds))]
        raise BadArgument(f"backend '{backend}' benchmarks generated meshes only (no scene)")
    if backend == "golden":
        return [bench_golden(n, min_seconds) for n in sizes]
    if backend == "cpu":
        return [bench_cpu(n, min_seconds) for n in sizes]
    if backend == "fpga":
        rows = []
        for n in sizes:
            rows.append(bench_fpga(square_system(n), min_seconds=min_seconds, **fpga))
        return rows
    if backend == "fixed":
        rows = []
        for n in sizes:
            g, f = bench_golden(n, min_seconds), bench_fixed(n, min_seconds)
            f["golden_steps_per_s"] = g["steps_per_s"]
            f["ratio_to_golden"] = f["steps_per_s"] / g["steps_per_s"]
            rows.append(f)
        return rows
    raise BadArgument(f"backend '{backend}' has no benchmark (available: golden, cpu, fixed, fpga)")
