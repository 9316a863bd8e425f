"""Export a run file to VTK for ParaView: one .vtu per frame plus a .pvd collection.

    export_vtk(npz_path, out_dir) -> list[Path]

Each out_dir/frame_NNNNN.vtu holds the node positions (padded to 3 components in 2D), the mesh cells
("triangle" in 2D, "tetra" in 3D) and the rheological elements as "line" cells. Point data: velocity
(3 components), object, pinned (0/1). Cell data: a (the element state; NaN on triangle/tetra cells)
and object. out_dir/run.pvd lists the frames with their times, so ParaView opens the whole series.

Same error conventions as sim.render: FileNotFoundError for a missing run file, ValueError for a
malformed one.
"""
from __future__ import annotations

from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np

from sim.runfile import load_run

EXPORT_KEYS = ("t", "x", "v", "a", "edges", "cells", "node_object", "pinned")
PVD_NAME = "run.pvd"


def _pad3(p: np.ndarray) -> np.ndarray:
    if p.shape[1] == 3:
        return np.ascontiguousarray(p, dtype=np.float64)
    out = np.zeros((len(p), 3), np.float64)
    out[:, : p.shape[1]] = p
    return out


def frame_name(i: int, n_frames: int) -> str:
    width = max(5, len(str(max(n_frames - 1, 0))))
    return f"frame_{i:0{width}d}.vtu"


def write_pvd(path: Path, times, files) -> Path:
    """A ParaView collection file listing (time, file) pairs; times written with full precision."""
    lines = ['<?xml version="1.0"?>',
             '<VTKFile type="Collection" version="0.1" byte_order="LittleEndian">',
             "  <Collection>"]
    for t, name in zip(times, files):
        lines.append(f'    <DataSet timestep="{float(t)!r}" group="" part="0" file={quoteattr(str(name))}/>')
    lines += ["  </Collection>", "</VTKFile>", ""]
    from .runfile import write_atomically
    return write_atomically(Path(path), lambda tmp: Path(tmp).write_text("\n".join(lines), encoding="utf-8"))


def export_vtk(npz_path, out_dir) -> list[Path]:
    """Write out_dir/frame_00000.vtu ... (one per frame) and out_dir/run.pvd; returns the .vtu paths in
    frame order. The directory is written whole or not at all (sim.runfile.output_directory: an existing
    out_dir is replaced when the new one is complete; files a user put there are kept)."""
    from .runfile import check_output_dir, output_directory
    final = check_output_dir(out_dir)
    run = load_run(npz_path, EXPORT_KEYS)
    with output_directory(final) as tmp:
        names = _export(run, tmp)
    return [final / n for n in names]


def _export(run: dict, out_dir: Path) -> list[str]:
    import meshio

    t, x, v, a = run["t"], run["x"], run["v"], run["a"]
    edges, cells, D = run["edges"], run["cells"], run["dim"]
    F, N = x.shape[0], x.shape[1]
    E, C = len(edges), len(cells)
    node_object = run["node_object"].astype(np.int32)
    pinned = run["pinned"].astype(np.int32)
    edge_object = run["node_object"][edges[:, 0]].astype(np.int32) if E else np.zeros(0, np.int32)
    cell_object = run["cell_object"].astype(np.int32)

    cell_type = "triangle" if D == 2 else "tetra"
    blocks, has_cells, has_lines = [], C > 0, E > 0
    if has_cells:
        blocks.append((cell_type, cells))
    if has_lines:
        blocks.append(("line", edges))
    if not blocks:  # nodes only: vertex cells so the points show up in ParaView
        blocks.append(("vertex", np.arange(N, dtype=np.int64).reshape(-1, 1)))

    cell_nan = np.full(C, np.nan)
    written = []
    for i in range(F):
        a_blocks, obj_blocks = [], []
        if has_cells:
            a_blocks.append(cell_nan)
            obj_blocks.append(cell_object)
        if has_lines:
            a_blocks.append(a[i])
            obj_blocks.append(edge_object)
        if not (has_cells or has_lines):
            a_blocks.append(np.full(N, np.nan))
            obj_blocks.append(node_object)
        mesh = meshio.Mesh(
            _pad3(x[i]), blocks,
            point_data={"velocity": _pad3(v[i]), "object": node_object, "pinned": pinned},
            cell_data={"a": a_blocks, "object": obj_blocks},
        )
        path = out_dir / frame_name(i, F)
        meshio.write(path, mesh, file_format="vtu")
        written.append(path.name)
    write_pvd(out_dir / PVD_NAME, t, written)
    return written
