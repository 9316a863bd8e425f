"""`rheo show run.npz --out frames.png|anim.gif`: pictures of a run."""
from __future__ import annotations

from .common import positive_int

NAME, HELP = "show", "render a run to PNG frames or a GIF animation"


def add_arguments(parser) -> None:
    parser.add_argument("run", help="run .npz written by `rheo simulate`")
    parser.add_argument("--out", required=True, help="output .png (frames side by side) or .gif (animation)")
    parser.add_argument("--frames", type=positive_int, help="number of frames in a PNG (default 4)")


def run(args) -> int:
    from sim.render import render
    from sim.runfile import check_output_file
    check_output_file(args.out, (".png", ".gif"))
    out = render(args.run, args.out, frames=args.frames)
    print(f"wrote {out}")
    return 0
