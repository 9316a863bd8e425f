"""Smoke test of the simulator machinery (sim/simulators.py) on Icarus and Verilator.

An 8-bit Amaranth counter is converted to Verilog and exercised by the cocotb module
tests/cocotb_smoke.py on both simulators. A missing simulator is a FAILURE
(SimulatorMissing propagates), never a skip: run `make verilator` once per machine.
"""

import stat
from pathlib import Path

import pytest
from amaranth.back import verilog
from amaranth.hdl import Module
from amaranth.lib import wiring
from amaranth.lib.wiring import In, Out

from sim import simulators
from sim.simulators import SimulatorMissing, find_verilator, run_cocotb

TESTS_DIR = Path(__file__).resolve().parent


class Counter8(wiring.Component):
    en: In(1)
    clr: In(1)
    count: Out(8)

    def elaborate(self, platform):
        m = Module()
        with m.If(self.clr):
            m.d.sync += self.count.eq(0)
        with m.Elif(self.en):
            m.d.sync += self.count.eq(self.count + 1)
        return m


@pytest.fixture(scope="module")
def counter_verilog(tmp_path_factory) -> Path:
    top = Counter8()
    text = verilog.convert(top, name="counter8", ports=None)
    path = tmp_path_factory.mktemp("counter8") / "counter8.v"
    path.write_text(text)
    return path


@pytest.mark.parametrize("simulator", ["icarus", "verilator"])
def test_counter_on_simulator(simulator, counter_verilog, tmp_path_factory):
    build_dir = tmp_path_factory.mktemp(f"build_{simulator}")
    kwargs = dict(
        simulator=simulator,
        verilog_sources=[counter_verilog],
        toplevel="counter8",
        test_module="cocotb_smoke",
        test_dir=TESTS_DIR,
        build_dir=build_dir,
        extra_env={"SMOKE_N": "37"},
        timeout_s=300,
    )
    res = run_cocotb(**kwargs)
    assert res == {"tests": 2, "failures": 0, "results_xml": build_dir / "results.xml"}

    # Second run reuses the build (stamp unchanged) and honours `testcase`.
    product = build_dir / ("sim.vvp" if simulator == "icarus" else "counter8")
    mtime = product.stat().st_mtime_ns
    res = run_cocotb(**{**kwargs, "testcase": "clear_and_wrap"})
    assert res["tests"] == 1
    assert product.stat().st_mtime_ns == mtime, "build was not reused"


def test_failing_cocotb_test_raises(counter_verilog, tmp_path_factory):
    build_dir = tmp_path_factory.mktemp("build_fail")
    with pytest.raises(RuntimeError, match=r"failed tests: counts_when_enabled"):
        run_cocotb(
            simulator="icarus",
            verilog_sources=[counter_verilog],
            toplevel="counter8",
            test_module="cocotb_smoke",
            test_dir=TESTS_DIR,
            build_dir=build_dir,
            extra_env={"SMOKE_N": "-1"},  # expected count -1 % 256 = 255: wrong
            testcase="counts_when_enabled",
        )


def _fake_verilator(directory: Path, version: str) -> Path:
    directory.mkdir(parents=True, exist_ok=True)
    exe = directory / "verilator"
    exe.write_text(f"#!/bin/sh\necho 'Verilator {version} 2025-01-01 rev fake'\n")
    exe.chmod(exe.stat().st_mode | stat.S_IXUSR | stat.S_IXGRP | stat.S_IXOTH)
    return exe


def test_find_verilator_missing_says_make_verilator(monkeypatch, tmp_path):
    # Only an old (Debian bookworm-like) verilator on PATH, nothing in the cache.
    old_dir = tmp_path / "oldbin"
    _fake_verilator(old_dir, "5.006")
    monkeypatch.setenv("RHEO_VERILATOR", "/nonexistent")
    monkeypatch.setenv("RHEO_CACHE", str(tmp_path / "empty"))
    monkeypatch.setenv("PATH", str(old_dir))
    with pytest.raises(SimulatorMissing) as exc:
        find_verilator()
    msg = str(exc.value)
    assert "make verilator" in msg
    assert "5.006" in msg and "too old" in msg
    assert "/nonexistent does not exist" in msg

    # ... and run_cocotb propagates it instead of skipping.
    with pytest.raises(SimulatorMissing):
        run_cocotb(
            simulator="verilator", verilog_sources=[], toplevel="x",
            test_module="cocotb_smoke", test_dir=TESTS_DIR, build_dir=tmp_path / "b",
        )


def test_find_verilator_order(monkeypatch, tmp_path):
    env_bin = _fake_verilator(tmp_path / "env", "5.040")
    cache_bin = _fake_verilator(tmp_path / "cache" / "verilator-5.048" / "bin", "5.048")
    path_dir = tmp_path / "pathbin"
    _fake_verilator(path_dir, "5.036")
    monkeypatch.setenv("PATH", str(path_dir))
    monkeypatch.setenv("RHEO_CACHE", str(tmp_path / "cache"))
    monkeypatch.setenv("RHEO_VERILATOR", str(env_bin))
    assert find_verilator() == str(env_bin)
    monkeypatch.delenv("RHEO_VERILATOR")
    assert find_verilator() == str(cache_bin)
    monkeypatch.setenv("RHEO_CACHE", str(tmp_path / "nocache"))
    assert find_verilator() == str(path_dir / "verilator")


def test_find_icarus_missing(monkeypatch, tmp_path):
    monkeypatch.setenv("PATH", str(tmp_path))
    with pytest.raises(SimulatorMissing, match="apt-get install iverilog"):
        simulators.find_icarus()
