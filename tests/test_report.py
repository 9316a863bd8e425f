"""`rheo report`: error against run time, written as CSV, JSON and plots."""
from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow      # `make test-fast` leaves these out

ROOT = Path(__file__).resolve().parents[1]


def test_report_orders_presets_and_time_steps(tmp_path):
    scene = (ROOT / "golden" / "scenes" / "press-2d-rheological.toml").read_text()
    scene = scene.replace("duration = 1.5", "duration = 0.3").replace("start = 0.1", "start = 0.02") \
                 .replace("end = 0.6", "end = 0.2")
    p = tmp_path / "short.toml"
    p.write_text(scene)
    out = tmp_path / "rep"
    # a place and route of the medium core, as `rheo synth` leaves it: the core `rheo verilog` emits, an Fmax
    placed = tmp_path / "placed"
    r = subprocess.run([sys.executable, "-m", "sim.cli", "verilog", str(p), "--preset", "medium", "--out", str(placed)],
                       cwd=ROOT, env=dict(os.environ, PYTHONPATH=str(ROOT)), capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr
    (placed / "synth.json").write_text(json.dumps({"place_and_route": True, "fmax_mhz": 75.0}))
    r = subprocess.run([sys.executable, "-m", "sim.cli", "report", str(p), "--out", str(out), "--synth", str(placed)],
                       cwd=ROOT, env=dict(os.environ, PYTHONPATH=str(ROOT)), capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr
    for name in ("error.csv", "summary.json", "error_vs_time.png", "cost_vs_accuracy.png"):
        assert (out / name).stat().st_size > 0
    s = json.loads((out / "summary.json").read_text())
    q = {k: v["max_relative"] for k, v in s["quantisation"].items()}
    assert q["wide"] < q["medium"] < q["narrow"], q          # more bits, less quantisation error
    assert q["wide"] <= 1e-4
    d = {k: v["max_relative"] for k, v in s["discretisation"].items() if isinstance(v, dict)}
    assert 0 < d["dt"] < d["2dt"] < d["4dt"], d               # first-order scheme: error grows with dt
    assert 1.5 < d["4dt"] / d["2dt"] < 2.5                    # ... about linearly
    rt = s["run_time_per_simulated_second"]
    assert rt["golden"] > 0 and rt["fixed-wide"] > 0 and rt["cpu"] > 0
    # the cpu backend is the golden physics: the same run to 1e-12, the same discretisation errors
    assert s["cpu"]["max_relative_vs_golden"] <= 1e-12
    for label, dc in s["cpu"]["discretisation"].items():
        assert abs(dc["max_relative"] - d[label]) <= 1e-9 * d[label] + 1e-12, (label, dc, d[label])
    # the FPGA: every element and every node take a clock of one lane, at the stated clock
    cyc = s["fpga"]["cycles_per_step"]["wide"]
    assert cyc >= 134 + 55 and s["fpga"]["clock_mhz"] == 50.0
    assert abs(rt["fpga-wide"] - cyc / (50e6 * s["dt"])) <= 1e-12 * rt["fpga-wide"]
    # the sensitivity floor (golden with rounded states) is part of what the bit-true model adds
    floor = s["quantisation"]["wide"]["sensitivity_floor_relative"]
    assert 0 < floor <= q["wide"], (floor, q["wide"])
    with open(out / "error.csv") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == s["frames"]
    assert float(rows[0]["t"]) == 0.0 and float(rows[-1]["t"]) > 0.29
    assert abs(max(float(row["quant_max_rel_wide"]) for row in rows) - q["wide"]) <= 1e-8 * q["wide"]  # CSV: 9 digits
    # --synth: the medium point at its measured clock, the others at the default, each saying so
    placed_cycles = json.loads((placed / "manifest.json").read_text())["cycles_per_step"]["value"]
    assert s["fpga"]["cycles_per_step"]["medium"] == placed_cycles
    assert s["fpga"]["clock_mhz_by_preset"] == {"narrow": 50.0, "medium": 75.0, "wide": 50.0}
    assert s["fpga"]["clock_source_by_preset"]["medium"] == f"measured Fmax ({placed})"
    assert abs(rt["fpga-medium"] - placed_cycles / (75e6 * s["dt"])) <= 1e-12 * rt["fpga-medium"]
    # a measured Fmax (rheo run --pnr) moves that preset's FPGA point only, and the plot is redrawn
    from sim.report import measured_clock
    png = (out / "cost_vs_accuracy.png").read_bytes()
    measured_clock(out, "medium", 87.5, "measured Fmax (test)")
    s2 = json.loads((out / "summary.json").read_text())
    rt2 = s2["run_time_per_simulated_second"]
    cyc_m = s["fpga"]["cycles_per_step"]["medium"]
    assert abs(rt2["fpga-medium"] - cyc_m / (87.5e6 * s["dt"])) <= 1e-12 * rt2["fpga-medium"]
    assert rt2["fpga-wide"] == rt["fpga-wide"] and rt2["fpga-narrow"] == rt["fpga-narrow"]
    assert s2["fpga"]["clock_source_by_preset"] == {"narrow": "assumed (default)", "medium": "measured Fmax (test)",
                                                    "wide": "assumed (default)"}
    assert (out / "cost_vs_accuracy.png").read_bytes() != png
