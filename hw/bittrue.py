"""The bit-true model: the hardware's step (hw/datapath.py) in NumPy integers with the scene's formats.

`BitTrue(system, preset)` derives the number formats (range analysis of the float datapath over a golden
run, hw/formats.py), builds the function units (hw/funcunits.py) and steps raw integer states exactly
as the hardware will. It is a `golden.model.Stepper`: `simulate(system, stepper=BitTrue(...))` runs it,
frames come back in SI units, and the run keeps the raw states and saturation counts of every frame
(`Run.raw`) and the formats and counts of the run (`Run.info`) for the run file. `FloatDatapath` is the
same step in float64 (the range analysis' run).
"""
from __future__ import annotations

import copy
import functools
import hashlib
import json
import os
import pickle
from pathlib import Path

import numpy as np

from golden.errors import BadArgument, SimulationDiverged
from golden.model import Stepper
from golden.system import System
from .arith import FixedArith, FloatArith
from .datapath import HwProbe, HwState, Params, probe_hold, probe_initial, step
from .fixed import Saturations
from .formats import FORMAT_PRESETS, FormatError, FormatSet, derive
from .units import HardwareUnits

FRICTION_SCALE_HEADROOM = 2.0 ** 8
RSQRT_INPUTS = {"inv_l": "l2", "tinv": "tl2", "tinv2": "tl4", "finv": "fmag2", "cinv": "cl2", "cinv2": "cl4",
                "pinv": "pr2", "pfinv": "pfmag2"}


def float_state(system: System, units: HardwareUnits, x, v, a, step_no=0, probe=None) -> HwState:
    """A state in float hardware units; `probe`: the golden ProbeState to take the probe's registers from
    (default: at its initial position, at rest)."""
    X = units.length(x)
    U = units.velocity(v)
    hp = None
    if system.probe is not None:
        from golden.probe import ProbeState
        gp = probe if probe is not None else ProbeState.initial(system.probe)
        P, R = units.length(gp.p), float(units.length(system.probe.radius))
        hp = HwProbe(list(P), list(units.velocity(gp.pdot)), list(P - R), list(P + R), [0.0] * system.dim,
                     driven=gp.driven, node_F=[np.zeros(0)] * system.dim)
    return HwState([X[:, k].copy() for k in range(system.dim)], [U[:, k].copy() for k in range(system.dim)],
                   np.asarray(a, float).copy(), step_no, hp)


RANGE_STORE_VARIABLE = "RHEO_RANGE_STORE"
"""An environment variable naming a directory where scene_ranges keeps its results for other processes (the
test suite sets it for its session, so that its workers and the commands they start share one analysis per
scene). The key holds the scene and the code of golden/ and hw/, so a kept result never outlives its code."""
_RANGES_KEPT = 64          # range analyses remembered in this process (a few numbers per quantity each)
_ranges_memo: dict[str, tuple] = {}


def scene_ranges(system: System, steps: int | None = None):
    """range_analysis of a scene: (peaks, increments), shared by the bit-true models of every preset.

    Computed once per scene content and step count (a run of the float datapath over the whole scene,
    the slow part of building a bit-true model), then remembered (Params and HardwareUnits are functions
    of the system)."""
    steps = system.n_steps if steps is None else steps
    key = hashlib.sha256(pickle.dumps((system, steps, _code_digest()))).hexdigest()[:24]
    if key not in _ranges_memo:
        _ranges_memo[key] = _stored(key, lambda: _analyse(system, steps))
        while len(_ranges_memo) > _RANGES_KEPT:
            del _ranges_memo[next(iter(_ranges_memo))]
    return copy.deepcopy(_ranges_memo[key])


def _analyse(system: System, steps: int):
    units = HardwareUnits.of(system)
    return range_analysis(system, Params.of(system, units), units, steps)


@functools.lru_cache(maxsize=None)
def _code_digest() -> str:
    """A digest of the code a range analysis runs (every module of golden/ and hw/)."""
    root = Path(__file__).resolve().parents[1]
    h = hashlib.sha256()
    for path in sorted(p for d in ("golden", "hw") for p in (root / d).rglob("*.py")):
        h.update(path.relative_to(root).as_posix().encode() + b"\0" + path.read_bytes())
    return h.hexdigest()


