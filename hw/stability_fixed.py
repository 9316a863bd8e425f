"""The measured largest stable dt of the bit-true model: golden.measure.measure with a bit-true trial.

trial_fixed(system, dt, ref, steps=, max_steps=, check_every=, seed=, perturb=, preset=, bit_ref=)
        -> (stable, reason or None, steps run)
    A bit-true trial at dt is stable if and only if

    1. the golden trial at dt is stable (golden.measure.trial with the same arguments and the golden
       reference run `ref`: the scene at dt, golden.measure.with_dt, run for its duration capped at
       max_steps, or exactly `steps` steps, from the perturbed start of golden.measure._start: free nodes
       displaced by PERTURB x the scene size, seeded random). If the float physics fails, the range
       analysis has nothing to derive number formats from: the trial is unstable and its reason says so;
    2. the float datapath trial at dt is stable: the run the range analysis makes (hw/datapath.py in
       float64 arithmetic, FloatArith, from the same perturbed start) with the checks of item 3 except
       the saturation count. It equals the golden run to float rounding per step, yet on a scene that is
       sensitive near its limit its trajectory parts from golden's and may blow up where golden's does
       not (fold-2d at dt = 6.29e-4 s: apart by 1e-9 m at step 43, exploding from step 911); the
       formats derived from such a run are garbage (a DamperTable error), so: unstable, reason says so;
    3. and the bit-true run at dt passes the golden trial's checks. Its formats are derived at that dt as
       a user gets them (`rheo simulate --backend fixed`): hw.bittrue.BitTrue(scene at dt with x0 = the
       perturbed start positions, preset) runs the range analysis of the float datapath over the trial's
       steps from that start; the raw state starts from exactly those positions (rounded to the x format;
       the scene's v0, a0). Every check_every steps (25, as the golden trial) its frame in SI units
       (BitTrue.frame) gets golden.watchdog.DivergenceTest (non-finite, a node out of the box, mechanical
       energy above GROWTH x the work bound) and the comparison with a reference run (energy above LOCAL
       x the reference's local peak + FLOOR x its peak, Reference.allowed), here `bit_ref`; and its
       saturations must not run away (hw.bittrue.RunawayWatch, judged on every step over fixed windows of
       256 steps; it raises SimulationDiverged). Formats the preset cannot
       derive at dt from that stable float run (NoFormats: what `rheo simulate --backend fixed` would
       refuse at this dt) count as unstable too, reason given.

measure_fixed(system, preset="wide", yardstick="bit-true", **kw) -> dict
    golden.measure.measure with trial_fixed: same bracket from the prediction, same golden reference run
    (at dt_ref = dt_pred / 2) for conditions 1 and 2, same geometric bisection to rel_tol, same step cap.
    A bit-true trial is never stable where the golden one is not (condition 1), so a bit-true limit below
    the golden one (at the bisection's resolution) is what the datapath and its quantisation cost. The
    reference run of condition 3 (the yardstick):
    * "bit-true" (default): the bit-true model of the same preset at the golden reference's dt and length
      (formats derived at dt_ref), so that the comparison judges growth, not accuracy;
    * "golden": the golden reference run itself, so that accuracy enters the verdict.
    Why the default: narrow words stagnate (MODEL.md 8: per-step increments below half an LSB round
    away). press-2d-viscoelastic in narrow freezes after its release with a residual energy the golden
    run loses (1e-6 J at dt = 4.4e-4 s, 1.4e-5 J at 1.1e-4 s, constant for ever): against the golden
    reference every trial that reaches the release fails, and the "limit" found is the dt at which the
    step cap ends the trials before it. The residual grows as dt shrinks (the position dead band is
    |v| dt < LSB / 2), so a bit-true reference at dt_ref holds at least the trials' residual.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from golden.errors import BadArgument, RheoError, StabilityError
from golden.system import System
from golden.measure import MAX_STEPS, PERTURB, Reference, measure, reference, trial
from .bittrue import BitTrue, FloatDatapath
from .datapath import NotSupported
from .formats import FORMAT_PRESETS

YARDSTICKS = ("bit-true", "golden")


class NoFormats(RheoError, RuntimeError):
    """The preset's formats cannot be derived from a stable float run (narrow on multi-2d at dt = 2.87e-4 s:
    the damper's f2 - f1 falls below one LSB of the force format, whose integer bits follow the peak)."""


