"""Pictures of a run file: a row of frames as PNG, or an animated GIF.

    render(npz_path, out_path, frames=None, dpi=100) -> Path
    render_before_after(npz_path, out_path, frame_indices, labels, dpi=100) -> Path

Elements are drawn as line segments coloured by object, 2D cells are lightly filled, pinned nodes are
small black markers and the floor (when the run has one) is a grey line in 2D or a translucent plane in
3D. A haptic run (`rheo haptic`) also shows the probe (a disc, or a sphere's outline) and the force on it
as an arrow with a readout. All panels / animation frames share one set of axis limits with equal aspect.

Errors meant to become one-line CLI messages: sim/runfile.py's RunFileMissing / RunFileError for a missing
or malformed run file (missing keys, inconsistent shapes), ValueError for bad frame indices or an unsupported
output suffix.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.animation import PillowWriter  # noqa: E402
from matplotlib.collections import LineCollection, PolyCollection  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402
from mpl_toolkits.mplot3d.art3d import Line3DCollection, Poly3DCollection  # noqa: E402
from PIL import Image  # noqa: E402  (a matplotlib dependency)

from golden.errors import BadArgument  # noqa: E402
from .runfile import load_run  # noqa: E402

DEFAULT_PANELS = 4
MAX_GIF_FRAMES = 200


# ----------------------------------------------------------------------------------------------------
# Frame selection, limits, colours
# ----------------------------------------------------------------------------------------------------

def _spread(count: int, F: int) -> list[int]:
    n = min(count, F)
    return [int(i) for i in np.unique(np.round(np.linspace(0, F - 1, n)).astype(np.int64))]


def select_frames(frames, F: int, default_count: int) -> list[int]:
    """None -> default_count frames evenly spread from first to last; int -> that many (at most F);
    a sequence -> those indices (negative ones count from the end). Out of range -> ValueError."""
    if frames is None:
        return _spread(default_count, F)
    if isinstance(frames, (bool, np.bool_)):
        raise ValueError(f"frames must be a count or a list of frame indices, got {frames!r}")
    if isinstance(frames, (int, np.integer)):
        if frames < 1:
            raise BadArgument(f"frame count must be at least 1, got {frames}")
        return _spread(int(frames), F)
    try:
        items = list(frames)
    except TypeError:
        raise BadArgument(f"frames must be a count or a list of frame indices, got {frames!r}") from None
    if not items:
        raise BadArgument("no frames selected")
    out = []
    for i in items:
        if isinstance(i, (bool, np.bool_)) or not isinstance(i, (int, np.integer)):
            raise BadArgument(f"frame index must be an integer, got {i!r}")
        if not -F <= i < F:
            raise BadArgument(f"frame index {int(i)} out of range: the run has {F} frames (0..{F - 1})")
        out.append(int(i) % F)
    return out


def _limits(run: dict, idx) -> tuple[np.ndarray, np.ndarray]:
    """Axis limits over the chosen frames (and the floor), with a margin; every axis gets a span of at
    least 20 % of the largest one so flat objects stay visible."""
    D = run["dim"]
    pts = run["x"][idx].reshape(-1, D)
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    if len(pts) == 0:
        raise BadArgument("the selected frames have no finite node coordinates")
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    if "probe" in run:
        pb = run["probe"]
        ps = np.concatenate([pb["p0"][None, :], pb["p"]])
        lo, hi = np.minimum(lo, ps.min(0) - pb["radius"]), np.maximum(hi, ps.max(0) + pb["radius"])
    fh = run["floor_height"]
    if np.isfinite(fh):
        lo[D - 1], hi[D - 1] = min(lo[D - 1], fh), max(hi[D - 1], fh)
    span = hi - lo
    big = span.max()
    if big <= 0:
        big = max(1e-3, 0.2 * np.abs(lo).max())
    short = span < 0.2 * big
    mid = 0.5 * (lo + hi)
    lo = np.where(short, mid - 0.1 * big, lo) - 0.05 * big
    hi = np.where(short, mid + 0.1 * big, hi) + 0.05 * big
    return lo, hi


def _object_colours(n: int) -> np.ndarray:
    cmap = matplotlib.colormaps["tab10"]
    return np.array([cmap(k % 10) for k in range(max(n, 1))])


def _line_width(E: int) -> float:
    return 1.5 if E <= 300 else 1.0 if E <= 3000 else 0.6


def _time_label(t: float) -> str:
    return f"t = {t:.4g} s"


# ----------------------------------------------------------------------------------------------------
# Drawing one frame into an axes, and updating it for the next animation frame
# ----------------------------------------------------------------------------------------------------

class _Painter:
    def __init__(self, run: dict, lo, hi):
        self.run, self.lo, self.hi = run, lo, hi
        self.D = run["dim"]
        colours = _object_colours(run["n_objects"])
        self.colours = colours
        edges, cells = run["edges"], run["cells"]
        # Elements are grouped by object: each object's elements form one polyline of NaN-separated
        # segments, one member of the (3D) line collection. Updating a few long paths per frame is far
        # cheaper than one matplotlib Path per element.
        edge_obj = run["node_object"][edges[:, 0]] if len(edges) else np.zeros(0, np.int64)
        self.edge_groups = [(k, edges[edge_obj == k]) for k in np.unique(edge_obj)]
        self.edge_colours = colours[[k for k, _ in self.edge_groups]] if self.edge_groups else np.zeros((0, 4))
        self.cell_colours = colours[run["cell_object"]] if len(cells) else np.zeros((0, 4))
        self.node_colours = colours[run["node_object"]]
        self.lw = _line_width(len(edges))
        self.probe = ProbePainter(run["probe"], self.D, lo, hi) if "probe" in run else None
        # 3D: draw the shaded surface of each object (its boundary triangles), not every interior element
        self.surface = None
        if self.D == 3 and len(cells):
            from golden.mesh import boundary_faces
            self.surface, _ = boundary_faces(cells, run["x"][0])
            self.surface_colours = colours[run["node_object"][self.surface[:, 0]]]

    def shaded(self, x: np.ndarray) -> np.ndarray:
        """Surface face colours lit from above-front: a dent shows as a change of shade."""
        p = x[self.surface]
        n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
        light = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
        k = 0.45 + 0.55 * np.clip(n @ light, 0.0, 1.0)
        rgba = self.surface_colours.copy()
        rgba[:, :3] *= k[:, None]
        rgba[:, 3] = 0.9
        return rgba

    def segments(self, x: np.ndarray) -> list[np.ndarray]:
        """One (3 E_k, D) polyline per object: start, end, NaN for each of its elements."""
        out = []
        for _, e in self.edge_groups:
            seg = np.empty((len(e), 3, x.shape[1]))
            seg[:, 0] = x[e[:, 0]]
            seg[:, 1] = x[e[:, 1]]
            seg[:, 2] = np.nan
            out.append(seg.reshape(-1, x.shape[1]))
        return out

    def setup_axes(self, ax):
        lo, hi, D = self.lo, self.hi, self.D
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        if D == 2:
            ax.set_aspect("equal")
        else:
            ax.set_zlim(lo[2], hi[2])
            ax.set_zlabel("z [m]")
            ax.set_box_aspect(tuple(hi - lo))
        fh = self.run["floor_height"]
        if np.isfinite(fh):
            if D == 2:
                ax.axhspan(lo[1], fh, color="0.93", zorder=0, lw=0)
                ax.axhline(fh, color="0.5", lw=1.5, zorder=0.5)
            else:
                quad = [[(lo[0], lo[1], fh), (hi[0], lo[1], fh), (hi[0], hi[1], fh), (lo[0], hi[1], fh)]]
                ax.add_collection3d(Poly3DCollection(quad, facecolors=(0.5, 0.5, 0.5, 0.2),
                                                     edgecolors=(0.5, 0.5, 0.5, 0.5)))

    def draw(self, ax, f: int) -> dict:
        """Draw frame f; returns the artists that update() moves."""
        run, D = self.run, self.D
        x = run["x"][f]
        edges, cells, pinned = run["edges"], run["cells"], run["pinned"]
        art = {}
        if D == 2:
            if len(cells):
                art["cells"] = ax.add_collection(PolyCollection(
                    x[cells], facecolors=self.cell_colours, edgecolors="none", alpha=0.25, zorder=1))
            if len(edges):
                art["edges"] = ax.add_collection(LineCollection(
                    self.segments(x), colors=self.edge_colours, linewidths=self.lw, zorder=2))
            else:
                art["nodes"] = ax.scatter(x[:, 0], x[:, 1], s=6, c=self.node_colours, zorder=2)
            (art["pinned"],) = ax.plot(x[pinned, 0], x[pinned, 1], ls="none", marker="o", ms=3,
                                       color="k", zorder=3)
        else:
            if self.surface is not None:
                pc = Poly3DCollection(x[self.surface], facecolors=self.shaded(x), edgecolors=(0, 0, 0, 0.25),
                                      linewidths=0.3)
                ax.add_collection3d(pc)
                art["surface"] = pc
            elif len(edges):
                lc = Line3DCollection(self.segments(x), colors=self.edge_colours, linewidths=self.lw)
                ax.add_collection3d(lc)
                art["edges"] = lc
            else:
                (art["nodes3"],) = ax.plot(x[:, 0], x[:, 1], x[:, 2], ls="none", marker="o", ms=2,
                                           color=self.colours[0])
            (art["pinned"],) = ax.plot(x[pinned, 0], x[pinned, 1], x[pinned, 2], ls="none", marker="o",
                                       ms=3, color="k")
        if self.probe is not None:
            art["probe"] = self.probe.draw(ax, *self.probe.at(run["t"][f]))
        return art

    def update(self, art: dict, f: int):
        run = self.run
        x = run["x"][f]
        p = run["pinned"]
        if "cells" in art:
            art["cells"].set_verts(x[run["cells"]])
        if "edges" in art:
            art["edges"].set_segments(self.segments(x))
        if "surface" in art:
            art["surface"].set_verts(x[self.surface])
            art["surface"].set_facecolor(self.shaded(x))
        if "nodes" in art:
            art["nodes"].set_offsets(x)
        if "nodes3" in art:
            art["nodes3"].set_data_3d(x[:, 0], x[:, 1], x[:, 2])
        if self.D == 2:
            art["pinned"].set_data(x[p, 0], x[p, 1])
        else:
            art["pinned"].set_data_3d(x[p, 0], x[p, 1], x[p, 2])
        if "probe" in art:
            self.probe.update(art["probe"], *self.probe.at(run["t"][f]))


class ProbePainter:
    """The probe of a haptic run (or of `rheo play`): a disc in 2D, a sphere's three great circles in 3D,
    the force on it as an arrow from its centre (length: ARROW_FRACTION of the picture per the run's peak
    force) and a readout. `at(t)`: the probe's (position, force, contacts) in the frame at time t."""

    ARROW_FRACTION = 0.25

    def __init__(self, probe: dict, D: int, lo, hi, peak_force: float | None = None):
        self.pb, self.D = probe, D
        peak = peak_force if peak_force is not None else (
            float(np.linalg.norm(probe["force"], axis=1).max()) if len(probe["force"]) else 0.0)
        self.scale = self.ARROW_FRACTION * float(np.max(np.asarray(hi) - np.asarray(lo))) / max(peak, 1e-300)

    def at(self, t: float):
        pb = self.pb
        s = int(np.searchsorted(pb["t"], t - 1e-12 * max(1.0, abs(t))))
        if len(pb["t"]) == 0 or s >= len(pb["t"]) or abs(pb["t"][s] - t) > 1e-9 * max(1.0, abs(t)):
            return pb["p0"], np.zeros(self.D), 0          # before the first sample: at rest, no force
        return pb["p"][s], pb["force"][s], int(pb["contacts"][s])

    def _circles(self, p):
        a = np.linspace(0.0, 2.0 * np.pi, 49)
        c, s_ = np.cos(a), np.sin(a)
        R = self.pb["radius"]
        if self.D == 2:
            return [np.stack([p[0] + R * c, p[1] + R * s_], 1)]
        z = np.zeros_like(a)
        return [p + R * np.stack(v, 1) for v in ((c, s_, z), (c, z, s_), (z, c, s_))]

    @staticmethod
    def readout(force, contacts) -> str:
        return f"probe force {np.linalg.norm(force):.3g} N, {contacts} node{'s' if contacts != 1 else ''}"

    def draw(self, ax, p, force, contacts) -> dict:
        from matplotlib.patches import Circle
        art = {}
        tip = p + self.scale * np.asarray(force)
        if self.D == 2:
            art["disc"] = ax.add_patch(Circle(p, self.pb["radius"], facecolor=(0.85, 0.2, 0.1, 0.25),
                                              edgecolor=(0.7, 0.1, 0.0), lw=1.2, zorder=4))
            art["arrow"] = ax.annotate("", xy=tip, xytext=p, zorder=5, annotation_clip=False,
                                       arrowprops=dict(arrowstyle="-|>", color=(0.7, 0.1, 0.0), lw=1.8))
            art["text"] = ax.text(0.02, 0.97, self.readout(force, contacts), transform=ax.transAxes, va="top",
                                  fontsize="small", color=(0.6, 0.1, 0.0), zorder=6)
        else:
            art["circles"] = [ax.plot(*c.T, color=(0.7, 0.1, 0.0), lw=1.0)[0] for c in self._circles(p)]
            (art["arrow3"],) = ax.plot(*np.stack([p, tip], 1), color=(0.7, 0.1, 0.0), lw=2.0)
            (art["tip3"],) = ax.plot(*tip[:, None], marker="o", ms=3, color=(0.7, 0.1, 0.0))
            art["text"] = ax.text2D(0.02, 0.97, self.readout(force, contacts), transform=ax.transAxes,
                                    va="top", fontsize="small", color=(0.6, 0.1, 0.0))
        return art

    def update(self, art: dict, p, force, contacts) -> None:
        tip = p + self.scale * np.asarray(force)
        if self.D == 2:
            art["disc"].center = tuple(p)
            art["arrow"].xy, art["arrow"].xyann = tuple(tip), tuple(p)
        else:
            for line, c in zip(art["circles"], self._circles(p)):
                line.set_data_3d(*c.T)
            art["arrow3"].set_data_3d(*np.stack([p, tip], 1))
            art["tip3"].set_data_3d(*tip[:, None])
        art["text"].set_text(self.readout(force, contacts))


