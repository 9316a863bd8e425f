"""Locate HDL simulators and run cocotb test modules against generated Verilog.

Two simulators are supported, both through ``cocotb_tools.runner``:

* Icarus Verilog >= 11 (Debian package ``iverilog``);
* Verilator >= 5.036 (cocotb 2.x refuses older ones; Debian bookworm ships 5.006),
  normally the pinned build made by ``make verilator`` (tools/build-verilator.sh).

A missing or too old simulator raises :class:`SimulatorMissing`, whose message says
how to get it. Callers (tests included) must let it propagate: never skip.
"""

from __future__ import annotations

import contextlib
import hashlib
import fcntl
import json
import os
import re
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET
from collections.abc import Iterator
from pathlib import Path

__all__ = [
    "SimulatorMissing",
    "find_icarus",
    "find_verilator",
    "verilator_cache_path",
    "run_cocotb",
]

ICARUS_MIN = (11, 0)
VERILATOR_MIN = (5, 36)
VERILATOR_PINNED = "5.048"  # keep in sync with tools/build-verilator.sh

_TIMESCALE = ("1ns", "1ps")  # Amaranth's Verilog carries no `timescale
_LOG_TAIL_LINES = 60


class SimulatorMissing(RuntimeError):
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


def verilator_cache_path() -> Path:
    """Where tools/build-verilator.sh installs the pinned Verilator binary."""
    cache = os.environ.get("RHEO_CACHE") or str(Path.home() / ".cache" / "rheo-fpga")
    return Path(cache) / f"verilator-{VERILATOR_PINNED}" / "bin" / "verilator"


def _verilator_version(binary: str) -> tuple[int, int] | None:
    # The `verilator` wrapper refuses to run when VERILATOR_ROOT points elsewhere.
    env = {k: v for k, v in os.environ.items() if k != "VERILATOR_ROOT"}
    try:
        proc = subprocess.run(
            [binary, "--version"], capture_output=True, text=True, timeout=60,
            check=False, env=env,
        )
    except (OSError, subprocess.SubprocessError):
        return None
    m = re.search(r"Verilator (\d+)\.(\d+)", proc.stdout)
    return (int(m.group(1)), int(m.group(2))) if m else None


def find_verilator() -> str:
    """The first Verilator >= 5.036 among ``$RHEO_VERILATOR``, the cache, ``PATH``."""
    candidates: list[tuple[str, str | None]] = []
    env_bin = os.environ.get("RHEO_VERILATOR")
    if env_bin:
        candidates.append(("RHEO_VERILATOR", env_bin))
    candidates.append(("cache", str(verilator_cache_path())))
    candidates.append(("PATH", shutil.which("verilator")))

    rejected: list[str] = []
    for origin, path in candidates:
        if path is None:
            rejected.append(f"  {origin}: no 'verilator' on PATH")
            continue
        if not (os.path.isfile(path) and os.access(path, os.X_OK)):
            rejected.append(f"  {origin}: {path} does not exist")
            continue
        ver = _verilator_version(path)
        if ver is None:
            rejected.append(f"  {origin}: {path} did not report a version")
        elif ver < VERILATOR_MIN:
            rejected.append(f"  {origin}: {path} is {_fmt(ver)}, too old")
        else:
            return os.path.abspath(path)
    raise SimulatorMissing(
        f"no Verilator >= {_fmt(VERILATOR_MIN)} found (cocotb 2.x refuses older ones; "
        "Debian bookworm's package is 5.006, too old).\n"
        + "\n".join(rejected)
        + f"\nRun `make verilator` to build the pinned Verilator {VERILATOR_PINNED} "
        f"into {verilator_cache_path().parent.parent} (~11 min, once), "
        "or set RHEO_VERILATOR to a Verilator >= 5.036 binary."
    )


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

    if simulator == "icarus":
        binary = find_icarus()
        build_args: list[str] = []
    elif simulator == "verilator":
        binary = find_verilator()
        build_args = ["-Wno-fatal"]  # Amaranth output triggers WIDTH* warnings
    else:
        raise ValueError(f"unsupported simulator {simulator!r} (use 'icarus' or 'verilator')")

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
    # The Verilator wrapper derives VERILATOR_ROOT from its own location and errors
    # out if the environment names another one, so drop it.
    env_updates: dict[str, str | None] = {
        "PATH": os.path.dirname(binary) + os.pathsep + os.environ.get("PATH", ""),
        "VERILATOR_ROOT": None,
    }
    if timeout_s is not None:
        # Honoured by the runner for the simulation command only (coreutils timeout).
        env_updates["SIM_CMD_PREFIX"] = f"timeout --kill-after=10 {float(timeout_s):g}"

    stamp = _build_stamp(simulator, binary, sources, toplevel, build_args)
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
                raise RuntimeError(
                    f"{simulator} build of {toplevel} failed ({e}); "
                    f"tail of {build_log}:\n{_tail(build_log)}"
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
        raise RuntimeError(
            f"{simulator} simulation of {toplevel} ({test_module}) terminated abnormally "
            f"({why}); tail of {test_log}:\n{_tail(test_log)}"
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
