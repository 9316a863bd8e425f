"""Throughput benchmark of a backend on generated meshes of about 1e3, 1e4 and 1e5 elements.

The benchmark scene is a square of rheological material (nonlinear damper) under gravity with its
bottom row pinned: element updates and node integration, the work every scene does. Figures are
measured on this machine: steps/s and element-updates/s (elements x steps / wall time).
"""
from __future__ import annotations

import math
import time

import numpy as np

from golden import mesh as meshlib
from golden.model import Golden, State, System
from golden.scene import PRESETS
from golden.elements import ElementParams

SIZES = (1_000, 10_000, 100_000)


def square_system(n_elements: int) -> System:
    """A 2D square mesh with about n_elements elements (a rectangle of n x n cells has 3 n^2 + 2 n)."""
    n = max(1, int(round((-2 + math.sqrt(4 + 12 * n_elements)) / 6)))
    m = meshlib.rectangle(1.0, 1.0, n, n)
    mat = PRESETS["rheological"]
    E, N = len(m.edges), len(m.nodes)
    l0 = np.linalg.norm(m.nodes[m.edges[:, 1]] - m.nodes[m.edges[:, 0]], axis=1)
    elem = ElementParams.build(np.full(E, mat["k1"]), np.full(E, mat["c1"]), np.full(E, mat["a_min"]),
                               np.full(E, mat["a_max"]), mat["a0"] * l0, np.full(E, mat["c_min"]),
                               np.full(E, mat["c_max"]), np.full(E, mat["f1"]), np.full(E, mat["f2"]))
    pinned = m.nodes[:, 1] == 0.0
    return System(f"bench-{E}", 2, m.nodes, np.zeros_like(m.nodes), np.full(N, 1e-3), pinned, m.edges,
                  np.full(E, mat["a0"]), elem, m.cells, np.zeros(N, np.int64), np.zeros(len(m.cells), np.int64),
                  ["square"], np.array([0.0, -9.81]), 1e-5, 0, 1)


def _timed(stepper, st, sys: System, min_seconds: float, **labels) -> dict:
    """Step until at least min_seconds (and 5 steps) have passed; throughput figures."""
    for _ in range(3):                       # warm-up: caches, first-call costs
        stepper.step(st)
    steps, t0 = 0, time.perf_counter()
    while True:
        stepper.step(st)
        steps += 1
        el = time.perf_counter() - t0
        if el >= min_seconds and steps >= 5:
            break
    return dict(**labels, elements=sys.n_elements, nodes=sys.n_nodes, steps=steps, seconds=el,
                steps_per_s=steps / el, element_updates_per_s=steps * sys.n_elements / el)


def bench_golden(n_elements: int, min_seconds: float = 1.0) -> dict:
    sys = square_system(n_elements)
    return _timed(Golden(sys), State.initial(sys), sys, min_seconds, backend="golden")


def bench_fixed(n_elements: int, min_seconds: float = 1.0, preset: str = "wide") -> dict:
    """The bit-true model on the same mesh (formats from a short range analysis of its first steps)."""
    from hw.bittrue import BitTrue
    sys = square_system(n_elements)
    sys.n_steps = 50
    bt = BitTrue(sys, preset, range_steps=50)
    return _timed(bt, bt.initial_state(), sys, min_seconds, backend="fixed", preset=preset)


def run(backend: str, sizes=SIZES, min_seconds: float = 1.0) -> list[dict]:
    if backend == "golden":
        return [bench_golden(n, min_seconds) for n in sizes]
    if backend == "fixed":
        rows = []
        for n in sizes:
            g, f = bench_golden(n, min_seconds), bench_fixed(n, min_seconds)
            f["golden_steps_per_s"] = g["steps_per_s"]
            f["ratio_to_golden"] = f["steps_per_s"] / g["steps_per_s"]
            rows.append(f)
        return rows
    raise ValueError(f"backend '{backend}' has no benchmark (available: golden, fixed)")
