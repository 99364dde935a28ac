"""The package's modules follow the data flow: no module imports one further down the flow
(scene -> mapping -> planning -> control -> sim -> record / eval -> api -> cli), and there is
no import cycle between modules, counting the imports made inside functions too."""

from __future__ import annotations

import ast
from pathlib import Path

import sanav_mj

ROOT = Path(sanav_mj.__file__).parent

#: the tier of each top-level module or sub-package (imports may only go to the same or a lower tier)
TIERS = {
    "resources": 0, "native": 0, "outputs": 0,
    "scene": 1,
    "footprint": 2,
    "mapping": 3,
    "planning": 4, "generate": 4,
    "control": 5,
    "sim": 6, "envs": 6,
    "record": 7,
    "eval": 8,
    "api": 9,
    "cli": 10, "__main__": 10, "": 10,  # "" the package's own __init__
}


def _module_name(path: Path) -> str:
    rel = path.relative_to(ROOT.parent).with_suffix("")
    parts = rel.parts[:-1] if rel.name == "__init__" else rel.parts
    return ".".join(parts)


def _imports(path: Path) -> set[str]:
    """Every sanav_mj module ``path`` imports, at module level or inside functions."""
    out: set[str] = set()
    tree = ast.parse(path.read_text(), str(path))
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module and node.module.split(".")[0] == "sanav_mj":
            for alias in node.names:  # ``from sanav_mj.eval import episode`` names a module
                sub = f"{node.module}.{alias.name}"
                out.add(sub if _exists(sub) else node.module)
        elif isinstance(node, ast.Import):
            out.update(a.name for a in node.names if a.name.split(".")[0] == "sanav_mj")
    return out


def _exists(module: str) -> bool:
    p = ROOT.parent.joinpath(*module.split("."))
    return p.with_suffix(".py").is_file() or (p / "__init__.py").is_file()


def _graph() -> dict[str, set[str]]:
    return {_module_name(p): _imports(p) for p in ROOT.rglob("*.py")}


def _tier(module: str) -> int:
    parts = module.split(".")
    return TIERS[parts[1] if len(parts) > 1 else ""]


def test_every_module_has_a_tier():
    unknown = sorted({m.split(".")[1] for m in _graph() if "." in m} - set(TIERS))
    assert not unknown, f"modules without a tier in TIERS: {unknown}"


def test_no_module_imports_one_further_down_the_data_flow():
    back = sorted((a, b) for a, targets in _graph().items() for b in targets
                  if a.split(".")[:2] != b.split(".")[:2] and _tier(b) > _tier(a))
    assert not back, f"imports against the data flow: {back}"


def test_the_run_modules_of_eval_follow_the_run():
    # prepare (before the loop) -> outcome (what a run returns) -> lidar (the lidar run) -> episode
    order = ["sanav_mj.eval.prepare", "sanav_mj.eval.outcome", "sanav_mj.eval.lidar", "sanav_mj.eval.episode"]
    g = _graph()
    for i, a in enumerate(order):
        later = set(order[i + 1:]) & g[a]
        assert not later, f"{a} imports {sorted(later)}, which come after it in the run"


def test_no_import_cycle():
    g = _graph()
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    cycles: list[list[str]] = []
    counter = [0]

    def visit(v: str) -> None:  # Tarjan's strongly connected components
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in g.get(v, ()):
            if w not in g:
                continue
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                cycles.append(sorted(comp))

    for v in sorted(g):
        if v not in index:
            visit(v)
    # a package's __init__ importing its own modules is not a cycle of the flow
    real = [c for c in cycles if not all(m == c[0] or m.startswith(c[0] + ".") for m in c)]
    assert not real, f"import cycles: {real}"
