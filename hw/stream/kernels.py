"""The per-item kernels of hw/datapath.py on PipeArith, as the streaming lanes use them.

Each lane kind runs its kernel through `PipeArith` (hw/pipeline.py) with its inputs at fixed stages:

  element  stage 0: issue (ROM and a read); 2: ROM fields and a; 7: x, u of nodes i and j
           (the window read presented at 3); contributions +fe (i), -fe (j) at `stage`; a at `state_stage`
  pair     stage 0: issue; 2: ROM fields; 7: x, u of the D + 1 nodes; contributions at `stage`, each
           zero where the pair's gate is closed (the ring still counts the item: see ForceRing `first`)
  node     stage 0: retirement (window, force ring and ROM reads); 2: x, u, ROM fields; 4: the exact
           sum of the force rings (partial sums of up to 4 rings at 3); x, u results at `stage`; with a
           probe, its registers (constant during a run: no stage) and the node's probe force (gate, pfe)
           at `probe_stage`
  probe    once per device sample (hw/stream/probeport.py): stage 0 the sample P and the previous P;
           P, Pdot, Lo, Hi at `stage`

`dry_run_*` builds a kernel on a throw-away Module to learn its stages and saturating quantities before
any component is elaborated (the schedule needs them at construction); each lane asserts at elaboration
that its real pipeline has the same stages.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from amaranth.hdl import Fragment, Module, Mux, Signal

from ..datapath import ProbeInputs, _node_flags, element_kernel, node_kernel, pair_kernel, probe_sample_kernel
from ..pipeline import PBool, PipeArith
from ..rtl_fixed import as_shape
from .bram import LATENCY
from .schedule import SLOT_REG
from .window import NODE_READ_LATENCY

ROM_STAGE = LATENCY               # ROM fields valid at stage 2
A_STAGE = ROM_STAGE + 1           # an element's a at stage 3: the memory's word registered beside the lane
SLOT_STAGE = ROM_STAGE + SLOT_REG  # a lane presents its window slots at stage 3 (formed at 2, registered)
NODE_STAGE = SLOT_STAGE + NODE_READ_LATENCY  # x, u at stage 7
GROUP_STAGE = ROM_STAGE + 1       # node lanes: x, u at stage 3, the window's group word registered beside the lane
FORCE_STAGE = LATENCY + 3         # node lanes: the force rings' words masked and registered, then summed in two levels
CLAMP_STAGE = True                # every lane's saturating results clamped a stage after their arithmetic
PROBE_REGS = (("P", "x"), ("Pdot", "pdot"), ("Lo", "x"), ("Hi", "x"))   # the probe's registers, their formats


class NodeArith(PipeArith):
    """PipeArith for node lanes: the step number travels with the node (nodes of two steps share the
    pipeline as retirement runs into the next period), so a load's time window is a stage-0 condition
    on the lane's `step` input instead of a constant of the phase."""

    def window(self, step_no, first, end) -> PBool:
        return PBool((step_no >= first) & (step_no < min(end, (1 << 32) - 1)), 0)


@dataclass
class Built:
    ar: PipeArith
    stage: int                 # contribution (element, pair) or result (node) stage
    outputs: dict              # kind-specific values (see the build functions)
    params: list = None        # dry runs: the per-item ROM fields the kernel asked for, (name, bits)
    param_values: dict = None  # dry runs of element and pair kernels: name -> (shape, raw values of every item)

    @property
    def quantities(self) -> list[str]:
        return sorted({s.quantity for s in self.ar.sat_sources})


def _signals(n, shape, name):
    return [Signal(shape, name=f"{name}{k}") for k in range(n)]


