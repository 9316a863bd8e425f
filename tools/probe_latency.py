"""Sample-in to force-out latency of the streaming core's probe port on a finer poke, from the schedule
alone (no elaboration): the built-in poke scene's block with its mesh divisions multiplied, under the
formats of the built-in scene (their range analysis would otherwise run the large mesh; like
tools/stream_fit.py), and the core's DP16KD by the block RAM model (all copies in block RAM, or with `--fit N` fitted to N DP16KD
as `rheo synth` fits them: shallow copies into LUT RAM). Latency = the sample kernel's stages + run_cycles(k) + DONE_STAGES, as
hw/stream/probeport.py `ProbePort.latency`.

    python tools/probe_latency.py poke-2d-1000-elements 3.125 5 4 wide [85.8 98.1]   # scene, refinement, P, Q, preset, MHz...
    python tools/probe_latency.py poke-2d-1000-elements 1 2,3 2 medium 65            # P,Pp: pair lanes apart
    python tools/probe_latency.py poke-2d-1000-elements 3.125 3,6 4 medium --fit 208 # LUT RAM moves to fit 208
"""
from __future__ import annotations

import re
import sys
import tempfile
import warnings
from pathlib import Path

warnings.filterwarnings("ignore")


def refined(scene: str, factor: float) -> str:
    """The scene file's text with its first mesh's divisions multiplied by factor."""
    from golden.scene import builtin_names
    if scene not in builtin_names():
        raise SystemExit(f"unknown built-in scene {scene!r}")
    text = (Path(__file__).resolve().parents[1] / "golden" / "scenes" / f"{scene}.toml").read_text()
    m = re.search(r"divisions = \[([^\]]*)\]", text)
    divs = [max(1, round(int(v) * factor)) for v in m.group(1).split(",")]
    return text[:m.start()] + f"divisions = [{', '.join(map(str, divs))}]" + text[m.end():]


def main(argv) -> int:
    from golden.errors import RheoError
    from golden.scene import load_scene
    from hw.bittrue import BitTrue
    from hw.stream.config import StreamConfig
    from hw.stream.core import StreamCore
    from hw.stream.probeport import DONE_STAGES
    argv, budget = list(argv), None
    if "--fit" in argv:                                # fit N DP16KD as rheo synth builds it (LUT RAM copies)
        k = argv.index("--fit")
        budget = int(argv[k + 1])
        del argv[k:k + 2]
    scene, factor, Q, preset = argv[0], float(argv[1]), int(argv[3]), argv[4]
    P, Pp = (int(v) for v in argv[2].split(",")) if "," in argv[2] else (int(argv[2]), None)
    clocks = [float(v) for v in argv[5:]] or [100.0]
    small = load_scene(scene)
    formats = BitTrue(small, preset).formats
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / f"{scene}-x{factor:g}.toml"
        path.write_text(refined(scene, factor))
        big = load_scene(str(path))
    runs = [(scene, small)] + ([(f"{scene} x{factor:g}", big)] if factor != 1 else [])
    for name, system in runs:
        try:
            cfg = StreamConfig.of(BitTrue(system, preset, formats=formats), P, Q, pair_lanes=Pp, dp16kd_budget=budget)
        except (RheoError, ValueError) as exc:
            print(f"{name}: {system.n_elements} elements, P {P}, Q {Q}: refused: {exc}", flush=True)
            continue
        sch = cfg.schedule
        core = StreamCore(cfg)                       # the block RAM model of tools/stream_fit.py
        dpr = sum(m.get("dpr16x4", 0) for m in core.memories())
        blocks = f"{core.block_rams()} DP16KD" + (f" (--fit {budget}: {len(core.lut_memories)} copies in LUT RAM, "
                                                   f"{dpr} TRELLIS_DPR16X4)" if budget is not None else "")
        latency = cfg.probe_dry.stage + sch.run_cycles(int(cfg.params.probe["k"])) + DONE_STAGES
        at = ", ".join(f"{latency / mhz:.1f} us at {mhz:g} MHz" for mhz in clocks)
        print(f"{name}: {system.n_elements} elements, {system.n_nodes} nodes, P {P}, Pp {cfg.pair_lanes}, Q {Q}, {preset}: "
              f"T {sch.period} (element slots {sch.element_slots}, pair slots {sch.pair_slots}), "
              f"latency {latency} cycles = {at}; {blocks}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
