"""The haptic loop (MODEL.md 4b, issue 16): a host program moves the probe one device sample at a time and
reads the force the object pushes it with, on any backend that can take a probe.

    from sim.haptic import connect
    with connect("poke-2d-rheological", backend="golden") as sim:      # or cpu, fixed, amaranth, icarus, verilator
        for p in positions:                   # one device sample each (a 1 kHz device: every 1 ms)
            force, contacts = sim.step(p)     # k steps with p held; the force of the last one (N)

`step(p)` holds p (metres, the probe's centre) for the scene's k steps per sample, with the probe's
velocity pdot = (p - p_prev) / (k dt), and returns a `Reading`: the force on the probe in the last of the
k steps (minus the exact sum of its node forces: what the device renders) and how many nodes touch it.
The same code drives every backend; the fixed-point backend's readings are bit-true (`Reading.raw`: the
force words the hardware's force stream carries); "amaranth" runs each sample through the streaming core's
probe port (hw/stream/probeport.py) in Amaranth's simulator and returns the words of its force stream;
"icarus" and "verilator" the same on the emitted Verilog (a cocotb session served command by command). A backend that cannot take a probe yet refuses when
connected, with a RheoError that says so.

Also here: the trajectory CSV of `rheo haptic` (`read_trajectory`), a trajectory run recorded as a run file
(`run_trajectory`), and the design poke as a trajectory (`design_trajectory`).
"""
from __future__ import annotations

import csv
import math
import time
from pathlib import Path
from typing import NamedTuple

import numpy as np

from golden.errors import RheoError
from golden.system import System

HAPTIC_BACKENDS = ("golden", "cpu", "fixed", "amaranth", "icarus", "verilator")   # backends that take a probe
LATER: dict = {}                          # backend -> why it cannot take a probe yet


class HapticError(RheoError, ValueError):
    """A haptic session, trajectory or probe position that cannot be used; the message says why."""


class Reading(NamedTuple):
    """What one device sample returns: the force on the probe (D,) in newtons, in the last of its k steps,
    the number of nodes touching the probe, and (fixed-point backends) the force as raw fprobe words."""
    force: np.ndarray
    contacts: int
    raw: np.ndarray | None = None


def _system(scene) -> System:
    if isinstance(scene, System):
        return scene
    from sim.cli.common import load_system
    return load_system(str(scene))


def _stepper(system: System, backend: str, preset: str, bittrue):
    if backend == "golden":
        from golden.model import Golden
        return Golden(system)
    if backend == "cpu":
        from sim.cpu import Cpu
        return Cpu(system)
    if backend == "fixed":
        if bittrue is not None:
            return bittrue
        from hw.bittrue import BitTrue
        with np.errstate(over="ignore", invalid="ignore"):
            return BitTrue(system, preset)
    if backend in ("amaranth", "icarus", "verilator"):      # the streaming core's probe port, simulated
        from hw.bittrue import BitTrue
        from sim.hwsim import AmaranthCore, PortStepper
        if bittrue is None:
            with np.errstate(over="ignore", invalid="ignore"):
                bittrue = BitTrue(system, preset)
        if backend == "amaranth":
            return PortStepper(bittrue, AmaranthCore(bittrue, core="stream"))
        from sim.hdlsim import HdlCore
        return PortStepper(bittrue, HdlCore(bittrue, backend))
    if backend in LATER:
        raise HapticError(f"backend '{backend}' cannot take a probe yet: {LATER[backend]}; use golden, cpu "
                          f"or fixed")
    raise HapticError(f"unknown backend '{backend}' (haptic backends: {', '.join(HAPTIC_BACKENDS)})")