def build_element(m, p, fmt, units, valid, name, src, A, Xi, Xj, Ui, Uj, tables=None, dsp="sim") -> Built:
    ar = PipeArith(m, fmt, units, valid, name, src, param_stage=ROM_STAGE, tables=tables, dsp=dsp,
                   clamp_stage=CLAMP_STAGE)
    with ar:
        a_in = ar.input(A, "a", A_STAGE)
        node = lambda vs, q: [ar.input(v, q, NODE_STAGE) for v in vs]
        fe, new_a = element_kernel(ar, p, node(Xi, "x"), node(Xj, "x"), node(Ui, "u"), node(Uj, "u"), a_in)
        fe_neg = [ar.neg(v) for v in fe]                  # node j's word (saturating, as the model)
        stage = max(v.stage for v in fe + fe_neg)
    return Built(ar, stage, {"fe": fe, "fe_neg": fe_neg, "a": new_a,
                             "state_stage": new_a.stage if new_a is not None else 0})


def build_pair(m, p, fmt, units, valid, name, src, kernel, X_roles, U_roles, tables=None, dsp="sim") -> Built:
    ar = PipeArith(m, fmt, units, valid, name, src, param_stage=ROM_STAGE, tables=tables, dsp=dsp,
                   clamp_stage=CLAMP_STAGE)
    D = p.dim
    with ar:
        ins = [[ar.input(v, "x", NODE_STAGE) for v in X_roles[r]] for r in range(D + 1)]
        ins += [[ar.input(v, "u", NODE_STAGE) for v in U_roles[r]] for r in range(D + 1)]
        gate, contribs = kernel(ar, p, *ins)
        stage = max(v.stage for _, v, _ in contribs)
        cond = ar.delay(gate.cond.sig, gate.cond.stage, stage) if gate.cond.stage is not None else gate.cond.sig
    roles = [[None] * D for _ in range(D + 1)]
    for k, v, role in contribs:
        roles[role][k] = Mux(cond, ar.at(v, stage), 0)
    return Built(ar, stage, {"roles": roles})


def build_node(m, p, fmt, units, valid, name, src, X, U, Fe, step, probe: ProbeInputs | None = None,
               dsp="sim") -> Built:
    """`probe`: the probe's registers (signals, per dimension), held still during a run: values of no stage.
    Outputs x, u; with a probe also "probe_gate" (the node touches it) and "probe_f" (its force, pfe), both
    to be read at "probe_stage"."""
    ar = NodeArith(m, fmt, units, valid, name, src, param_stage=ROM_STAGE, dsp=dsp, clamp_stage=CLAMP_STAGE)
    with ar:
        Xp = [ar.input(v, "x", GROUP_STAGE) for v in X]
        Up = [ar.input(v, "u", GROUP_STAGE) for v in U]
        Fp = [ar.input(v, "fe", FORCE_STAGE) for v in Fe]
        if probe is None:
            new_x, new_u = node_kernel(ar, p, Xp, Up, Fp, step, _node_flags(p))
            extra = {}
        else:
            regs = ProbeInputs(*[[ar.input(v, q, None) for v in vs]
                                 for vs, (_, q) in zip(probe, PROBE_REGS)])
            new_x, new_u, (gate, force) = node_kernel(ar, p, Xp, Up, Fp, step, _node_flags(p), regs)
            extra = {"probe_gate": gate.cond, "probe_f": force,
                     "probe_stage": max([v.stage for v in force] + [gate.cond.stage])}
        stage = max(v.stage for v in new_x + new_u)
    return Built(ar, stage, {"x": new_x, "u": new_u, **extra})


def build_probe_sample(m, p, fmt, units, valid, name, P, Pprev, dsp="sim") -> Built:
    """The per-sample kernel: P (the sample) and Pprev (the held position) at stage 0 -> P, Pdot, Lo, Hi at
    `stage` (P delayed to it)."""
    ar = PipeArith(m, fmt, units, valid, name, dsp=dsp, clamp_stage=CLAMP_STAGE)
    with ar:
        Pi = [ar.input(v, "x", 0) for v in P]
        Pdot, Lo, Hi = probe_sample_kernel(ar, p, Pi, [ar.input(v, "x", 0) for v in Pprev])
        stage = max(v.stage for v in Pdot + Lo + Hi)
    return Built(ar, stage, {"P": Pi, "Pdot": Pdot, "Lo": Lo, "Hi": Hi})


