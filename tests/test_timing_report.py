"""sim.synth's reading of a nextpnr timing report: the worst path and the endpoint census.

The reports here are written by hand in nextpnr-ecp5 0.11's JSON layout (`--report` with
`--detailed-timing-report`); tests/test_synth.py checks the same functions on a real run."""

from sim.synth import critical_path, endpoint_census, endpoint_class, render_markdown

CLK = "$glbnet$clk$TRELLIS_IO_IN"


def _step(kind, delay, a, b, la=(1, 1), lb=(1, 1)):
    return {"type": kind, "delay": delay, "from": {"cell": a, "loc": list(la), "port": "Q"},
            "to": {"cell": b, "loc": list(lb), "port": "D"}}


REPORT = {
    "critical_paths": [{"from": f"posedge {CLK}", "to": f"posedge {CLK}", "path": [
        _step("clk-to-q", 0.5, "src_TRELLIS_FF_Q", "src_TRELLIS_FF_Q", (10, 4), (10, 4)),
        _step("routing", 6.0, "src_TRELLIS_FF_Q", "lut_LUT4_Z", (10, 4), (40, 24)),
        _step("logic", 0.25, "lut_LUT4_Z", "lut_LUT4_Z", (40, 24), (40, 24)),
        _step("routing", 1.0, "lut_LUT4_Z", "el2.el2_sub_7_TRELLIS_FF_Q_3", (40, 24), (41, 24)),
        _step("setup", 0.1, "el2.el2_sub_7_TRELLIS_FF_Q_3", "el2.el2_sub_7_TRELLIS_FF_Q_3", (41, 24), (41, 24)),
    ]}],
    "detailed_net_timings": [
        {"net": "a", "driver": "x", "endpoints": [
            {"cell": "el2.el2_sub_7_TRELLIS_FF_Q_3", "port": "DI", "delay": [7.0, 7.85]},
            {"cell": "el0.el0_sub_12_TRELLIS_FF_Q", "port": "DI", "delay": [3.0, 8.5]},
            {"cell": "window.copy3.di_r0_c1_TRELLIS_FF_Q_5", "port": "DI", "delay": [1.0, 7.99]}]},
        {"net": "b", "driver": "y", "endpoints": [
            {"cell": "store.bank1.bram_r0_c11.dp16kd", "port": "ADA5", "delay": [9.0, 9.0]},
            {"cell": "el1.el1_line_9.0.1$DPRAM_COMB0", "port": "WAD0", "delay": [2.0, 2.0]}]},
    ],
}


def test_endpoint_class_names_a_register_or_block_with_indices_as_hashes():
    assert endpoint_class("el3.el3_sub_41_TRELLIS_FF_Q_7") == "el#.el#_sub_#"
    assert endpoint_class("el0.el0_line_9.0.1$DPRAM_COMB0") == "el#.el#_line_#"
    assert endpoint_class("store.bank1.bram_r0_c11.dp16kd") == "store.bank#.bram_r#_c#.dp16kd"
    assert endpoint_class("el2.el2_prod_3_a_TRELLIS_FF_Q_DI_LUT4_Z") == "el#.el#_prod_#_a"


def test_census_counts_the_pins_after_the_period_by_class():
    c = endpoint_census(REPORT, 8.0)                  # 125 MHz
    assert c["endpoints"] == 5 and c["late"] == 2     # 8.5 and 9.0 arrive after 8 ns; 7.99 does not
    assert c["classes"] == [{"cells": "el#.el#_sub_#", "late": 1}, {"cells": "store.bank#.bram_r#_c#.dp16kd", "late": 1}]
    c = endpoint_census(REPORT, 7.5)
    assert c["late"] == 4 and c["classes"][0] == {"cells": "el#.el#_sub_#", "late": 2}
    assert endpoint_census({"critical_paths": []}, 8.0) is None      # no detailed report: no census


