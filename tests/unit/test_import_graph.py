"""The backend's import graph: no circles, and a numerical core that knows nothing of the web.

Built with grimp from the source, so lazy imports inside functions count too: a circle
hidden in a function body is still a circle a reader has to untangle.
"""

from __future__ import annotations

import grimp
import pytest

WEB_OR_DB = ("fastapi", "starlette", "sqlalchemy", "alembic", "psycopg", "uvicorn", "pydantic_settings")
APP_PARTS = ("main", "deps", "db", "config", "security", "errors", "users", "runs", "edits", "tasks", "maps",
             "tiles", "jobs", "worker", "commands", "cli", "demo")
CORE = ("posefix.core", "posefix.mapmatch", "posefix.io")


@pytest.fixture(scope="module")
def graph() -> grimp.ImportGraph:
    return grimp.build_graph("posefix", include_external_packages=True, cache_dir=None)


def own_modules(graph: grimp.ImportGraph) -> list[str]:
    return sorted(m for m in graph.modules if m == "posefix" or m.startswith("posefix."))


def strongly_connected(nodes: list[str], edges: dict[str, set[str]]) -> list[list[str]]:
    """Tarjan's algorithm, iterative: the groups of nodes that reach one another."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    groups: list[list[str]] = []
    counter = 0
    for root in nodes:
        if root in index:
            continue
        work = [(root, iter(sorted(edges.get(root, ()))))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            v, it = work[-1]
            nxt = next(it, None)
            if nxt is not None:
                if nxt not in index:
                    index[nxt] = low[nxt] = counter
                    counter += 1
                    stack.append(nxt)
                    on_stack.add(nxt)
                    work.append((nxt, iter(sorted(edges.get(nxt, ())))))
                elif nxt in on_stack:
                    low[v] = min(low[v], index[nxt])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                group = []
                while True:
                    w = stack.pop()
                    on_stack.discard(w)
                    group.append(w)
                    if w == v:
                        break
                if len(group) > 1:
                    groups.append(sorted(group))
    return groups


def module_edges(graph: grimp.ImportGraph) -> dict[str, set[str]]:
    own = set(own_modules(graph))
    return {m: {w for w in graph.find_modules_directly_imported_by(m) if w in own} for m in own}


def test_tarjan_finds_a_planted_circle():
    edges = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert strongly_connected(["a", "b", "c", "d"], edges) == [["a", "b", "c"]]
    assert strongly_connected(["a", "b"], {"a": {"b"}}) == []


def test_no_module_imports_itself_back(graph):
    circles = strongly_connected(own_modules(graph), module_edges(graph))
    assert circles == [], f"import circles: {circles}"


def package_of(module: str) -> str:
    return ".".join(module.split(".")[:2])


def test_no_circles_between_packages(graph):
    """A domain package (runs, edits, tasks, ...) and another never import each other both ways."""
    packages: dict[str, set[str]] = {}
    for m, targets in module_edges(graph).items():
        src = package_of(m)
        packages.setdefault(src, set()).update(package_of(t) for t in targets if package_of(t) != src)
    # Top-level modules (posefix.main, posefix.deps, ...) are the app's edge, not packages.
    is_package = {p for p in packages if any(m.startswith(p + ".") for m in own_modules(graph))}
    edges = {p: {q for q in qs if q in is_package} for p, qs in packages.items() if p in is_package}
    circles = strongly_connected(sorted(edges), edges)
    assert circles == [], f"package circles: {circles}"


@pytest.mark.parametrize("core", CORE)
def test_the_numerical_core_imports_no_web_or_database_code(graph, core):
    offenders = []
    for m in own_modules(graph):
        if m != core and not m.startswith(core + "."):
            continue
        for w in graph.find_modules_directly_imported_by(m):
            top = w.split(".")[0]
            part = w.split(".")[1] if w.startswith("posefix.") and w.count(".") >= 1 else None
            if top in WEB_OR_DB or part in APP_PARTS:
                offenders.append((m, w))
    assert offenders == [], f"{core} reaches web or database code: {offenders}"


def test_architecture_page_matches_the_code():
    """docs/ARCHITECTURE.md's drawing and file index are what scripts/architecture.py makes
    from the code now (after moving or adding a module: python scripts/architecture.py --write)."""
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[2] / "scripts" / "architecture.py"
    spec = importlib.util.spec_from_file_location("architecture", path)
    arch = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(arch)
    text = arch.DOC.read_text()
    for name, body in arch.blocks().items():
        assert arch.current(text, name) == body, f"docs/ARCHITECTURE.md: the {name} block is stale; run python scripts/architecture.py --write"
