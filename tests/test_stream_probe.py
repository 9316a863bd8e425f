"""The streaming core's probe port (hw/stream/probeport.py) equals the bit-true model bit for bit, in
Amaranth's simulator: a poke trajectory streamed through `probe_in` with random gaps between samples and
random back-pressure on `force_out`; every force word and contact count, and the node and element state
at the end, against `BitTrue` (hold_probe, k steps, probe_raw); the measured latency from each sample's
handshake to its force against the core's `probe_latency` (the manifest's). The same on the emitted
Verilog on Icarus and Verilator through cocotb (sim/cocotb_core.py; marked hdl), and with RHEO_STREAM_ALL=1
the built-in poke-2d-viscoelastic on Verilator.

Amaranth's simulator runs the built-in poke scene at about 130 cycles a second (12 samples of 4,000
cycles: 6 minutes), so this test takes tests/scenes/poke-tiny.toml (15 nodes, k = 4, 139 cycles a step at
P = Q = 2), poked between two top nodes of different node lanes.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
from amaranth.sim import Simulator

from golden.scene import load_scene
from hw.bittrue import BitTrue
from hw.datapath import NotSupported
from hw.stream import build_core, resolve_core
from hw.stream.nodeword import pack_ints, unpack_ints
from sim.host import HostDriver
from sim.hwsim import AmaranthBus

TINY = str(Path(__file__).resolve().parent / "scenes" / "poke-tiny.toml")


def probe_model(scene, preset="wide", range_steps=None):
    """The bit-true model of a poke scene, formats from its design poke (`range_steps` of it)."""
    return BitTrue(load_scene(scene), preset, range_steps=range_steps)


def trajectory(bt, n, down):
    """`n` device samples (metres) straight down from the scene's initial probe position, `down` m apart."""
    p0 = bt.system.probe.position
    return [p0 - down * (s + 1) * np.eye(bt.system.dim)[-1] for s in range(n)]


def expected(bt, positions):
    """Per sample: the x words the host sends, then (force words, contacts) after its k steps; the end state."""
    st = bt.initial_state()
    words, outs = [], []
    for p in positions:
        bt.hold_probe(st, p)
        words.append([int(v) for v in st.probe.P])
        for _ in range(bt.params.probe["k"]):
            bt.step(st)
        outs.append(([int(v) for v in bt.probe_raw(st)], st.probe.contacts))
    return words, outs, st


def stream_samples(core, words, seed, read_state=True):
    """Amaranth's simulator: load the initial state, stream `words` through probe_in with random gaps,
    take force_out under random back-pressure. Returns ([(force words, contacts)], latencies, end state)."""
    rng = np.random.default_rng(seed)
    cfg, pp = core.cfg, core.probe
    D = cfg.dim
    sim = Simulator(core)
    sim.add_clock(1e-8)
    result = {}

    async def bench(ctx):
        drv = HostDriver.for_map(cfg.host_map, core.cycles_per_step, AmaranthBus(ctx, core.host))
        init = cfg.init
        await drv.load(init["X"], init["U"], init["A"], 0)
        i_in, gap, t = 0, int(rng.integers(0, 8)), 0
        hs, outs, lat = [], [], []
        seen = False                       # force_out.valid seen for the sample in flight
        pi, fo = core.probe_in, core.force_out
        while len(outs) < len(words):
            if i_in < len(words) and gap == 0:
                ctx.set(pi.valid, 1)
                ctx.set(pi.payload, pack_ints(words[i_in], pp.x_bits))
            else:
                ctx.set(pi.valid, 0)
            ready = int(rng.random() < 0.3)
            ctx.set(fo.ready, ready)
            if ctx.get(pi.valid) and ctx.get(pi.ready):
                hs.append(t)
                i_in += 1
                gap = int(rng.integers(0, 40))
            elif gap:
                gap -= 1
            if ctx.get(fo.valid):
                if not seen:
                    lat.append(t - hs[len(outs)])
                    seen = True
                if ready:
                    w = int(ctx.get(fo.payload))
                    F = unpack_ints(w, D, pp.f_bits)
                    outs.append((F, w >> (D * pp.f_bits)))
                    seen = False
            await ctx.tick()
            t += 1
        ctx.set(pi.valid, 0)
        result.update(outs=outs, lat=lat, state=await drv.read_state() if read_state else None)

    sim.add_testbench(bench)
    sim.run()
    return result["outs"], result["lat"], result["state"]