# ----------------------------------------------------------------------------------------------------
# Output
# ----------------------------------------------------------------------------------------------------

def _suffix_of(out_path) -> str:
    suffix = Path(out_path).suffix.lower()
    if suffix not in (".png", ".gif"):
        raise BadArgument(f"unsupported output format '{Path(out_path).suffix}': use .png or .gif")
    return suffix


def _write_atomically(out_path: Path, write) -> Path:
    from .runfile import write_atomically
    return write_atomically(out_path, write)


def _panel_size(lo, hi, D: int, size: float) -> tuple[float, float]:
    """Figure inches for one panel of nominal size `size`: the data box keeps its aspect within a
    bounded panel (at most 1.5 size wide, at least 0.5 size high), plus room for the labels."""
    if D == 3:
        return size * 1.15, size * 1.1
    ratio = float((hi[0] - lo[0]) / (hi[1] - lo[1]))
    width = float(np.clip(size * ratio, 0.75 * size, 1.5 * size))
    height = float(np.clip(width / ratio, 0.5 * size, 1.25 * size))
    return width + 0.7, height + 0.6


def _legend_handles(run: dict, painter: _Painter):
    used = sorted(set(run["node_object"].tolist()) | set(run["cell_object"].tolist()))
    if len(used) < 2:
        return []
    return [Line2D([], [], color=painter.colours[k], lw=2, label=run["object_names"][k]) for k in used]