class Session:
    """One haptic loop on one backend: `step(p)` per device sample. `state` is the backend's state,
    `frame()` its (x, v, a) in SI units, `samples` the device samples done, `time` the simulated time."""

    def __init__(self, scene, backend: str = "golden", preset: str = "wide", bittrue=None):
        self.system = _system(scene)
        if self.system.probe is None:
            raise HapticError(f"scene '{self.system.name}' has no [probe] table: nothing to touch it with")
        self.backend = backend
        self.stepper = _stepper(self.system, backend, preset, bittrue)
        if not self.stepper.takes_probe:
            raise HapticError(f"backend '{backend}' cannot take a probe yet; use "
                              f"{' or '.join(b for b in HAPTIC_BACKENDS if b != backend)}")
        self.state = self.stepper.initial_state()
        self.k = self.system.probe.k
        self.samples = 0
        self.position = np.asarray(self.system.probe.position, float).copy()

    @property
    def dim(self) -> int:
        return self.system.dim

    @property
    def time(self) -> float:
        return self.state.step * self.system.dt

    def step(self, p) -> Reading:
        """One device sample: hold p (D,) in metres for k steps; the force of the last step."""
        p = np.asarray(p, float)
        if p.shape != (self.dim,) or not np.all(np.isfinite(p)):
            raise HapticError(f"a probe position is {self.dim} finite numbers (metres), got {p.tolist()!r}")
        self.stepper.hold_probe(self.state, p)
        with np.errstate(over="ignore", invalid="ignore"):
            self.stepper.advance(self.state, self.k)
        self.samples += 1
        self.position = p.copy()
        force, contacts = self.stepper.probe_reading(self.state)
        raw = self.stepper.probe_raw(self.state)
        return Reading(np.asarray(force, float), int(contacts), raw)

    def frame(self):
        """(x, v, a) of the current state in SI units."""
        return self.stepper.frame(self.state)

    def close(self) -> None:
        self.stepper.close()

    def __enter__(self) -> "Session":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def connect(scene, backend: str = "golden", preset: str = "wide", bittrue=None) -> Session:
    """A haptic session on `scene` (a built-in name, a scene file or a System with a [probe]) and `backend`
    (golden, cpu, fixed; amaranth, icarus, verilator: the streaming core's probe port, simulated); `preset`: the fixed backend's number formats (derived for the scene's design
    poke); `bittrue`: a bit-true model to use instead (its formats)."""
    return Session(scene, backend, preset, bittrue)


# ---------------------------------------------------------------------------------------------------------
# trajectories
# ---------------------------------------------------------------------------------------------------------

MAX_TRAJECTORY_ROWS = 10_000_000