@pytest.mark.filterwarnings("ignore::amaranth.hdl.UnusedElaboratable")
def test_probe_port_streams_the_bit_true_forces():
    """P = Q = 2 (15 nodes: the last group is short): 4 samples 0.5 mm apart, the last two touching two
    nodes of different node lanes (their forces summed across lanes)."""
    bt = probe_model(TINY)
    words, want, st = expected(bt, trajectory(bt, 4, 5e-4))
    assert want[0][1] == 0 and want[-1][1] == 2          # the trajectory touches two nodes
    sat = bt.sat.total
    core = build_core(bt, 2, 2, "stream")
    check_stream(bt, core, words, want, st, sat, seed=16)


def check_stream(bt, core, words, want, st, sat, seed):
    """stream_samples against the bit-true model's forces, end state and saturations; latency = manifest."""
    outs, lat, (X, U, A, step, hw_sat, _) = stream_samples(core, words, seed=seed)
    for n, (got, exp) in enumerate(zip(outs, want)):
        assert got == exp, f"sample {n}: force words, contacts {got}, bit-true {exp}"
    assert step == st.step
    for k in range(len(X)):
        assert np.array_equal(X[k], st.X[k]), f"x{k}"
        assert np.array_equal(U[k], st.U[k]), f"u{k}"
    assert np.array_equal(A, st.A)
    assert hw_sat == sat
    assert lat == [core.probe_latency] * len(words), (lat, core.probe_latency)


def test_core_runs_of_a_probe_scene_without_the_port_are_refused_in_one_line():
    """`rheo simulate --backend amaranth` (RUN only: nobody drives the port) and `rheo verilog --core phased`
    refuse a probe scene in one line each."""
    import subprocess
    import sys
    root = Path(__file__).resolve().parents[1]
    for args, words in ((["simulate", "poke-2d-viscoelastic", "--backend", "amaranth", "--out", "unused.npz"],
                         ("has a probe", "probe port", "--backend fixed")),
                        (["verilog", "poke-2d-viscoelastic", "--core", "phased", "--out", "unused"],
                         ("phased core has no probe port", "--core stream"))):
        r = subprocess.run([sys.executable, "-m", "sim.cli", *args], cwd=root, capture_output=True, text=True)
        lines = [ln for ln in r.stderr.splitlines() if ln.startswith("rheo: error:")]
        assert r.returncode == 2 and len(lines) == 1, r.stderr[-2000:]
        assert all(w in lines[0] for w in words), lines[0]


def test_probe_scenes_go_to_the_streaming_core():
    from hw.datapath import Params
    from hw.units import HardwareUnits
    system = load_scene("poke-2d-viscoelastic")
    params = Params.of(system, HardwareUnits.of(system))
    assert resolve_core(params, "auto") == resolve_core(params, "stream") == "stream"
    with pytest.raises(NotSupported, match="phased core has no probe port"):
        resolve_core(params, "phased")


def check_verilog(simulator, scene, samples, down, P, Q, seed, range_steps=None, Pp=None):
    """The emitted Verilog (`rheo verilog --core stream`) on a simulator through cocotb (sim/cocotb_core.py):
    the same proof as check_stream, the latency against the manifest's."""
    from sim.hdlsim import emit_core, run_job
    bt = probe_model(scene, range_steps=range_steps)
    words, want, st = expected(bt, trajectory(bt, samples, down))
    assert want[0][1] == 0 and want[-1][1] > 0
    core_dir, man, drv = emit_core(bt, P, Q, core="stream", pair_lanes=Pp)
    assert man["lanes"]["pair_lanes"] == (P if Pp is None else Pp)
    pm = man["probe_port"]
    x_bits, f_bits = bt.formats["x"].width, bt.formats["fprobe"].width
    init = bt.initial_state()
    out = run_job(simulator, core_dir, drv, drv.load_words(init.X, init.U, init.A, 0), [],
                  probe={"words": words, "x_bits": x_bits, "f_bits": f_bits, "seed": seed}, timeout_s=1800)
    got = [(list(f), c) for f, c in zip(out["forces"], out["contacts"])]
    for n, (g, e) in enumerate(zip(got, want)):
        assert g == (list(e[0]), e[1]), f"{simulator}: sample {n}: {g}, bit-true {e}"
    assert len(got) == len(want)
    X, U, A, step, sat, _ = out["frames"][-1]
    assert step == st.step
    for k in range(bt.system.dim):
        assert np.array_equal(X[k], st.X[k]), f"{simulator}: x{k}"
        assert np.array_equal(U[k], st.U[k]), f"{simulator}: u{k}"
    assert np.array_equal(A, st.A)
    assert sat == bt.sat.total
    assert out["latency"] == [pm["latency_cycles"]] * samples, (out["latency"], pm["latency_cycles"])
    return pm


