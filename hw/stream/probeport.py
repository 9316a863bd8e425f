"""`ProbePort`: the haptic probe of a scene with a [probe] (MODEL.md 4b; issue 16 item 3), as two streams.

  samples  in (amaranth.lib.stream, valid/ready): one device sample, D position words in the x format
           (hardware units, as the host converts them: BitTrue.hold_probe), word k at bits k w .. (k+1) w - 1
  forces   out: the force on the probe of the sample's last step, D fprobe words, then the contact count

A sample is taken (ready) only when the core is idle, no sample is in flight and the force of the last
one has been taken: back-pressure on `forces` holds the device loop. On a sample the port runs the
per-sample kernel (hw/datapath.py `probe_sample_kernel` through PipeArith: Pdot = (P - Pprev) / k and the
bounding box Lo, Hi), loads the probe's registers P, Pdot, Lo, Hi and starts a run of k steps (the
scene's steps per sample) on Control. During the run the registers hold still and feed every node lane's
`node_kernel`, whose probe term gives each node's force (gate, pfe): the port sums them exactly over the
node lanes and the step's nodes (an integer sum at pfe's binary point, restarted by each step's first
group: retirement runs into the next period), and after the run converts the last step's sum to fprobe
and negates it as `_probe_outputs` does.

Latency from the sample's handshake cycle to the first cycle with `forces.valid`, in cycles, known at
construction: `latency` = sample kernel stages + Control's run_cycles(k) + DONE_STAGES. Throughput: one
sample per latency + 1 cycles with a device that answers at once (a sample is taken in the cycle after
its force is).

Port off (the host's RUN register used instead): the registers hold the last sample (at reset: the
scene's initial probe position, at rest), the bit-true model's driven probe without a new sample
(`st.probe.driven = True` and no `hold_probe`). Saturations of the sample kernel and of the force's
conversion count with the core's (`quantities`, `sat0`, ...); the host's rounding of the position is the
host's (the bit-true model counts it in `hold_probe`).
"""
from __future__ import annotations

from amaranth.hdl import Cat, Module, Mux, Signal, signed
from amaranth.lib import stream, wiring
from amaranth.lib.wiring import In, Out

from ..arith import FixedArith
from ..datapath import probe_initial
from ..rtl_fixed import FixedValue, as_shape, tree_sum
from .element import SAT_BITS
from .kernels import PROBE_REGS as REGS, build_probe_sample
from .nodeword import bits_for, split_words
from .schedule import SAT_TAIL

DONE_STAGES = 2        # the cycle the port sees Control idle, then the output register


def LaneProbeSignature(dim: int, pfe_bits: int):
    """What a node lane gives the port at its probe stage (hw/stream/node.py)."""
    return wiring.Signature({"valid": Out(1), "first": Out(1), "touch": Out(1), "f": Out(dim * pfe_bits)})


