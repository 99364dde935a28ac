"""Structure of the control package: no import cycle, no module over 800 lines, no class over 400."""

from __future__ import annotations

import ast
import importlib
import pkgutil
from pathlib import Path

import sanav_mj.control as control

PACKAGE = Path(control.__file__).parent
MAX_MODULE_LINES = 800
MAX_CLASS_LINES = 400


def _modules() -> dict[str, Path]:
    return {f"sanav_mj.control.{m.name}": PACKAGE / f"{m.name}.py" for m in pkgutil.iter_modules([str(PACKAGE)])}


def _imports(path: Path, package_modules: set[str]) -> set[str]:
    """Modules of the package that ``path`` imports (at any depth: lazy imports count too)."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module:
            if node.module in package_modules:
                out.add(node.module)
            for alias in node.names:  # from sanav_mj.control import sa_mpc
                if f"{node.module}.{alias.name}" in package_modules:
                    out.add(f"{node.module}.{alias.name}")
        elif isinstance(node, ast.Import):
            out.update(a.name for a in node.names if a.name in package_modules)
    return out


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One cycle of ``graph`` as a list of nodes (first == last), or None."""
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(n: str) -> list[str] | None:
        state[n] = 1
        stack.append(n)
        for m in sorted(graph.get(n, ())):
            if state.get(m) == 1:
                return stack[stack.index(m):] + [m]
            if m not in state:
                found = visit(m)
                if found:
                    return found
        stack.pop()
        state[n] = 2
        return None

    for n in sorted(graph):
        if n not in state:
            found = visit(n)
            if found:
                return found
    return None


def test_find_cycle_finds_a_cycle_and_accepts_a_tree():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b", "c"}, "b": {"c"}, "c": set()}) is None


def test_every_control_module_imports_and_the_import_graph_has_no_cycle():
    mods = _modules()
    assert "sanav_mj.control.problem" in mods and "sanav_mj.control.backends" in mods
    for name in mods:
        importlib.import_module(name)
    graph = {name: _imports(path, set(mods)) - {name} for name, path in mods.items()}
    # the package __init__ re-exports lazily; it is not part of a module's dependencies
    assert find_cycle(graph) is None, f"import cycle: {' -> '.join(find_cycle(graph))}"


def test_the_whole_package_has_no_import_cycle():
    import sanav_mj

    root = Path(sanav_mj.__file__).parent
    mods = {}
    for path in root.rglob("*.py"):
        parts = path.relative_to(root.parent).with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        mods[name] = path
    graph = {name: _imports(path, set(mods)) - {name} for name, path in mods.items()}
    cycle = find_cycle(graph)
    assert cycle is None, f"import cycle: {' -> '.join(cycle)}"


def test_no_module_over_800_lines_and_no_class_over_400():
    too_long = []
    for name, path in _modules().items():
        text = path.read_text()
        n = len(text.splitlines())
        if n > MAX_MODULE_LINES:
            too_long.append(f"{name}: {n} lines")
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, ast.ClassDef):
                size = node.end_lineno - node.lineno + 1
                if size > MAX_CLASS_LINES:
                    too_long.append(f"{name}.{node.name}: {size} lines")
    assert not too_long, "; ".join(too_long)