def _panels_png(run: dict, out_path: Path, idx: list[int], titles: list[str], dpi: int,
                suptitle: str) -> Path:
    D = run["dim"]
    lo, hi = _limits(run, idx)
    painter = _Painter(run, lo, hi)
    pw, ph = _panel_size(lo, hi, D, 3.2)
    n = len(idx)
    fig = plt.figure(figsize=(pw * n, ph + 0.5), layout="constrained")
    try:
        for i, (f, title) in enumerate(zip(idx, titles)):
            ax = fig.add_subplot(1, n, i + 1, projection="3d" if D == 3 else None)
            painter.setup_axes(ax)
            painter.draw(ax, f)
            ax.set_title(title)
            if D == 2 and i > 0:
                ax.set_ylabel("")
        handles = _legend_handles(run, painter)
        if handles:
            fig.legend(handles=handles, loc="outside lower center", ncol=min(len(handles), 6),
                       fontsize="small", frameon=False)
        if suptitle:
            fig.suptitle(suptitle)
        return _write_atomically(out_path, lambda tmp: fig.savefig(tmp, format="png", dpi=dpi,
                                                                 bbox_inches="tight", pad_inches=0.1))
    finally:
        plt.close(fig)


class _OctreePillowWriter(PillowWriter):
    """PillowWriter that reduces each frame to a 256-colour palette with Pillow's fast octree quantizer
    as it is grabbed; Pillow's default (median cut, at save time) dominated the time of a long GIF."""

    def grab_frame(self, **savefig_kwargs):
        super().grab_frame(**savefig_kwargs)
        frames = getattr(self, "_frames", None)
        if frames and frames[-1].mode == "RGB":
            frames[-1] = frames[-1].quantize(256, method=Image.Quantize.FASTOCTREE)


