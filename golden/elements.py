"""The three-element rheological element (MODEL.md section 2), vectorised over all elements.

Per element k between start node i and end node j (e points i -> j):

    d = x_j - x_i,  l = |d|,  e = d / l,  ldot = e . (v_j - v_i),  s = a l - L
    c2 = clip(A exp(-B |T_prev|), c_min, c_max)      (constant c2: A = c_min = c_max, B = 0)
    adot = (-k1 s - (c1 a - c2 (1 - a)) ldot) / ((c1 + c2) l)
    adot = 0 where a sits on a bound and adot points outward          (active clamp, eq. 9)
    T = k1 s + c1 (adot l + a ldot)                                     (tension, T > 0 pulls)

Node i receives +T e and node j receives -T e (the same word, so internal forces cancel).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def _compact(values: np.ndarray):
    """A per-element parameter array, or a float when every element has the same value (faster)."""
    values = np.asarray(values, float)
    return float(values[0]) if values.size and np.all(values == values[0]) else values


@dataclass
class ElementParams:
    """Per-element material parameters; each field is an (E,) array or a float if uniform."""
    k1: object
    c1: object
    a_min: object
    a_max: object
    L: np.ndarray            # natural length of the Voigt part, a0 * l0
    c_min: object            # damper c2 bounds; equal for a constant damper
    c_max: object
    A: object                # c2 = A exp(-B f) between f1 and f2
    B: object
    nonlinear: bool          # False: every element has a constant c2 (no exp at run time)
    fixed_a: bool = False    # a_min = a_max for every element: no a state (viscoelastic)

    @classmethod
    def build(cls, k1, c1, a_min, a_max, L, c_min, c_max, f1, f2):
        c_min, c_max = np.asarray(c_min, float), np.asarray(c_max, float)
        f1, f2 = np.asarray(f1, float), np.asarray(f2, float)
        varies = c_max > c_min
        B = np.where(varies, np.log(np.where(varies, c_max / c_min, 1.0)) / np.where(varies, f2 - f1, 1.0), 0.0)
        A = c_max * np.exp(B * f1)
        return cls(_compact(k1), _compact(c1), _compact(a_min), _compact(a_max), np.asarray(L, float),
                   _compact(c_min), _compact(c_max), _compact(A), _compact(B), bool(np.any(varies)),
                   bool(np.all(np.asarray(a_min) == np.asarray(a_max))))

    def damper(self, f_prev: np.ndarray):
        """c2 from the previous step's |T| (one-step-lagged nonlinear damper, MODEL.md section 2)."""
        if not self.nonlinear:
            return self.c_min
        return np.clip(self.A * np.exp(-self.B * f_prev), self.c_min, self.c_max)


def element_forces(xt, vt, a, f_prev, i, j, p: ElementParams):
    """Element tensions from component-major positions and velocities xt, vt (D, N).

    Returns (T, T/l, d, adot): tension (E,), tension per unit length (E,), the edge vectors
    d = x_j - x_i as a list of D arrays (E,), and the clamped rate of a (E,). T e = (T/l) d.
    """
    D = len(xt)
    d = [np.take(xt[k], j) - np.take(xt[k], i) for k in range(D)]
    dv = [np.take(vt[k], j) - np.take(vt[k], i) for k in range(D)]
    l2 = d[0] * d[0]
    dd = d[0] * dv[0]
    for k in range(1, D):
        l2 += d[k] * d[k]
        dd += d[k] * dv[k]
    l = np.sqrt(l2)
    inv_l = 1.0 / l
    ldot = dd * inv_l
    c2 = p.damper(f_prev)
    k1s = p.k1 * (a * l - p.L)
    if p.fixed_a:      # a_min = a_max everywhere: a never moves, adot = 0 (viscoelastic)
        adot = np.zeros_like(a)
        T = k1s + p.c1 * a * ldot
    else:
        adot = ((c2 - (p.c1 + c2) * a) * ldot - k1s) * inv_l / (p.c1 + c2)
        adot = np.where(a <= p.a_min, np.maximum(adot, 0.0), adot)
        adot = np.where(a >= p.a_max, np.minimum(adot, 0.0), adot)
        T = k1s + p.c1 * (adot * l + a * ldot)
    return T, T * inv_l, d, adot
