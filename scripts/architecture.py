"""The generated parts of docs/ARCHITECTURE.md: the layer drawing and the file index.

    python scripts/architecture.py            # print both
    python scripts/architecture.py --write    # refresh them in docs/ARCHITECTURE.md

The drawing is posefix's package import graph (grimp reads every import, lazy ones included);
the index names every backend file with the first line of its docstring, package by package
in the order data flows. tests/unit/test_import_graph.py checks both against the code, so the
page cannot drift from it: after adding, moving or renaming a module, run ``--write``.
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

import grimp

ROOT = Path(__file__).resolve().parent.parent
PKG = ROOT / "backend" / "posefix"
DOC = ROOT / "docs" / "ARCHITECTURE.md"
# The order a run's data takes: read, solved, stored and served, edited, queued, reviewed.
FLOW = ["io", "core", "engine", "runs", "edits", "jobs", "worker", "tasks", "mapmatch", "maps", "basemap",
        "tiles", "users", "commands"]


def markers(name: str) -> tuple[str, str]:
    return (f"<!-- {name}:begin (generated: python scripts/architecture.py --write) -->", f"<!-- {name}:end -->")


def unit_of(module: str) -> str | None:
    """The drawing's node for a module: its package under posefix, or the top-level module."""
    parts = module.split(".")
    if parts[0] != "posefix" or len(parts) == 1:
        return None
    return parts[1]


def package_edges() -> dict[str, set[str]]:
    graph = grimp.build_graph("posefix", include_external_packages=False, cache_dir=None)
    edges: dict[str, set[str]] = {}
    for m in graph.modules:
        src = unit_of(m)
        if src is None:
            continue
        edges.setdefault(src, set())
        for w in graph.find_modules_directly_imported_by(m):
            dst = unit_of(w)
            if dst is not None and dst != src:
                edges[src].add(dst)
    return edges


def drawing() -> str:
    lines = ["```mermaid", "flowchart TD"]
    edges = package_edges()
    for src in sorted(edges):
        for dst in sorted(edges[src]):
            lines.append(f"  {src} --> {dst}")
    lines.append("```")
    return "\n".join(lines)


def summary(path: Path) -> str:
    doc = ast.get_docstring(ast.parse(path.read_text())) or ""
    first = " ".join(doc.strip().split("\n\n")[0].split())
    return first.replace("|", "\\|") or "(no docstring)"


def file_index() -> str:
    top = sorted(p for p in PKG.glob("*.py") if p.name != "__init__.py")
    packages = sorted(p.name for p in PKG.iterdir() if (p / "__init__.py").exists())
    order = [p for p in FLOW if p in packages] + [p for p in packages if p not in FLOW]
    out = ["| file | what it does |", "| --- | --- |"]
    for name in order:
        out.append(f"| **{name}/** | {summary(PKG / name / '__init__.py')} |")
        for f in sorted((PKG / name).rglob("*.py")):
            if f.name == "__init__.py" and f.parent == PKG / name:
                continue
            out.append(f"| `{f.relative_to(PKG / name).as_posix()}` | {summary(f)} |")
    out.append("| **top level** | the app's edge: wiring, settings, the database, errors |")
    for f in top:
        out.append(f"| `{f.name}` | {summary(f)} |")
    return "\n".join(out)


def blocks() -> dict[str, str]:
    return {"import-graph": drawing(), "file-index": file_index()}


def current(text: str, name: str) -> str | None:
    begin, end = markers(name)
    if begin not in text or end not in text:
        return None
    return text[text.index(begin) + len(begin): text.index(end)].strip("\n")


def main(argv: list[str]) -> int:
    new = blocks()
    if "--write" not in argv:
        for name, body in new.items():
            print(f"{name}:\n{body}\n")
        return 0
    text = DOC.read_text()
    for name, body in new.items():
        if current(text, name) is None:
            raise SystemExit(f"{DOC}: no {markers(name)[0]!r} marker to write between")
        begin, end = markers(name)
        head, tail = text[: text.index(begin) + len(begin)], text[text.index(end):]
        text = f"{head}\n{body}\n{tail}"
    DOC.write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
