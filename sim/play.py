"""`rheo play SCENE`: the haptic loop with the mouse as the device. A matplotlib window shows the object and
the probe; pressing the mouse button in the axes and dragging moves the probe, the object deforms live (one
device sample, k steps, per animation frame) and the force on the probe is drawn as an arrow with a
readout.

`PlayController` holds all of it and handles the events itself (`on_press`, `on_motion`, `on_release`,
`tick`), so a test drives it on the Agg backend with synthetic mouse events and no display. The probe
follows the mouse at a bounded speed (`max_speed`, m/s): a jump of the pointer is not a jump of the probe.
3D scenes are shown from the side (x and z; the probe keeps its y).
"""
from __future__ import annotations

import numpy as np

from matplotlib.collections import LineCollection, PolyCollection

from .haptic import Session
from .render import ProbePainter

DEFAULT_MAX_SPEED = 0.05       # m/s: the probe's top speed behind the pointer
DEFAULT_ARROW_NEWTONS = 0.5    # N drawn as an arrow a quarter of the view long


class PlayController:
    """The play window's state and event handling. `fig`: a matplotlib figure to draw into (any backend);
    `samples_per_frame` device samples run per `tick` (each k steps)."""

    def __init__(self, session: Session, fig, max_speed: float = DEFAULT_MAX_SPEED, samples_per_frame: int = 1,
                 arrow_newtons: float = DEFAULT_ARROW_NEWTONS):
        self.session, self.fig = session, fig
        system = session.system
        self.D = system.dim
        self.axes_idx = [0, self.D - 1]                 # the view: x and the vertical
        self.max_step = max_speed * session.k * system.dt
        self.samples_per_frame = samples_per_frame
        self.target = None                              # where the pointer drags the probe (view coords)
        self.dragging = False
        self.reading = None
        self.peak_force = 0.0
        self.ax = ax = fig.add_subplot(1, 1, 1)
        x0 = system.x0[:, self.axes_idx]
        pb = system.probe
        p0 = np.asarray(pb.position, float)
        lo = np.minimum(x0.min(0), p0[self.axes_idx] - 2 * pb.radius)
        hi = np.maximum(x0.max(0), p0[self.axes_idx] + 2 * pb.radius)
        if system.floor is not None:
            lo[1] = min(lo[1], system.floor.height)
        pad = 0.08 * float(np.max(hi - lo))
        lo, hi = lo - pad, hi + pad
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
        ax.set_aspect("equal")
        ax.set_xlabel("x [m]")
        ax.set_ylabel(("y" if self.D == 2 else "z") + " [m]")
        ax.set_title(f"{system.name}: drag the probe with the mouse")
        if system.floor is not None:
            ax.axhspan(lo[1], system.floor.height, color="0.93", zorder=0, lw=0)
            ax.axhline(system.floor.height, color="0.5", lw=1.5, zorder=0.5)
        self._cells = system.cells if self.D == 2 else np.zeros((0, 3), np.int64)
        x = self._view(system.x0)
        self.cells_art = ax.add_collection(PolyCollection(x[self._cells], facecolors=(0.2, 0.4, 0.8, 0.2),
                                                          edgecolors="none", zorder=1))
        self.edges_art = ax.add_collection(LineCollection(x[system.edges], colors=(0.2, 0.4, 0.8), lw=0.8,
                                                          zorder=2))
        self.painter = ProbePainter({"radius": pb.radius, "p0": p0[self.axes_idx], "t": np.zeros(0),
                                     "p": np.zeros((0, 2)), "force": np.zeros((0, 2)), "contacts": np.zeros(0)},
                                    2, lo, hi, peak_force=arrow_newtons)
        self.probe_art = self.painter.draw(ax, p0[self.axes_idx], np.zeros(2), 0)
        self.time_art = ax.text(0.98, 0.97, "t = 0 s", transform=ax.transAxes, ha="right", va="top",
                                fontsize="small")
        self.cids = [fig.canvas.mpl_connect(name, fn) for name, fn in (
            ("button_press_event", self.on_press), ("motion_notify_event", self.on_motion),
            ("button_release_event", self.on_release))]

    # ---- geometry
    def _view(self, x):
        return np.asarray(x)[..., self.axes_idx]

    def probe_view(self) -> np.ndarray:
        return self.session.position[self.axes_idx]

    # ---- events
    def on_press(self, event) -> None:
        if event.inaxes is not self.ax or event.xdata is None:
            return
        self.dragging = True
        self.target = np.array([event.xdata, event.ydata], float)

    def on_motion(self, event) -> None:
        if self.dragging and event.inaxes is self.ax and event.xdata is not None:
            self.target = np.array([event.xdata, event.ydata], float)

    def on_release(self, event) -> None:
        """The probe stops where it is (it is not thrown towards the pointer's last position)."""
        self.dragging = False
        self.target = None

    # ---- the loop
    def next_position(self) -> np.ndarray:
        """The probe's next device sample: a step of at most max_step towards the pointer's target."""
        p = self.session.position.copy()
        if self.target is None:
            return p
        here = p[self.axes_idx]
        step = self.target - here
        dist = float(np.linalg.norm(step))
        if dist > self.max_step:
            step *= self.max_step / dist
        p[self.axes_idx] = here + step
        return p

    def tick(self, *_):
        """One animation frame: samples_per_frame device samples, then the picture."""
        for _ in range(self.samples_per_frame):
            self.reading = self.session.step(self.next_position())
        self.peak_force = max(self.peak_force, float(np.linalg.norm(self.reading.force)))
        self.redraw()
        return self.reading

    def redraw(self) -> None:
        x, _, _ = self.session.frame()
        xv = self._view(x)
        self.cells_art.set_verts(xv[self._cells])
        self.edges_art.set_segments(xv[self.session.system.edges])
        r = self.reading
        force = np.zeros(2) if r is None else np.asarray(r.force)[self.axes_idx]
        self.painter.update(self.probe_art, self.probe_view(), force, 0 if r is None else r.contacts)
        self.time_art.set_text(f"t = {self.session.time:.3f} s")
        self.fig.canvas.draw_idle()

    def run(self, interval_ms: int = 30):
        """Animate in the figure's window until it is closed (an interactive backend)."""
        import matplotlib.pyplot as plt
        timer = self.fig.canvas.new_timer(interval=interval_ms)
        timer.add_callback(self.tick)
        timer.start()
        plt.show()
        timer.stop()