def _from_start(s: System, start) -> System:
    """The scene whose x0 is the perturbed start: range analysis and initial state begin there."""
    return dataclasses.replace(s, x0=np.ascontiguousarray(start.x))


def float_datapath_model(s: System, start):
    """The `model` hook of golden.measure._run for the float datapath."""
    return FloatDatapath(_from_start(s, start))


def bittrue_model(preset: str):
    """The `model` hook of golden.measure._run: BitTrue of the scene at dt whose x0 is the perturbed
    start, so that its range analysis and its initial state both begin where the golden trial began."""
    _check(preset, FORMAT_PRESETS, "format preset")

    def model(s: System, start):
        try:
            bt = BitTrue(_from_start(s, start), preset)
        except NotSupported:                     # a scene the bit-true model cannot run at all
            raise
        except ValueError as exc:                # derive, function units: the preset cannot hold it at dt
            raise NoFormats(f"the {preset} formats cannot be derived at dt = {s.dt:.4g} s ({exc})") from None
        return bt
    return model


def _check(value: str, known, what: str) -> None:
    if value not in known:
        raise BadArgument(f"unknown {what} '{value}' (known: {', '.join(known)})")


def trial_fixed(system: System, dt: float, ref: Reference | None = None, steps: int | None = None,
                max_steps: int = MAX_STEPS, check_every: int = 25, seed: int = 0, perturb: float = PERTURB,
                preset: str = "wide", bit_ref: Reference | None = None):
    """One bit-true trial at dt (module docstring); returns (stable, reason or None, steps run)."""
    model = bittrue_model(preset)
    args = dict(steps=steps, max_steps=max_steps, check_every=check_every, seed=seed, perturb=perturb)
    ok, why, n = trial(system, dt, ref, **args)
    if not ok:
        # the formats come from the float run, which fails here: nothing to derive them from
        return False, f"the golden trial is unstable, so no formats can be derived at this dt ({why})", n
    ok, why, n = trial(system, dt, ref, model=float_datapath_model, **args)
    if not ok:
        return False, (f"the float datapath (the range analysis' run) is unstable, so no formats can be "
                       f"derived at this dt ({why})"), n
    try:
        ok, why, n = trial(system, dt, bit_ref, model=model, **args)
    except NoFormats as exc:                     # what a user gets at this dt: no bit-true run at all
        return False, f"bit-true ({preset}): {exc}", 0
    return ok, (None if ok else f"bit-true ({preset}): {why}"), n


def bittrue_reference(system: System, ref: Reference, preset: str, check_every: int = 25, seed: int = 0,
                      perturb: float = PERTURB) -> Reference:
    """The bit-true model's energy history at the golden reference's dt and length (its last check time
    is its end: _run checks at the last step)."""
    try:
        return reference(system, ref.dt, float(ref.t[-1]), check_every, seed, perturb, model=bittrue_model(preset))
    except RuntimeError as exc:                  # unstable, or NoFormats: no yardstick, no measurement
        raise StabilityError(f"scene '{system.name}': bit-true ({preset}) reference run: {exc}") from None


def measure_fixed(system: System, preset: str = "wide", yardstick: str = "bit-true", **kw) -> dict:
    """golden.measure.measure on bit-true trials of the preset (module docstring); the keys of measure
    plus preset, yardstick and bit_ref_dt (dt of the bit-true reference run, None without one)."""
    _check(preset, FORMAT_PRESETS, "format preset")
    _check(yardstick, YARDSTICKS, "yardstick")
    own: dict = {}

    def trial_fn(s, dt, ref, **k):
        if ref is not None and yardstick == "bit-true" and "ref" not in own:
            own["ref"] = bittrue_reference(s, ref, preset)       # once, at the first trial
        return trial_fixed(s, dt, ref, preset=preset, bit_ref=own.get("ref", ref), **k)

    r = measure(system, trial_fn=trial_fn, **kw)
    return {**r, "preset": preset, "yardstick": yardstick,
            "bit_ref_dt": own["ref"].dt if "ref" in own else None}
