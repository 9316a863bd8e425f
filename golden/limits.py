"""Sizes checked before anything is allocated: a request this machine cannot hold is an error that names
it, never a MemoryError from deep inside NumPy (issue 13)."""
from __future__ import annotations

import os

# What one node of a scene costs the golden model and the scene compiler, all arrays together (positions,
# velocities, masses, the ~3 (2D) to ~7 (3D) elements and their parameters, cells, topology pairs, a few
# temporaries of a step): a generous round figure, so that the check errs on the side of refusing.
BYTES_PER_NODE = 4096
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


def mesh_nodes_fit(nodes: float, what: str) -> str | None:
    return over_memory(float(nodes) * BYTES_PER_NODE, f"{what} ({nodes:.3g} nodes)")
