"""Scene -> specialised core -> Verilog and its manifest (`rheo verilog`).

The scene decides what is elaborated (the specialisation table below); the manifest lists the units
present and left out, every number format, the memories, lanes and the cycles-per-step formula.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .bittrue import BitTrue
from .core import Core

TOP = "rheo_core"


def primitive_models() -> list[Path]:
    """The Verilog models of the ECP5 primitives a streaming core built with ram = "ecp5" instantiates
    (DP16KD, MULT18X18D): Yosys knows the cells, simulators need these beside the core's Verilog."""
    from .mult18x18d import MULT18X18D_MODEL
    from .stream.bram import DP16KD_MODEL
    return [DP16KD_MODEL, MULT18X18D_MODEL]

# unit -> (scene feature that needs it, what it is); the one specialisation table
SPECIALISATION = [
    ("element_pipeline", lambda f: True, "element pipeline: d, l, e, ldot, adot, T, +/- T e"),
    ("rsqrt_element_length", lambda f: True, "1/sqrt unit for 1/l"),
    ("k1_multiplier", lambda f: f["k1_multiply"], "k1 s multiplier (absent when k1 = 0: plastic)"),
    ("a_state", lambda f: f["a_state"], "a memory and update, adot datapath (absent: viscoelastic)"),
    ("damper_tables", lambda f: f["damper_table"],
     "inverse tables Phi (tension and damper rate from the drive) and Psi (damper force on the a_min stop)"),
    ("constant_damper", lambda f: f["a_state"] and not f["damper_table"],
     "constant c2 / (c1 + c2), 1 / (c1 + c2) and c2"),
    ("pair_pipeline", lambda f: f["topology"], "topology preservation pairs (vertex, opposite facet)"),
    ("collision_pipeline", lambda f: f["collision"], "vertex-facet collision pairs (static list, no broad phase)"),
    ("rsqrt_collision_facet", lambda f: f["collision"], "1/sqrt unit for the facet normal of a collision pair"),
    ("collision_friction", lambda f: f["collision_friction"], "regularised Coulomb friction between objects"),
    ("floor_contact", lambda f: f["floor"], "floor penalty contact in the node pipeline"),
    ("friction", lambda f: f["friction"], "regularised Coulomb friction at the floor"),
    ("rsqrt_friction", lambda f: (f["friction"] or f["collision_friction"]) and f["dim"] == 3,
     "1/sqrt unit for |tangential force| (3D)"),
    ("probe_port", lambda f: f["probe"], "haptic probe: sample and force streams, the per-sample kernel, the "
                                         "probe term in the node pipeline (1/sqrt unit for 1/d), the exact force sum"),
    ("probe_friction", lambda f: f["probe_friction"], "regularised Coulomb friction on the probe"),
    ("gravity", lambda f: f["gravity"], "gravity added to every free node"),
    ("loads", lambda f: f["loads"], "external loads: per-node membership flags and step windows"),
    ("per_node_mass", lambda f: f["per_node_mass"], "per-node 1/m memory and multiplier (absent: uniform mass)"),
]


def full_featured(system):
    """The scene with every optional unit switched on, for measuring what specialisation saves.

    Same mesh, masses (one node 1.5x heavier: per-node mass), lanes and formats preset; added where the
    scene lacks them: gravity, a floor with friction just under the object, topology preservation and
    collisions with friction (when it has cells), a load on node 0, and a rheological material with a
    nonlinear damper (k1 > 0, a state, damper tables). Its physics is plausible (the range analysis of
    its formats runs it), but it is a resource yardstick, not a scene to study.
    """
    import dataclasses
    import math
    from golden import mesh as meshlib
    from golden.builder import collision_of, element_arrays
    from golden.contact import Floor
    from golden.elements import ElementParams
    from golden.scene import MATERIALS
    from golden.system import Load, Topology
    D = system.dim
    arrays, a0 = element_arrays(MATERIALS["rheological"], system.x0, system.edges)
    mass = system.mass.copy()
    mass[np.argmax(~system.pinned)] *= 1.5
    kf = float(mass.min()) / system.dt
    gravity = system.gravity if np.any(system.gravity) else np.eye(D)[D - 1] * -9.81
    floor = system.floor or Floor(float(system.x0[:, D - 1].min()) - 1e-3, 1e4, 1.0, 0.3, kf)
    floor = dataclasses.replace(floor, mu=floor.mu or 0.3, k_f=floor.k_f if floor.mu else kf)
    topology, collision = system.topology, system.collision
    if len(system.cells) and topology is None:
        topology = Topology(meshlib.topology_pairs(system.cells, system.x0), 1e3, 0.5, 0.002)
    if len(system.cells) and collision is None:
        collision = collision_of(system.cells, system.edges, system.x0, 1e4, 1.0, 0.002, 0.3, kf / 2)
    elif collision is not None and not collision.mu:
        collision = dataclasses.replace(collision, mu=0.3, k_f=kf / 2)
    loads = system.loads or [Load(np.array([0]), np.eye(D)[0] * 1e-3, 0.0, math.inf)]
    return dataclasses.replace(system, name=f"{system.name}-full", mass=mass, elem=ElementParams.build(**arrays),
                               a0=a0, gravity=gravity, floor=floor, topology=topology, collision=collision,
                               loads=loads)


