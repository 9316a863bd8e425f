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
from .formats import PRESETS, FormatSet, derive
from .units import HardwareUnits

FRICTION_SCALE_HEADROOM = 2.0 ** 8
RSQRT_INPUTS = {"inv_l": "l2", "tinv": "tl2", "tinv2": "tl4", "finv": "fmag2", "cinv": "cl2", "cinv2": "cl4"}


def float_state(sys: System, units: HardwareUnits, x, v, a, f_prev=None, step_no=0) -> HwState:
    X = units.length(x)
    U = units.velocity(v)
    fp = np.zeros(sys.n_elements) if f_prev is None else f_prev
    return HwState([X[:, k].copy() for k in range(sys.dim)], [U[:, k].copy() for k in range(sys.dim)],
                   np.asarray(a, float).copy(), fp, step_no)


def range_analysis(sys: System, params: Params, units: HardwareUnits, steps: int | None = None) -> dict:
    """Peak |value| of every datapath quantity over every step of the float datapath.

    The float datapath equals the golden model up to float rounding (tests/test_datapath.py), so this
    is the range analysis of a golden run, including short transients such as impacts.
    """
    ar = FloatArith()
    st = float_state(sys, units, sys.x0, sys.v0, sys.a0)
    for _ in range(sys.n_steps if steps is None else steps):
        st = step(ar, st, params)
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
    if params.damper is not None:      # the tables span the whole curve, whatever the run visited
        dp = params.damper
        peaks["c2"] = max(peaks.get("c2", 0.0), dp.c1 + dp.c_max)
        peaks["ic12"] = max(peaks.get("ic12", 0.0), 1.0 / (dp.c1 + dp.c_min))
        peaks["force"] = max(peaks.get("force", 0.0), dp.f2)
    return peaks


def function_units(fmt: FormatSet, params: Params) -> dict:
    from .funcunits import DamperTable, Rsqrt
    pre = fmt.preset
    units = {}
    for out, inp in RSQRT_INPUTS.items():
        if out in fmt and inp in fmt:
            units[out] = Rsqrt(fmt[inp], fmt[out], seed_bits=pre.rsqrt_seed_bits, newton_steps=pre.rsqrt_newton,
                               name=out)
    if params.damper is not None:
        dp = params.damper
        units["damper"] = DamperTable(fmt["force"], fmt["c2"], fmt["ic12"], dp.c1, dp.c_min, dp.c_max,
                                      dp.f1, dp.f2, segments_log2=pre.damper_segments_log2)
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
            peaks = range_analysis(sys, self.params, self.units, range_steps)
            formats = derive(peaks, PRESETS[preset], {**sys.formats, **(overrides or {})})
        self.formats = formats
        self.sat = Saturations()          # saturations of the run (what the hardware counts)
        self.const_sat = Saturations()    # saturations converting constants and the initial state
        self.ar = FixedArith(formats, function_units(formats, self.params), self.sat, self.const_sat)

    def initial_state(self) -> HwState:
        sys, fm = self.sys, self.formats
        X = self.units.length(sys.x0)
        U = self.units.velocity(sys.v0)
        return HwState([fm["x"].from_float(X[:, k], self.const_sat, "x") for k in range(sys.dim)],
                       [fm["u"].from_float(U[:, k], self.const_sat, "u") for k in range(sys.dim)],
                       fm["a"].from_float(sys.a0, self.const_sat, "a"),
                       np.zeros(sys.n_elements, np.int64), 0)

    def step(self, st: HwState) -> None:
        new = step(self.ar, st, self.params)
        st.X, st.U, st.A, st.FP, st.step = new.X, new.U, new.A, new.FP, new.step

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