def test_critical_path_splits_logic_from_routing():
    cp = critical_path(REPORT, CLK)
    assert cp["from"] == "src_TRELLIS_FF_Q" and cp["to"] == "el2.el2_sub_7_TRELLIS_FF_Q_3"
    assert cp["delay_ns"] == 7.85 and cp["routing_ns"] == 7.0 and cp["logic_ns"] == 0.85 and cp["cells"] == 1
    assert cp["longest_route"] == {"delay_ns": 6.0, "from": "src_TRELLIS_FF_Q", "to": "lut_LUT4_Z", "tiles": 50}
    assert critical_path(REPORT, "other_clock") is None
    assert critical_path({}, CLK) is None


def test_report_md_states_the_path_and_the_census():
    r = {"top": "t", "device": "ecp5-85k", "speed_grade": 6, "place_and_route": True, "fmax_mhz": 127.4,
         "timing_met": True, "clock_constraint_mhz": 125.0, "utilization": {}, "yosys_cells": {"LUT4": 1},
         "luts": 1, "flip_flops": 0, "carry_cells": 0, "mult18x18": 0, "block_rams": 0, "distributed_rams": 0,
         "clock_port": "clk", "tool_versions": {"yosys": "Yosys 0.70", "nextpnr-ecp5": "0.11"},
         "wall_s": {"yosys": 1.0, "nextpnr": 2.0},
         "critical_path": critical_path(REPORT, CLK), "late_endpoints": endpoint_census(REPORT, 8.0)}
    md = render_markdown(r)
    assert ("Critical path: `src_TRELLIS_FF_Q` -> `el2.el2_sub_7_TRELLIS_FF_Q_3`, 7.85 ns = 0.85 ns of logic "
            "(1 cell) + 7.00 ns of routing; its longest route 6.00 ns over 50 tiles") in md
    assert "reached after the clock period (8 ns, setup not counted): **2** of 5" in md
    assert "| `el#.el#_sub_#` | 1 |" in md
    del r["critical_path"], r["late_endpoints"]       # a result cached before these fields
    assert "Critical path" not in render_markdown(r)
    assert "stalled" not in md
    r.update(seed=4, stalled_seeds=[{"seed": 3, "iteration": 57, "overused": 1319, "fewest": 495, "fewest_at": 42}])
    assert ("timing **met** (seed 4; router2 stalled with seed 3 (1,319 overused wires at iteration 57, "
            "fewest 495 at 42))") in render_markdown(r)


def test_rheo_synth_prints_the_critical_path_and_the_late_pins(tmp_path, monkeypatch, capsys):
    """`rheo synth` ends with the worst path and how many endpoint pins are late (the tools faked: the
    printing of their result is what is checked here)."""
    import sim.cli.synth as cli_synth
    from sim.cli import main

    def fake(args, bt, out, emit, synthesize):
        (out / "synth.json").write_text("{}")
        r = {"luts": 10, "flip_flops": 20, "mult18x18": 1, "block_rams": 2, "fmax_mhz": 127.4, "timing_met": True,
             "critical_path": critical_path(REPORT, CLK), "late_endpoints": endpoint_census(REPORT, 8.0),
             "cycles_per_step": 100, "modelled_steps_per_s": 1274000.0, "seed": 2,
             "stalled_seeds": [{"seed": 1, "iteration": 57, "overused": 1319, "fewest": 495, "fewest_at": 42}]}
        return r, {"verilog": "rheo_core.v", "cycles_per_step": {"value": 100}}
    monkeypatch.setattr(cli_synth, "_synthesize", fake)
    monkeypatch.setattr(cli_synth, "hardware_model", lambda args: None)
    assert main(["synth", "creep-1d", "--out", str(tmp_path / "d")]) == 0
    out = capsys.readouterr().out
    assert ("critical path src_TRELLIS_FF_Q -> el2.el2_sub_7_TRELLIS_FF_Q_3: 7.85 ns, 7.00 of it routing; "
            "2 of 5 endpoint pins late") in out
    assert "seed 2, speed grade 6); router2 stalled with seed 1" in out       # the seed that routed, not --seed
