"""The manifest of a streaming core (`rheo verilog --core stream`): units, formats, memories with their
DP16KD budget, the schedule, the saturation flags, the host interface with the renumbering and, for a
scene with a [probe], the probe port with its latency in cycles."""
from __future__ import annotations

def manifest(bt, core, specialisation, top: str) -> dict:
    cfg, sch = core.cfg, core.schedule
    feats = cfg.features()
    present = [{"unit": u, "what": what} for u, need, what in specialisation if need(feats)]
    absent = [{"unit": u, "what": what} for u, need, what in specialisation if not need(feats)]
    mems = core.memories()
    units = core.own_unit_memories()
    E, N, Pn = cfg.n_elements, cfg.n_nodes, cfg.n_pairs
    host = cfg.host_map.to_dict()
    host["read_latency_cycles"] = core.hostport.read_latency       # the bus registered on entry
    host["node_order"] = "reverse Cuthill-McKee: node n is node_numbering[n] of the stream; slot = its % Q, word = its // Q"
    host["node_numbering"] = [int(v) for v in cfg.order.perm]
    host["element_position"] = [int(v) for v in cfg.order.element_position()]
    return {
        "top": top,
        "core": "stream",
        "scene": bt.system.name,
        "preset": bt.formats.preset.name,
        "dim": cfg.dim,
        "nodes": N, "elements": E, "pairs": Pn, "collision_pairs": 0,
        "lanes": {"element_lanes_P": cfg.lanes, "pair_lanes": cfg.pair_lanes if Pn else 0, "collision_lanes": 0,
                  "node_lanes_Q": cfg.node_lanes},
        "ram": cfg.ram,
        "features": {k: (bool(v) if not isinstance(v, int) or isinstance(v, bool) else v) for k, v in feats.items()},
        "units_present": present,
        "units_left_out": absent,
        "function_units": {name: u.to_dict() for name, u in cfg.units.items()},
        "formats": bt.formats.to_dict(),
        "hardware_units": bt.units.to_dict(),
        "memories": mems + units,
        "memory_bits": int(sum(m["depth"] * m["width"] for m in mems + units)),
        "block_rams_dp16kd": int(sum(m["dp16kd"] for m in mems)),
        "block_ram_fit": {"dp16kd_budget": cfg.dp16kd_budget, "dp16kd_with_unit_roms": core.block_rams(),
                          "lut_ram_memories": core.lut_memories,
                          "dpr16x4": int(sum(m.get("dpr16x4", 0) for m in mems))},
        "cycles_per_step": {
            "formula": "T = max(ceil(E/P), ceil(pairs/Pp), the schedule's read-after-write bounds); a run of n steps "
                       "takes A0 + (n - 1) T + drain + 1 cycles",
            "E": E, "pairs": Pn, "collision_pairs": 0, "N": N, "P": cfg.lanes, "Pp": cfg.pair_lanes if Pn else 0,
            "Q": cfg.node_lanes,
            "value": sch.period, "run_cycles_1": sch.run_cycles(1),
        },
        "spare_lanes": cfg.spare_lanes(),
        "schedule": sch.to_dict(),
        "saturation_flags": core.sat_quantities,
        "constant_saturations": core.const_saturations,
        "host_interface": host,
        "probe_port": probe_port(core),
    }


def probe_port(core) -> dict | None:
    """The probe port of a scene with a [probe] (hw/stream/probeport.py): its streams' word layout and the
    latency from a sample's handshake to its force, in cycles (None without a probe)."""
    pp = core.probe
    if pp is None:
        return None
    D = core.cfg.dim
    return {
        "steps_per_sample_k": pp.k,
        "latency_cycles": pp.latency,
        "latency_formula": "sample kernel stages + run_cycles(k) + 2 (Control idle seen, output register)",
        "sample_kernel_stages": pp.sample_stage,
        "run_cycles_k": core.schedule.run_cycles(pp.k),
        "probe_in": {"ports": "probe_in__valid, probe_in__ready, probe_in__payload",
                     "payload": f"{D} words of {pp.x_bits} bits (format x, hardware units), word k at bits "
                                f"{pp.x_bits} k .. {pp.x_bits} (k + 1) - 1"},
        "force_out": {"ports": "force_out__valid, force_out__ready, force_out__payload",
                      "payload": f"{D} words of {pp.f_bits} bits (format fprobe: the force on the probe of the "
                                 f"sample's last step), then the contact count ({pp.count_bits} bits)"},
        "port_off": "RUN through the host interface: the probe's registers hold the last sample",
    }
