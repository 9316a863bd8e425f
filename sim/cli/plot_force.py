"""`rheo plot-force run.npz [run2.npz ...] --out loops.png`: force against indentation of haptic runs."""
from __future__ import annotations

NAME, HELP = "plot-force", "draw force against indentation of haptic runs (loading-unloading loops)"


def add_arguments(parser) -> None:
    parser.add_argument("runs", nargs="+", help="run files written by `rheo haptic`")
    parser.add_argument("--out", required=True, help="output .png")
    parser.add_argument("--labels", nargs="+", help="a label per run file (default: the scene names)")


def run(args) -> int:
    from sim.forceplot import plot_force
    out = plot_force(args.runs, args.out, args.labels)
    print(f"wrote {out}")
    return 0
