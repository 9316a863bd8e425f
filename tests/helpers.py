"""Helpers shared by the tests (plain functions; conftest.py holds the cached fixtures)."""
from __future__ import annotations

from golden.model import simulate
from hw.bittrue import BitTrue


def run_fixed(system, preset="wide", steps=None, every=None, bittrue=None):
    """The bit-true model's run of a scene: (Run, its raw per-frame arrays, the BitTrue that ran it)."""
    bt = bittrue or BitTrue(system, preset, range_steps=max(system.n_steps, steps or 0))
    run = simulate(system, steps=steps, every=every, stepper=bt)
    return run, run.raw, bt