@pytest.mark.hdl
def test_probe_port_verilog_on_verilator():
    """Icarus runs the same cocotb bench in test_probe_port_verilog_with_pair_lanes_apart_on_icarus."""
    check_verilog("verilator", TINY, 7, 3e-4, 2, 2, seed=7)


@pytest.mark.hdl
@pytest.mark.filterwarnings("ignore::amaranth.hdl.UnusedElaboratable")
def test_probe_port_verilog_with_pair_lanes_apart_on_icarus():
    """Pp = 3 pair lanes beside P = 1 element lane, as `rheo synth poke-... --pair-lanes` (the poke scenes'
    pairs outnumber their elements): a shorter latency than with one pair lane, the same forces."""
    bt = probe_model(TINY)
    assert build_core(bt, 1, 2, "stream", pair_lanes=3).probe_latency < build_core(bt, 1, 2, "stream").probe_latency
    check_verilog("icarus", TINY, 4, 5e-4, 1, 2, seed=11, Pp=3)


if os.environ.get("RHEO_STREAM_ALL"):                # the long set, as tests/test_stream_hdl.py's: not collected
    @pytest.mark.hdl                                  # otherwise (a skip would read as a missing tool)
    def test_probe_port_verilog_builtin_poke_scene():
        """The built-in poke-2d-viscoelastic (153 nodes, k = 10, P = Q = 2: 3,988 cycles a sample) on
        Verilator: 12 samples 0.125 mm apart (4x the design poke's speed, formats of its first 600 steps):
        1 mm of air, then contact. With RHEO_STREAM_ALL=1: about 5 minutes."""
        pm = check_verilog("verilator", "poke-2d-viscoelastic", 12, 1.25e-4, 2, 2, seed=3, range_steps=600)
        assert pm["steps_per_sample_k"] == 10