def _gif(run: dict, out_path: Path, idx: list[int], dpi: int) -> Path:
    D = run["dim"]
    lo, hi = _limits(run, idx)
    painter = _Painter(run, lo, hi)
    pw, ph = _panel_size(lo, hi, D, 4.5)
    fig = plt.figure(figsize=(pw, ph + 0.5))
    try:
        ax = fig.add_subplot(1, 1, 1, projection="3d" if D == 3 else None)
        painter.setup_axes(ax)
        art = painter.draw(ax, idx[0])
        title = ax.set_title(_time_label(run["t"][idx[0]]))
        if run["scene"]:
            fig.suptitle(run["scene"])
        fig.tight_layout()
        fig.set_layout_engine(None)  # the layout is fixed now: no layout pass before every frame
        t = run["t"]
        duration = float(t[idx[-1]] - t[idx[0]])
        # real time when that gives a watchable rate, else clamped to 5..30 frames per second
        fps = float(np.clip((len(idx) - 1) / duration, 5, 30)) if duration > 0 and len(idx) > 1 else 10.0

        def write(tmp):
            writer = _OctreePillowWriter(fps=fps)
            with writer.saving(fig, tmp, dpi):
                for f in idx:
                    painter.update(art, f)
                    title.set_text(_time_label(t[f]))
                    writer.grab_frame()

        return _write_atomically(out_path, write)
    finally:
        plt.close(fig)


