"""`Control`: the run. RUN n starts three periodic processes that follow the schedule
(hw/stream/schedule.py) for n periods each, from their own start cycles:

  fill     at run cycle fill_start + k T + phase, where the fill phase ROM has a 1: group g (counted
           from 0 in each period) of step k is read from the node store; `fill` carries it
  issue    at issue_start - ISSUE_FANOUT + k T + c, c < C: item slot c of step k; `issue` (each lane
           registers it: ISSUE_FANOUT, hw/stream/core.py, so the lanes see it at issue_start + k T + c)
  retire   at retire_start - RETIRE_FANOUT + k T + phase, where the retire phase ROM has a 1: group g
           of step k retires; `retire` (with the step number: STEP, which counts retired steps; the node
           lanes, the force rings and the window register it: RETIRE_FANOUT, hw/stream/core.py)

Each process keeps a window base register, k Gs mod Wg for its step k, added to its group index for
the window slot. Its counters run LOOKAHEAD = 3 cycles ahead of its events, so that the phase ROM (a
BlockRam, read latency 2) answers in time and its bit is registered before the event. The run ends
`drain` cycles after the last step's last
retirement (its results written and its saturations counted; counted from the control's retirement, a
RETIRE_FANOUT earlier): busy falls after run_cycles(n) cycles.
STEP counts every retired step; the RUN register (steps left) counts down with it. CYCLES counts the
cycles spent busy since reset. While idle, the host may write STEP (`step_we`) and start a run.
"""
from __future__ import annotations

from amaranth.hdl import Module, Signal
from amaranth.lib import wiring
from amaranth.lib.wiring import In, Out

from ..rtl_fixed import KEEP_APART_TAG
from .bram import LATENCY, BlockRam
from .element import IssueSignature
from .node import RetireSignature
from .nodeword import bits_for, delay
from .schedule import ISSUE_FANOUT, LOOKAHEAD, RETIRE_FANOUT, SAT_TAIL

FillSignature = RetireSignature


