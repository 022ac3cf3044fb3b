"""The architecture's rules, enforced over the import graph (kind: property).

DESIGN.md ("The layout the architecture asks for") states the rules; this
file reads every module of the five packages with :mod:`ast` (no import
side effects, lazy imports inside functions included) and fails on:

* a package importing against the dependency direction (``isp`` imports
  nothing of the others; ``modules`` and ``calibration`` import ``isp``;
  ``restoration`` imports those three; ``export`` any of them);
* ``calibration.sfr`` importing the optics (or anything built on them);
* a library module importing a command-line module (``cli``);
* an import cycle between modules;
* a ``_private`` name imported from another module, or read off an imported
  module as an attribute; and a ``_private`` package (``modules.common``)
  imported from outside the package that owns it.

Each failure lists every offending import with its file and line, so the
message says what to move.
"""

from __future__ import annotations

import ast
import dataclasses
import sys
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

import pytest

pytestmark = pytest.mark.property

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("isp", "modules", "calibration", "restoration", "export")

#: which top-level packages each package may import (DESIGN.md's arrows)
ALLOWED = {
    "isp": set(),
    "modules": {"isp"},
    "calibration": {"isp"},
    "restoration": {"isp", "modules", "calibration"},
    "export": {"isp", "modules", "calibration", "restoration"},
}

#: what the SFR may not import: it measures edges and knows nothing of lenses
SFR_FORBIDDEN = ("calibration.optics", "calibration.simulate", "calibration.fit", "calibration.loop",
                 "calibration.cli", "calibration.demo")


@dataclass(frozen=True)
class Import:
    source: str       # importing module
    target: str       # imported module (the longest prefix that is a module of the tree)
    name: str | None  # a name imported from the target, or an attribute read off it
    line: int
    typing_only: bool = False   # inside ``if TYPE_CHECKING:``: never executed, no cycle at run time

    def where(self) -> str:
        return f"{self.source.replace('.', '/')}.py:{self.line}"


def _modules() -> dict[str, Path]:
    mods = {}
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            rel = path.relative_to(ROOT).with_suffix("")
            parts = list(rel.parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            mods[".".join(parts)] = path
    return mods


MODULES = _modules()


def _module_of(dotted: str) -> str | None:
    while dotted and dotted not in MODULES:
        dotted = dotted.rpartition(".")[0]
    return dotted or None


def _absolute(module: str, node: ast.ImportFrom) -> str:
    if not node.level:
        return node.module or ""
    base = module.split(".")
    if MODULES[module].name != "__init__.py":
        base = base[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def _imports(module: str) -> list[Import]:
    tree = ast.parse(MODULES[module].read_text(encoding="utf-8"))
    out: list[Import] = []
    aliases: dict[str, str] = {}   # local name -> module it is bound to
    typing_lines = {n.lineno for blk in ast.walk(tree)
                    if isinstance(blk, ast.If) and isinstance(blk.test, ast.Name) and blk.test.id == "TYPE_CHECKING"
                    for stmt in blk.body for n in ast.walk(stmt) if isinstance(n, (ast.Import, ast.ImportFrom))}
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                target = _module_of(a.name)
                if target:
                    out.append(Import(module, target, None, node.lineno))
                    if a.asname:
                        aliases[a.asname] = a.name if a.name in MODULES else target
        elif isinstance(node, ast.ImportFrom):
            base = _absolute(module, node)
            for a in node.names:
                full = f"{base}.{a.name}"
                if full in MODULES:
                    out.append(Import(module, full, None, node.lineno))
                    aliases[a.asname or a.name] = full
                else:
                    target = _module_of(base)
                    if target:
                        out.append(Import(module, target, a.name, node.lineno))
    for node in ast.walk(tree):
        if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name)
                and node.value.id in aliases and node.attr.startswith("_")
                and not node.attr.startswith("__")):
            out.append(Import(module, aliases[node.value.id], node.attr, node.lineno))
    out = [dataclasses.replace(i, typing_only=True) if i.line in typing_lines else i for i in out]
    return [i for i in out if i.target != module]


