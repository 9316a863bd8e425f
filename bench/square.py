"""The hand-vectorised C loop of the benchmark square (bench/square.c): built with gcc, loaded with ctypes.

For the benchmark only (the yardstick the cpu backend is held to, issue 14), not a backend: it runs the
benchmark square of sim/bench.py and nothing else. `CSquare(system)` checks that the system is such a square
(2D, one material, no contact, no loads); `advance(n)` steps it; `state()` gives x (N, 2), v, a.
The library is built once per source hash into $RHEO_BUILD/bench (default build/bench).
"""
from __future__ import annotations

import ctypes
import hashlib
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np

SOURCE = Path(__file__).with_name("square.c")
FLAGS = ["-O3", "-march=native", "-ffast-math", "-fopenmp-simd", "-fPIC", "-shared"]


class Unavailable(RuntimeError):
    """No C compiler, or a system the loop does not cover; the message says which."""


class _Material(ctypes.Structure):
    _fields_ = [(n, ctypes.c_double) for n in
                ("k1", "c1", "a_min", "a_max", "c_min", "c_max", "B", "f1", "f2", "Y1", "Y2", "g0", "g1", "dt")]


def library() -> ctypes.CDLL:
    cc = shutil.which("gcc") or shutil.which("cc")
    if cc is None:
        raise Unavailable("no C compiler (gcc) on PATH: apt install gcc")
    key = hashlib.sha256(SOURCE.read_bytes() + " ".join(FLAGS).encode()).hexdigest()[:12]
    out = Path(os.environ.get("RHEO_BUILD", "build")) / "bench" / f"square-{key}.so"
    if not out.is_file():
        out.parent.mkdir(parents=True, exist_ok=True)
        res = subprocess.run([cc, *FLAGS, str(SOURCE), "-o", str(out), "-lm"], capture_output=True, text=True)
        if res.returncode != 0:
            raise Unavailable(f"{cc} could not build {SOURCE}: {res.stderr.strip()[:500]}")
    return ctypes.CDLL(str(out))


def _uniform(value, name):
    arr = np.atleast_1d(np.asarray(value, float))
    if not np.all(arr == arr.flat[0]):
        raise Unavailable(f"the C loop takes one material; '{name}' varies")
    return float(arr.flat[0])


class CSquare:
    def __init__(self, system):
        if system.dim != 2 or system.floor or system.topology or system.collision or system.loads or not system.elem.nonlinear \
                or system.elem.fixed_a:
            raise Unavailable(f"the C loop covers the benchmark square only, not '{system.name}'")
        self.lib = library()
        p = system.elem
        f = {n: _uniform(getattr(p, n), n) for n in ("k1", "c1", "a_min", "a_max", "c_min", "c_max", "B", "f1", "f2")}
        f["Y1"], f["Y2"] = f["f1"] * (1.0 + f["c1"] / f["c_max"]), f["f2"] * (1.0 + f["c1"] / f["c_min"])
        self.mat = _Material(**f, g0=system.gravity[0] * system.dt, g1=system.gravity[1] * system.dt, dt=system.dt)
        N, E = system.n_nodes, system.n_elements
        self.N, self.E = N, E
        self.ei, self.ej = (np.ascontiguousarray(system.edges[:, c], np.uint32) for c in (0, 1))
        self.x = np.ascontiguousarray(system.x0.T, float)
        self.v = np.ascontiguousarray(system.v0.T, float)
        self.a = system.a0.astype(float).copy()
        self.L = np.ascontiguousarray(np.broadcast_to(p.L, (E,)), float)
        self.inv_m_dt = np.where(system.pinned, 0.0, system.dt / system.mass)
        self.free = (~system.pinned).astype(float)
        self.scratch = [np.zeros(E) for _ in range(7)] + [np.zeros(E, np.int32), np.zeros(E), np.zeros(N), np.zeros(N)]

    def advance(self, n: int) -> None:
        ptr = lambda a: a.ctypes.data_as(ctypes.c_void_p)
        s = self.scratch
        self.lib.run(ctypes.c_int64(n), ctypes.c_int64(self.N), ctypes.c_int64(self.E), ptr(self.ei), ptr(self.ej),
                     ptr(self.x[0]), ptr(self.x[1]), ptr(self.v[0]), ptr(self.v[1]), ptr(self.a), ptr(self.L),
                     ptr(self.inv_m_dt), ptr(self.free), ctypes.byref(self.mat), *(ptr(a) for a in s))

    def state(self):
        return self.x.T.copy(), self.v.T.copy(), self.a.copy()
