"""The project's errors. Every problem the user can cause or meet (a bad scene or mesh, a number format that
cannot hold the scene, a run that diverges, a missing simulator or toolchain, a size this machine cannot
hold) is a `RheoError`; the command line prints it as one line and exits with code 2. Anything else is a
bug and keeps its traceback."""
from __future__ import annotations


class RheoError(Exception):
    """A problem for the user to fix, stated in one message that names it (and, where there is one, the
    remedy)."""


class SimulationDiverged(RheoError, RuntimeError):
    """The run blew up (non-finite state, exploding energy, runaway saturations); the message says when
    and where."""
