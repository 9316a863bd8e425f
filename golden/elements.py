"""The three-element rheological element (MODEL.md section 2, version 2), vectorised over all elements.

Per element k between start node i and end node j (e points i -> j):

    d = x_j - x_i,  l = |d|,  e = d / l,  ldot = e . (v_j - v_i),  s = a l - L
    Y = k1 s + c1 ldot                         the drive: the Voigt force if the damper were rigid
    T = Phi(Y),  w' = T / c2(|T|)              the series balance Y = G(T) = T + c1 T / c2(|T|), solved
    adot = ((1 - a) ldot - w') / l             exactly (no lag); w' is the damper's rate of lengthening
  stops (a on a bound at the start of the step, adot pointing outward; adot = 0 then):
    a >= a_max (the damper on its stop):       T = k1 s + c1 a ldot
    a <= a_min (the Voigt part on its stop):   T = Psi((1 - a) ldot), Psi the inverse of H(T) = T / c2(|T|)
    a_min = a_max (no a state):                T = k1 s + c1 a ldot always

Node i receives +T e and node j receives -T e (the same word, so internal forces cancel).

The damper c2(f) = clip(A exp(-B f), c_min, c_max) makes G and H odd, continuous and strictly increasing:
linear below f1 and above f2, convex in between, where T is found by Newton's method kept inside
[f1, f2] (`solve_convex`), to float64 precision. A constant damper needs no solve at all.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

SOLVE_RTOL = 1e-12          # |G(T) - Y| <= SOLVE_RTOL |Y| + SOLVE_ATOL after a solve
SOLVE_ATOL = 1e-300
SOLVE_MAX_ITER = 100


def _compact(values: np.ndarray):
    """A per-element parameter array, or a float when every element has the same value (faster)."""
    values = np.asarray(values, float)
    return float(values[0]) if values.size and np.all(values == values[0]) else values


def _sub(value, idx):
    """A per-element parameter restricted to the items idx (a float stays a float)."""
    return value if np.isscalar(value) or np.ndim(value) == 0 else value[idx]


def solve_convex(F, dF, y, lo, hi):
    """Solve F(t) = y for t in [lo, hi], F convex and strictly increasing there (vectorised).

    F(t, idx) and dF(t, idx) evaluate the function and its derivative for the items idx. Newton from the
    chord's root (below the solution of a convex F) overshoots to the right once, then descends
    monotonically; each iterate is kept inside [lo, hi]. Returns t with |F(t) - y| <= SOLVE_RTOL |y| +
    SOLVE_ATOL, or raises if that takes more than SOLVE_MAX_ITER steps (a bug, not a physics case).
    """
    y = np.asarray(y, float)
    lo, hi = np.broadcast_to(lo, y.shape), np.broadcast_to(hi, y.shape)
    all_idx = np.arange(y.size)
    Flo, Fhi = F(lo, all_idx), F(hi, all_idx)
    width = np.where(Fhi > Flo, Fhi - Flo, 1.0)
    t = np.clip(lo + (y - Flo) * (hi - lo) / width, lo, hi)
    act = all_idx
    for _ in range(SOLVE_MAX_ITER):
        r = F(t[act], act) - y[act]
        open_ = np.abs(r) > SOLVE_RTOL * np.abs(y[act]) + SOLVE_ATOL
        if not open_.any():
            return t
        act, r = act[open_], r[open_]
        t[act] = np.clip(t[act] - r / dF(t[act], act), lo[act], hi[act])
    raise ArithmeticError("damper solve did not converge")


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
    nonlinear: bool          # False: every element has a constant c2 (no solve at run time)
    fixed_a: bool = False    # a_min = a_max for every element: no a state (viscoelastic)
    f1: object = np.inf      # the damper's knees (inf: a constant damper)
    f2: object = np.inf

    @classmethod
    def build(cls, k1, c1, a_min, a_max, L, c_min, c_max, f1, f2):
        c_min, c_max = np.asarray(c_min, float), np.asarray(c_max, float)
        f1, f2 = np.asarray(f1, float), np.asarray(f2, float)
        varies = c_max > c_min
        B = np.where(varies, np.log(np.where(varies, c_max / c_min, 1.0)) / np.where(varies, f2 - f1, 1.0), 0.0)
        with np.errstate(over="ignore"):             # A only names the law; the code uses c_max and f1
            A = c_max * np.exp(B * np.where(varies, f1, 0.0))
        return cls(_compact(k1), _compact(c1), _compact(a_min), _compact(a_max), np.asarray(L, float),
                   _compact(c_min), _compact(c_max), _compact(A), _compact(B), bool(np.any(varies)),
                   bool(np.all(np.asarray(a_min) == np.asarray(a_max))),
                   _compact(np.where(varies, f1, np.inf)), _compact(np.where(varies, f2, np.inf)))

    # ---- the damper law
    def damper(self, f: np.ndarray):
        """c2 at the force magnitude f (MODEL.md section 2)."""
        if not self.nonlinear:
            return self.c_min
        return np.clip(self.c_max * np.exp(-self.B * (np.asarray(f, float) - self.f1)), self.c_min, self.c_max)

    def _mid(self, mag, lo, hi):
        """Items whose magnitude lies on the exponential piece, [lo, hi) (lo = inf: constant dampers)."""
        return np.flatnonzero((mag >= lo) & (mag < hi))

    def _exp_law(self, idx):
        """H(t) = t / c2(t) = t e^(B (t - f1)) / c_max and its derivative on the items idx, t in [f1, f2]."""
        B, f1, cmax = _sub(self.B, idx), _sub(self.f1, idx), _sub(self.c_max, idx)

        def H(t, k):
            return t * np.exp(_sub(B, k) * (t - _sub(f1, k))) / _sub(cmax, k)

        def dH(t, k):
            bk = _sub(B, k)
            return np.exp(bk * (t - _sub(f1, k))) * (1.0 + bk * t) / _sub(cmax, k)
        return H, dH

    def phi(self, Y: np.ndarray, idx=None):
        """T = Phi(Y), the inverse of G(T) = T + c1 T / c2(|T|), and the damper rate w' = T / c2(|T|).

        Linear below Y1 = f1 (1 + c1/c_max) (T = Y c_max / (c1 + c_max)) and above Y2 = f2 (1 + c1/c_min);
        solved in between. `idx`: the elements Y belongs to (default: all)."""
        c1, cmin, cmax = (_sub(v, idx) if idx is not None else v for v in (self.c1, self.c_min, self.c_max))
        mag = np.abs(Y)
        if not self.nonlinear:
            return Y * (cmin / (c1 + cmin)), Y / (c1 + cmin)
        f1, f2 = (_sub(v, idx) if idx is not None else v for v in (self.f1, self.f2))
        Y1, Y2 = f1 * (1.0 + c1 / cmax), f2 * (1.0 + c1 / cmin)
        c2 = np.where(mag < Y1, cmax, cmin)
        T, wd = Y * (c2 / (c1 + c2)), Y / (c1 + c2)
        mid = self._mid(mag, Y1, Y2)
        if mid.size:
            H, dH = self._exp_law(mid if idx is None else _as_index(idx)[mid])
            c1m = _sub(c1, mid)
            t = solve_convex(lambda t, k: t + _sub(c1m, k) * H(t, k), lambda t, k: 1.0 + _sub(c1m, k) * dH(t, k),
                             mag[mid], _sub(f1, mid), _sub(f2, mid))
            sign = np.sign(Y[mid])
            T[mid] = sign * t
            wd[mid] = sign * H(t, np.arange(mid.size))
        return T, wd

    def psi(self, W: np.ndarray, idx=None):
        """T = Psi(W), the inverse of H(T) = T / c2(|T|): the damper's force at the rate W (MODEL.md 2,
        the Voigt part on its a_min stop). Linear below W1 = f1 / c_max and above W2 = f2 / c_min."""
        cmin, cmax = (_sub(v, idx) if idx is not None else v for v in (self.c_min, self.c_max))
        if not self.nonlinear:
            return W * cmin
        f1, f2 = (_sub(v, idx) if idx is not None else v for v in (self.f1, self.f2))
        mag = np.abs(W)
        T = W * np.where(mag < f1 / cmax, cmax, cmin)
        mid = self._mid(mag, f1 / cmax, f2 / cmin)
        if mid.size:
            H, dH = self._exp_law(mid if idx is None else _as_index(idx)[mid])
            T[mid] = np.sign(W[mid]) * solve_convex(H, dH, mag[mid], _sub(f1, mid), _sub(f2, mid))
        return T


@dataclass(frozen=True)
class DamperLaw:
    """One force-dependent damper beside its c1 (scalars, any consistent units): the curves of MODEL.md 2 v2.

    H(T) = T / c2(T), the damper's rate at the force T, and G(T) = T + c1 H(T), the drive that balances
    T in series; both odd and strictly increasing, linear below f1 and above f2, convex in between.
    """
    c1: float
    c_min: float
    c_max: float
    f1: float
    f2: float

    @property
    def B(self) -> float:
        return math.log(self.c_max / self.c_min) / (self.f2 - self.f1)

    # H and its derivatives on [f1, f2] (e^(B (t - f1)) / c_max = 1 / c2(t))
    def H(self, t):
        return t * np.exp(self.B * (t - self.f1)) / self.c_max

    def dH(self, t):
        return np.exp(self.B * (t - self.f1)) * (1.0 + self.B * t) / self.c_max

    def d2H(self, t):
        B = self.B
        return np.exp(B * (t - self.f1)) * B * (2.0 + B * t) / self.c_max

    def G(self, t):
        return t + self.c1 * self.H(t)

    def dG(self, t):
        return 1.0 + self.c1 * self.dH(t)

    def d2G(self, t):
        return self.c1 * self.d2H(t)

    # the knees of Phi = G^-1 (in the drive Y) and of Psi = H^-1 (in the rate W), and the linear slopes
    @property
    def Y1(self) -> float:
        return self.f1 * (1.0 + self.c1 / self.c_max)

    @property
    def Y2(self) -> float:
        return self.f2 * (1.0 + self.c1 / self.c_min)

    @property
    def W1(self) -> float:
        return self.f1 / self.c_max

    @property
    def W2(self) -> float:
        return self.f2 / self.c_min

    def slopes(self, c2: float) -> tuple:
        """(dT/dY, dw'/dY) on a linear piece with damper c2."""
        return c2 / (self.c1 + c2), 1.0 / (self.c1 + c2)


def _as_index(idx) -> np.ndarray:
    idx = np.asarray(idx)
    return np.flatnonzero(idx) if idx.dtype == bool else idx


def element_forces(xt, vt, a, i, j, p: ElementParams):
    """Element tensions from component-major positions and velocities xt, vt (D, N).

    Returns (T, T/l, d, adot): tension (E,), tension per unit length (E,), the edge vectors
    d = x_j - x_i as a list of D arrays (E,), and the rate of a (E,), 0 on a stop. T e = (T/l) d.
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
    k1s = p.k1 * (a * l - p.L)
    if p.fixed_a:      # a_min = a_max everywhere: a never moves, the damper is rigid (viscoelastic)
        return (T := k1s + p.c1 * a * ldot), T * inv_l, d, np.zeros_like(a)
    T, wd = p.phi(k1s + p.c1 * ldot)
    W = (1.0 - a) * ldot                  # the damper's rate if the Voigt part were rigid
    adot = (W - wd) * inv_l
    at_lo, at_hi = a <= p.a_min, a >= p.a_max
    hi_stop = at_hi & ((adot > 0) | at_lo)           # a_min = a_max: the damper is rigid
    lo_stop = at_lo & (adot < 0) & ~at_hi
    if hi_stop.any():
        T = np.where(hi_stop, k1s + p.c1 * a * ldot, T)
        adot[hi_stop] = 0.0
    if lo_stop.any():
        lo = np.flatnonzero(lo_stop)
        T[lo] = p.psi(W[lo], lo)
        adot[lo] = 0.0
    return T, T * inv_l, d, adot
