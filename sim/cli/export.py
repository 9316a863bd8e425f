"""`rheo export run.npz --vtk DIR`: a VTK time series of a run for ParaView."""
from __future__ import annotations

NAME, HELP = "export", "write a VTK time series (ParaView) of a run"


def add_arguments(parser) -> None:
    parser.add_argument("run", help="run .npz written by `rheo simulate`")
    parser.add_argument("--vtk", required=True, metavar="DIR", help="output directory (frame_*.vtu and run.pvd)")


def run(args) -> int:
    from sim.vtk_export import export_vtk
    files = export_vtk(args.run, args.vtk)
    print(f"wrote {len(files)} VTK frames and run.pvd to {args.vtk}")
    return 0