@pytest.mark.hdl
@pytest.mark.filterwarnings("ignore::amaranth.hdl.UnusedElaboratable")
def test_probe_scene_verilog_has_the_port_and_passes_verilator_lint(tmp_path):
    """`rheo verilog` of a probe scene: the streams on the top, the manifest's latency = the core's."""
    import subprocess
    from hw import emit
    from sim.simulators import find_verilator
    bt = probe_model(TINY)
    man = emit.write(bt, tmp_path, 2, 2, core="stream")
    text = (tmp_path / man["verilog"]).read_text()
    for port in ("probe_in__valid", "probe_in__ready", "probe_in__payload", "force_out__valid", "force_out__ready",
                 "force_out__payload"):
        assert f" {port}" in text, port
    pm = man["probe_port"]
    assert pm["latency_cycles"] == build_core(bt, 2, 2, "stream").probe_latency == \
        pm["sample_kernel_stages"] + pm["run_cycles_k"] + 2
    assert "probe_port" in {u["unit"] for u in man["units_present"]}
    r = subprocess.run([find_verilator(), "--lint-only", "-Wno-WIDTH", "--top-module", man["top"],
                        str(tmp_path / man["verilog"])], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr[-3000:]


def placed_directory(d: Path, lanes: int, fmax_mhz: float = 50.0, budget: int = 208) -> dict:
    """What `rheo synth TINY --preset wide --lanes LANES --node-lanes 2 --block-rams BUDGET --out d` leaves,
    with a synth.json stating `fmax_mhz` (the Verilog and manifest are the real emission; no Yosys here)."""
    import json
    from hw import emit
    man = emit.write(probe_model(TINY), d, lanes, 2, "stream", ram="ecp5", dp16kd_budget=budget)
    placed = {"device": "ecp5-85k", "place_and_route": True, "fmax_mhz": fmax_mhz, "router": "router2", "seed": 3,
              "floorplan": {"regions": 5, "cells_placed": 77, "netlist": "rheo_core-floorplan.json"},
              "luts": 1111, "flip_flops": 2222, "mult18x18": 33, "block_rams": 44}
    (d / "synth.json").write_text(json.dumps(placed))
    return man


def rheo_bench(*args):
    import json
    import subprocess
    import sys
    root = Path(__file__).resolve().parents[1]
    r = subprocess.run([sys.executable, "-m", "sim.cli", "bench", "--backend", "fpga", "--scene", TINY, "--preset", "wide",
                        "--node-lanes", "2", "--seconds", "0.2", "--json", *args],
                       cwd=root, capture_output=True, text=True, timeout=3600)
    return r, (json.loads(r.stdout)["results"][0] if r.returncode == 0 else None)


@pytest.mark.hdl
@pytest.mark.filterwarnings("ignore::amaranth.hdl.UnusedElaboratable")
def test_bench_fpga_states_the_probe_ports_latency_and_sample_rate_at_rheo_synths_fmax(tmp_path):
    """`rheo bench --backend fpga --scene` of a probe scene: samples through the port on Verilator, the
    measured latency = the manifest's, in microseconds at Fmax, and the device samples per second; with
    `--synth DIR` the Fmax, resources, router, seed and floorplan are those of `rheo synth`'s place and route in DIR.
    A DIR whose Verilog differs by one byte (another block RAM fit, another version) is refused once the
    core is emitted, before the simulator: no Fmax borrowed from another netlist."""
    man = placed_directory(tmp_path / "placed", lanes=2, fmax_mhz=47.5)
    r, row = rheo_bench("--lanes", "2", "--synth", str(tmp_path / "placed"))
    assert r.returncode == 0, r.stderr[-3000:]
    L = row["probe_latency_cycles"]
    assert row["probe_k"] == 4 and row["probe_latency_measured"] == [L, L]
    assert L == build_core(probe_model(TINY), 2, 2, "stream").probe_latency
    assert row["fmax_mhz"] == 47.5 and str(tmp_path / "placed") in row["fmax_source"]
    assert row["resources"] == {"luts": 1111, "flip_flops": 2222, "mult18x18": 33, "block_rams": 44}
    assert row["place_and_route"] == {"router": "router2", "placer": "heap", "seed": 3, "speed_grade": 6,
                                      "dp16kd_budget": 208,
                                      "floorplan": {"regions": 5, "cells_placed": 77,
                                                    "netlist": "rheo_core-floorplan.json"}}
    assert row["probe_latency_us"] == pytest.approx(L / 47.5, rel=1e-12)
    assert row["device_samples_per_s"] == pytest.approx(47.5e6 / (L + 1), rel=1e-12)
    verilog = tmp_path / "placed" / man["verilog"]
    verilog.write_text(verilog.read_text().replace("module ", "module  ", 1))
    r, _ = rheo_bench("--lanes", "2", "--synth", str(tmp_path / "placed"))
    assert r.returncode == 2 and "Traceback" not in r.stderr and r.stdout == "", r.stderr
    assert "its Verilog is not this core's" in r.stderr and "verilator" not in r.stderr.lower(), r.stderr


@pytest.mark.parametrize("lanes, placed, words", [
    (1, {"fmax_mhz": 50.0}, ["not this bench's core", "element_lanes_P 2"]),
    (2, {"fmax_mhz": None}, ["holds no Fmax"]),
])
def test_bench_refuses_a_synth_directory_of_another_core_or_without_fmax(tmp_path, lanes, placed, words):
    """`--synth DIR` of another lane count, or of a Yosys-only run, is refused before any run: exit 2, one line."""
    import json
    d = tmp_path / "placed"
    d.mkdir()
    (d / "rheo_core.v").write_text("module rheo_core(); endmodule\n")
    (d / "manifest.json").write_text(json.dumps({
        "verilog": "rheo_core.v", "scene": "poke-tiny", "preset": "wide", "core": "stream",
        "lanes": {"element_lanes_P": 2, "pair_lanes": 2, "collision_lanes": 0, "node_lanes_Q": 2}}))
    (d / "synth.json").write_text(json.dumps({"device": "ecp5-85k", "place_and_route": True, **placed}))
    r, _ = rheo_bench("--lanes", str(lanes), "--synth", str(d))
    assert r.returncode == 2 and "Traceback" not in r.stderr and r.stdout == "", r.stderr
    assert all(w in r.stderr for w in words) and len(r.stderr.strip().splitlines()) == 1, r.stderr
