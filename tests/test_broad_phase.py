"""The collision broad phase: misses no contact, and its work grows about linearly with the surface."""
from __future__ import annotations

import numpy as np
import pytest

from golden.scene import load_scene


def _row_of_blocks(tmp_path, n, jitter=0.0, seed=0):
    rng = np.random.default_rng(seed)
    objs = []
    for b in range(n):
        x, y = 0.012 * b + rng.uniform(-jitter, jitter), rng.uniform(-jitter, jitter)
        objs.append(f"""
[[objects]]
name = "b{b}"
mesh = {{ type = "rectangle", size = [0.01, 0.01], divisions = [2, 2] }}
material = {{ preset = "viscoelastic", node_mass = 1e-3 }}
position = [{x}, {y}]
""")
    p = tmp_path / f"row{n}_{seed}.toml"
    p.write_text("""
dim = 2
[integrator]
dt = 1e-4
duration = 0.01
[collision]
K = 1e3
threshold = 0.002
""" + "".join(objs))
    return load_scene(p)


def _brute_force_contacts(col, x):
    """Every (vertex, facet) pair within the threshold with the foot on the facet, by testing all pairs."""
    found = set()
    for v in col.vertices:
        for f, (a, b) in enumerate(col.facets):
            if v in (a, b):
                continue
            u = x[b] - x[a]
            t = np.dot(x[v] - x[a], u) / np.dot(u, u)
            n = np.array([u[1], -u[0]]) / np.linalg.norm(u)
            if 0 <= t <= 1 and abs(np.dot(x[v] - x[a], n)) <= col.threshold:
                found.add((int(v), f))
    return found


@pytest.mark.parametrize("seed", range(5))
def test_broad_phase_misses_no_contact(tmp_path, seed):
    system = _row_of_blocks(tmp_path, 6, jitter=0.004, seed=seed)
    col = system.collision
    rng = np.random.default_rng(seed)
    x = system.x0 + rng.normal(0, 5e-4, system.x0.shape)
    vi, fi = col.candidates(x)
    cand = set(zip(col.vertices[vi].tolist(), fi.tolist()))
    contacts = _brute_force_contacts(col, x)
    assert contacts, "the configuration should have contacts"
    assert contacts <= cand, contacts - cand


def test_broad_phase_work_grows_linearly(tmp_path):
    per_facet = []
    for n in (8, 32, 128):
        system = _row_of_blocks(tmp_path, n)
        col = system.collision
        vi, _ = col.candidates(system.x0)
        per_facet.append(len(vi) / len(col.facets))
    all_pairs_ratio = len(_row_of_blocks(tmp_path, 128).collision.vertices)   # candidates per facet if quadratic
    assert max(per_facet) < 2 * min(per_facet), per_facet
    assert per_facet[-1] < 0.1 * all_pairs_ratio, (per_facet, all_pairs_ratio)
