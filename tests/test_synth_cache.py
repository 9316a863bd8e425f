"""sim/synth.py `synthesize_cached`: a result is filed under what ran, so a Yosys-only result never
answers a place-and-route question (and a place-and-route result answers both)."""
from __future__ import annotations

import json

import pytest

import sim.synth as synth


def test_a_yosys_only_result_does_not_answer_place_and_route(tmp_path, monkeypatch):
    monkeypatch.setenv("RHEO_BUILD", str(tmp_path / "build"))
    runs = []

    def fake(verilog, top, out_dir, device, clock_mhz, progress, place_and_route, **nextpnr):
        runs.append(place_and_route)
        out_dir.mkdir(parents=True)
        result = {"fmax_mhz": 91.0 if place_and_route else None}
        (out_dir / "synth.json").write_text(json.dumps(result))
        return result

    monkeypatch.setattr(synth, "synthesize", fake)
    v = tmp_path / "core.v"
    v.write_text("module rheo_core; endmodule\n")
    r, d = synth.synthesize_cached(v, "rheo_core", place_and_route=False)
    assert r["fmax_mhz"] is None and d.name.endswith("-yosys")
    r, d = synth.synthesize_cached(v, "rheo_core", place_and_route=True)    # must place and route now
    assert r["fmax_mhz"] == 91.0 and d.name.endswith("-pnr") and runs == [False, True]
    r, d = synth.synthesize_cached(v, "rheo_core", place_and_route=False)   # the pnr result answers this too
    assert r["fmax_mhz"] == 91.0 and runs == [False, True]


def test_a_result_of_another_yosys_script_answers_nothing(tmp_path, monkeypatch):
    """The key holds the Yosys script: a result made before the script changed (say, before the operand
    registers were kept apart) is not returned for the same Verilog."""
    monkeypatch.setenv("RHEO_BUILD", str(tmp_path / "build"))
    runs = []

    def fake(verilog, top, out_dir, device, clock_mhz, progress, place_and_route, **nextpnr):
        runs.append(synth.KEEP_APART_TAG)
        out_dir.mkdir(parents=True)
        (out_dir / "synth.json").write_text(json.dumps({"tag": synth.KEEP_APART_TAG}))
        return {"tag": synth.KEEP_APART_TAG}

    monkeypatch.setattr(synth, "synthesize", fake)
    v = tmp_path / "core.v"
    v.write_text("module rheo_core; endmodule\n")
    assert synth.synthesize_cached(v, "rheo_core")[0] == {"tag": "_keep_apart"}
    assert synth.synthesize_cached(v, "rheo_core")[0] == {"tag": "_keep_apart"} and len(runs) == 1
    monkeypatch.setattr(synth, "KEEP_APART_TAG", "_other")
    assert synth.synthesize_cached(v, "rheo_core")[0] == {"tag": "_other"} and runs == ["_keep_apart", "_other"]