def _dry_src(fields, values=None):
    def src(q, raw, shape):
        sig = Signal(shape, name=f"dry_{q}")
        fields.append((q, len(sig)))
        if values is not None:
            values[q] = (shape, np.asarray(raw))
        return sig
    return src


def _finish(m):
    Fragment.get(m, None)           # elaborate the function units too: nothing is left unused


def dry_run_element(p, fmt, units) -> Built:
    m, fields, values = Module(), [], {}
    D = p.dim
    xs, us = as_shape(fmt["x"]), as_shape(fmt["u"])
    b = build_element(m, p, fmt, units, Signal(), "dry_el", _dry_src(fields, values), Signal(as_shape(fmt["a"])),
                      _signals(D, xs, "xi"), _signals(D, xs, "xj"), _signals(D, us, "ui"), _signals(D, us, "uj"))
    b.ar.saturation_events()
    _finish(m)
    b.params, b.param_values = fields, values
    return b


def dry_run_pair(p, fmt, units) -> Built:
    m, fields, values = Module(), [], {}
    D = p.dim
    xs, us = as_shape(fmt["x"]), as_shape(fmt["u"])
    b = build_pair(m, p, fmt, units, Signal(), "dry_pr", _dry_src(fields, values), pair_kernel,
                   [_signals(D, xs, f"x{r}_") for r in range(D + 1)], [_signals(D, us, f"u{r}_") for r in range(D + 1)])
    b.ar.saturation_events()
    _finish(m)
    b.params, b.param_values = fields, values
    return b


def dry_run_node(p, fmt, units, fe_bits: int) -> Built:
    """`fe_bits`: the width of the lane's force sums (StreamConfig.force_sum_bits): an operation's stages
    depend on its operands' widths (whether it can saturate: PipeArith `clamp_stage`)."""
    m, fields = Module(), []
    D = p.dim
    xs, us = as_shape(fmt["x"]), as_shape(fmt["u"])
    from amaranth.hdl import signed
    probe = None
    if p.probe is not None:
        probe = ProbeInputs(*[_signals(D, as_shape(fmt[q]), f"probe_{n}")
                              for n, q in PROBE_REGS])
    b = build_node(m, p, fmt, units, Signal(), "dry_nd", _dry_src(fields), _signals(D, xs, "x"), _signals(D, us, "u"),
                   _signals(D, signed(fe_bits), "f"), Signal(32), probe)
    b.ar.saturation_events()
    _finish(m)
    b.params = fields
    return b


def dry_run_probe_sample(p, fmt, units) -> Built:
    m = Module()
    xs = as_shape(fmt["x"])
    b = build_probe_sample(m, p, fmt, units, Signal(), "dry_ps", _signals(p.dim, xs, "P"), _signals(p.dim, xs, "Pprev"))
    b.ar.saturation_events()
    _finish(m)
    return b


def first_flags(nodes: np.ndarray) -> np.ndarray:
    """1 where a node occurs for the first time in `nodes` (a lane role's items in slot order)."""
    flags = np.zeros(len(nodes), np.int64)
    if len(nodes):
        _, idx = np.unique(nodes, return_index=True)
        flags[idx] = 1
    return flags


def last_flags(nodes: np.ndarray) -> np.ndarray:
    """1 where a node occurs for the last time in `nodes`."""
    flags = np.zeros(len(nodes), np.int64)
    if len(nodes):
        _, idx = np.unique(nodes[::-1], return_index=True)
        flags[len(nodes) - 1 - idx] = 1
    return flags


def max_count(nodes: np.ndarray) -> int:
    """The most items of one lane role that touch one node (the accumulator's headroom)."""
    return int(np.bincount(nodes).max()) if len(nodes) else 1