def render(npz_path, out_path, frames=None, dpi=100) -> Path:
    """Render a run file to a PNG (a row of frames) or an animated GIF, chosen by out_path's suffix.

    frames: None (PNG: 4 frames evenly spread from first to last; GIF: every frame, subsampled to at
    most 200), an int count of evenly spread frames, or a list of frame indices (negative ones count
    from the end). Returns the output path.
    """
    out_path = Path(out_path)
    suffix = _suffix_of(out_path)
    run = load_run(npz_path)
    F = len(run["t"])
    if suffix == ".png":
        idx = select_frames(frames, F, DEFAULT_PANELS)
        return _panels_png(run, out_path, idx, [_time_label(run["t"][f]) for f in idx], dpi, run["scene"])
    idx = select_frames(frames, F, MAX_GIF_FRAMES)
    return _gif(run, out_path, idx, dpi)


def render_before_after(npz_path, out_path, frame_indices, labels, dpi=100) -> Path:
    """Draw the chosen frames side by side as a PNG, each titled with its label (e.g. "before press",
    "pressed", "after release"). Frame indices may be negative (counting from the end)."""
    out_path = Path(out_path)
    if _suffix_of(out_path) != ".png":
        raise BadArgument(f"unsupported output format '{out_path.suffix}' for a before/after picture: use .png")
    labels = [str(s) for s in labels]
    run = load_run(npz_path)
    if isinstance(frame_indices, (int, np.integer)):
        frame_indices = [frame_indices]
    idx = select_frames(frame_indices, len(run["t"]), DEFAULT_PANELS)
    if len(labels) != len(idx):
        raise BadArgument(f"{len(idx)} frame(s) but {len(labels)} label(s)")
    return _panels_png(run, out_path, idx, labels, dpi, "")
