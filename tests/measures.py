"""Measures of the seed's behaviours shared by the 2D and 3D scene tests (computed from frames only)."""
from __future__ import annotations

import numpy as np


def quarter_sinks(system, run):
    """Sink of the top face's mean height (last axis) in the first and in the last quarter of the run."""
    up = system.dim - 1
    top = np.flatnonzero(system.x0[:, up] == system.x0[:, up].max())
    h = run.x[:, top, up].mean(1)
    T = run.t[-1]
    q = [np.interp(k * T / 4, run.t, h) for k in range(5)]
    return q[0] - q[1], q[3] - q[4]