def build(bt: BitTrue, lanes: int = 1, node_lanes: int = 1, core: str = "phased", ram: str = "sim",
          pair_lanes: int | None = None, dp16kd_budget: int | None = None):
    """(Core, elaborated Verilog text, manifest dict) for a bit-true model's scene and formats. `core`:
    "phased" (hw/core.py), "stream" (hw/stream/) or "auto" (stream unless collisions); `ram`: the
    streaming core's block RAMs and multipliers, "sim" (inferred) or "ecp5" (DP16KD and MULT18X18D
    instances, `primitive_models`); `pair_lanes`: the
    streaming core's topology-pair lanes (default: lanes); `dp16kd_budget`: the device's block RAMs, which
    the streaming core fits by moving shallow copies into LUT RAM (hw/stream/core.py)."""
    from amaranth.back import verilog
    from .stream import build_core, resolve_core
    kind = resolve_core(bt.params, core)
    c = build_core(bt, lanes, node_lanes, kind, ram, pair_lanes, dp16kd_budget)
    text = verilog.convert(c, name=TOP, emit_src=False)
    if kind == "stream":
        from .stream.manifest import manifest as stream_manifest
        return c, text, stream_manifest(bt, c, SPECIALISATION, TOP)
    return c, text, manifest(bt, c)


def manifest(bt: BitTrue, core: Core) -> dict:
    cfg = core.cfg
    feats = cfg.features()
    present = [{"unit": u, "what": what} for u, need, what in SPECIALISATION if need(feats)]
    absent = [{"unit": u, "what": what} for u, need, what in SPECIALISATION if not need(feats)]
    E, N, Pn, Cn = cfg.n_elements, cfg.n_nodes, cfg.n_pairs, cfg.n_collision_pairs
    mems = core.memories
    return {
        "top": TOP,
        "core": "phased",
        "scene": bt.system.name,
        "preset": bt.formats.preset.name,
        "dim": cfg.dim,
        "nodes": N, "elements": E, "pairs": Pn, "collision_pairs": Cn,
        "lanes": {"element_lanes_P": cfg.lanes, "pair_lanes": cfg.lanes if Pn else 0,
                  "collision_lanes": cfg.lanes if Cn else 0, "node_lanes_Q": cfg.node_lanes},
        "features": {k: (bool(v) if not isinstance(v, int) or isinstance(v, bool) else v) for k, v in feats.items()},
        "units_present": present,
        "units_left_out": absent,
        "function_units": {name: u.to_dict() for name, u in cfg.units.items()},
        "formats": bt.formats.to_dict(),
        "hardware_units": bt.units.to_dict(),
        "memories": mems,
        "memory_bits": int(sum(m["depth"] * m["width"] for m in mems)),
        "cycles_per_step": {
            "formula": "max(ceil(E/P), ceil(pairs/P), ceil(collision_pairs/P)) + drain_elements + ceil(N/Q) "
                       "+ drain_nodes",
            "E": E, "pairs": Pn, "collision_pairs": Cn, "N": N, "P": cfg.lanes, "Q": cfg.node_lanes,
            "drain_elements": core.drain_elements, "drain_nodes": core.drain_nodes,
            "value": core.cycles_per_step,
        },
        "saturation_flags": core.sat_quantities,
        "constant_saturations": core.const_saturations,
        "host_interface": cfg.host_map.to_dict(),
    }


def write(bt: BitTrue, out_dir, lanes: int = 1, node_lanes: int = 1, core: str = "phased", ram: str = "sim",
          pair_lanes: int | None = None, dp16kd_budget: int | None = None) -> dict:
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    core, text, man = build(bt, lanes, node_lanes, core, ram, pair_lanes, dp16kd_budget)
    (out / f"{TOP}.v").write_text(text)
    man["verilog"] = f"{TOP}.v"
    man["verilog_modules"] = sorted(set(line.split()[1].split("(")[0] for line in text.splitlines()
                                        if line.startswith("module ")))
    (out / "manifest.json").write_text(json.dumps(man, indent=2, default=_json_default))
    return man


def _json_default(o):
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, (np.floating,)):
        return float(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")
