"""Sizes checked before anything is allocated: a request this machine cannot hold is an error that names
it, never a MemoryError from deep inside NumPy (issue 13)."""
from __future__ import annotations

import os

# What one node of a scene costs the golden model and the scene compiler, all arrays together (positions,
# velocities, masses, the ~3 (2D) to ~7 (3D) elements and their parameters, cells, topology pairs, a few
# temporaries of a step): a generous round figure, so that the check errs on the side of refusing.
BYTES_PER_NODE = 4096
# What one node costs the other backends (peak memory of `rheo simulate square:N --backend B --steps 2` under
# /usr/bin/time, less the interpreter's 31 MB, per node, rounded up: golden and fixed about 6 kB at 1e4
# nodes, the range analysis and integer copies included; the Amaranth core, elaborated as Python objects
# per memory word and simulated, 290 kB at 361 nodes; Icarus Verilog compiling and running the emitted core,
# 1.06 MB at 121 nodes; Verilator and the FPGA benchmark taken as Icarus).
BACKEND_BYTES_PER_NODE = {"golden": BYTES_PER_NODE, "cpu": BYTES_PER_NODE, "fixed": 2 * BYTES_PER_NODE,
                          "amaranth": 96 * BYTES_PER_NODE, "icarus": 384 * BYTES_PER_NODE,
                          "verilator": 384 * BYTES_PER_NODE, "fpga": 384 * BYTES_PER_NODE}
SHARE = 0.5            # of the physical memory that one run may plan to use


def physical_memory() -> int:
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):     # not POSIX: assume a small machine
        return 8 << 30


def _gb(n: float) -> str:
    return f"{n / 2 ** 30:.3g} GB"


def over_memory(need_bytes: float, what: str) -> str | None:
    """None when `need_bytes` fits SHARE of this machine's memory, else a message naming `what`."""
    have = physical_memory()
    if need_bytes <= SHARE * have:
        return None
    return f"{what} needs about {_gb(need_bytes)} of memory; this machine has {_gb(have)}"


def mesh_nodes_fit(nodes: float, what: str, backend: str = "golden") -> str | None:
    """None when a mesh of `nodes` nodes fits this machine on `backend`, else a message naming `what`."""
    per = BACKEND_BYTES_PER_NODE.get(backend, BYTES_PER_NODE)
    on = "" if backend in ("golden", "cpu") else f" on the {backend} backend"
    return over_memory(float(nodes) * per, f"{what} ({nodes:.3g} nodes){on}")
