"""`SaturationCounter`: the run's saturation count and the sticky flag per quantity.

Every lane reports, per saturating quantity, how many of its items saturated that quantity in a cycle
(PipeArith `saturation_events`, registered in the lane). The reports are registered on entry (they come
from lanes all over the die: the route and a chunk's adders in one cycle took 12.7 ns on the 1e4 square),
summed in LEVELS = 5 registered levels of sums of up to FAN_IN = 4 values (no long adder tree in one
cycle: there are about 15 reports per lane, 110 on the 1e4 square at P = 6, whose one-cycle sum of 14
chunks arrived at 12.5 ns, and a sum of 8 at 10.6 ns; at most FAN_IN^LEVELS reports), then added into
`count` (saturating at 2^32 - 1): an event is in `count` LATENCY = 7 cycles after its lane register. `flags` bit k (quantity `quantities[k]`,
sorted by name as the manifest lists them) is set when any lane reports that quantity, and stays set: the
reports' "any" per quantity is registered in parts of up to HIT_FAN_IN reports first (one OR of a
quantity's 22 reports on the 1e4 square arrived at 11.8 ns), so a flag rises 3 cycles after its lane
register.
`clear` zeroes both (events already summed but not yet in `count` are lost with it).
"""
from __future__ import annotations

from amaranth.hdl import Cat, Module, Mux, Signal
from amaranth.lib import wiring
from amaranth.lib.wiring import In, Out

from ..rtl_fixed import tree_sum
from .element import SAT_BITS


FAN_IN = 4
LEVELS = 5
LATENCY = LEVELS + 2          # entry register, the levels, count
HIT_FAN_IN = 8                # reports per registered part of a quantity's "any"


class SaturationCounter(wiring.Component):
    def __init__(self, events: list[str]):
        """`events`: the quantity of each event input ev0, ev1, ..."""
        self.events = list(events)
        if len(self.events) > FAN_IN ** LEVELS:
            raise ValueError(f"{len(self.events)} saturation reports; the counter sums at most "
                             f"{FAN_IN ** LEVELS} ({LEVELS} levels of {FAN_IN})")
        self.quantities = sorted(set(self.events))
        members = {f"ev{k}": In(SAT_BITS) for k in range(len(self.events))}
        members.update({"clear": In(1), "count": Out(32), "flags": Out(max(1, len(self.quantities)))})
        super().__init__(members)

    def elaborate(self, platform):
        m = Module()
        evs = [getattr(self, f"ev{k}") for k in range(len(self.events))]
        entered = [Signal.like(ev, name=f"ev{k}_in") for k, ev in enumerate(evs)]
        m.d.sync += [r.eq(ev) for r, ev in zip(entered, evs)]
        evs = entered
        with m.If(self.clear):
            m.d.sync += [self.count.eq(0), self.flags.eq(0)]
        if not evs:
            return m
        # wide enough for every report at its most in one cycle (16 bits at least: the square's netlist)
        width = max(16, (len(evs) * ((1 << SAT_BITS) - 1)).bit_length())
        sums = evs
        for level in range(LEVELS):
            parts = [sums[k:k + FAN_IN] for k in range(0, len(sums), FAN_IN)]
            sums = [Signal(width, name=f"sum{level}_{j}") for j in range(len(parts))]
            m.d.sync += [s.eq(tree_sum(part)) for s, part in zip(sums, parts)]
        per_cycle, = sums
        hits = []
        for k, qq in enumerate(self.quantities):
            mine = [ev != 0 for ev, q in zip(evs, self.events) if q == qq]
            parts = [Signal(name=f"hit{k}_{j}") for j in range(0, len(mine), HIT_FAN_IN)]
            m.d.sync += [r.eq(Cat(*mine[j:j + HIT_FAN_IN]).any())
                         for j, r in zip(range(0, len(mine), HIT_FAN_IN), parts)]
            hits.append(Cat(*parts).any())
        hits = Cat(*hits)
        new = self.count + per_cycle
        with m.If(~self.clear):
            m.d.sync += [self.count.eq(Mux(new >> 32 != 0, 0xFFFFFFFF, new[:32])), self.flags.eq(self.flags | hits)]
        return m
