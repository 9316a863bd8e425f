"""router2 stalls are seen in nextpnr's log and the next seed is tried (sim/synth.py `RouterWatch`,
`place_and_route_seeds`), with a fake nextpnr that writes router2's log lines."""
import sys
import time

import pytest

from sim.synth import STALL_ITERATIONS, STALL_MINUTES, RouterWatch, SynthesisError, place_and_route_seeds, stall_text

# overused wires by iteration (1 ..), router2 on the 1e4 square at P = 6 (s13 netlist, seed 2): measured
STALLED = [62668, 37749, 24909, 17605, 13026, 10590, 8656, 7329, 6307, 5533, 4594, 4085, 3536, 3182, 2802, 2659,
           2294, 2060, 1751, 1623, 1554, 1476, 1276, 1211, 1142, 1054, 1025, 867, 862, 839, 735, 656, 665, 613,
           572, 544, 565, 534, 507, 516, 524, 495, 503, 534, 563, 610, 671, 701, 765, 787, 807, 855, 900, 996,
           1054, 1155, 1319, 1506, 1781]
# the same start, then the bumps of a run that gets through: a plateau above its fewest, then down to 0
ROUTED = STALLED[:42] + [503, 534, 563, 610, 671, 701, 640, 600, 560, 520, 498, 480, 300, 120, 20, 0]


def log_of(counts):
    return "".join(f"Info:     iter={k + 1} wires={1000000 + k} overused={c} overuse={c} archfail=NA\n"
                   for k, c in enumerate(counts))


def test_a_climb_after_the_fewest_count_is_a_stall():
    watch = RouterWatch()
    stall = watch.feed(log_of(STALLED))
    # fewest 495 at 42; 15 iterations on (57) the count is 1,319 >= 2 x 495
    assert stall == {"iteration": 57, "overused": 1319, "fewest": 495, "fewest_at": 42}
    assert 57 - 42 == STALL_ITERATIONS


def test_a_plateau_that_comes_down_is_not_a_stall():
    watch = RouterWatch()
    assert watch.feed(log_of(ROUTED)) is None
    assert watch.last == (len(ROUTED), 0) and watch.fewest == 0


def test_the_log_read_again_counts_each_iteration_once():
    watch = RouterWatch()
    for n in range(1, len(STALLED) + 1):
        stall = watch.feed(log_of(STALLED[:n]))      # the whole log so far, every poll
        if stall is not None:
            break
    assert stall is not None and stall["iteration"] == 57


# a grind: router2 on the same square (s14 netlist, seed 6), about 6 minutes an iteration, the count hovering
# above its fewest (4,457 at iteration 18 and 5,396 at 21 measured; the rest of the curve made up around them)
GRIND = [65744, 41000, 30000, 24000, 19500, 16000, 14000, 12500, 11200, 10300, 9800, 9385, 8100, 7000, 6100,
         5400, 4900, 4457, 4700, 5100, 5396, 5200, 4900, 4800, 4600]


def feed_one_by_one(watch, counts, seconds_each):
    """Feed the log as it grows, one iteration every seconds_each; the first stall or None."""
    for n in range(1, len(counts) + 1):
        stall = watch.feed(log_of(counts[:n]), now=n * seconds_each)
        if stall is not None:
            return stall
    return None


def test_a_grind_without_a_new_fewest_is_a_stall():
    stall = feed_one_by_one(RouterWatch(), GRIND, 360.0)
    # fewest 4,457 seen at 18 x 360 s; 30 minutes later (23 x 360 s) iteration 23 is the latest
    assert STALL_MINUTES == 30.0
    assert stall == {"iteration": 23, "overused": 4900, "fewest": 4457, "fewest_at": 18, "minutes": 30.0}
    assert stall_text(stall) == "4,900 overused wires at iteration 23, fewest 4,457 at 18, none fewer for 30 min"


def test_one_iteration_longer_than_the_limit_is_a_grind_too():
    watch = RouterWatch()
    assert watch.feed(log_of(GRIND[:18]), now=0.0) is None
    assert watch.feed(log_of(GRIND[:18]), now=60 * STALL_MINUTES - 1) is None      # no new line yet
    assert watch.feed(log_of(GRIND[:18]), now=60 * STALL_MINUTES)["fewest_at"] == 18


