"""The bit-true model: the hardware's step (hw/datapath.py) in NumPy integers with the scene's formats.

`BitTrue(system, preset)` derives the number formats (range analysis of the float datapath over a golden
run, hw/formats.py), builds the function units (hw/funcunits.py) and steps raw integer states exactly
as the hardware will. It plugs into `golden.model.simulate` as a stepper; frames come back in SI units,
and the raw states and saturation counts are kept for the run file.
"""
from __future__ import annotations

import numpy as np

from golden.model import SimulationDiverged, System, simulate
from .arith import FixedArith, FloatArith
from .datapath import HwState, Params, step
from .fixed import Saturations
from .formats import PRESETS, FormatError, FormatSet, derive
from .units import HardwareUnits

FRICTION_SCALE_HEADROOM = 2.0 ** 8
RSQRT_INPUTS = {"inv_l": "l2", "tinv": "tl2", "tinv2": "tl4", "finv": "fmag2", "cinv": "cl2", "cinv2": "cl4"}


def float_state(sys: System, units: HardwareUnits, x, v, a, step_no=0) -> HwState:
    X = units.length(x)
    U = units.velocity(v)
    return HwState([X[:, k].copy() for k in range(sys.dim)], [U[:, k].copy() for k in range(sys.dim)],
                   np.asarray(a, float).copy(), step_no)


def range_analysis(sys: System, params: Params, units: HardwareUnits, steps: int | None = None):
    """Peak |value| of every datapath quantity over every step of the float datapath, and the typical
    per-step increment of each state (x, u, a: the median over steps of the largest increment of any item).

    The float datapath equals the golden model up to float rounding (tests/test_datapath.py), so this
    is the range analysis of a golden run, including short transients such as impacts.
    Returns (peaks, increments).
    """
    ar = FloatArith()
    st = float_state(sys, units, sys.x0, sys.v0, sys.a0)
    n = sys.n_steps if steps is None else steps
    inc = {q: np.zeros(n) for q in ("x", "u", "a")}
    for k in range(n):
        new = step(ar, st, params)
        inc["x"][k] = max(float(np.max(np.abs(u))) for u in new.U)
        inc["u"][k] = max(float(np.max(np.abs(u1 - u0))) for u0, u1 in zip(st.U, new.U))
        inc["a"][k] = float(np.max(np.abs(new.A - st.A))) if new.A.size else 0.0
        st = new
    increments = {q: _typical_increment(v) for q, v in inc.items() if n and not (q == "a" and params.fixed_a)}
    peaks = dict(ar.peak)
    # quantities the run never reached (a contact that never happens) still need formats: take their
    # ranges from one step of the initial state with every gate open
    probe = FloatArith(open_gates=True)
    step(probe, float_state(sys, units, sys.x0, sys.v0, sys.a0), params)
    for q, v in probe.peak.items():
        peaks.setdefault(q, v)
    # the 3D friction scale 1/|k_f v_t| is formed only while sliding, which a scene at rest never does in
    # the probe: its range is then that of 1/sqrt(peak |k_f v_t|^2), with headroom for smaller inputs
    if "fmag2" in peaks and "finv" not in peaks:
        peaks["finv"] = FRICTION_SCALE_HEADROOM / np.sqrt(max(peaks["fmag2"], np.finfo(float).tiny))
    return peaks, increments


MOTION_FRACTION = 1e-3     # steps whose largest increment is below this fraction of the run's peak are at rest


def _typical_increment(per_step: np.ndarray) -> float:
    """The median of the per-step largest increments over the steps in motion (an object at rest, whose
    increments decay below any LSB, is not stagnating)."""
    moving = per_step[per_step >= MOTION_FRACTION * per_step.max()] if per_step.size else per_step
    return float(np.median(moving)) if moving.size else 0.0


PSI_EXTRA_SEGMENTS_LOG2 = 4    # Psi's input W spans f1 / c_max .. f2 / c_min (c_max / c_min ~ 1000): 16x the
                                # segments keep its steep start within a fraction of a per cent


def _segments(table: str, preset) -> int:
    return min(12, preset.damper_segments_log2 + (PSI_EXTRA_SEGMENTS_LOG2 if table == "psi" else 0))


def function_units(fmt: FormatSet, params: Params) -> dict:
    """The bit-true function units of the formats: 1/sqrt per RSQRT_INPUTS quantity, the damper's tables.

    A 1/sqrt is a table (RsqrtTable, one multiplier) when the preset asks for one and its internal relative
    error bound is at most 2^-W for the output's width W (the relative size of the output's own rounding,
    half an LSB, at the top of its range), otherwise Newton (Rsqrt: three to four multipliers a step)."""
    from .funcunits import InverseTable, Rsqrt, RsqrtTable
    pre = fmt.preset
    units = {}
    for out, inp in RSQRT_INPUTS.items():
        if out in fmt and inp in fmt:
            unit = None
            if pre.rsqrt_table_segments_log2:
                unit = RsqrtTable(fmt[inp], fmt[out], segments_log2=pre.rsqrt_table_segments_log2, name=out)
                if unit.internal_relative_error_bound() > 2.0 ** -fmt[out].width:
                    unit = None
            units[out] = unit or Rsqrt(fmt[inp], fmt[out], seed_bits=pre.rsqrt_seed_bits,
                                       newton_steps=pre.rsqrt_newton, name=out)
    for name, curve in params.curves.items():
        if all(q in fmt for q in (curve.input, *curve.outputs)):
            units[name] = InverseTable(fmt[curve.input], [fmt[q] for q in curve.outputs], curve,
                                       segments_log2=_segments(name, pre))
    return units


