"""Force against indentation of haptic runs (`rheo plot-force`): the loading-unloading loops that tell a
viscoelastic object (it returns on its curve) from a plastic one (it keeps its dent) and a rheological one
(in between).

Indentation: how far the probe's lowest point is below the top of the object under it at rest (the
highest node within the probe's radius of its initial centre, sideways), along the poke direction (-y in 2D,
-z in 3D); force: the force the object pushes the probe back with, along the same axis (up positive).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from .runfile import RunFileError, load_run, write_atomically  # noqa: E402


def indentation_and_force(run: dict) -> tuple[np.ndarray, np.ndarray]:
    """(indentation (S,) m, force (S,) N) per device sample of a haptic run (load_run's dict)."""
    pb = run["probe"]
    x0, R, p0 = run["x"][0], pb["radius"], pb["p0"]
    side = np.linalg.norm(x0[:, :-1] - p0[None, :-1], axis=1)
    under = side < R
    top = float(x0[under, -1].max()) if under.any() else float(x0[:, -1].max())
    return top - (pb["p"][:, -1] - R), pb["force"][:, -1]


def plot_force(runs, out_path, labels=None, dpi=120) -> Path:
    """One figure with the force-indentation loop of each haptic run file."""
    out_path = Path(out_path)
    if out_path.suffix.lower() != ".png":
        raise ValueError(f"unsupported output format '{out_path.suffix}' for a force plot: use .png")
    loaded = []
    for path in runs:
        run = load_run(path)
        if "probe" not in run:
            raise RunFileError(f"run file {path} has no probe: plot-force takes the run files of `rheo haptic`")
        loaded.append(run)
    labels = list(labels) if labels else [r["scene"] or Path(p).stem for r, p in zip(loaded, runs)]
    if len(labels) != len(loaded):
        raise ValueError(f"{len(loaded)} run file(s) but {len(labels)} label(s)")
    fig, ax = plt.subplots(figsize=(6.4, 4.4), layout="constrained")
    try:
        for run, label in zip(loaded, labels):
            d, F = indentation_and_force(run)
            line, = ax.plot(d * 1e3, F, lw=1.6, label=label)
            mid = len(d) // 4
            if len(d) > 2:                              # an arrowhead on the loading branch
                ax.annotate("", xy=(d[mid + 1] * 1e3, F[mid + 1]), xytext=(d[mid] * 1e3, F[mid]),
                            arrowprops=dict(arrowstyle="-|>", color=line.get_color(), lw=1.2))
        ax.axhline(0.0, color="0.6", lw=0.8)
        ax.axvline(0.0, color="0.6", lw=0.8, ls=":")
        ax.set_xlabel("indentation below the surface [mm]")
        ax.set_ylabel("force on the probe, up [N]")
        ax.set_title("poke and release: force against indentation")
        ax.legend(frameon=False)
        return write_atomically(out_path, lambda tmp: fig.savefig(tmp, format="png", dpi=dpi))
    finally:
        plt.close(fig)
