"""`rheo scenes`: the built-in scenes, one line each."""
from __future__ import annotations

NAME, HELP = "scenes", "list the built-in scenes"


def add_arguments(parser) -> None:
    pass


def run(args) -> int:
    from golden.scene import builtin_names, read_scene
    for name in builtin_names():
        print(f"{name:26s} {read_scene(name).description}")
    return 0
