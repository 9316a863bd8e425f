"""`rheo`: the command line. One module per subcommand (sim/cli/*.py), each with its NAME, HELP,
`add_arguments(parser)` and `run(args)`. Every user error (a `golden.errors.RheoError`) is one line on
stderr and exit code 2, never a traceback; anything else is a bug and keeps its traceback."""
from __future__ import annotations

import argparse
import errno
import os
import signal
import sys

from . import bench, export, haptic, play, plot_force, report, run, scenes, show, simulate, stability, synth, verilog
from .common import UsageError

COMMANDS = (scenes, simulate, haptic, play, verilog, synth, show, plot_force, export, bench, stability, report, run)

__all__ = ["COMMANDS", "UsageError", "build_parser", "error_line", "main"]


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="rheo", description="Rheological soft-object simulator: golden model, "
                                "bit-true fixed point and FPGA pipeline (Kimura et al. 2002).")
    sub = p.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for cmd in COMMANDS:
        s = sub.add_parser(cmd.NAME, help=cmd.HELP, description=getattr(cmd, "DESCRIPTION", None))
        cmd.add_arguments(s)
        s.set_defaults(func=cmd.run)
    return p


def main(argv=None) -> int:
    from golden.errors import RheoError
    parser = build_parser()
    args = parser.parse_args(argv)
    signal.signal(signal.SIGTERM, _terminated)       # SIGTERM like Ctrl-C: outputs are cleaned up alike
    previous_hook, sys.unraisablehook = sys.unraisablehook, _interrupt_not_swallowed(sys.unraisablehook)
    try:
        return args.func(args)
    except BrokenPipeError:                          # `rheo scenes | head -1`: the reader left; no message
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
    except RheoError as exc:
        print(error_line(exc), file=sys.stderr)
        return 2
    except OSError as exc:
        # Outputs are written through sim.runfile (write_atomically, output_directory), which turn these
        # into an OutputError naming the path; this catches the same file-system problems where a library
        # opens a path the user named (a scene, a mesh, a run file): a path that is not readable, a
        # directory or on a full disk is the user's to fix. Any other OSError is a bug: traceback.
        if exc.errno not in USER_FILE_ERRNOS or exc.filename is None:
            raise
        print(error_line(f"{exc.filename}: {exc.strerror}"), file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("rheo: interrupted", file=sys.stderr)
        return 130
    finally:
        sys.unraisablehook = previous_hook


USER_FILE_ERRNOS = {errno.EACCES, errno.EPERM, errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EISDIR, errno.ENOTDIR,
                    errno.ENOENT, errno.ENAMETOOLONG, errno.EEXIST}


def error_line(exc) -> str:
    """The one line a user error prints: its message's lines joined, so a remedy on a later line is kept."""
    text = "; ".join(line.strip() for line in str(exc).splitlines() if line.strip())
    return f"rheo: error: {text or type(exc).__name__}"


def _terminated(signum, frame):
    raise KeyboardInterrupt


def _interrupt_not_swallowed(default_hook):
    """An `unraisablehook`. Python drops an exception raised inside a weakref callback or a finaliser
    ("Exception ignored in ..."): an interrupt landing there would be lost and the run would go on (CI
    saw `rheo run` finish its simulations after SIGTERM). This delivers it again 10 ms later, from a
    timer: raised here, it would be dropped once more."""
    def hook(unraisable):
        if isinstance(unraisable.exc_value, KeyboardInterrupt):
            signal.signal(signal.SIGALRM, _terminated)
            signal.setitimer(signal.ITIMER_REAL, 0.01)
        else:
            default_hook(unraisable)
    return hook