def _stored(key: str, compute):
    """compute(), or its result from the directory RHEO_RANGE_STORE names (one process computes it while the
    others wait)."""
    if not os.environ.get(RANGE_STORE_VARIABLE):
        return compute()
    import fcntl
    store = Path(os.environ[RANGE_STORE_VARIABLE])
    store.mkdir(parents=True, exist_ok=True)
    path = store / f"{key}.pickle"
    with open(store / f"{key}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if path.exists():
            return pickle.loads(path.read_bytes())
        result = compute()
        tmp = path.with_suffix(f".{os.getpid()}.tmp")
        try:
            tmp.write_bytes(pickle.dumps(result))
            os.replace(tmp, path)
        finally:
            tmp.unlink(missing_ok=True)      # an interrupted write leaves nothing behind
        return result


def range_analysis(system: System, params: Params, units: HardwareUnits, steps: int | None = None):
    """Peak |value| of every datapath quantity over every step of the float datapath, and the typical
    per-step increment of each state (x, u, a: the median over steps of the largest increment of any item).

    The float datapath equals the golden model up to float rounding (tests/test_datapath.py), so this
    is the range analysis of a golden run, including short transients such as impacts.
    Returns (peaks, increments).
    """
    ar = FloatArith()
    st = float_state(system, units, system.x0, system.v0, system.a0)
    n = system.n_steps if steps is None else steps
    inc = {q: np.zeros(n) for q in ("x", "u", "a")}
    for k in range(n):
        new = step(ar, st, params)
        inc["x"][k] = max(float(np.max(np.abs(u))) for u in new.U)
        inc["u"][k] = max(float(np.max(np.abs(u1 - u0))) for u0, u1 in zip(st.U, new.U))
        inc["a"][k] = float(np.max(np.abs(new.A - st.A))) if new.A.size else 0.0
        st = new
    increments = {q: _typical_increment(v) for q, v in inc.items() if n and not (q == "a" and params.fixed_a)}
    peaks = dict(ar.peak)
    if params.probe is not None:
        # the probe's geometry has known ranges: inside its box |x_k - p_k| < R, |x - p|^2 < D R^2, d < R
        R = params.probe["R"]
        for q, v in (("pr", R), ("pr2", params.dim * R * R), ("pdist", R)):
            peaks[q] = max(peaks.get(q, 0.0), v)
    # quantities the run never reached (a contact that never happens) still need formats: take their
    # ranges from one step of the initial state with every gate open
    probe = FloatArith(open_gates=True)
    # open gates feed items outside their domain too (1/sqrt(0) of a friction force that is zero, a facet
    # of no area): inf and nan are the expected values there, and _int_bits takes a non-finite peak as no
    # range; silenced here alone so that a real overflow anywhere else still warns
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        step(probe, float_state(system, units, system.x0, system.v0, system.a0), params)
    for q, v in probe.peak.items():
        if np.isfinite(v):               # 1/sqrt(0) of an opened gate (a friction at rest) is no range
            peaks.setdefault(q, v)
    # the 3D friction scale 1/|k_f v_t| is formed only while sliding, which a scene at rest never does in
    # the probe: its range is then that of 1/sqrt(peak |k_f v_t|^2), with headroom for smaller inputs
    for mag2, inv in (("fmag2", "finv"), ("pfmag2", "pfinv")):
        if mag2 in peaks and inv not in peaks:
            peaks[inv] = FRICTION_SCALE_HEADROOM / np.sqrt(max(peaks[mag2], np.finfo(float).tiny))
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


class FloatDatapath(Stepper):
    """The hardware's step (hw/datapath.py) in float64, in hardware units: the range analysis' run, equal to
    the golden model up to float rounding."""

    takes_probe = True

    def __init__(self, system: System):
        self.system, self.units = system, HardwareUnits.of(system)
        self.params, self.ar = Params.of(system, self.units), FloatArith()

    def initial_state(self) -> HwState:
        return float_state(self.system, self.units, self.system.x0, self.system.v0, self.system.a0)

    def step(self, st: HwState) -> None:
        new = step(self.ar, st, self.params)
        st.X, st.U, st.A, st.step, st.probe = new.X, new.U, new.A, new.step, new.probe

    def frame(self, st: HwState):
        x = np.stack([self.units.to_length(c) for c in st.X], 1)
        v = np.stack([self.units.to_velocity(c) for c in st.U], 1)
        return x, v, np.asarray(st.A, float)

    def hold_probe(self, st: HwState, p) -> None:
        st.probe.driven = True
        probe_hold(self.ar, self.params, st.probe, self.units.length(p))

    def probe_reading(self, st: HwState) -> tuple:
        return self.units.to_force(np.asarray(st.probe.F, float)), st.probe.contacts

    def probe_position(self, st: HwState):
        return None if st.probe is None else self.units.to_length(np.asarray(st.probe.P, float))


class BitTrue(Stepper):
    """Steps a System bit for bit as the hardware does."""

    takes_probe = True

    def __init__(self, system: System, preset: str = "wide", formats: FormatSet | None = None,
                 overrides: dict | None = None, range_steps: int | None = None, ranges: tuple | None = None):
        """`formats`: use these; else they are derived for `preset` from `ranges` ((peaks, increments) of
        `range_analysis`, which does not depend on the preset: several presets share one) or from a range
        analysis over `range_steps` steps (default: the scene's)."""
        if preset not in FORMAT_PRESETS:
            raise BadArgument(f"unknown format preset '{preset}' (known: {', '.join(FORMAT_PRESETS)})")
        self.system = system
        self.units = HardwareUnits.of(system)
        self.params = Params.of(system, self.units)
        if formats is None:
            peaks, increments = ranges or scene_ranges(system, range_steps)
        try:
            if formats is None:
                formats = derive(peaks, FORMAT_PRESETS[preset], {**system.formats, **(overrides or {})}, increments)
            units = function_units(formats, self.params)
        except FormatError as exc:       # a format too wide, a function unit the formats cannot make
            raise FormatError(f"scene '{system.name}', preset {preset}: no number formats for this scene: {exc}; "
                              f"use another preset or a [formats] table") from None
        self.formats = formats
        self.preset = preset
        self.sat = Saturations()          # saturations of the run (what the hardware counts)
        self.const_sat = Saturations()    # saturations converting constants and the initial state
        self.ar = FixedArith(formats, units, self.sat, self.const_sat)
        self.runaway = RunawayWatch(system, preset, self.sat)     # judged on every step (step())
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
            raise FormatError(f"scene '{self.system.name}', preset {self.preset}: the number formats cannot hold "
                              f"the scene's constants or initial state: {'; '.join(m for _, m in bad)} "
                              f"(formats: {fmt}); use a wider preset or fix the [formats] table")

    def stagnation_messages(self) -> list[str]:
        """One warning per stagnating state (FormatSet.stagnation), with the increment and LSB in SI units."""
        si = {"x": (self.units.to_length, "m"), "u": (self.units.to_velocity, "m/s")}
        out = []
        for f in self.formats.stagnation():
            q = f["quantity"]
            conv, unit = si.get(q, (lambda v: v, ""))
            out.append(f"scene '{self.system.name}', preset {self.preset}: {q} stagnates: its typical increment "
                       f"{f['what']}, {float(conv(f['increment'])):.3g}{' ' + unit if unit else ''}, is "
                       f"{f['lsbs']:.2g} LSB of its format {self.formats[q]} (LSB "
                       f"{float(conv(f['lsb'])):.3g}{' ' + unit if unit else ''}): round to nearest loses that "
                       f"motion; use a wider preset, a larger dt or a [formats] override")
        return out

    def initial_state(self, ar: FixedArith | None = None) -> HwState:
        if ar is None:
            self.runaway.start(0)
        system = self.system
        X = self.units.length(system.x0)
        U = self.units.velocity(system.v0)
        ar = ar or self.ar
        conv = ar.convert_constant
        return HwState([conv("x", X[:, k]) for k in range(system.dim)], [conv("u", U[:, k]) for k in range(system.dim)],
                       conv("a", system.a0), 0,
                       probe_initial(ar, self.params) if self.params.probe is not None else None)

    def step(self, st: HwState) -> None:
        before = self.sat.total
        new = step(self.ar, st, self.params)
        st.X, st.U, st.A, st.step, st.probe = new.X, new.U, new.A, new.step, new.probe
        self.runaway.add(st.step, self.sat.total - before)

    def hold_probe(self, st: HwState, p) -> None:
        """A device sample: the host converts p (metres) to the x format (rounded; a position the format
        cannot hold saturates and counts), and the sample kernel forms pdot and the bounding box."""
        st.probe.driven = True
        probe_hold(self.ar, self.params, st.probe, self.units.length(p))

    def probe_reading(self, st: HwState) -> tuple:
        return self.units.to_force(self.formats["fprobe"].to_float(np.asarray(st.probe.F))), st.probe.contacts

    def probe_raw(self, st: HwState) -> np.ndarray:
        """The force on the probe as raw fprobe words (what the hardware's force stream will carry)."""
        return np.asarray(st.probe.F, np.int64).copy()

    def probe_position(self, st: HwState):
        return None if st.probe is None else self.units.to_length(self.formats["x"].to_float(np.asarray(st.probe.P)))

    def frame(self, st: HwState):
        fm = self.formats
        x = np.stack([self.units.to_length(fm["x"].to_float(c)) for c in st.X], 1)
        v = np.stack([self.units.to_velocity(fm["u"].to_float(c)) for c in st.U], 1)
        return x, v, fm["a"].to_float(st.A)

    def raw(self, st: HwState):
        return np.stack(st.X, 1), np.stack(st.U, 1), np.asarray(st.A).copy()

    def record(self, st: HwState) -> dict:
        """The frame's raw words and saturation count (runaways are judged per step, not here)."""
        x, u, a = self.raw(st)
        return {"x_raw": x, "v_raw": u, "a_raw": a, "saturations": self.sat.total}

    def run_info(self) -> dict:
        """The run file's fixed-point metadata: preset, formats, stagnation findings, saturation counts per
        quantity (run time and constants) and the hardware units."""
        names = sorted(self.sat)
        return dict(preset=np.str_(self.preset), formats=np.str_(json.dumps(self.formats.to_dict())),
                    stagnation=np.str_(json.dumps(self.formats.stagnation())),
                    saturation_names=np.array(names, dtype=str),
                    saturation_counts=np.array([self.sat[n] for n in names], np.int64),
                    constant_saturations=np.str_(json.dumps(dict(self.const_sat))),
                    units=np.str_(json.dumps(self.units.to_dict())))


RUNAWAY_FRACTION = 0.01     # saturations per node and element update of a window that count as a runaway
RUNAWAY_MIN = 16            # ... and never fewer than this many in a window
RUNAWAY_WINDOW = 256        # steps: the run is judged in fixed windows [k W, (k + 1) W), whatever --every is
SUSTAINED_STEPS = RUNAWAY_WINDOW // 2   # a window with saturations on more steps than this is a runaway


class RunawayWatch:
    """Stops a run whose saturations run away, judged on fixed windows of RUNAWAY_WINDOW steps counted from
    step 0, so that the verdict does not depend on how often frames are recorded (issue 13). A window is a
    runaway when

    * its saturations exceed max(RUNAWAY_MIN, RUNAWAY_FRACTION x the node and element updates of the window)
      (a violent runaway: judged as soon as the count passes the limit), or
    * saturations happen on more than SUSTAINED_STEPS of its steps (a sustained one: a format that cannot
      hold what the scene keeps doing, e.g. an object crushed against a clamped force, a few saturations
      on every step). Known per step only where the steps are taken one at a time (the bit-true model).

    A transient blow (a few steps of saturation that the run recovers from) passes both. Steps taken many
    at a time (a simulated core between read-backs) are told with `add(step, count, steps=n)`; the caller
    never lets such a chunk cross a window boundary (`window_end`), so the count test is exact."""

    def __init__(self, system, preset: str, sat=None):
        self.system, self.preset, self.sat = system, preset, sat
        self.limit = max(RUNAWAY_MIN, RUNAWAY_FRACTION * (system.n_nodes + system.n_elements) * RUNAWAY_WINDOW)
        self.start(0)

    def start(self, step: int) -> None:
        self.window, self.count, self.steps = step // RUNAWAY_WINDOW, 0, 0

    @staticmethod
    def window_end(step: int) -> int:
        """The first step of the window after the one `step` is in."""
        return (step // RUNAWAY_WINDOW + 1) * RUNAWAY_WINDOW

    def add(self, step: int, count: int, steps: int = 1) -> None:
        """`count` saturations in the `steps` steps that ended at step `step`."""
        window = (step - 1) // RUNAWAY_WINDOW
        if window != self.window:
            self.window, self.count, self.steps = window, 0, 0
        self.count += count
        if count and steps == 1:
            self.steps += 1
        if self.count > self.limit:
            self._stop(step, f"{self.count} in steps {window * RUNAWAY_WINDOW}..{step}, over the limit of "
                             f"{self.limit:.0f} for a window of {RUNAWAY_WINDOW} steps")
        if self.steps > SUSTAINED_STEPS:
            self._stop(step, f"on {self.steps} of the steps {window * RUNAWAY_WINDOW}..{step} ({self.count} in all): "
                             f"saturating on more than half the steps of a {RUNAWAY_WINDOW}-step window")

    def _stop(self, step: int, what: str):
        top = ", ".join(f"{q} {n}" for q, n in self.sat.most_common(3)) if self.sat else "the hardware's count"
        raise SimulationDiverged(
            f"scene '{self.system.name}': runaway saturations in the bit-true model (preset {self.preset}) at "
            f"step {step}: {what} (so far: {top}); the formats cannot hold this run: use a wider preset, "
            f"override formats in [formats], or reduce dt")
