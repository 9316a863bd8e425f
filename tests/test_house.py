"""How the code is joined: imports run one way (golden <- hw <- sim) with no cycle, the kernels name only
quantities that have number formats, and the interfaces are the abstract ones."""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("golden", "hw", "sim")
LAYER = {"golden": 0, "hw": 1, "sim": 2}


def _modules() -> dict[str, Path]:
    out = {}
    for pkg in PACKAGES:
        for path in (ROOT / pkg).rglob("*.py"):
            parts = path.relative_to(ROOT).with_suffix("").parts
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join(parts)] = path
    return out


def _imports(name: str, path: Path, known: set[str]) -> set[str]:
    """Project modules that `name` imports anywhere in its source (module level or inside functions)."""
    tree = ast.parse(path.read_text())
    is_pkg = path.name == "__init__.py"
    base = name.split(".") if is_pkg else name.split(".")[:-1]
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            mod = node.module or ""
            if node.level:
                mod = ".".join(base[:len(base) - node.level + 1] + ([mod] if mod else []))
            targets = [mod] + [f"{mod}.{a.name}" for a in node.names]
        else:
            continue
        for t in targets:
            while t and t not in known:
                t = t.rpartition(".")[0]
            if t and t != name:
                found.add(t)
    return found


def _graph():
    mods = _modules()
    known = set(mods)
    return {name: _imports(name, path, known) for name, path in mods.items()}


def test_imports_run_one_way():
    """golden imports nothing from hw or sim; hw nothing from sim."""
    bad = [f"{m} imports {t}" for m, ts in _graph().items() for t in ts
           if LAYER[t.split(".")[0]] > LAYER[m.split(".")[0]]]
    assert not bad, bad


def test_no_import_cycle():
    graph = _graph()
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(m):
        state[m] = 1
        stack.append(m)
        for t in sorted(graph[m]):
            if t in graph[m] and state.get(t) == 1:
                cycle = stack[stack.index(t):] + [t]
                pytest.fail("import cycle: " + " -> ".join(cycle))
            if t not in state:
                visit(t)
        stack.pop()
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m)


def test_the_walk_sees_imports():
    """The checks above would catch a cycle: the walk finds the known edges, relative and absolute."""
    graph = _graph()
    assert "golden.system" in graph["golden.model"]          # from .system import ...
    assert "golden.model" in graph["hw.bittrue"]             # from golden.model import ...
    assert "hw.formats" in graph["hw.datapath"]


def test_kernels_name_only_quantities_that_exist():
    """Every Q.name the hardware modules write is a quantity or constant of hw/formats.py."""
    from hw.formats import Q
    missing = []
    for path in (ROOT / "hw").glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id == "Q":
                if node.attr not in Q.__members__:
                    missing.append(f"{path.name}:{node.lineno} Q.{node.attr}")
    assert not missing, missing


def test_interfaces_are_abstract_and_implemented():
    from golden.model import Golden, Stepper
    from hw.arith import Arith, ArrayGate, FixedArith, FloatArith, Gate
    from hw.bittrue import BitTrue, FloatDatapath
    from hw.pipeline import PipeArith, RtlGate
    from sim.cpu import Cpu
    from sim.hwsim import HardwareStepper
    for cls in (Stepper, Arith, Gate):
        with pytest.raises(TypeError):
            cls()
    for cls in (FloatArith, FixedArith, PipeArith):
        assert issubclass(cls, Arith) and not cls.__abstractmethods__, cls
    for cls in (ArrayGate, RtlGate):
        assert issubclass(cls, Gate) and not cls.__abstractmethods__, cls
    for cls in (Golden, Cpu, BitTrue, FloatDatapath, HardwareStepper):
        assert issubclass(cls, Stepper) and not cls.__abstractmethods__, cls


def test_cli_presets_are_the_format_presets():
    from hw.formats import FORMAT_PRESETS
    from sim.cli.common import FORMAT_PRESETS as CLI_PRESETS
    assert tuple(FORMAT_PRESETS) == CLI_PRESETS
