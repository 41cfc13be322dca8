"""The host package's layers: imports run one way, and no module imports itself in a circle.

A module may import its own layer and the layers below it (earlier in LAYERS), never one
above. Every import counts: at module level, inside functions and under TYPE_CHECKING.
"""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "host" / "imulink"

#: Bottom to top. The package root holds the version, the error root and the progress bars;
#: the protocol (the schema, the one source of formats, and the codec) comes before the core,
#: whose Q formats it defines.
LAYERS = ("", "protocol", "core", "io", "sim", "board", "analysis", "hil", "monitor", "cli")
RANK = {name: rank for rank, name in enumerate(LAYERS)}


def module_names(root: Path = PACKAGE) -> dict[str, Path]:
    names = {}
    for path in root.rglob("*.py"):
        parts = path.relative_to(root.parent).with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
        names[".".join(parts)] = path
    return names


def layer_of(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 2 or (len(parts) == 2 and parts[1] in RANK) else ""


def imports_of(module: str, path: Path, known: set[str]) -> set[str]:
    """The package's modules that `module` imports (`from PACKAGE import NAME` counts as the
    submodule NAME where there is one, else as PACKAGE)."""
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[:len(package.split(".")) - node.level + 1]
                source = ".".join(base + ([node.module] if node.module else []))
            else:
                source = node.module or ""
            found |= {f"{source}.{alias.name}" if f"{source}.{alias.name}" in known else source
                      for alias in node.names}
    return {name for name in found if name in known and name != module}


def import_graph(root: Path = PACKAGE) -> dict[str, set[str]]:
    names = module_names(root)
    return {module: imports_of(module, path, set(names)) for module, path in names.items()}


def against_layers(graph: dict[str, set[str]]) -> list[str]:
    return sorted(f"{module} ({layer_of(module) or 'root'}) imports {target} ({layer_of(target) or 'root'})"
                  for module, targets in graph.items() for target in targets
                  if RANK[layer_of(target)] > RANK[layer_of(module)])


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Every strongly connected group of more than one module (Tarjan)."""
    index, low, stack, on_stack, groups = {}, {}, [], set(), []

    def visit(node):
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for target in sorted(graph[node]):
            if target not in index:
                visit(target)
                low[node] = min(low[node], low[target])
            elif target in on_stack:
                low[node] = min(low[node], index[target])
        if low[node] == index[node]:
            group = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                group.append(member)
                if member == node:
                    break
            if len(group) > 1:
                groups.append(sorted(group))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return groups


def test_every_module_belongs_to_a_layer():
    for module in module_names():
        assert layer_of(module) in RANK, module


def test_imports_run_down_the_layers():
    assert against_layers(import_graph()) == []


def test_no_import_cycles():
    assert cycles(import_graph()) == []


@pytest.mark.parametrize("files, finding", [
    ({"core/__init__.py": "from imulink.hil import record\n", "hil/__init__.py": "def record(): pass\n"},
     "layers"),
    ({"protocol/__init__.py": "from imulink import core\n", "core/__init__.py": ""}, "layers"),
    ({"io/a.py": "from imulink.io import b\n", "io/b.py": "from imulink.io.a import x\n", "io/__init__.py": ""},
     "cycle"),
    ({"io/a.py": "from . import b\n", "io/b.py": "from .a import x\n", "io/__init__.py": ""}, "cycle"),
])
def test_the_checks_find_what_they_look_for(tmp_path, files, finding):
    root = tmp_path / "imulink"
    for name, text in {"__init__.py": "", **files}.items():
        (root / name).parent.mkdir(parents=True, exist_ok=True)
        (root / name).write_text(text)
    graph = import_graph(root)
    assert (against_layers(graph) != []) == (finding == "layers")
    assert (cycles(graph) != []) == (finding == "cycle")