def test_rheo_synth_hands_its_placement_seed_placer_and_speed_grade_to_nextpnr(tmp_path):
    """`rheo synth --seed N` reaches synthesize() (nextpnr's --seed) and its result; the default is 1; so do
    --placer (default heap) and --speed-grade (default 6, the slowest part)."""
    from sim.cli import build_parser
    from sim.cli.synth import _synthesize
    calls = []

    class FakeEmit:
        @staticmethod
        def write(bt, out, **kw):
            return {"verilog": "core.v", "top": "top", "scene": "s", "preset": "narrow", "core": "stream", "dim": 2,
                    "lanes": {"element_lanes_P": 2, "pair_lanes": 0, "node_lanes_Q": 1},
                    "elements": 1, "nodes": 2, "units_present": [], "cycles_per_step": {"value": 10}}

    def fake_synthesize(verilog, top, out, **kw):
        calls.append((kw["seed"], kw["placer"], kw["speed_grade"], kw["floorplan"]))
        return {"seed": kw["seed"], "fmax_mhz": None}
    parser = build_parser()
    lanes = [[r"el0\.(?!.*\.shared_)", r"ring_el0_r\d+\.", r"window\.copy(0|1)\."], [r"el0\..*\.shared_"],
             [r"el1\.(?!.*\.shared_)", r"ring_el1_r\d+\.", r"window\.copy(2|3)\."], None]
    for argv, seed, placer, grade, plan in (
            (["synth", "creep-1d", "--out", "d", "--seed", "5"], 5, "heap", 6, lanes),
            (["synth", "creep-1d", "--out", "d"], 1, "heap", 6, lanes),
            (["synth", "creep-1d", "--out", "d", "--placer", "static"], 1, "static", 6, lanes),
            (["synth", "creep-1d", "--out", "d", "--speed-grade", "8", "--floorplan", "none"], 1, "heap", 8, None),
            (["synth", "creep-1d", "--out", "d", "--device", "ecp5-45k"], 1, "heap", 6, None),    # sites unknown
            (["synth", "creep-1d", "--out", "d", "--no-pnr"], 1, "heap", 6, None)):
        r, _ = _synthesize(parser.parse_args(argv), None, tmp_path, FakeEmit, fake_synthesize)
        assert calls[-1] == (seed, placer, grade, plan) and r["seed"] == seed


def test_an_unknown_speed_grade_is_refused(tmp_path, capsys):
    """`--speed-grade 9` is a usage error (exit 2, naming the grades), and synthesize() refuses it before
    any tool runs."""
    from sim.cli import build_parser
    with pytest.raises(SystemExit) as e:
        build_parser().parse_args(["synth", "creep-1d", "--out", "d", "--speed-grade", "9"])
    assert e.value.code == 2 and "choose from 6, 7, 8" in capsys.readouterr().err
    v = tmp_path / "core.v"
    v.write_text("module rheo_core(input clk); endmodule\n")
    with pytest.raises(ValueError, match="unknown ECP5 speed grade 9 .*6, 7, 8"):
        synth.synthesize(v, "rheo_core", tmp_path / "out", speed_grade=9)
    assert not (tmp_path / "out").exists()


def test_rheo_synth_fits_the_devices_block_ram(tmp_path):
    """`rheo synth` hands the streaming core its device's DP16KD (208 on an LFE5U-85F, 108 on a 45F) as the
    block RAM budget the core fits with LUT RAM copies (hw/stream/core.py), or the one `--block-rams` asks."""
    from sim.cli import build_parser
    from sim.cli.synth import _synthesize
    budgets = []

    class FakeEmit:
        @staticmethod
        def write(bt, out, **kw):
            budgets.append(kw["dp16kd_budget"])
            return {"verilog": "core.v", "top": "top", "scene": "s", "preset": "narrow", "lanes": 1, "core": "phased",
                    "elements": 1, "nodes": 2, "units_present": [], "cycles_per_step": {"value": 10}}

    parser = build_parser()
    for argv in (["synth", "creep-1d", "--out", "d"], ["synth", "creep-1d", "--out", "d", "--device", "ecp5-45k"],
                 ["synth", "creep-1d", "--out", "d", "--block-rams", "160"]):
        _synthesize(parser.parse_args(argv), None, tmp_path, FakeEmit, lambda *a, **kw: {"fmax_mhz": None})
    assert budgets == [208, 108, 160]


