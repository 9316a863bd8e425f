"""The run file: an NPZ with the frames of one run and the mesh, identical in layout for every backend.

Keys: t (F,), x and v (F, N, D) in SI units, a (F, E), edges (E, 2), cells (C, D + 1), node_object (N,),
cell_object (C,), object_names, pinned (N,), mass (N,), dim, dt, scene, backend, floor_height (NaN
without a floor). A haptic run (`rheo haptic`) records a frame every few device samples and adds, per
sample, probe_t (S,) (the time at the sample's end), probe_p (S, D) (the position held), probe_force
(S, D) (the force on the probe in the sample's last step, N) and probe_contacts (S,), and probe_radius,
probe_p0 (the initial position) and probe_k (steps per sample); the fixed backend also probe_force_raw. Fixed-point and hardware backends add x_raw, v_raw, a_raw and saturations per frame, and
preset, formats, stagnation, saturation_names, saturation_counts, constant_saturations and units; the
simulated cores also cycles ((runs, 2): steps and cycles of each run) and cycles_per_step.
"""
from __future__ import annotations

import contextlib
import errno
import json
import os
import shutil
import signal
import tempfile
import zipfile
import zlib
from pathlib import Path

import numpy as np

from golden.errors import BadArgument, OutputError, RheoError
from golden.system import Run, System

DRAWING_KEYS = ("t", "x", "edges", "cells", "node_object", "pinned")     # what a picture needs
_READ_ERRORS = (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error)
_OPTIONAL_KEYS = ("v", "a", "cell_object", "object_names", "dim", "scene", "floor_height")
PROBE_KEYS = ("probe_t", "probe_p", "probe_force", "probe_contacts", "probe_radius", "probe_p0")


class RunFileError(RheoError, ValueError):
    """A run file that is unreadable or malformed; the message names it and the problem."""


class RunFileMissing(RunFileError, FileNotFoundError):
    """No run file where one was named."""


def run_arrays(system: System, run: Run, backend: str) -> dict:
    """Every array of the run file: the frames, the mesh, and what the backend added (raw words, formats)."""
    return dict(**run.raw, **run.info,
        t=run.t, x=run.x, v=run.v, a=run.a,
        edges=system.edges, cells=system.cells, node_object=system.node_object, cell_object=system.cell_object,
        object_names=np.array(system.object_names), pinned=system.pinned, mass=system.mass,
        dim=np.int64(system.dim), dt=np.float64(system.dt), scene=np.str_(system.name), backend=np.str_(backend),
        floor_height=np.float64(system.floor.height if system.floor is not None else np.nan),
    )


def haptic_arrays(system: System, arrays: dict, backend: str, extra: dict | None = None) -> dict:
    """The run file of a haptic run (sim/haptic.py run_trajectory's arrays): the frames and the mesh as
    run_arrays, plus the probe per device sample."""
    raw = {k: arrays[k] for k in ("x_raw", "v_raw", "a_raw", "saturations") if k in arrays}
    run = Run(arrays["t"], arrays["x"], arrays["v"], arrays["a"], float(arrays["wall_seconds"]), raw, dict(extra or {}))
    out = run_arrays(system, run, backend)
    out.update({k: v for k, v in arrays.items() if k.startswith("probe_")})
    return out


def save(path, arrays: dict) -> Path:
    """Write atomically: a failed write never leaves a half file in place of a good one."""
    path = Path(path)
    if path.suffix != ".npz":
        raise BadArgument(f"output file must end in .npz, got '{path.name}'")
    return write_atomically(path, lambda tmp: np.savez_compressed(tmp, **arrays))


def write_atomically(path, write) -> Path:
    """Call write(tmp) on a hidden temporary file beside `path`, give it the mode a plain open() would
    (mkstemp's is 0600), then rename it into place: a failed or interrupted write (SIGINT, SIGTERM: the CLI
    turns both into KeyboardInterrupt) leaves the old file byte-identical and no temporary behind. A file
    system problem (not writable, a directory in the way, a full disk) is an OutputError naming `path`."""
    path = Path(path)
    check_output_file(path)
    tmp = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(suffix=path.suffix, prefix=f".{path.stem}.", dir=path.parent)
        os.close(fd)
        write(tmp)
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    except OSError as exc:
        raise _output_error(path, exc) from None
    finally:
        if tmp is not None and os.path.exists(tmp):
            os.unlink(tmp)
    return path


