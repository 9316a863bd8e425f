"""The floorplan of the streaming core's hard blocks (hw/stream/floorplan.py regions, sim/synth.py sites):
pure Python, no tools. That nextpnr routes the 1e4 square with it is measured, not tested here
(docs/streaming-core.md, session 20)."""
import re
import statistics

import pytest

from golden.errors import BadArgument
from hw.stream.floorplan import lane_floorplan, lane_pair_copies
from sim.synth import BLOCK_SITES, SynthesisError, floorplan_bels


def _x(bel):
    return int(re.match(r"X(\d+)/", bel).group(1))


def _square_like_cells(P=6):
    """Hard blocks named as the streaming core names them (P element lanes, shared tables in even lanes)."""
    cells = {}
    for k in range(P):
        for c in (2 * k, 2 * k + 1):
            cells.update({f"window.copy{c}.bram_r0_c{i}.dp16kd": "DP16KD" for i in range(6)})
        cells.update({f"ring_el{k}_r0.ring.bram_r0_c{i}.dp16kd": "DP16KD" for i in range(2)})
        cells.update({f"el{k}.el{k}_a.bram_r0_c{i}.dp16kd": "DP16KD" for i in range(3)})
        cells.update({f"el{k}.el{k}_prod_{i}": "MULT18X18D" for i in range(20)})
        cells[f"el{k}.el{k}_sub_{k}"] = "TRELLIS_FF"          # not a hard block: no site
        if k % 2 == 0:
            cells.update({f"el{k}.el{k}_inverse_psi_153.shared_rom_0.bram_r0_c{i}.dp16kd": "DP16KD" for i in range(8)})
    cells.update({f"store.bank{b}.bram_r0_c{i}.dp16kd": "DP16KD" for b in range(2) for i in range(12)})
    cells.update({f"window.copy{2 * P}.bram_r0_c{i}.dp16kd": "DP16KD" for i in range(6)})
    return cells


def test_each_lane_gets_a_stripe_and_its_multipliers_beside_it():
    cells = _square_like_cells()
    bels = floorplan_bels(cells, lane_floorplan(6, 0, 2), "ecp5-85k")
    hard = {n for n, t in cells.items() if t in ("DP16KD", "MULT18X18D")}
    assert set(bels) == hard
    assert len(set(bels.values())) == len(bels)                       # no site twice
    for n, bel in bels.items():
        assert bel in BLOCK_SITES["ecp5-85k"][cells[n]], (n, bel)
    def rams(pattern):
        return [_x(b) for n, b in bels.items() if cells[n] == "DP16KD" and re.match(pattern, n)]
    lane = [rams(rf"(el{k}\.(?!.*shared)|ring_el{k}_|window\.copy({2 * k}|{2 * k + 1})\.)") for k in range(6)]
    shared = [rams(rf"el{2 * j}\..*shared") for j in range(3)]
    central = rams(r"(store|window\.copy12\.)")
    # left to right: lane 0, its pair's tables, lane 1, a share of the rest, lane 2, ...
    order = [lane[0], shared[0], lane[1], lane[2], shared[1], lane[3], lane[4], shared[2], lane[5]]
    for left, right in zip(order, order[1:]):
        assert max(left) <= min(right), (left, right)
    assert all(max(lane[1]) <= x <= min(lane[2]) or max(lane[3]) <= x <= min(lane[4]) for x in central)
    assert any(x <= min(lane[2]) for x in central) and any(x >= max(lane[3]) for x in central)
    taken = set()
    for k in range(6):     # a lane's multipliers: the sites nearest its block RAMs that lanes before it left
        mine = [b for n, b in bels.items() if n.startswith(f"el{k}.") and cells[n] == "MULT18X18D"]
        taken |= set(mine)
        centre = statistics.mean(lane[k])
        left = [_x(b) for b in BLOCK_SITES["ecp5-85k"]["MULT18X18D"] if b not in taken]
        assert max(abs(_x(b) - centre) for b in mine) <= min(abs(x - centre) for x in left), (k, mine)
        assert min(lane[k]) <= statistics.mean(_x(b) for b in mine) <= max(lane[k]), (k, mine, lane[k])