def test_router_placer_and_seed_reach_nextpnr_and_key_the_cache(tmp_path, monkeypatch):
    """`synthesize_cached` hands router, placer and seed to synthesize() and files each choice apart: a
    router1 result does not answer a router2 question, nor a heap placement a static one (their Fmax
    differ)."""
    monkeypatch.setenv("RHEO_BUILD", str(tmp_path / "build"))
    runs = []

    def fake(verilog, top, out_dir, router, seed, placer, speed_grade, **kw):
        runs.append((router, seed) + ((placer,) if placer != "heap" else ()) + ((speed_grade,) if speed_grade != 6 else ()))
        out_dir.mkdir(parents=True)
        (out_dir / "synth.json").write_text(json.dumps({"router": router, "seed": seed}))
        return {"router": router, "seed": seed}

    monkeypatch.setattr(synth, "synthesize", fake)
    v = tmp_path / "core.v"
    v.write_text("module rheo_core; endmodule\n")
    assert synth.synthesize_cached(v, "rheo_core")[0] == {"router": "router1", "seed": 1}
    assert synth.synthesize_cached(v, "rheo_core", router="router2", seed=3)[0] == {"router": "router2", "seed": 3}
    assert synth.synthesize_cached(v, "rheo_core", router="router2", seed=3)[0] == {"router": "router2", "seed": 3}
    assert synth.synthesize_cached(v, "rheo_core", seed=3)[0] == {"router": "router1", "seed": 3}
    assert synth.synthesize_cached(v, "rheo_core", seed=3, placer="static")[0] == {"router": "router1", "seed": 3}
    assert synth.synthesize_cached(v, "rheo_core", seed=3, placer="static")[0] == {"router": "router1", "seed": 3}
    assert synth.synthesize_cached(v, "rheo_core", seed=3, speed_grade=8)[0] == {"router": "router1", "seed": 3}
    plan = [["el0\\."], None]
    assert synth.synthesize_cached(v, "rheo_core", seed=3, floorplan=plan)[0] == {"router": "router1", "seed": 3}
    assert synth.synthesize_cached(v, "rheo_core", seed=3, floorplan=plan)[0] == {"router": "router1", "seed": 3}
    assert runs == [("router1", 1), ("router2", 3), ("router1", 3), ("router1", 3, "static"), ("router1", 3, 8),
                    ("router1", 3)]          # a floorplan is filed apart from the same run without one


def test_rheo_bench_hands_its_place_and_route_choices_to_the_fpga_benchmark(monkeypatch):
    """`rheo bench --backend fpga --router R --seed N --block-rams B` reaches sim.bench's fpga run (which
    builds the core for B DP16KD and places and routes it with R and N); defaults router1, 1, None (all
    the device has)."""
    import sim.bench as bench
    from sim.cli import build_parser
    from sim.cli.bench import run
    seen = []

    def fake_run(backend, **kw):
        seen.append({k: kw[k] for k in ("router", "placer", "seed", "speed_grade", "block_rams", "floorplan")})
        return []
    monkeypatch.setattr(bench, "run", fake_run)
    monkeypatch.setattr("sim.cli.bench._print_fpga", lambda rows: None)
    monkeypatch.setattr("sim.synth.check_tools", lambda place_and_route=True: None)
    parser = build_parser()
    for argv in (["bench", "--backend", "fpga"],
                 ["bench", "--backend", "fpga", "--router", "router2", "--placer", "static", "--seed", "4",
                  "--speed-grade", "7", "--block-rams", "160", "--floorplan", "none"]):
        assert run(parser.parse_args(argv)) == 0
    assert seen == [{"router": "router1", "placer": "heap", "seed": 1, "speed_grade": 6, "block_rams": None,
                     "floorplan": "auto"},
                    {"router": "router2", "placer": "static", "seed": 4, "speed_grade": 7, "block_rams": 160,
                     "floorplan": "none"}]