# ----------------------------------------------------------------------------------------------------
# Outputs: checked before any work starts; a directory output is whole or not there (issue 13)
# ----------------------------------------------------------------------------------------------------

_FILE_SYSTEM_ERRNOS = {errno.EACCES, errno.EPERM, errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EISDIR,
                       errno.ENOTDIR, errno.ENOENT, errno.ENAMETOOLONG, errno.EEXIST, errno.EXDEV}
MARKER = ".rheo-output"          # in every output directory: the files rheo wrote there (JSON list)


def _output_error(path, exc: OSError) -> Exception:
    if exc.errno not in _FILE_SYSTEM_ERRNOS:
        return exc                                   # not the user's file system problem: a bug, re-raised
    return OutputError(f"cannot write {path}: {exc.strerror or exc}")


def _check_parent(path: Path, what: str) -> None:
    """The nearest existing ancestor of `path` is a directory rheo may write into."""
    parent = path.parent
    while not parent.exists() and not parent.is_symlink() and parent != parent.parent:
        parent = parent.parent
    if not parent.is_dir():
        raise OutputError(f"{what} {path}: {parent} is not a directory")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise OutputError(f"{what} {path}: {parent} is not writable")


def check_output_file(path, suffixes: tuple[str, ...] = ()) -> Path:
    """Refuse, before any work, a file output that cannot be written: an existing directory, a parent that is
    a file or not writable, a suffix not in `suffixes`."""
    path = Path(path)
    if suffixes and path.suffix.lower() not in suffixes:
        raise BadArgument(f"output file {path} must end in {' or '.join(suffixes)}")
    if path.is_dir():
        raise OutputError(f"output file {path} is an existing directory")
    _check_parent(path, "output file")
    return path


