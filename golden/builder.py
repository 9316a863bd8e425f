"""Building a System from objects (as warp's ModelBuilder is the one way a Model is made): the scene
compiler (golden/scene.py), the benchmark square (sim/bench.py) and the full-featured variant of a scene
(hw/emit.py) all build through here, so materials become element arrays and surfaces become collision
lists in one place.

    b = SystemBuilder(dim)
    b.add_object("block", mesh, material, masses, pinned, position, velocity)   # returns its first node
    system = b.build(name, gravity, dt, n_steps, every, floor=..., topology=..., collision=..., loads=...,
                     probe=...)

A material is a resolved table (golden/scene.py MATERIALS or a scene's [material]): k1, c1, a0, a_min,
a_max and either a constant c2 or the nonlinear damper's c_min, c_max, f1, f2.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from . import mesh as meshlib
from .contact import Collision, Floor
from .elements import ElementParams
from .probe import Probe
from .system import System, Topology

NONLINEAR = ("c_min", "c_max", "f1", "f2")
ELEMENT_FIELDS = ("k1", "c1", "a_min", "a_max", "L", "c_min", "c_max", "f1", "f2")


def element_arrays(material: dict, nodes: np.ndarray, edges: np.ndarray) -> tuple[dict, np.ndarray]:
    """Per-element parameter arrays (ELEMENT_FIELDS) and initial a of a material on a mesh's edges: the
    Voigt part's natural length L = a0 l0 (l0 the rest length); a constant c2 is a damper with
    c_min = c_max = c2 (and knees that are never used)."""
    E = len(edges)
    l0 = np.linalg.norm(nodes[edges[:, 1]] - nodes[edges[:, 0]], axis=1)
    arrays = {k: np.full(E, float(material[k])) for k in ("k1", "c1", "a_min", "a_max")}
    arrays["L"] = material["a0"] * l0
    if "c2" in material:
        arrays.update(c_min=np.full(E, float(material["c2"])), c_max=np.full(E, float(material["c2"])),
                      f1=np.zeros(E), f2=np.ones(E))
    else:
        arrays.update({k: np.full(E, float(material[k])) for k in NONLINEAR})
    return arrays, np.full(E, float(material["a0"]))


def collision_of(cells: np.ndarray, edges: np.ndarray, x0: np.ndarray, K: float, C: float, threshold: float,
                 mu: float, k_f: float) -> Collision:
    """Vertex-facet collision between every surface vertex and every surface facet of the meshes (pairs of
    nodes joined by an element never collide)."""
    N = len(x0)
    faces, _ = meshlib.boundary_faces(cells, x0)
    keys = np.concatenate([edges[:, 0] * N + edges[:, 1], edges[:, 1] * N + edges[:, 0]])
    return Collision(np.unique(faces), faces, np.sort(keys), N, K, C, threshold, mu, k_f)


@dataclass
class TopologySpec:
    """Topology preservation (MODEL.md 3) over every cell: penalty K, damping C, margin eps."""
    K: float
    C: float
    eps: float


@dataclass
class CollisionSpec:
    """Vertex-facet collision (MODEL.md 4); k_f NaN: the default regularisation (SystemBuilder.build)."""
    K: float
    C: float
    threshold: float
    mu: float = 0.0
    k_f: float = math.nan


class SystemBuilder:
    """Accumulates objects, then builds the System."""

    def __init__(self, dim: int):
        if dim not in (2, 3):
            raise ValueError(f"dim must be 2 or 3, got {dim}")
        self.dim = dim
        self.names: list[str] = []
        self.materials: list[dict] = []
        self._nodes, self._vel, self._mass, self._pinned = [], [], [], []
        self._edges, self._cells, self._a0 = [], [], []
        self._params = {k: [] for k in ELEMENT_FIELDS}
        self._node_object, self._cell_object = [], []
        self.n_nodes = 0

    def add_object(self, name: str, mesh: meshlib.Mesh, material: dict, masses: np.ndarray,
                   pinned: np.ndarray | None = None, position=None, velocity=None) -> int:
        """Add one object (mesh in its own coordinates, moved by `position`); returns its first node's
        index. Pinned nodes start at rest (MODEL.md 5)."""
        o, n, D = len(self.names), len(mesh.nodes), self.dim
        pin = np.zeros(n, bool) if pinned is None else np.asarray(pinned, bool)
        v = np.tile(np.zeros(D) if velocity is None else np.asarray(velocity, float), (n, 1))
        v[pin] = 0.0
        self._nodes.append(mesh.nodes + (np.zeros(D) if position is None else np.asarray(position, float)))
        self._vel.append(v)
        self._mass.append(np.asarray(masses, float))
        self._pinned.append(pin)
        self._edges.append(mesh.edges + self.n_nodes)
        self._cells.append(np.asarray(mesh.cells, np.int64).reshape(-1, D + 1) + self.n_nodes)
        arrays, a0 = element_arrays(material, mesh.nodes, mesh.edges)
        for k in ELEMENT_FIELDS:
            self._params[k].append(arrays[k])
        self._a0.append(a0)
        self._node_object.append(np.full(n, o))
        self._cell_object.append(np.full(len(mesh.cells), o))
        self.names.append(name)
        self.materials.append(material)
        first, self.n_nodes = self.n_nodes, self.n_nodes + n
        return first

    def build(self, name: str, gravity, dt: float, n_steps: int, every: int, floor: Floor | None = None,
              topology: TopologySpec | None = None, collision: CollisionSpec | None = None, loads=(),
              formats: dict | None = None, description: str = "", probe: Probe | None = None) -> System:
        """The System of the objects added. Friction regularisation left at NaN gets half the explicit limit
        of its slip damper: on the floor and the probe m_min / dt (the limit is 2 m / dt for one node), between objects
        m_min / (2 dt) (a vertex-facet pair moves both its sides)."""
        cat = np.concatenate
        D = self.dim
        x0, edges = cat(self._nodes), cat(self._edges)
        cells = cat(self._cells).reshape(-1, D + 1)
        mass = cat(self._mass)
        m_min = float(mass.min())
        if floor is not None and math.isnan(floor.k_f):
            floor.k_f = m_min / dt
        if probe is not None and math.isnan(probe.k_f):
            probe.k_f = m_min / dt          # like the floor's: the probe is one more static-law contact
        topo = None
        if topology is not None:
            topo = Topology(meshlib.topology_pairs(cells, x0), topology.K, topology.C, topology.eps)
        coll = None
        if collision is not None:
            k_f = m_min / (2.0 * dt) if math.isnan(collision.k_f) else collision.k_f
            coll = collision_of(cells, edges, x0, collision.K, collision.C, collision.threshold, collision.mu, k_f)
        elem = ElementParams.build(**{k: cat(v) for k, v in self._params.items()})
        return System(name, D, x0, cat(self._vel), mass, cat(self._pinned), edges, cat(self._a0), elem, cells,
                      cat(self._node_object), cat(self._cell_object).astype(np.int64), list(self.names),
                      np.asarray(gravity, float), dt, n_steps, every, floor, topo, coll, list(loads),
                      list(self.materials), dict(formats or {}), description=description, probe=probe)