def read_trajectory(path, system: System) -> np.ndarray:
    """A trajectory CSV: a header, then one row per device sample, absolute positions `x,y[,z]` (metres) or
    offsets `dx,dy[,dz]` from the scene's initial probe position. Returns (S, D) absolute positions. Every
    problem is one HapticError naming the file, and the row and column where there is one (rows count
    from the first data row, 1; lines count the header too)."""
    path = Path(path)
    D = system.dim
    names = ["x", "y", "z"][:D]
    if system.probe is None:
        raise HapticError(f"scene '{system.name}' has no [probe] table: nothing to move along {path}")
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise HapticError(f"trajectory file not found: {path}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise HapticError(f"cannot read trajectory file {path}: {exc}") from None
    rows = list(csv.reader(text.splitlines()))
    while rows and not any(c.strip() for c in rows[-1]):
        rows.pop()
    if not rows:
        raise HapticError(f"{path}: empty; expected a header ({','.join(names)} or "
                          f"{','.join('d' + n for n in names)}) and one row per device sample")
    header = [c.strip() for c in rows[0]]
    if header == names:
        offsets = False
    elif header == ["d" + n for n in names]:
        offsets = True
    else:
        raise HapticError(f"{path}: line 1: the header must be {','.join(names)} (absolute positions, m) or "
                          f"{','.join('d' + n for n in names)} (offsets from the probe's initial position, m) for "
                          f"this {D}D scene, got {','.join(header)!r}")
    data = rows[1:]
    if not data:
        raise HapticError(f"{path}: no rows after the header: one row per device sample expected")
    if len(data) > MAX_TRAJECTORY_ROWS:
        raise HapticError(f"{path}: {len(data)} rows, more than {MAX_TRAJECTORY_ROWS} device samples")
    out = np.empty((len(data), D))
    for r, row in enumerate(data, start=1):
        where = f"{path}: row {r} (line {r + 1})"
        if len(row) != D:
            raise HapticError(f"{where}: {len(row)} field(s), expected {D} ({','.join(header)})")
        for c, cell in enumerate(row):
            try:
                v = float(cell.strip())
            except ValueError:
                raise HapticError(f"{where}, column '{header[c]}': {cell.strip()!r} is not a number") from None
            if not math.isfinite(v):
                raise HapticError(f"{where}, column '{header[c]}': {cell.strip()!r} is not finite")
            out[r - 1, c] = v
    return out + system.probe.position[None, :] if offsets else out


def write_trajectory(path, positions: np.ndarray, offsets_from=None) -> Path:
    """Write positions (S, D) as a trajectory CSV (offsets from `offsets_from` when given)."""
    positions = np.asarray(positions, float)
    D = positions.shape[1]
    names = ["x", "y", "z"][:D]
    if offsets_from is not None:
        positions = positions - np.asarray(offsets_from, float)[None, :]
        names = ["d" + n for n in names]
    lines = [",".join(names)] + [",".join(f"{v:.9g}" for v in row) for row in positions]
    from sim.runfile import write_atomically
    return write_atomically(Path(path), lambda tmp: Path(tmp).write_text("\n".join(lines) + "\n"))


def design_trajectory(system: System, samples: int | None = None) -> np.ndarray:
    """The scene's design poke as absolute positions (S, D), one per device sample, over the scene's
    duration (or `samples`)."""
    pb = system.probe
    n = samples if samples is not None else max(1, system.n_steps // pb.k)
    return pb.design_path(n, system.dt)


def run_trajectory(session: Session, positions: np.ndarray, every: int | None = None, progress=None) -> dict:
    """Drive `session` along positions (S, D); record the probe per sample and a frame every `every`
    samples (default: about 200 frames; the initial state and the last sample always). Returns the run-file
    arrays of a haptic run: t, x, v, a per frame (and a fixed-point backend's raw words and saturation
    counts), and probe_t, probe_p, probe_force, probe_contacts (and probe_force_raw on fixed-point
    backends) per sample. Every frame is checked by the divergence watchdog (and a fixed-point backend's
    saturations for a runaway)."""
    from golden.watchdog import EnergyWatch
    from golden.system import State
    positions = np.asarray(positions, float)
    S, D = positions.shape
    every = max(1, every if every is not None else S // 200)
    system = session.system
    watch = EnergyWatch(system)
    frames_at = sorted(set(range(0, S + 1, every)) | {S})
    n_frames = len(frames_at)
    x = np.empty((n_frames,) + system.x0.shape)
    v = np.empty_like(x)
    a = np.empty((n_frames, system.n_elements))
    t = np.empty(n_frames)
    force = np.empty((S, D))
    contacts = np.empty(S, np.int64)
    raw, per_frame = [], {}
    f = 0

    def record(done):
        nonlocal f
        x[f], v[f], a[f] = session.frame()
        t[f] = session.time
        watch.check(State(x[f], v[f], a[f], session.state.step), session.position)
        for key, val in session.stepper.record(session.state).items():     # raw words; runaway saturations stop
            per_frame.setdefault(key, []).append(val)
        f += 1

    record(0)
    t0 = time.perf_counter()
    for s in range(S):
        r = session.step(positions[s])
        force[s], contacts[s] = r.force, r.contacts
        if r.raw is not None:
            raw.append(r.raw)
        if s + 1 == frames_at[f]:
            record(s + 1)
        if progress is not None:
            progress(1)
    wall = time.perf_counter() - t0
    k, dt = session.k, system.dt
    out = dict(t=t, x=x, v=v, a=a, probe_t=(np.arange(S) + 1) * k * dt, probe_p=positions.copy(),
               probe_force=force, probe_contacts=contacts, probe_radius=np.float64(system.probe.radius),
               probe_p0=np.asarray(system.probe.position, float), probe_k=np.int64(k),
               wall_seconds=np.float64(wall))
    if raw:
        out["probe_force_raw"] = np.asarray(raw, np.int64)
    out.update({key: np.asarray(val) for key, val in per_frame.items()})
    return out
