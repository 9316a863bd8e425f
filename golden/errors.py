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


class BadArgument(RheoError, ValueError):
    """An argument that names nothing known (a preset, backend, simulator, device, output format) or is out
    of its range; the message names it and what is allowed."""


class StabilityError(RheoError, RuntimeError):
    """A stability measurement that cannot be made (its reference run is unstable, no bracket found)."""


class OutputError(RheoError, OSError):
    """An output that cannot be written where the user asked (not writable, a directory where a file is
    wanted or the reverse, a full disk); the message names the path."""


class SimulatorFailed(RheoError, RuntimeError):
    """An HDL simulator that is present but failed to build or run the core; the message names the
    simulator, its log and the log's last error line."""
