"""Hardware units: the scene's SI quantities scaled so that the time step is 1.

Length unit ell (a power of two metres near the scene's size), time unit dt, mass unit m_ref (the
smallest free node mass). In these units the model's equations keep their form with dt = 1, so the
datapath never multiplies by dt:

    x^ = x / ell            u^ = v dt / ell (displacement per step)     F^ = F dt^2 / (m_ref ell)
    k^ = k dt^2 / m_ref     c^ = c dt / m_ref                            g^ = g dt^2 / ell
    inverse mass ratio mu_i = m_ref / m_i (<= 1)                          a, mu, weights: unchanged
and one step is  u^ += mu_i F^ + g^,  x^ += u^,  a += adot^ (adot^ = adot dt).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from golden.system import System


@dataclass(frozen=True)
class HardwareUnits:
    ell: float     # metres per length unit
    dt: float      # seconds per step
    m_ref: float   # kg per mass unit

    @classmethod
    def of(cls, system: System) -> "HardwareUnits":
        size = float(np.ptp(system.x0, axis=0).max())
        free = system.mass[~system.pinned] if np.any(~system.pinned) else system.mass
        return cls(2.0 ** math.ceil(math.log2(max(size, 1e-9))), system.dt, float(free.min()))

    # SI -> hardware
    def length(self, x):
        return np.asarray(x, float) / self.ell

    def velocity(self, v):
        return np.asarray(v, float) * self.dt / self.ell

    def force(self, f):
        return np.asarray(f, float) * self.dt ** 2 / (self.m_ref * self.ell)

    def stiffness(self, k):
        return np.asarray(k, float) * self.dt ** 2 / self.m_ref

    def damping(self, c):
        return np.asarray(c, float) * self.dt / self.m_ref

    def acceleration(self, g):
        return np.asarray(g, float) * self.dt ** 2 / self.ell

    # hardware -> SI
    def to_length(self, x):
        return np.asarray(x, float) * self.ell

    def to_velocity(self, u):
        return np.asarray(u, float) * self.ell / self.dt

    def to_force(self, f):
        return np.asarray(f, float) * self.m_ref * self.ell / self.dt ** 2

    def to_dict(self) -> dict:
        return {"ell_m": self.ell, "dt_s": self.dt, "m_ref_kg": self.m_ref}
