"""The run file: an NPZ with the frames of one run and the mesh, identical in layout for every backend.

Keys: t (F,), x and v (F, N, D) in SI units, a (F, E), edges (E, 2), cells (C, D + 1), node_object (N,),
cell_object (C,), object_names, pinned (N,), mass (N,), dim, dt, scene, backend, floor_height (NaN
without a floor). Backends may add raw integer states and counters.
"""
from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np

from golden.model import Run, System


def run_arrays(sys: System, run: Run, backend: str) -> dict:
    return dict(
        t=run.t, x=run.x, v=run.v, a=run.a,
        edges=sys.edges, cells=sys.cells, node_object=sys.node_object, cell_object=sys.cell_object,
        object_names=np.array(sys.object_names), pinned=sys.pinned, mass=sys.mass,
        dim=np.int64(sys.dim), dt=np.float64(sys.dt), scene=np.str_(sys.name), backend=np.str_(backend),
        floor_height=np.float64(sys.floor.height if sys.floor is not None else np.nan),
    )


def save(path, arrays: dict) -> Path:
    """Write atomically: a failed write never leaves a half file in place of a good one."""
    path = Path(path)
    if path.suffix != ".npz":
        raise ValueError(f"output file must end in .npz, got '{path.name}'")
    return write_atomically(path, lambda tmp: np.savez_compressed(tmp, **arrays))


def write_atomically(path, write) -> Path:
    """Call write(tmp) on a hidden temporary file beside `path`, give it the mode a plain open() would
    (mkstemp's is 0600), then rename it into place: a failed or interrupted write (SIGINT, SIGTERM: the CLI
    turns both into KeyboardInterrupt) leaves the old file byte-identical and no temporary behind."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(suffix=path.suffix, prefix=f".{path.stem}.", dir=path.parent)
    os.close(fd)
    try:
        write(tmp)
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return path


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def load(path) -> dict:
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"run file not found: {path}")
    try:
        with np.load(path, allow_pickle=False) as f:
            return {k: f[k] for k in f.files}
    except (OSError, ValueError) as exc:
        raise ValueError(f"cannot read run file {path}: {exc}") from None