def test_a_netlist_is_reused_only_from_the_same_verilog_and_yosys_script(tmp_path, monkeypatch):
    """`synthesize(..., netlist_from=DIR)` (`rheo synth --netlist-from`) takes an earlier output directory's
    Yosys netlist instead of running Yosys (no tool runs here), and refuses one of other Verilog, of another
    Yosys script (another top) or without a netlist, naming which."""
    def no_tools(step, *a, **kw):
        raise AssertionError(f"{step} ran")
    monkeypatch.setattr(synth, "_run", no_tools)
    top, text = "rheo_core", "module rheo_core(input clk); endmodule\n"
    src = tmp_path / "earlier"
    src.mkdir()
    (src / "core.v").write_text(text)
    (src / "synth.ys").write_text(synth.yosys_script('read_verilog "core.v"', top, "clk", f"{top}.json"))
    netlist = {"modules": {top: {"ports": {"clk": {}}, "cells": {"a": {"type": "LUT4"}, "b": {"type": "LUT4"},
                                                                "f": {"type": "TRELLIS_FF"}}}}}
    (src / f"{top}.json").write_text(json.dumps(netlist))
    (src / "synth.json").write_text(json.dumps({"wall_s": {"yosys": 321.5}}))

    def run(name, verilog_text, top=top):
        out = tmp_path / name
        out.mkdir()
        (out / "core.v").write_text(verilog_text)
        return synth.synthesize(out / "core.v", top, out, place_and_route=False, netlist_from=src), out

    r, out = run("again", text)
    assert (r["luts"], r["flip_flops"], r["wall_s"]["yosys"], r["netlist_from"]) == (2, 1, 321.5, str(src))
    assert json.loads((out / f"{top}.json").read_text()) == netlist and "earlier" in (out / "report.md").read_text()
    with pytest.raises(ValueError, match="its Verilog core.v is not this core's"):
        run("edited", text.replace("clk", "clock"))
    with pytest.raises(ValueError, match="its Yosys script is not this run's"):
        run("other-top", text, top="other")
    (src / f"{top}.json").unlink()
    with pytest.raises(ValueError, match=f"its netlist {top}.json is missing"):
        run("no-netlist", text)


def test_a_floorplan_reaches_nextpnr_as_sites_on_the_blocks(tmp_path, monkeypatch):
    """`synthesize(..., floorplan=...)` hands nextpnr TOP-floorplan.json: the netlist with a BEL attribute (a
    site of the device) on each DP16KD and MULT18X18D, none on the logic; TOP.json itself keeps none (a later
    `--netlist-from` of it is not floorplanned). nextpnr is not run here."""
    top, text = "rheo_core", "module rheo_core(input clk); endmodule\n"
    src = tmp_path / "earlier"
    src.mkdir()
    (src / "core.v").write_text(text)
    (src / "synth.ys").write_text(synth.yosys_script('read_verilog "core.v"', top, "clk", f"{top}.json"))
    cells = {"el0.el0_a.bram_r0_c0.dp16kd": {"type": "DP16KD"}, "el0.el0_prod_3": {"type": "MULT18X18D"},
             "store.bank0.bram_r0_c0.dp16kd": {"type": "DP16KD"}, "el0.el0_sub_1": {"type": "LUT4"}}
    (src / f"{top}.json").write_text(json.dumps({"modules": {top: {"ports": {"clk": {}}, "cells": cells}}}))
    seen = {}

    def fake_pnr(argv_of_seed, log, cwd, timeout_s, seed, router, say):
        argv = argv_of_seed(seed)
        seen["json"] = argv[argv.index("--json") + 1]
        seen["netlist"] = json.loads((cwd / seen["json"]).read_text())
        raise synth.SynthesisError("nextpnr: stopped by the test")
    monkeypatch.setattr(synth, "place_and_route_seeds", fake_pnr)
    out = tmp_path / "out"
    out.mkdir()
    (out / "core.v").write_text(text)
    with pytest.raises(synth.SynthesisError, match="stopped by the test"):
        synth.synthesize(out / "core.v", top, out, netlist_from=src, floorplan=[[r"el0\."], None])
    assert seen["json"] == f"{top}-floorplan.json"
    got = {n: c.get("attributes", {}).get("BEL") for n, c in seen["netlist"]["modules"][top]["cells"].items()}
    sites = synth.BLOCK_SITES["ecp5-85k"]
    assert got["el0.el0_a.bram_r0_c0.dp16kd"] in sites["DP16KD"] and got["el0.el0_prod_3"] in sites["MULT18X18D"]
    assert got["store.bank0.bram_r0_c0.dp16kd"] in sites["DP16KD"] and got["el0.el0_sub_1"] is None
    assert "BEL" not in json.dumps(json.loads((out / f"{top}.json").read_text()))
