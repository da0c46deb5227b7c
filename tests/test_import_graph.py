"""No import cycle in rtsim/: the graph of imports between rtsim's modules is acyclic, and every module
imports alone, in an interpreter where no other rtsim module was imported before it. Imports inside
functions count too: a cycle hidden behind a lazy import is still a cycle of the design."""
from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = "rtsim"


def _modules() -> dict[str, Path]:
    out = {}
    for path in sorted((ROOT / PACKAGE).rglob("*.py")):
        parts = path.relative_to(ROOT).with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        out[name] = path
    return out


def _imports(path: Path, name: str, is_package: bool, modules) -> set[str]:
    """Modules named by the module's import statements, at any depth."""
    tree = ast.parse(path.read_text(), str(path))
    here = name if is_package else name.rpartition(".")[0]
    found: set[str] = set()

    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                pkg = here.split(".")[: len(here.split(".")) - node.level + 1]
                base = ".".join(pkg + ([base] if base else []))
            # a name that is a submodule is an edge to that module; any other name is read from the
            # module `base` itself (for a parent package: from its __init__, a real edge)
            found.update(f"{base}.{a.name}" for a in node.names)
            if not all(f"{base}.{a.name}" in modules for a in node.names):
                found.add(base)
    return found


def _graph() -> dict[str, set[str]]:
    mods = _modules()
    graph = {}
    for name, path in mods.items():
        targets = _imports(path, name, path.name == "__init__.py", mods)
        graph[name] = {t for t in targets if t in mods and t != name}
    return graph


def _find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    state: dict[str, int] = {}
    stack: list[str] = []

    def dfs(n):
        state[n] = 1
        stack.append(n)
        for m in sorted(graph[n]):
            if state.get(m) == 1:
                return stack[stack.index(m):] + [m]
            if m not in state:
                found = dfs(m)
                if found:
                    return found
        stack.pop()
        state[n] = 2
        return None

    for n in sorted(graph):
        if n not in state:
            found = dfs(n)
            if found:
                return found
    return None


def test_the_cycle_finder_finds_a_cycle():
    assert _find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert _find_cycle({"a": {"b"}, "b": set()}) is None


def test_rtsim_import_graph_is_acyclic():
    graph = _graph()
    assert len(graph) > 50 and "rtsim.vehicle.car.build" in graph
    assert "rtsim.vehicle.car.layout" in graph["rtsim.vehicle.car.build"]     # edges are seen
    cycle = _find_cycle(graph)
    assert cycle is None, "import cycle: " + " -> ".join(cycle)


def test_every_module_imports_alone():
    names = sorted(_modules())
    code = f"""
import importlib, sys
failed = []
for name in {names!r}:
    for m in [m for m in sys.modules if m == {PACKAGE!r} or m.startswith({PACKAGE + '.'!r})]:
        del sys.modules[m]
    try:
        importlib.import_module(name)
    except Exception as exc:
        failed.append(f"{{name}}: {{type(exc).__name__}}: {{exc}}")
print("\\n".join(failed))
"""
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "", out.stdout
