"""`rheo stability SCENE [--measure [--model golden|fixed|both] [--preset P]] [--json]`: the predicted (and
measured) largest stable dt of a scene, and the guard `refuse_if_unstable` for `rheo simulate` and `rheo run`
(golden/stability.py has the formulas, golden/measure.py the bisection, hw/stability_fixed.py the bit-true
trial)."""
from __future__ import annotations

import json
import math

from .common import FORMAT_PRESETS, UsageError, load_system, scene_argument

MODELS = ("golden", "fixed", "both")


NAME, HELP = "stability", "predicted (and measured) largest stable dt of a scene"
DESCRIPTION = ("Predict the largest dt at which the explicit (symplectic Euler) step of a scene is stable, with "
               "the node or element that limits it; --measure also finds the real limit by bisection on runs of "
               "the golden model, or of the bit-true model (--model fixed or both).")


def add_arguments(parser) -> None:
    scene_argument(parser)
    parser.add_argument("--measure", action="store_true",
                        help="also measure the limit on real runs (seconds to a minute for the built-in 2D scenes)")
    # default None, not the default value: given without --measure is an error (run)
    parser.add_argument("--model", choices=MODELS, default=None,
                        help="--measure on the golden model, the bit-true model or both (default: golden; "
                             "measuring the bit-true model takes 5-10x as long)")
    parser.add_argument("--preset", choices=FORMAT_PRESETS, default=None,
                        help="--measure --model fixed/both: number-format preset of the bit-true model (default: wide)")
    parser.add_argument("--json", action="store_true", help="print JSON")


def _finite(x):
    """JSON has no infinity: None stands for 'no bound'."""
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, dict):
        return {k: _finite(v) for k, v in x.items()}
    if isinstance(x, list):
        return [_finite(v) for v in x]
    return x


def _s(x: float) -> str:
    return "none" if not math.isfinite(x) else f"{x:.4g} s"


def _measured(m: dict) -> dict:
    return {"dt_meas": m["dt_meas"], "stable_at": m["lo"], "unstable_at": m["hi"], "ratio": m["ratio"],
            "runs": len(m["trials"]), "seconds": m["seconds"], "reference_dt": m["dt_ref"]}


def report(system, measure: bool = False, model: str = "golden", preset: str = "wide") -> dict:
    """Prediction (and measurement) as one dict: "measured" on the golden model, "measured_fixed" on the
    bit-true model of the preset (hw/stability_fixed.py), with "vs_golden" (its limit / golden's) for both."""
    from golden.measure import measure as measure_dt
    from golden.stability import predict
    if model not in MODELS:
        raise UsageError(f"unknown model '{model}' (known: {', '.join(MODELS)})")
    p = predict(system)
    out = {"scene": system.name, "nodes": system.n_nodes, "elements": system.n_elements, **p}
    if not measure:
        return out
    if model in ("golden", "both"):
        from sim.cpu import Cpu, stability_model  # the golden physics, compiled: the same verdicts, faster
        if system.probe is not None and not Cpu.takes_probe:
            out["measured"] = {**_measured(measure_dt(system, pred=p)), "stepper": "golden"}   # the probe
        else:
            out["measured"] = {**_measured(measure_dt(system, pred=p, model=stability_model)), "stepper": "cpu"}
    if model in ("fixed", "both"):
        from hw.stability_fixed import measure_fixed
        m = measure_fixed(system, preset, pred=p)
        out["measured_fixed"] = {"preset": preset, **_measured(m), "yardstick": m["yardstick"],
                                 "bit_true_reference_dt": m["bit_ref_dt"]}
        if "measured" in out:
            out["measured_fixed"]["vs_golden"] = m["dt_meas"] / out["measured"]["dt_meas"]
    return out


def run(args) -> int:
    given = [opt for opt, val in (("--model", args.model), ("--preset", args.preset)) if val is not None]
    if given and not args.measure:
        raise UsageError(f"{' and '.join(given)} {'apply' if len(given) > 1 else 'applies'} only with --measure")
    if args.preset is not None and args.model in (None, "golden"):
        raise UsageError("--preset is the bit-true model's: use it with --model fixed or --model both")
    system = load_system(args.scene)
    out = report(system, args.measure, args.model or "golden", args.preset or "wide")
    if args.json:
        print(json.dumps(_finite(out), indent=2))
        return 0
    q = out["parts"]
    print(f"{out['scene']}: {out['nodes']} nodes, {out['elements']} elements")
    print(f"  predicted stable dt  {_s(out['dt_pred'])}  (limited by {out['limiting']})")
    print(f"  scene dt             {_s(out['dt'])}  margin {out['margin']:.3g} x"
          + ("  ** above the predicted limit **" if out["margin"] < 1 else ""))
    print(f"  node bound           {_s(out['node_bound'])}: node {q['node']}, {q['case']}")
    line = (f"    mass {q['mass']:.4g} kg; elements k {q['k_elements']:.4g} N/m, c {q['c_elements']:.4g} N s/m"
            + (f", c2 {q['c2_elements']:.4g} N s/m" if "c2_elements" in q else ""))
    if q["mode"] == "mesh":
        line += f" (mesh factor {q['mesh_factor']:.3f}, x {q['element_scale']:.3f})"
    else:
        line += f"; {q['contact']} contact K {q['k_contact']:.4g} N/m, C {q['c_contact']:.4g} N s/m"
    print(line)
    el = f"  element bound        {_s(out['element_bound'])}"
    if "element_k1" in q:
        el += (f": element {q['element']} (a state; k1 {q['element_k1']:.4g}, c1 {q['element_c1']:.4g}, "
               f"c_min {q['element_c_min']:.4g})")
    print(el)
    for note in out["notes"]:
        print(f"  note: {note}")
    if "measured" in out:
        m = out["measured"]
        print(f"  measured stable dt   {_s(m['dt_meas'])}  (stable at {m['stable_at']:.4g} s, unstable at "
              f"{m['unstable_at']:.4g} s; {m['runs']} runs, {m['seconds']:.1f} s)")
        print(f"  predicted / measured {m['ratio']:.3f}")
    if "measured_fixed" in out:
        m = out["measured_fixed"]
        print(f"  bit-true ({m['preset']}) stable dt {_s(m['dt_meas'])}  (stable at {m['stable_at']:.4g} s, "
              f"unstable at {m['unstable_at']:.4g} s; {m['runs']} runs, {m['seconds']:.1f} s)")
        print(f"  predicted / bit-true {m['ratio']:.3f}"
              + (f";  bit-true / golden {m['vs_golden']:.3f}" if "vs_golden" in m else ""))
    return 0


def refuse_if_unstable(system, force: bool) -> None:
    """Raise UsageError (one line) when the scene's dt is above the predicted stable limit, unless force."""
    if force:
        return
    from golden.stability import predict
    p = predict(system)
    if system.dt > p["dt_pred"]:
        raise UsageError(f"scene '{system.name}': dt = {system.dt:g} s exceeds the predicted stable limit "
                         f"{p['dt_pred']:.4g} s (limited by {p['limiting']}); use a smaller dt or --force")