class Control(wiring.Component):
    def __init__(self, schedule, ram: str = "sim"):
        if schedule.period < 2:       # the processes decide a period's end a cycle ahead
            raise ValueError(f"a period of {schedule.period} cycles: the control needs at least 2")
        self.schedule, self.ram = schedule, ram
        sch = schedule
        assert sch.retire_start - RETIRE_FANOUT > LOOKAHEAD, "the retirement starts before its phase ROM answers"
        self.wbits, self.gbits = bits_for(sch.window_groups), bits_for(sch.groups)
        super().__init__({
            "start": In(1), "steps": In(32), "step_we": In(1), "step_wdata": In(32),
            "busy": Out(1), "cycles": Out(32), "steps_left": Out(32), "step": Out(32),
            "fill": Out(wiring.Signature({"valid": Out(1), "group": Out(self.gbits), "slot": Out(self.wbits)})),
            "issue": Out(IssueSignature(sch.slots, sch.window_groups)),
            "retire": Out(wiring.Signature({"valid": Out(1), "group": Out(self.gbits), "slot": Out(self.wbits),
                                            "step": Out(32), "last": Out(1)})),
        })

    def elaborate(self, platform):
        m = Module()
        sch = self.schedule
        T = sch.period
        cap = max(sch.retire_start, sch.fill_start, sch.issue_start)
        busy, a, n = Signal(), Signal(range(cap + 1)), Signal(32)     # a: run cycle, up to the last start
        m.d.comb += self.busy.eq(busy)
        with m.If(busy):
            m.d.sync += self.cycles.eq(self.cycles + 1)
            with m.If(a != cap):
                m.d.sync += a.eq(a + 1)

        def process(name, start, rom_bits):
            """(valid, phase, step) at event time, and the end of the process's last step."""
            ph_e, act_e = Signal(range(T), name=f"{name}_ph_e"), Signal(name=f"{name}_act_e")
            # the period's last phase and the run's last period, each decided a cycle ahead into a register
            # (nextpnr: ph_e == T - 1 and k == n - 1 in the cycle that uses them took 9.7 ns)
            ph_last, k_left, k_zero = Signal(name=f"{name}_ph_last"), Signal(32, name=f"{name}_k_left"), Signal(name=f"{name}_k_zero")
            m.d.sync += k_zero.eq(k_left == 0)       # k_left changes once a period (T >= 2): valid by the next
            # phase 0 at run cycle start - LOOKAHEAD: `go` one cycle before it, decided a cycle ahead (the
            # run-cycle compare, `busy` and the reset of ph_e in one cycle took 14.9 ns on the 1e4 square)
            go, go_cycle = Signal(name=f"{name}_go"), start - LOOKAHEAD - 1
            if go_cycle == 0:                                     # the run's first cycle: the start itself
                m.d.sync += go.eq(~busy & self.start & (self.steps != 0))
            else:
                m.d.sync += go.eq(busy & (a == go_cycle - 1))
            with m.If(go):
                m.d.sync += [act_e.eq(1), ph_e.eq(0), ph_last.eq(0), k_left.eq(n - 1)]
            with m.Elif(act_e):
                with m.If(ph_last):
                    m.d.sync += [ph_e.eq(0), ph_last.eq(0), k_left.eq(k_left - 1)]
                    with m.If(k_zero):
                        m.d.sync += act_e.eq(0)
                with m.Else():
                    m.d.sync += [ph_e.eq(ph_e + 1), ph_last.eq(ph_e == T - 2)]
            with m.If(~busy):
                m.d.sync += act_e.eq(0)
            act_rom = delay(m, act_e, LATENCY, f"{name}_act")             # beside the phase ROM's word
            act = delay(m, act_rom, LOOKAHEAD - LATENCY, f"{name}_act_ev")
            ph = delay(m, ph_e, LOOKAHEAD, f"{name}_ph")
            if rom_bits is None:
                en = own = act
            else:
                rom = BlockRam(1, T, init=[int(b) for b in rom_bits], writable=False, ram=self.ram)
                m.submodules[f"{name}_phases"] = rom
                m.d.comb += rom.r_addr.eq(ph_e)
                # the event bit registered beside its consumers (nextpnr had the ROM, the last-group test and
                # the host port's step counters in one cycle across the chip: 11.9 ns), in two copies kept
                # apart: the output's, which goes to every lane, and the control's own (one register for
                # both sat between them: 4.5 + 6.5 ns of routing into the run's end on the 1e4 square)
                hit = act_rom & rom.r_data[0]
                en = delay(m, hit, LOOKAHEAD - LATENCY, f"{name}_en")
                own = delay(m, hit, LOOKAHEAD - LATENCY, f"{name}_en_own{KEEP_APART_TAG}")
            # the step's window base: k Gs mod Wg
            base = Signal(self.wbits, name=f"{name}_base")
            with m.If(~act):
                m.d.sync += base.eq(0)
            with m.Elif(ph == T - 1):
                m.d.sync += base.eq(base + sch.base_step)
            return en, own, ph, base

        # fill
        f_en, _, f_ph, f_base = process("fill", sch.fill_start, sch.fill_phases())
        f_g = Signal(self.gbits, name="fill_group")
        with m.If(f_en):
            m.d.sync += f_g.eq(f_g + 1)
        with m.If((f_ph == T - 1) | ~busy):
            m.d.sync += f_g.eq(0)
        m.d.comb += [self.fill.valid.eq(f_en), self.fill.group.eq(f_g), self.fill.slot.eq(f_base + f_g)]
        # issue
        i_act, _, i_ph, i_base = process("issue", sch.issue_start - ISSUE_FANOUT, None)
        m.d.comb += [self.issue.valid.eq(i_act & (i_ph < sch.slots)), self.issue.slot.eq(i_ph),
                     self.issue.base.eq(i_base)]
        # retire
        r_en, r_own, r_ph, r_base = process("retire", sch.retire_start - RETIRE_FANOUT, sch.retire_phases())
        r_g = Signal(self.gbits, name="retire_group")
        # r_g == Gs - 1, kept in a register beside r_g (the compare and the step counters' enables were
        # one cycle)
        at_last = Signal(name="retire_at_last", init=int(sch.groups == 1))
        with m.If(r_en):
            m.d.sync += [r_g.eq(r_g + 1), at_last.eq((r_g == sch.groups - 2) if sch.groups > 1 else 0)]
        with m.If((r_ph == T - 1) | ~busy):
            m.d.sync += [r_g.eq(0), at_last.eq(int(sch.groups == 1))]
        last, last_own = Signal(), Signal()
        m.d.comb += [last.eq(r_en & at_last), last_own.eq(r_own & at_last),
                     self.retire.valid.eq(r_en), self.retire.group.eq(r_g), self.retire.slot.eq(r_base + r_g),
                     self.retire.step.eq(self.step), self.retire.last.eq(last)]

        # steps, the end of the run
        drain = RETIRE_FANOUT + sch.latencies.node + SAT_TAIL
        draining = Signal(range(drain + 2))
        # steps_left == 1, registered (steps_left changes once a period at most: valid by the next `last`)
        one_left = Signal(name="one_left")
        m.d.sync += one_left.eq(self.steps_left == 1)
        with m.If(busy):
            with m.If(last_own):
                m.d.sync += [self.step.eq(self.step + 1), self.steps_left.eq(self.steps_left - 1)]
                with m.If(one_left):
                    m.d.sync += draining.eq(drain)
            with m.Elif(draining == 1):
                m.d.sync += [busy.eq(0), draining.eq(0)]
            with m.Elif(draining != 0):
                m.d.sync += draining.eq(draining - 1)
        with m.Else():
            with m.If(self.step_we):
                m.d.sync += self.step.eq(self.step_wdata)
            with m.If(self.start & (self.steps != 0)):
                m.d.sync += [busy.eq(1), a.eq(0), n.eq(self.steps), self.steps_left.eq(self.steps)]
        return m
