"""`rheo play SCENE [--backend golden|fixed]`: drag the probe with the mouse and feel (see) the object
push back, live (sim/play.py)."""
from __future__ import annotations

from .common import FORMAT_PRESETS, UsageError, load_system, positive_float, positive_int, scene_argument

NAME, HELP = "play", "drag a scene's probe with the mouse in a window; the object deforms live"
DESCRIPTION = ("Open a window on a scene with a [probe] table: press the mouse button in it and drag, and the "
               "probe follows the pointer (at a bounded speed); every animation frame runs one device sample "
               "(the scene's k steps) and draws the object, the probe and the force on it. 3D scenes are shown "
               "from the side (x, z). Needs a display.")


def add_arguments(parser) -> None:
    scene_argument(parser)
    parser.add_argument("--backend", default="golden", choices=("golden", "fixed"),
                        help="model to run (default: golden; fixed: the bit-true model, slower)")
    parser.add_argument("--preset", default="wide", choices=FORMAT_PRESETS,
                        help="number-format preset of the fixed backend (default: wide)")
    parser.add_argument("--samples-per-frame", type=positive_int, default=1,
                        help="device samples (of k steps each) per animation frame (default 1)")
    parser.add_argument("--max-speed", type=positive_float, default=0.05,
                        help="the probe's top speed behind the pointer, m/s (default 0.05)")


def run(args) -> int:
    import os
    import sys
    system = load_system(args.scene)
    if system.probe is None:
        raise UsageError(f"scene '{system.name}' has no [probe] table: nothing to drag")
    if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        raise UsageError("rheo play opens a window, and there is no display here (DISPLAY is not set); "
                         "`rheo haptic` drives the probe from a trajectory file instead")
    import matplotlib.pyplot as plt
    try:
        plt.switch_backend("TkAgg")
    except (ImportError, RuntimeError) as exc:
        raise UsageError(f"rheo play needs an interactive matplotlib backend (TkAgg): {exc}") from None
    from sim.haptic import connect
    from sim.play import PlayController
    with connect(system, args.backend, args.preset) as sim:
        fig = plt.figure(figsize=(8, 5))
        PlayController(sim, fig, max_speed=args.max_speed, samples_per_frame=args.samples_per_frame).run()
    return 0
