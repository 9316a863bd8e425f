"""A scene's design poke (its [probe] depth and poke_time: straight down and back, then at rest until the
scene's duration) as a trajectory CSV of offsets for `rheo haptic`, one row per device sample; optionally
with another poke time and total duration (s).

    .venv/bin/python tools/poke_trajectory.py poke-2d-rheological docs/poke-2d.csv [POKE_TIME DURATION]
"""
from __future__ import annotations

import sys

from golden.scene import load_scene
from sim.haptic import design_trajectory, write_trajectory


def main(argv) -> int:
    if len(argv) not in (2, 4):
        print(__doc__.strip().splitlines()[-1].strip(), file=sys.stderr)
        return 2
    system = load_scene(argv[0])
    samples = None
    if len(argv) == 4:
        system.probe.poke_time = float(argv[2])
        samples = int(round(float(argv[3]) / (system.probe.k * system.dt)))
    traj = design_trajectory(system, samples)
    path = write_trajectory(argv[1], traj, offsets_from=system.probe.position)
    print(f"wrote {path}: {len(traj)} device samples")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
