"""How far a scene's own physics wanders under rounding: the golden model with its states on a format's grid.

Some scenes are sensitive: an element whose a reaches a clamp bound, or a contact that starts (within the
threshold, foot on the facet), switches a force on or off, and a difference of one LSB can move that
switch by a step. Their trajectories then part by far more than the rounding itself, whatever the
arithmetic. To tell the bit-true model's own error from this, `rounded_golden` runs the golden model
(float64 physics) with x, v and a rounded to the preset's state formats after every step: the most
accurate machine with those state words. Its distance from the golden run is the scene's sensitivity
floor at that word width; a bit-true error near it is the scene's, not the datapath's.
"""
from __future__ import annotations

import numpy as np

from golden.model import Golden
from golden.system import State, System, frame_steps


def rounded_golden(system: System, formats, units, steps: int | None = None, every: int = 1) -> np.ndarray:
    """Positions (F, N, D) in metres of the golden model whose x, v, a are rounded to `formats` every step,
    at the frames of golden.model.frame_steps(steps, every)."""
    steps = system.n_steps if steps is None else int(steps)
    fx, fu, fa = formats["x"], formats["u"], formats["a"]
    gold, st = Golden(system), State.initial(system)
    at = frame_steps(steps, max(1, every))
    out = np.empty((len(at),) + system.x0.shape)

    def on_grid():
        st.x[:] = units.to_length(fx.to_float(fx.from_float(units.length(st.x))))
        st.v[:] = units.to_velocity(fu.to_float(fu.from_float(units.velocity(st.v))))
        st.a[:] = fa.to_float(fa.from_float(st.a))

    on_grid()
    for f, target in enumerate(at):
        while st.step < target:
            gold.step(st)
            on_grid()
        out[f] = st.x
    return out