class BitTrue:
    """Steps a System bit for bit as the hardware does."""

    def __init__(self, sys: System, preset: str = "wide", formats: FormatSet | None = None,
                 overrides: dict | None = None, range_steps: int | None = None):
        if preset not in PRESETS:
            raise ValueError(f"unknown format preset '{preset}' (known: {', '.join(PRESETS)})")
        self.sys = sys
        self.units = HardwareUnits.of(sys)
        self.params = Params.of(sys, self.units)
        if formats is None:
            peaks, increments = range_analysis(sys, self.params, self.units, range_steps)
            formats = derive(peaks, PRESETS[preset], {**sys.formats, **(overrides or {})}, increments)
        self.formats = formats
        self.preset = preset
        self.sat = Saturations()          # saturations of the run (what the hardware counts)
        self.const_sat = Saturations()    # saturations converting constants and the initial state
        self.ar = FixedArith(formats, function_units(formats, self.params), self.sat, self.const_sat)
        self._check_representable()

    def _check_representable(self):
        """Refuse formats under which a constant or the initial state saturates or rounds to nothing: one
        dry step on a throw-away arithmetic converts every constant the datapath uses."""
        dry = FixedArith(self.formats, self.ar.units, Saturations(), Saturations(), Saturations())
        step(dry, self.initial_state(dry), self.params)
        bad = [(q, f"{q} saturates ({n} value{'s' * (n > 1)})") for q, n in dry.const_sat.most_common()]
        bad += [(q, f"{q} rounds to zero ({n} value{'s' * (n > 1)})") for q, n in dry.lost.most_common()]
        if bad:
            fmt = ", ".join(f"{q} = {self.formats[q]}" for q in dict.fromkeys(q for q, _ in bad) if q in self.formats)
            raise FormatError(f"scene '{self.sys.name}', preset {self.preset}: the number formats cannot hold "
                              f"the scene's constants or initial state: {'; '.join(m for _, m in bad)} "
                              f"(formats: {fmt}); use a wider preset or fix the [formats] table")

    def stagnation_messages(self) -> list[str]:
        """One warning per stagnating state (FormatSet.stagnation), with the increment and LSB in SI units."""
        si = {"x": (self.units.to_length, "m"), "u": (self.units.to_velocity, "m/s")}
        out = []
        for f in self.formats.stagnation():
            q = f["quantity"]
            conv, unit = si.get(q, (lambda v: v, ""))
            out.append(f"scene '{self.sys.name}', preset {self.preset}: {q} stagnates: its typical increment "
                       f"{f['what']}, {float(conv(f['increment'])):.3g}{' ' + unit if unit else ''}, is "
                       f"{f['lsbs']:.2g} LSB of its format {self.formats[q]} (LSB "
                       f"{float(conv(f['lsb'])):.3g}{' ' + unit if unit else ''}): round to nearest loses that "
                       f"motion; use a wider preset, a larger dt or a [formats] override")
        return out

    def initial_state(self, ar: FixedArith | None = None) -> HwState:
        sys = self.sys
        X = self.units.length(sys.x0)
        U = self.units.velocity(sys.v0)
        conv = (ar or self.ar).convert_constant
        return HwState([conv("x", X[:, k]) for k in range(sys.dim)], [conv("u", U[:, k]) for k in range(sys.dim)],
                       conv("a", sys.a0), 0)

    def step(self, st: HwState) -> None:
        new = step(self.ar, st, self.params)
        st.X, st.U, st.A, st.step = new.X, new.U, new.A, new.step

    def frame(self, st: HwState):
        fm = self.formats
        x = np.stack([self.units.to_length(fm["x"].to_float(c)) for c in st.X], 1)
        v = np.stack([self.units.to_velocity(fm["u"].to_float(c)) for c in st.U], 1)
        return x, v, fm["a"].to_float(st.A)

    def raw(self, st: HwState):
        return np.stack(st.X, 1), np.stack(st.U, 1), np.asarray(st.A).copy()


RUNAWAY_FRACTION = 0.01     # saturations per node and element update that count as a runaway


def check_saturations(bt: "BitTrue", steps: int, new: int, preset: str) -> None:
    """Stop a run whose saturations run away: more than 1 % of the updates of an output interval."""
    sys = bt.sys
    limit = max(16, RUNAWAY_FRACTION * (sys.n_nodes + sys.n_elements) * max(steps, 1))
    if new > limit:
        top = ", ".join(f"{q} {n}" for q, n in bt.sat.most_common(3))
        raise SimulationDiverged(
            f"scene '{sys.name}': runaway saturations in the bit-true model (preset {preset}): {new} in the "
            f"last {steps} steps (so far: {top}); the formats cannot hold this run: use a wider preset, "
            f"override formats in [formats], or reduce dt")


def simulate_fixed(sys: System, preset="wide", steps=None, every=None, progress=False, bittrue=None):
    """Run the bit-true model; returns (Run in SI units, raw frames dict, BitTrue)."""
    bt = bittrue or BitTrue(sys, preset, range_steps=max(sys.n_steps, steps or 0))
    raws = {"x_raw": [], "v_raw": [], "a_raw": [], "saturations": []}
    last = {"step": 0, "sat": 0}

    class Recorder:
        def initial_state(self):
            return bt.initial_state()

        def step(self, st):
            bt.step(st)

        def frame(self, st):
            check_saturations(bt, st.step - last["step"], bt.sat.total - last["sat"], preset)
            last["step"], last["sat"] = st.step, bt.sat.total
            x, u, a = bt.raw(st)
            raws["x_raw"].append(x)
            raws["v_raw"].append(u)
            raws["a_raw"].append(a)
            raws["saturations"].append(bt.sat.total)
            return bt.frame(st)

    run = simulate(sys, steps=steps, every=every, progress=progress, stepper=Recorder())
    return run, {k: np.asarray(v) for k, v in raws.items()}, bt
