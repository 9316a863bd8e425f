"""`rheo verilog`: the scene decides what is elaborated; the Verilog passes Verilator's lint."""
from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _rheo(*args):
    return subprocess.run([sys.executable, "-m", "sim.cli", *args], cwd=ROOT, capture_output=True, text=True)


@pytest.fixture(scope="module")
def emitted(tmp_path_factory):
    out = {}
    for name in ("press-2d-rheological", "press-2d-viscoelastic", "press-2d-plastic", "gravity-2d-linear"):
        d = tmp_path_factory.mktemp(name)
        r = _rheo("verilog", name, "--out", str(d), "--core", "phased")
        assert r.returncode == 0, r.stderr
        out[name] = (d, json.loads((d / "manifest.json").read_text()))
    return out


def _units(man):
    return {u["unit"] for u in man["units_present"]}, {u["unit"] for u in man["units_left_out"]}


@pytest.mark.hdl
def test_manifest_lists_units_formats_memories_and_cycles(emitted):
    d, man = emitted["press-2d-rheological"]
    present, absent = _units(man)
    assert {"element_pipeline", "damper_tables", "a_state", "pair_pipeline", "floor_contact"} <= present
    assert "constant_damper" in absent and "per_node_mass" in absent
    assert present.isdisjoint(absent)
    assert man["formats"]["x"]["format"].startswith("SQ(") and man["formats"]["x"]["width"] == 32
    cps = man["cycles_per_step"]
    assert cps["value"] == (max(-(-cps["E"] // cps["P"]), -(-cps["pairs"] // cps["P"])) + cps["drain_elements"]
                            + -(-cps["N"] // cps["Q"]) + cps["drain_nodes"])
    assert man["memory_bits"] == sum(m["depth"] * m["width"] for m in man["memories"])
    assert (d / man["verilog"]).stat().st_size > 10_000


@pytest.mark.hdl
def test_specialisation_leaves_out_what_a_scene_does_not_need(emitted):
    _, rheo = emitted["press-2d-rheological"]
    _, visco = emitted["press-2d-viscoelastic"]
    _, plastic = emitted["press-2d-plastic"]
    _, grav = emitted["gravity-2d-linear"]
    assert {"a_state", "damper_tables"} <= _units(visco)[1]                   # a Voigt element: no a, no table
    assert "k1_multiplier" in _units(plastic)[1]                              # k1 = 0: no multiplier
    assert {"loads", "damper_tables"} <= _units(grav)[1] and "gravity" in _units(grav)[0]
    # what is left out is really not there: fewer memories, no damper table (Phi, Psi) module, fewer bits
    assert not any("inverse_" in m for m in visco["verilog_modules"])
    assert all(any(f"inverse_{t}" in m for m in rheo["verilog_modules"]) for t in ("phi", "psi"))
    assert visco["memory_bits"] < rheo["memory_bits"]
    assert grav["memory_bits"] < visco["memory_bits"]


def _verilator():
    from sim.simulators import SimulatorMissing, find_verilator
    try:
        return find_verilator()
    except SimulatorMissing:
        found = shutil.which("verilator")             # any Verilator lints; cocotb needs the new one
        if found is None:
            raise
        return found


@pytest.mark.hdl
@pytest.mark.parametrize("name", ["press-2d-rheological", "press-2d-viscoelastic", "gravity-2d-linear"])
def test_verilog_passes_verilator_lint(emitted, name):
    d, man = emitted[name]
    r = subprocess.run([_verilator(), "--lint-only", "-Wno-WIDTH", "--top-module", man["top"],
                        str(d / man["verilog"])],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr[-3000:]


@pytest.mark.hdl
def test_lanes_are_parameters(tmp_path):
    r = _rheo("verilog", "gravity-2d-linear", "--out", str(tmp_path), "--lanes", "2", "--node-lanes", "3",
              "--core", "phased")
    assert r.returncode == 0, r.stderr
    man = json.loads((tmp_path / "manifest.json").read_text())
    assert man["lanes"]["element_lanes_P"] == 2 and man["lanes"]["node_lanes_Q"] == 3
    assert sum(m["name"].startswith("acc_el1") for m in man["memories"]) > 0


@pytest.mark.hdl
def test_a_spare_lane_is_named_with_the_options_of_one_fewer(tmp_path):
    """gravity-2d-linear has fewer nodes than elements: one element lane's items outlast one node lane's
    retirement, so a second node lane buys nothing, and `rheo verilog` says so."""
    r = _rheo("verilog", "gravity-2d-linear", "--out", str(tmp_path), "--lanes", "1", "--node-lanes", "2",
              "--core", "stream")
    assert r.returncode == 0, r.stderr
    man = json.loads((tmp_path / "manifest.json").read_text())
    assert man["nodes"] < man["elements"]
    assert [s["lanes"] for s in man["spare_lanes"]] == ["node_lanes_Q"]
    assert man["spare_lanes"][0]["period_T"] <= man["cycles_per_step"]["value"]
    assert "note: one node lane fewer (--lanes 1 --pair-lanes 1 --node-lanes 1)" in r.stdout, r.stdout


@pytest.mark.hdl
def test_full_featured_3d_build_has_every_unit_even_with_friction_that_never_slides():
    """The full-feature yardstick of a 3D scene at rest: its floor friction never slides in the range
    run, yet its 1/|k_f v_t| unit must get a format and the core must elaborate (it once raised KeyError)."""
    import dataclasses
    from hw import emit
    from hw.bittrue import BitTrue
    from hw.core import CoreConfig, schedule
    from sim.cli.common import load_system as _load_system
    base = dataclasses.replace(_load_system("gravity-3d-linear"), n_steps=20)
    bt = BitTrue(emit.full_featured(base), "narrow")
    assert {"finv", "cinv2", "tinv2", "phi", "psi"} <= set(bt.ar.units)
    assert bt.formats["finv"].width == bt.formats.preset.operand          # an operand like any other
    timing = schedule(CoreConfig.of(bt))
    assert timing["cycles_per_step"] > base.n_elements