def check_output_dir(path) -> Path:
    """Refuse, before any work, a directory output that cannot be written: an existing file, a parent that is
    a file or not writable."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise OutputError(f"output directory {path} is an existing file")
    _check_parent(path, "output directory")
    return path


@contextlib.contextmanager
def output_directory(path):
    """Yield a fresh temporary directory beside `path` to write a multi-file output into; when the block ends
    without error, move it into place as `path` in one rename. A failed or interrupted block leaves `path`
    as it was (byte for byte) and nothing new behind.

    An existing `path` is replaced only then, whole, except for the files a user put there: what rheo wrote
    before (listed in its MARKER file) goes, every other file is carried over into the new directory unless
    the new output has a file of the same name (hard links: no copy, no time)."""
    path = check_output_dir(path)
    tmp = None
    try:
        with _as_output_error(path):
            path.parent.mkdir(parents=True, exist_ok=True)
            tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".partial", dir=path.parent))
            os.chmod(tmp, 0o777 & ~_umask())
        yield tmp
        with _as_output_error(path):
            written = sorted(str(f.relative_to(tmp)) for f in tmp.rglob("*")
                             if not f.is_dir() and f.name != MARKER)
            (tmp / MARKER).write_text(json.dumps(written, indent=0) + "\n")
            if path.exists():
                _carry_over(path, tmp)
            _swap(tmp, path)
    finally:
        if tmp is not None and tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)


@contextlib.contextmanager
def _as_output_error(path):
    try:
        yield
    except OSError as exc:
        raise _output_error(path, exc) from None


def _carry_over(old: Path, new: Path) -> None:
    """Link into `new` the files of `old` that rheo did not write there (its MARKER lists what it wrote)."""
    try:
        ours = set(json.loads((old / MARKER).read_text()))
    except (OSError, ValueError):
        ours = set()
    for f in sorted(old.rglob("*")):
        rel = f.relative_to(old)
        if f.name == MARKER or str(rel) in ours or f.is_dir() and not f.is_symlink():
            continue
        dst = new / rel
        if dst.exists() or dst.is_symlink():
            continue                                  # the new output has a file of that name
        for up in rel.parents:
            if (new / up).exists() and not (new / up).is_dir():
                raise OutputError(f"cannot replace {old}: its file {f} would lie under the new output's file "
                                  f"{new.name}/{up}; move it away first")
        dst.parent.mkdir(parents=True, exist_ok=True)
        if f.is_symlink():
            os.symlink(os.readlink(f), dst)
        else:
            try:
                os.link(f, dst)
            except OSError:
                shutil.copy2(f, dst)


def _swap(tmp: Path, path: Path) -> None:
    """Move `tmp` into place as `path` with SIGINT and SIGTERM held back, so that an interrupt finds either
    the old directory or the new one."""
    old_mask = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT, signal.SIGTERM})
    try:
        if path.exists():
            trash = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".old", dir=path.parent))
            os.rename(path, trash / "old")
            try:
                os.rename(tmp, path)
            except OSError:
                os.rename(trash / "old", path)
                raise
            finally:
                shutil.rmtree(trash, ignore_errors=True)
        else:
            os.rename(tmp, path)
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old_mask)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


# ----------------------------------------------------------------------------------------------------
# Reading and checking a run file (the renderer, the VTK export)
# ----------------------------------------------------------------------------------------------------

def load_run(npz_path, required=DRAWING_KEYS) -> dict:
    """Read the keys of a run file needed here, check their shapes and return them normalised.

    Returns a dict with at least t, x, edges, cells (shape (C, D+1) even when empty), node_object,
    pinned, cell_object, object_names (list of str), n_objects, dim, scene (str), floor_height (float,
    NaN without a floor), plus v and a when present.
    """
    path = Path(npz_path)
    if not path.is_file():
        raise RunFileMissing(f"run file not found: {path}")
    data = {}
    try:
        f = np.load(path, allow_pickle=False)
    except _READ_ERRORS as exc:
        raise RunFileError(f"cannot read run file {path}: {exc}") from None
    if not hasattr(f, "files"):
        raise RunFileError(f"cannot read run file {path}: not an NPZ archive")
    try:
        with f:
            files = set(f.files)
            missing = [k for k in required if k not in files]
            if not missing:
                for k in (set(required) | set(_OPTIONAL_KEYS) | set(PROBE_KEYS)) & files:
                    try:
                        data[k] = f[k]
                    except ValueError:
                        if k in required:
                            raise
                        # an optional key that cannot be read without pickling is ignored
    except _READ_ERRORS as exc:
        raise RunFileError(f"cannot read run file {path}: {exc}") from None
    if missing:
        raise RunFileError(f"run file {path} lacks required key(s): {', '.join(missing)}")
    return _check_run(path, data)


def _bad(path, what):
    return RunFileError(f"run file {path}: {what}")


def _check_run(path, d: dict) -> dict:
    x = np.asarray(d["x"], dtype=np.float64)
    if x.ndim != 3 or x.shape[2] not in (2, 3):
        raise _bad(path, f"x must have shape (F, N, 2|3), got {x.shape}")
    F, N, D = x.shape
    if F == 0:
        raise _bad(path, "the run has no frames")
    t = np.asarray(d["t"], dtype=np.float64).reshape(-1)
    if t.shape != (F,):
        raise _bad(path, f"t has {t.size} entries but x has {F} frames")
    if "dim" in d and int(d["dim"]) != D:
        raise _bad(path, f"dim is {int(d['dim'])} but x has {D} components")

    edges = np.asarray(d["edges"])
    if edges.size == 0:
        edges = np.zeros((0, 2), np.int64)
    if edges.ndim != 2 or edges.shape[1] != 2:
        raise _bad(path, f"edges must have shape (E, 2), got {edges.shape}")
    edges = edges.astype(np.int64)
    E = len(edges)

    out = dict(t=t, x=x, edges=edges, dim=D)

    if "cells" in d:
        cells = np.asarray(d["cells"])
        if cells.size == 0:
            cells = np.zeros((0, D + 1), np.int64)
        if cells.ndim != 2 or cells.shape[1] != D + 1:
            raise _bad(path, f"cells must have shape (C, {D + 1}) in {D}D, got {cells.shape}")
        cells = cells.astype(np.int64)
    else:
        cells = np.zeros((0, D + 1), np.int64)
    out["cells"] = cells
    for name, idx in (("edges", edges), ("cells", cells)):
        if idx.size and (idx.min() < 0 or idx.max() >= N):
            raise _bad(path, f"{name} refer to nodes outside 0..{N - 1}")

    node_object = np.asarray(d["node_object"]).reshape(-1) if "node_object" in d else np.zeros(N, np.int64)
    if node_object.shape != (N,):
        raise _bad(path, f"node_object has {node_object.size} entries for {N} nodes")
    node_object = node_object.astype(np.int64)
    if N and node_object.min() < 0:
        raise _bad(path, "node_object has negative entries")
    out["node_object"] = node_object

    pinned = np.asarray(d["pinned"]).reshape(-1) if "pinned" in d else np.zeros(N, bool)
    if pinned.shape != (N,):
        raise _bad(path, f"pinned has {pinned.size} entries for {N} nodes")
    out["pinned"] = pinned.astype(bool)

    cell_object = None
    if "cell_object" in d:
        cell_object = np.asarray(d["cell_object"]).reshape(-1).astype(np.int64)
        if cell_object.shape != (len(cells),):
            cell_object = None
    if cell_object is None:  # fall back on the object of each cell's first node
        cell_object = node_object[cells[:, 0]] if len(cells) else np.zeros(0, np.int64)
    out["cell_object"] = cell_object

    names = [str(s) for s in np.asarray(d.get("object_names", [])).reshape(-1)]
    n_objects = max(len(names), int(node_object.max()) + 1 if N else 0,
                    int(cell_object.max()) + 1 if len(cell_object) else 0)
    names += [f"object {k}" for k in range(len(names), n_objects)]
    out["object_names"] = names
    out["n_objects"] = n_objects

    if "v" in d:
        v = np.asarray(d["v"], dtype=np.float64)
        if v.shape != x.shape:
            raise _bad(path, f"v has shape {v.shape} but x has {x.shape}")
        out["v"] = v
    if "a" in d:
        a = np.asarray(d["a"], dtype=np.float64)
        if a.size == 0 and E == 0:
            a = np.zeros((F, 0))
        if a.shape != (F, E):
            raise _bad(path, f"a must have shape ({F}, {E}), got {a.shape}")
        out["a"] = a

    out["scene"] = str(d["scene"]) if "scene" in d else ""
    fh = np.asarray(d.get("floor_height", np.nan), dtype=np.float64).reshape(-1)
    out["floor_height"] = float(fh[0]) if fh.size else float("nan")
    if all(k in d for k in PROBE_KEYS):
        out["probe"] = _check_probe(path, d, D)
    return out


def _check_probe(path, d: dict, D: int) -> dict:
    """The probe of a haptic run: per sample t (S,), p and force (S, D), contacts (S,); radius, p0 (D,)."""
    t = np.asarray(d["probe_t"], np.float64).reshape(-1)
    S = len(t)
    p = np.asarray(d["probe_p"], np.float64)
    force = np.asarray(d["probe_force"], np.float64)
    contacts = np.asarray(d["probe_contacts"]).reshape(-1)
    for name, arr in (("probe_p", p), ("probe_force", force)):
        if arr.shape != (S, D):
            raise _bad(path, f"{name} must have shape ({S}, {D}), got {arr.shape}")
    if contacts.shape != (S,):
        raise _bad(path, f"probe_contacts has {contacts.size} entries for {S} samples")
    p0 = np.asarray(d["probe_p0"], np.float64).reshape(-1)
    if p0.shape != (D,):
        raise _bad(path, f"probe_p0 must have {D} entries, got {p0.size}")
    radius = float(np.asarray(d["probe_radius"], np.float64).reshape(-1)[0])
    return dict(t=t, p=p, force=force, contacts=contacts.astype(np.int64), p0=p0, radius=radius)