GRAPH = {m: _imports(m) for m in MODULES}


def _all() -> list[Import]:
    return [i for imps in GRAPH.values() for i in imps]


def _report(bad: list[Import], what: str) -> str:
    lines = sorted({f"  {i.where()}: {i.source} -> {i.target}" + (f".{i.name}" if i.name else "")
                    for i in bad})
    return f"{len(lines)} {what}:\n" + "\n".join(lines)


def _top(m: str) -> str:
    return m.split(".")[0]


def _is_cli(m: str) -> bool:
    return ".cli." in f".{m}." or m.endswith("__main__")


def test_the_graph_is_read():
    """The rules below are only as good as the graph: it holds every module
    and the imports known to exist."""
    assert len(MODULES) > 100
    targets = {i.target for i in GRAPH["isp.pipeline"]}
    assert "isp.registry" in targets or "isp.frame" in targets


def test_packages_import_in_the_design_direction():
    bad = [i for i in _all() if _top(i.target) != _top(i.source)
           and _top(i.target) not in ALLOWED[_top(i.source)]]
    assert not bad, _report(bad, "imports against the packages' direction (isp <- modules, calibration "
                                 "<- restoration <- export)")


def test_sfr_imports_no_optics():
    bad = [i for i in _all() if i.source.startswith("calibration.sfr")
           and i.target.startswith(SFR_FORBIDDEN)]
    assert not bad, _report(bad, "imports of lens code by calibration.sfr")


def test_no_library_module_imports_a_command_line_module():
    bad = [i for i in _all() if _is_cli(i.target) and not _is_cli(i.source)]
    assert not bad, _report(bad, "library modules importing a cli module")


def test_no_import_cycles():
    edges = defaultdict(set)
    for i in _all():
        if i.target != i.source and not i.typing_only:
            edges[i.source].add(i.target)
    sys.setrecursionlimit(max(10_000, sys.getrecursionlimit()))
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    cycles: list[list[str]] = []

    def visit(v: str) -> None:  # Tarjan's strongly connected components
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in edges.get(v, ()):
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

    for v in MODULES:
        if v not in index:
            visit(v)
    assert not cycles, f"{len(cycles)} import cycles:\n" + "\n".join("  " + " <-> ".join(c) for c in cycles)


def test_no_private_name_crosses_a_module_boundary():
    bad = [i for i in _all() if i.name and i.name.startswith("_") and not i.name.startswith("__")
           and i.target != i.source]
    assert not bad, _report(bad, "private names used outside their module (make them public, or move the code)")


def test_private_packages_stay_inside_their_parent():
    def owner(m: str) -> str | None:
        parts = m.split(".")
        for k, p in enumerate(parts):
            if p.startswith("_") and not p.startswith("__"):
                return ".".join(parts[:k])
        return None

    bad = [i for i in _all() if owner(i.target) and not i.source.startswith(owner(i.target) + ".")
           and i.source != owner(i.target)]
    assert not bad, _report(bad, "imports of a private package from outside its parent")


def test_benchmarks_use_only_public_names():
    """The benchmark scripts are the library's users: what they need from it
    is public API, not its internals."""
    bad = []
    for path in sorted((ROOT / "benchmarks").glob("*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and node.module and not node.level:
                for a in node.names:
                    if (a.name.startswith("_") and not a.name.startswith("__")
                            and node.module != "benchmarks" and _module_of(node.module)):
                        bad.append(f"  benchmarks/{path.name}:{node.lineno}: {node.module}.{a.name}")
    assert not bad, f"{len(bad)} private names imported by benchmarks:\n" + "\n".join(bad)


@pytest.mark.parametrize("package", [m for m, p in MODULES.items() if p.name == "__init__.py"])
def test_every_package_says_what_it_holds_and_may_import(package):
    doc = ast.get_docstring(ast.parse(MODULES[package].read_text(encoding="utf-8")))
    assert doc and len(doc) > 40, f"{package}/__init__.py: docstring missing or too short"
    assert "import" in doc.lower(), f"{package}/__init__.py: docstring does not say what it may import"