def test_pair_lanes_own_their_window_copies():
    regions = lane_floorplan(1, 2, 2)          # el0: copies 0, 1; pr0: 2, 3, 4; pr1: 5, 6, 7; the rest between
    def region_of(name):
        return [i for i, pats in enumerate(regions) if pats and any(re.match(p, name) for p in pats)]
    el0, pr0, pr1 = region_of("el0.x"), region_of("pr0.x"), region_of("pr1.x")
    assert len({*el0, *pr0, *pr1}) == 3
    assert region_of("window.copy1.bram") == el0 and region_of("window.copy2.bram") == pr0
    assert region_of("window.copy4.bram") == pr0 and region_of("window.copy5.bram") == pr1
    assert region_of("window.copy8.bram") == [] and region_of("ring_pr1_r2.ring") == pr1
    assert region_of("el1.x") == [] and region_of("el10.x") == []
    shared = region_of("pr0.pr0_rsqrt.shared_table_rom.bram")
    assert pr0[0] < shared[0] < pr1[0] and el0[0] < pr0[0]               # between the pair's lanes
    assert regions[el0[0] + 1] is None                                   # the rest between el0 and the pair


def test_floorplan_refuses_what_it_cannot_place():
    cells = _square_like_cells()
    with pytest.raises(BadArgument, match="ecp5-45k"):
        floorplan_bels(cells, lane_floorplan(6, 0, 2), "ecp5-45k")
    too_many = dict(cells, **{f"el0.el0_extra_{i}.dp16kd": "DP16KD" for i in range(100)})
    with pytest.raises(SynthesisError, match="DP16KD for 208 sites"):
        floorplan_bels(too_many, lane_floorplan(6, 0, 2), "ecp5-85k")
    with pytest.raises(ValueError, match="no region"):
        floorplan_bels(cells, [pats for pats in lane_floorplan(6, 0, 2) if pats is not None], "ecp5-85k")


def test_sites_of_the_85k_die():
    sites = BLOCK_SITES["ecp5-85k"]
    assert len(set(sites["DP16KD"])) == 208 and len(set(sites["MULT18X18D"])) == 156    # the LFE5U-85F's
    # as nextpnr 0.11 named two of them in a placement of the 1e4 square (session 20)
    assert "X24/Y70/EBR1" in sites["DP16KD"] and "X31/Y10/MULT18_0" in sites["MULT18X18D"]


@pytest.mark.parametrize("P, Pp, dim", [(6, 0, 2), (3, 0, 2), (2, 3, 2), (1, 2, 3)])
def test_the_fills_relay_groups_are_the_window_copies_of_each_lane_pair(P, Pp, dim):
    """The window copies each relay of the fill serves (hw/stream/window.py) are those the floorplan puts in one
    lane pair's stripe: each region of a pair names exactly them."""
    groups = lane_pair_copies(P, Pp, dim)
    assert sorted(c for g in groups for c in g) == list(range(2 * P + (dim + 1) * Pp))
    lanes = [r for r in lane_floorplan(P, Pp, dim) if r is not None and any(p.startswith("window") for p in r)]
    named = []
    for lane in lanes:
        pat = next(p for p in lane if p.startswith("window"))
        named.append([c for c in range(2 * P + (dim + 1) * Pp) if re.match(pat, f"window.copy{c}.bram_r0_c0")])
    expect, i = [], 0
    for count in (P, Pp):
        lanes, i = named[i:i + count], i + count
        expect += [sum(lanes[j:j + 2], []) for j in range(0, count, 2)]
    assert groups == expect
    assert groups[0] == list(range(4 if P >= 2 else 2))
