"""Shared, cached test fixtures: scene systems and their derived number formats (range analysis is
the slow part of building a bit-true model, and several test files need the same ones)."""
from __future__ import annotations

import functools
import os
import shutil
import tempfile

import pytest

from golden.scene import load_scene


def pytest_configure(config):
    """One store of range analyses for the session (hw/bittrue.py RHEO_RANGE_STORE), shared by its xdist
    workers and the commands they start: a scene's analysis runs once, not once per process and preset."""
    from hw.bittrue import RANGE_STORE_VARIABLE
    worker = getattr(config, "workerinput", None)
    if worker is None:
        config.rheo_range_store = tempfile.mkdtemp(prefix="rheo-ranges-")
    os.environ[RANGE_STORE_VARIABLE] = worker["rheo_range_store"] if worker else config.rheo_range_store


@pytest.hookimpl(optionalhook=True)
def pytest_configure_node(node):          # pytest-xdist, in the controller: hand the store to a worker
    node.workerinput["rheo_range_store"] = node.config.rheo_range_store


def pytest_unconfigure(config):
    if getattr(config, "workerinput", None) is None:
        shutil.rmtree(config.rheo_range_store, ignore_errors=True)


def sweep(candidates, representative: dict) -> list:
    """The built-in scenes a per-scene test takes: `candidates` (every scene it applies to) with
    RHEO_ALL_SCENES=1, else those of them in `representative` ({scene: what it covers that the others do
    not}), so that `make test` stays within CI's hour."""
    missing = set(representative) - set(candidates)
    assert not missing, f"representative scenes the test does not apply to: {sorted(missing)}"
    return list(candidates) if os.environ.get("RHEO_ALL_SCENES") else [n for n in candidates if n in representative]


@pytest.fixture(autouse=True)
def fast_verilator_builds(monkeypatch, request):
    """Verilator's C++ at -O0 for every test and the `rheo` commands they start: the builds of large cores
    are most of an HDL test's time (minutes at -Os), the simulated runs short. A test marked
    optimised_verilator keeps -Os: the 3D collision core built in 1 minute at -O0 but ran its 159,000 cycles
    in 578 s (67 s at -Os, built in 7 minutes)."""
    flags = os.environ.get("MAKEFLAGS", "")
    if "OPT_FAST" not in flags and request.node.get_closest_marker("optimised_verilator") is None:
        monkeypatch.setenv("MAKEFLAGS", (flags + " OPT_FAST=-O0 OPT_SLOW=-O0 OPT_GLOBAL=-O0").strip())


@functools.lru_cache(maxsize=None)
def scene_system(name: str):
    return load_scene(name)


@functools.lru_cache(maxsize=None)
def formats(name: str, preset: str):
    """The formats `rheo simulate --backend fixed` derives for a built-in scene (full range analysis, once a
    session: hw/bittrue.py scene_ranges)."""
    from hw.bittrue import BitTrue
    return BitTrue(scene_system(name), preset).formats


def bittrue(name: str, preset: str):
    """A fresh bit-true model of a built-in scene with the cached formats."""
    from hw.bittrue import BitTrue
    return BitTrue(scene_system(name), preset, formats=formats(name, preset))