class ProbePort(wiring.Component):
    def __init__(self, cfg):
        p = cfg.params
        if p.probe is None or cfg.probe_dry is None:
            raise ValueError("ProbePort: the scene has no [probe]")
        self.cfg, self.k = cfg, int(p.probe["k"])
        fmt, D = cfg.formats, cfg.dim
        self.x_bits, self.f_bits, self.pfe_bits = fmt["x"].width, fmt["fprobe"].width, fmt["pfe"].width
        if fmt["fprobe"].f < fmt["pfe"].f:
            raise ValueError("ProbePort: fprobe has a coarser binary point than pfe (the model's scatter refuses it)")
        self.count_bits = max(1, cfg.n_nodes.bit_length())
        self.sample_stage = cfg.probe_dry.stage
        self.probe_stage = cfg.node_dry.outputs["probe_stage"]
        sch = cfg.schedule
        # the sum is final one cycle after the last group's probe stage: by the end of Control's drain
        assert self.probe_stage <= sch.latencies.node + SAT_TAIL, (self.probe_stage, sch.latencies.node)
        self.latency = self.sample_stage + sch.run_cycles(self.k) + DONE_STAGES
        self.quantities = sorted(set(cfg.probe_dry.quantities) | {"fprobe"})
        members = {
            "samples": In(stream.Signature(D * self.x_bits)),
            "forces": Out(stream.Signature(D * self.f_bits + self.count_bits)),
            "busy": In(1), "host_start": In(1),
            "start": Out(1), "steps": Out(32), "active": Out(1),
            "lanes": In(LaneProbeSignature(D, self.pfe_bits)).array(cfg.node_lanes),
        }
        members.update({f"reg_{name}": Out(D * fmt[q].width) for name, q in REGS})
        members.update({f"sat{k}": Out(SAT_BITS) for k in range(len(self.quantities))})
        super().__init__(members)

    def initial_registers(self) -> dict:
        """The registers at reset (raw, per dimension): probe_initial of the bit-true model."""
        cfg = self.cfg
        init = probe_initial(FixedArith(cfg.formats, cfg.units), cfg.params)
        return {name: [int(v) for v in getattr(init, name)] for name, _ in REGS}

    def elaborate(self, platform):
        m = Module()
        cfg, p, fmt, D = self.cfg, self.cfg.params, self.cfg.formats, self.cfg.dim
        init = self.initial_registers()
        regs = {name: [Signal(as_shape(fmt[q]), name=f"probe_{name}{k}", init=init[name][k]) for k in range(D)]
                for name, q in REGS}
        for name, _ in REGS:
            m.d.comb += getattr(self, f"reg_{name}").eq(Cat(*regs[name]))

        pending, running = Signal(), Signal()           # a sample in flight; its run started
        m.d.comb += self.active.eq(pending)
        m.d.comb += self.samples.ready.eq(~pending & ~self.forces.valid & ~self.busy & ~self.host_start)
        accept = Signal()
        m.d.comb += accept.eq(self.samples.valid & self.samples.ready)

        # the sample kernel, then the registers and the run
        built = build_probe_sample(m, p, fmt, cfg.units, accept, "ps",
                                   split_words(self.samples.payload, D, as_shape(fmt["x"])), regs["P"], cfg.ram)
        ar, s = built.ar, built.stage
        assert s == self.sample_stage, f"probe sample kernel: stage {s}, the dry run has {self.sample_stage}"
        load = ar.valid_at(s)
        new = {name: [ar.at(v, s) for v in built.outputs[name]] for name, _ in REGS}   # delays outside the If
        with m.If(load):
            for name, _ in REGS:
                m.d.sync += [r.eq(v) for r, v in zip(regs[name], new[name])]
        m.d.comb += [self.start.eq(load), self.steps.eq(self.k)]
        with m.If(accept):
            m.d.sync += pending.eq(1)
        with m.If(load):
            m.d.sync += running.eq(1)

        # the exact sum over the node lanes and the step's nodes, restarted by each step's first group
        acc_bits = self.pfe_bits + bits_for(cfg.n_nodes + 1) + 1
        lanes = self.lanes
        f_of = lambda q, k: lanes[q].f[k * self.pfe_bits:(k + 1) * self.pfe_bits].as_signed()
        acc = [Signal(signed(acc_bits), name=f"probe_sum{k}") for k in range(D)]
        count = Signal(self.count_bits)
        group_sum = [tree_sum([f_of(q, k) for q in range(len(lanes))]) for k in range(D)]   # zero unless touching
        group_count = tree_sum([lanes[q].touch for q in range(len(lanes))])
        with m.If(lanes[0].valid & lanes[0].first):                    # lane 0 holds a node of every group
            m.d.sync += [a.eq(g) for a, g in zip(acc, group_sum)] + [count.eq(group_count)]
        with m.Elif(lanes[0].valid):
            m.d.sync += [a.eq(a + g) for a, g in zip(acc, group_sum)] + [count.eq(count + group_count)]

        # after the run: minus the sum in fprobe (as _probe_outputs), into the output register
        done = Signal()
        m.d.comb += done.eq(running & ~self.busy)
        F, flags = [], []
        for a in acc:
            v, f1 = FixedValue(a, fmt["pfe"].f).round(fmt["fprobe"])
            v, f2 = (-v).round(fmt["fprobe"])
            F.append(v.raw)
            flags += [f1, f2]
        with m.If(done):
            m.d.sync += [running.eq(0), pending.eq(0), self.forces.valid.eq(1),
                         self.forces.payload.eq(Cat(*F, count))]
        with m.Elif(self.forces.valid & self.forces.ready):
            m.d.sync += self.forces.valid.eq(0)

        # saturations: the sample kernel's, and the conversion's (counted when the force is made)
        events = dict(ar.saturation_events())
        conv = Signal(SAT_BITS, name="probe_fprobe_sats")
        m.d.sync += conv.eq(Mux(done, tree_sum(flags), 0))
        events["fprobe"] = conv if "fprobe" not in events else events["fprobe"] + conv
        for k, q in enumerate(self.quantities):
            m.d.comb += getattr(self, f"sat{k}").eq(events[q])
        return m
