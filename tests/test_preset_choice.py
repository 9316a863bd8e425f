"""--preset auto (issue 15: defaults do not trade accuracy for speed silently): the narrowest format preset
whose bit-true run stays within 1e-3 of the object size of golden, said with the errors that decided it.
Expected choices come from bit-true and golden runs made here, not from the chooser."""
from __future__ import annotations

import numpy as np
import pytest

from golden.model import simulate
from hw.bittrue import BitTrue
from sim.backends import PRESET_BUDGET, narrowest_preset
from sim.bench import square_system
from sim.cli import build_parser

from conftest import scene_system


def _error(system, preset, steps):
    every = max(1, steps // 50)
    gold = simulate(system, steps=steps, every=every)
    run = simulate(system, steps=steps, every=every, stepper=BitTrue(system, preset, range_steps=steps))
    return np.abs(run.x - gold.x).max() / np.ptp(system.x0, axis=0).max()


def test_a_preset_that_cannot_run_the_scene_is_passed_over():
    """The benchmark square under narrow: x's 61 um LSB saturates every element's strain from the first
    step (a runaway), so the choice is medium, within the budget."""
    system = square_system(300)
    with pytest.raises(Exception, match="runaway saturations"):
        _error(system, "narrow", system.n_steps)
    preset, err, why = narrowest_preset(system)
    assert preset == "medium" and err == pytest.approx(_error(system, "medium", system.n_steps), rel=1e-9)
    assert err <= PRESET_BUDGET and "narrow cannot run it" in why and "the narrowest within" in why


@pytest.mark.parametrize("budget", [1e-4, 1e-2, 0.5])
def test_the_first_preset_within_the_budget_is_chosen(budget):
    system = scene_system("gravity-2d-linear")
    steps = 600
    errors = {p: _error(system, p, steps) for p in ("narrow", "medium", "wide")}
    expected = next((p for p in ("narrow", "medium", "wide") if errors[p] <= budget), "wide")
    preset, err, why = narrowest_preset(system, steps=steps, budget=budget)
    assert preset == expected and err == pytest.approx(errors[preset], rel=1e-9)
    assert ("no preset is within" in why) == (errors[expected] > budget)


def test_synth_and_bench_default_to_auto():
    parser = build_parser()
    assert parser.parse_args(["synth", "press-2d-rheological", "--out", "d"]).preset == "auto"
    assert parser.parse_args(["bench", "--backend", "fpga"]).preset is None        # bench: auto for fpga
    assert parser.parse_args(["synth", "press-2d-rheological", "--out", "d", "--preset", "wide"]).preset == "wide"