# router2 near its end on the 1e4 square at P = 6 (session 17's netlist, seed 2), iterations 40 to 66: measured
FINISHING = [3, 6, 5, 2, 5, 4, 1, 1, 1, 1, 1, 2, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 2, 1]


def test_a_count_of_one_or_two_is_not_a_stall():
    """The ratio alone (2 >= 2 x 1, 19 iterations after the fewest) stopped this run; it is 1 wire from
    routed, so it goes on (the grind rule, STALL_MINUTES without a new fewest, still bounds it)."""
    watch = RouterWatch()
    assert watch.feed(log_of(STALLED[:39] + FINISHING)) is None
    assert watch.last == (39 + len(FINISHING), 1) and watch.fewest == 1
    assert RouterWatch(excess=1).feed(log_of(STALLED[:39] + FINISHING))["overused"] == 2   # what it was


def test_a_routed_run_at_its_measured_pace_is_not_a_grind():
    # routed runs of the square took 20 to 30 s an iteration (55b4a19: 61 iterations, nextpnr 1,588 s)
    assert feed_one_by_one(RouterWatch(), ROUTED, 30.0) is None


FAKE = r'''
import sys, time
args = sys.argv[1:]
seed, log = int(args[args.index("--seed") + 1]), args[args.index("--log") + 1]
counts = {stalled}.get(seed, {routed})
with open(log, "w") as f:
    f.write("Info: Max frequency for clock '$glbnet$clk': 62.53 MHz (FAIL at 100.00 MHz)\n")
    f.write("Info: Running router2...\n")
    for k, c in enumerate(counts):
        f.write(f"Info:     iter={{k + 1}} wires={{1000000 + k}} overused={{c}} overuse={{c}} archfail=NA\n")
        f.flush()
        time.sleep(0.002)
if seed in {stalled}:
    time.sleep(60)                     # a stalled router runs on: only the watch stops it
'''


def fake_nextpnr(tmp_path, stalled_seeds):
    script = tmp_path / "fake_nextpnr.py"
    stalled = {s: STALLED + [2000] * 5 for s in stalled_seeds}
    script.write_text(FAKE.format(stalled=stalled, routed=ROUTED))
    return lambda seed: [sys.executable, str(script), "--seed", str(seed), "--log", "nextpnr.log"]


def test_a_stalled_seed_is_stopped_and_the_next_one_routes(tmp_path):
    said = []
    t0 = time.monotonic()
    seed, stalls = place_and_route_seeds(fake_nextpnr(tmp_path, {3}), tmp_path / "nextpnr.log", tmp_path, 300.0,
                                         3, "router2", said.append, poll_s=0.05)
    assert time.monotonic() - t0 < 30                 # the stalled run was killed, not waited for
    assert seed == 4
    assert stalls == [{"seed": 3, "iteration": 57, "overused": 1319, "fewest": 495, "fewest_at": 42}]
    assert (tmp_path / "nextpnr-seed3-stalled.log").is_file()
    assert "overused=0" in (tmp_path / "nextpnr.log").read_text()     # the log is the routed seed's
    assert any("stalled with seed 3" in s and "trying seed 4" in s for s in said), said
    # the placement's estimate, said once a seed before its routing (the stalled seed's for certain: it runs on)
    placed = [k for k, s in enumerate(said) if "placed" in s and "Fmax estimate 62.53 MHz before routing" in s]
    stalled = next(k for k, s in enumerate(said) if "stalled with seed 3" in s)
    assert 1 <= len(placed) <= 2 and placed[0] < stalled, said


def test_every_seed_stalled_is_an_error_naming_them(tmp_path):
    with pytest.raises(SynthesisError, match=r"stalled with every seed tried: seed 1: 1,319 overused wires at "
                                             r"iteration 57, fewest 495 at 42; seed 2: .*; seed 3: "):
        place_and_route_seeds(fake_nextpnr(tmp_path, {1, 2, 3}), tmp_path / "nextpnr.log", tmp_path, 300.0,
                              1, "router2", poll_s=0.05)


def test_router1_runs_once_unwatched(tmp_path):
    # router1 writes no iter= lines of router2's form; a stall-shaped log from it is not watched
    seed, stalls = place_and_route_seeds(lambda s: [sys.executable, "-c", "import sys; sys.exit(0)"],
                                         tmp_path / "nextpnr.log", tmp_path, 60.0, 5, "router1")
    assert (seed, stalls) == (5, [])
