"""Shared, cached test fixtures: scene systems and their derived number formats (range analysis is
the slow part of building a bit-true model, and several test files need the same ones)."""
from __future__ import annotations

import functools

from golden.scene import load_scene


@functools.lru_cache(maxsize=None)
def scene_system(name: str):
    return load_scene(name)


@functools.lru_cache(maxsize=None)
def formats(name: str, preset: str):
    """The formats `rheo simulate --backend fixed` derives for a built-in scene (full range analysis)."""
    from hw.bittrue import BitTrue
    return BitTrue(scene_system(name), preset).formats


def bittrue(name: str, preset: str):
    """A fresh bit-true model of a built-in scene with the cached formats."""
    from hw.bittrue import BitTrue
    return BitTrue(scene_system(name), preset, formats=formats(name, preset))
