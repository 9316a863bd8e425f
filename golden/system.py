"""A compiled scene as plain data: the System (every array a step needs, SI units), the State of a run
and the recorded Run. No physics here: the steppers (golden/model.py, the cpu backend, the bit-true model,
the hardware) all read these."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .contact import Collision, Floor
from .elements import ElementParams
from .probe import Probe, ProbeState


@dataclass
class Load:
    nodes: np.ndarray        # (n,) node indices
    force: np.ndarray        # (D,) force on each selected node, N
    start: float
    end: float


@dataclass
class Topology:
    pairs: np.ndarray        # (P, D + 1): vertex, then its opposite facet
    K: float
    C: float
    eps: float


@dataclass
class System:
    """A compiled scene: every array the step needs, in SI units."""
    name: str
    dim: int
    x0: np.ndarray           # (N, D)
    v0: np.ndarray           # (N, D)
    mass: np.ndarray         # (N,)
    pinned: np.ndarray       # (N,) bool
    edges: np.ndarray        # (E, 2) start, end
    a0: np.ndarray           # (E,)
    elem: ElementParams
    cells: np.ndarray        # (C, D + 1)
    node_object: np.ndarray  # (N,)
    cell_object: np.ndarray  # (C,)
    object_names: list
    gravity: np.ndarray      # (D,)
    dt: float
    n_steps: int
    every: int
    floor: Floor | None = None
    topology: Topology | None = None
    collision: Collision | None = None
    loads: list = field(default_factory=list)
    materials: list = field(default_factory=list)   # per object: the resolved material table
    formats: dict = field(default_factory=dict)     # [formats] overrides for the bit-true model / hardware
    description: str = ""
    probe: Probe | None = None                      # the haptic probe (MODEL.md 4b)

    @property
    def n_nodes(self) -> int:
        return len(self.x0)

    @property
    def n_elements(self) -> int:
        return len(self.edges)


def component_major(arr: np.ndarray) -> np.ndarray:
    """The same (N, D) array, stored as a contiguous (D, N) buffer (fast per-axis gathers)."""
    return np.ascontiguousarray(arr.T).T


@dataclass
class State:
    x: np.ndarray            # (N, D), component-major storage
    v: np.ndarray
    a: np.ndarray            # (E,)
    step: int = 0
    probe: ProbeState | None = None    # the probe's held inputs and last outputs (scenes with a probe)

    @classmethod
    def initial(cls, system: System) -> "State":
        return cls(component_major(system.x0), component_major(system.v0), system.a0.copy(),
                   probe=ProbeState.initial(system.probe) if system.probe is not None else None)

    def copy(self) -> "State":
        """An independent state (component_major alone returns its argument when it is already so stored)."""
        return State(component_major(self.x.copy()), component_major(self.v.copy()), self.a.copy(), self.step,
                     self.probe.copy() if self.probe is not None else None)


@dataclass
class Run:
    """Frames of a run in SI units, from any backend. Fixed-point and hardware backends add per frame their
    raw state words and saturation counts (`raw`: x_raw, v_raw, a_raw, saturations), and their run-file
    metadata (`info`: preset, formats, cycles measured by a simulated core...)."""
    t: np.ndarray            # (F,)
    x: np.ndarray            # (F, N, D)
    v: np.ndarray
    a: np.ndarray            # (F, E)
    wall_seconds: float = 0.0
    raw: dict = field(default_factory=dict)
    info: dict = field(default_factory=dict)


def frame_steps(n_steps: int, every: int) -> np.ndarray:
    """Step numbers at which frames are recorded: 0, every, 2 every, ..., and always the last."""
    s = np.arange(0, n_steps + 1, every)
    if s[-1] != n_steps:
        s = np.append(s, n_steps)
    return s
