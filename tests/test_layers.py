"""The packages import one way, bottom up (the order of the README's Tour):

maps < core < (dynamics | traffic | replay | sensors | comms, which never import each other)
< scenario | env < benchmark | viz | diagnostic < train. agents/ and zoo/ import nothing from the
simulator or train/ (policies read plain observation arrays and return action arrays; the
simulator reaches them through policy resolvers, ``smarts.core.policies``).

Every import is read, function-level ones included (a lazy import is still a dependency); only
imports under ``if TYPE_CHECKING:`` are skipped. A failure lists each upward or sideways import and
each import cycle between files."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TOPS = ("smarts", "agents", "zoo", "train")

LAYERS: dict[str, int] = {
    "smarts.maps": 1,
    "smarts.core": 2,
    "smarts.dynamics": 3,
    "smarts.traffic": 3,
    "smarts.replay": 3,
    "smarts.sensors": 3,
    "smarts.comms": 3,
    "smarts.scenario": 4,
    "smarts.env": 4,
    "smarts.benchmark": 5,
    "smarts.viz": 5,
    "smarts.diagnostic": 5,
    "train": 6,
}
SIBLINGS = ("smarts.dynamics", "smarts.traffic", "smarts.replay", "smarts.sensors", "smarts.comms")
"""Packages of one layer that must not import each other (the scenario and env layer may)."""
CONTRACT: tuple[str, ...] = ()
"""What agents/ and zoo/ may import from the simulator: nothing today."""


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def package_of(module: str) -> str | None:
    best = None
    for prefix in LAYERS:
        if module == prefix or module.startswith(prefix + "."):
            best = prefix if best is None or len(prefix) > len(best) else best
    return best


def import_graph() -> dict[str, set[str]]:
    files = {module_name(p): p for top in TOPS for p in (ROOT / top).rglob("*.py")}
    edges: dict[str, set[str]] = {m: set() for m in files}
    for module, path in files.items():
        package = module if path.name == "__init__.py" else module.rpartition(".")[0]
        tree = ast.parse(path.read_text(), str(path))
        type_only = {
            id(node)
            for block in ast.walk(tree)
            if isinstance(block, ast.If) and "TYPE_CHECKING" in ast.unparse(block.test)
            for statement in block.body
            for node in ast.walk(statement)
        }
        for node in ast.walk(tree):
            if id(node) in type_only:
                continue
            if isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    parts = package.split(".")
                    base = ".".join(parts[: len(parts) - node.level + 1] + ([base] if base else []))
                names = [base] + [f"{base}.{alias.name}" for alias in node.names]
            else:
                continue
            for name in names:
                while name and name not in files:
                    name = name.rpartition(".")[0]
                if name and name != module:
                    edges[module].add(name)
    return edges


def wrong_way_imports(edges: dict[str, set[str]]) -> list[str]:
    found = []
    for source, targets in edges.items():
        top = source.split(".")[0]
        for target in targets:
            if top in ("agents", "zoo"):
                allowed = target.split(".")[0] in ("agents", "zoo") or (bool(CONTRACT) and target.startswith(CONTRACT))
                if not allowed:
                    found.append(f"{source} -> {target} (agents and zoo import nothing from the simulator or train)")
                continue
            a, b = package_of(source), package_of(target)
            if a is None or b is None:
                if target.split(".")[0] in ("agents", "zoo") and top == "smarts":
                    found.append(f"{source} -> {target} (the simulator receives policies, it does not import them)")
                continue
            if LAYERS[b] > LAYERS[a]:
                found.append(f"{source} -> {target} (upward: {a} sits below {b})")
            elif a != b and a in SIBLINGS and b in SIBLINGS:
                found.append(f"{source} -> {target} (sideways: {a} and {b} are siblings)")
    return sorted(found)


def import_cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one file (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    cycles = []
    for root in sorted(edges):
        if root in index:
            continue
        work = [(root, iter(sorted(edges[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(edges[child]))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                if len(component) > 1:
                    cycles.append(sorted(component))
    return cycles


def test_every_import_goes_down_the_layers():
    wrong = wrong_way_imports(import_graph())
    assert not wrong, "imports against the layer order:\n" + "\n".join(wrong)


def test_no_import_cycles():
    cycles = import_cycles(import_graph())
    assert not cycles, "import cycles:\n" + "\n".join(" / ".join(c) for c in cycles)


def test_the_checker_sees_function_level_imports_and_cycles(tmp_path):
    edges = {"smarts.maps.a": {"smarts.env.x"}, "smarts.env.x": {"smarts.maps.a"}, "agents.p": {"train.ppo"}}
    edges.update({"train.ppo": set()})
    assert import_cycles(edges) == [["smarts.env.x", "smarts.maps.a"]]
    wrong = wrong_way_imports(edges)
    assert any(w.startswith("smarts.maps.a -> smarts.env.x (upward") for w in wrong)
    assert any(w.startswith("agents.p -> train.ppo") for w in wrong)
    # A lazy import inside a function is found by the real walk too.
    graph = import_graph()
    assert "smarts.benchmark.suites" in graph["smarts.benchmark.runner"]
