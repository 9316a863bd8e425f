"""`rheo run`: the main job on one scene (what `make run` does; sim/mainjob.py)."""
from __future__ import annotations

from .common import FORMAT_PRESETS, check_backend_fits, load_system, positive_int

NAME, HELP = "run", "the main job: golden, bit-true, Verilog checked bit for bit, report, synthesis"
DEFAULT_SCENE = "press-2d-rheological"


def add_arguments(parser) -> None:
    parser.add_argument("--scene", default=DEFAULT_SCENE, help=f"scene (default: {DEFAULT_SCENE})")
    parser.add_argument("--out", default="out", help="output directory (default: out)")
    parser.add_argument("--preset", default="wide", choices=FORMAT_PRESETS,
                        help="format preset of the bit-true run and Verilog (default: wide)")
    parser.add_argument("--hdl-steps", type=positive_int, default=200,
                        help="steps simulated in Verilog and checked bit for bit (default 200)")
    parser.add_argument("--simulator", choices=["verilator", "icarus"], default=None,
                        help="HDL simulator of the check (default: Verilator where installed, else Icarus)")
    parser.add_argument("--no-synth", dest="synth", action="store_false", help="skip the synthesis")
    parser.add_argument("--pnr", action="store_true",
                        help="also place and route with nextpnr for Fmax (tens of minutes; cached by the Verilog's hash)")


def run(args) -> int:
    from sim.mainjob import hdl_simulator, main_job
    from sim.runfile import check_output_dir
    from sim.simulators import check_simulator
    from .stability import refuse_if_unstable
    check_output_dir(args.out)                     # every argument and tool before any work
    simulator = hdl_simulator(args.simulator)[0]
    check_simulator(simulator)
    if args.synth:
        from sim.synth import check_tools
        check_tools(args.pnr)
    system = load_system(args.scene)
    refuse_if_unstable(system, force=False)
    check_backend_fits(system, simulator)
    main_job(system, args.out, preset=args.preset, hdl_steps=args.hdl_steps, synth=args.synth,
             place_and_route=args.pnr, simulator=args.simulator, log=lambda m: print(m, flush=True))
    return 0
