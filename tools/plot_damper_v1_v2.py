"""README figure: one rheological-preset element under a constant 0.04 N pull, tension per step, the
v1 element (c2 from the previous step's |T|) against v2 (the series balance solved exactly, golden model).

    .venv/bin/python tools/plot_damper_v1_v2.py docs/damper-v1-v2.png
"""
from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import matplotlib
matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from golden.model import Golden
from golden.system import State
from golden.scene import load_scene

F, DT, STEPS, MASS, LENGTH = 0.04, 1e-5, 3000, 1e-3, 0.01
K1, C1, A0, C_MIN, C_MAX, F1, F2 = 50.0, 0.5, 0.5, 0.5, 500.0, 0.01, 0.05


def v2_tensions() -> np.ndarray:
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "pull.toml"
        p.write_text(f"""
dim = 2
[integrator]
dt = {DT!r}
duration = {DT * STEPS!r}
[[objects]]
mesh = {{ type = "explicit", nodes = [[0.0, 0.0], [{LENGTH!r}, 0.0]], edges = [[0, 1]] }}
material = {{ preset = "rheological" }}
masses = [{MASS!r}, {MASS!r}]
pinned = [0]
[[loads]]
nodes = [1]
force = [{F!r}, 0.0]
""")
        system = load_scene(p)
    g, st, out = Golden(system), State.initial(system), []
    for n in range(STEPS):
        out.append(g.forces(st, n * DT)[1][0])
        g.step(st)
    return np.array(out)


def v1_tensions() -> np.ndarray:
    """The v1 law, written out for this figure only: c2 from |T| of the previous step."""
    B = np.log(C_MAX / C_MIN) / (F2 - F1)
    L = A0 * LENGTH
    x, v, a, t_prev, out = LENGTH, 0.0, A0, 0.0, []
    for _ in range(STEPS):
        c2 = np.clip(C_MAX * np.exp(-B * (t_prev - F1)), C_MIN, C_MAX)
        k1s = K1 * (a * x - L)
        adot = ((c2 - (C1 + c2) * a) * v - k1s) / ((C1 + c2) * x)
        T = k1s + C1 * (adot * x + a * v)
        out.append(T)
        v += DT * (F - T) / MASS
        x += DT * v
        a = min(max(a + DT * adot, 0.05), 1.0)
        t_prev = abs(T)
    return np.array(out)


def main(path: str) -> None:
    v1, v2 = v1_tensions(), v2_tensions()
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6))
    n = np.arange(STEPS)
    for ax, (lo, hi) in zip(axes, ((0, STEPS), (STEPS - 40, STEPS))):
        ax.plot(n[lo:hi], v1[lo:hi], ".-", lw=0.6, ms=2, label="v1: c2 from the previous step's |T|")
        ax.plot(n[lo:hi], v2[lo:hi], "-", lw=1.6, label="v2: Y = G(T) solved each step")
        ax.axhline(F, color="k", lw=0.6, ls=":")
        ax.set_xlabel("step (dt = 1e-5 s)")
        ax.set_ylabel("tension T (N)")
    axes[0].set_title("0.04 N pull on one rheological element")
    axes[1].set_title("the last 40 steps")
    axes[0].legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    print(f"{path}: v1 alternates {v1[-2]:.4f} / {v1[-1]:.4f} N, v2 settles at {v2[-1]:.4f} N")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "docs/damper-v1-v2.png")
