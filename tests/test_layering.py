"""docs/architecture.md §1: gonio never imports sim (nor the benchmarks); they are found through gonio.plugins."""

from __future__ import annotations

import ast
import functools
from pathlib import Path

import pytest

import gonio
from gonio.errors import ConfigError
from gonio.plugins import plugin

FORBIDDEN = ("sim", "benchmarks", "tests")


@functools.lru_cache(maxsize=None)
def _nodes(path: Path) -> tuple:
    """The import statements of ``path``, at any depth (parsed once per run: the tests below read the same files)."""
    tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
    return tuple(n for n in ast.walk(tree) if isinstance(n, (ast.Import, ast.ImportFrom)))


def _imports(path: Path):
    for node in _nodes(path):
        if isinstance(node, ast.Import):
            yield from (a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            yield node.module


def test_gonio_never_imports_sim_or_benchmarks():
    root = Path(gonio.__file__).parent
    bad = [f"{p.relative_to(root.parent)}: {m}" for p in sorted(root.rglob("*.py")) for m in _imports(p)
           if m.split(".")[0] in FORBIDDEN]
    assert not bad, bad


def test_the_simulator_is_found_through_the_entry_points():
    assert plugin("sim.rig").SimRig.__module__ == "sim.rig"
    assert hasattr(plugin("benchmarks.report"), "write_report")
    assert plugin("sim.rig") is plugin("sim.rig")  # looked up once per process
    with pytest.raises(ConfigError, match="not installed"):
        plugin("sim.no_such_plugin")


# -- the package graph (issue 31 item 3): layers point one way -----------------------------------------------------
#: Imports between subpackages that point the wrong way and close a circle, known and not yet cut, each with what
#: cuts it. Without them the subpackage graph must have no circle; a listed one that is gone fails the test too
#: (remove it from the list then).
KNOWN_BACK_EDGES: dict[tuple[str, str], str] = {}  # empty since issue 31 cut io → session and rig → pipeline
#: Circles between two CLI modules, known and not yet cut (issue 31: every command a thin shell over the API).
KNOWN_CLI_CIRCLES: set = set()


def _module_name(root: Path, path: Path) -> str:
    parts = path.relative_to(root.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imported_modules(path: Path, module: str):
    """Every module an import statement of ``path`` names, at any depth (imports inside functions count: a lazy
    import is still a dependency), relative imports resolved; ``from gonio import x`` names ``gonio.x``."""
    package = module.split(".") if path.name == "__init__.py" else module.split(".")[:-1]
    for node in _nodes(path):
        if isinstance(node, ast.Import):
            yield from (a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(package[: len(package) - node.level + 1] + ([base] if base else []))
            yield base
            yield from (f"{base}.{a.name}" for a in node.names)


def _subpackage_graph() -> dict[str, set[str]]:
    """``{subpackage: subpackages its modules import}`` over gonio's subpackages (directories)."""
    root = Path(gonio.__file__).parent
    subs = {p.name for p in root.iterdir() if (p / "__init__.py").is_file()}
    graph: dict[str, set[str]] = {s: set() for s in subs}
    for path in root.rglob("*.py"):
        module = _module_name(root, path)
        parts = module.split(".")
        if len(parts) < 2 or parts[1] not in subs:
            continue
        for name in _imported_modules(path, module):
            target = name.split(".")
            if len(target) >= 2 and target[0] == "gonio" and target[1] in subs and target[1] != parts[1]:
                graph[parts[1]].add(target[1])
    return graph


def _circles(graph: dict[str, set[str]]) -> set[frozenset]:
    """The strongly connected components of more than one node (Tarjan 1972), as sets of names."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    out: set[frozenset] = set()

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.add(frozenset(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_the_circle_finder_finds_circles():
    assert _circles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == {frozenset("abc")}
    assert _circles({"a": {"b"}, "b": set()}) == set()


def test_no_import_circle_between_gonio_subpackages():
    """docs/architecture.md §1: e.g. fit results do not import io (the exports depend on the fit, not the
    reverse): FitResult.from_json/to_json are in gonio.fit, to_mitsuba/to_pbrt/to_gltf in gonio.io."""
    graph = _subpackage_graph()
    assert "io" not in graph["fit"], "gonio.fit imports gonio.io: the data formats depend on the fit, not the reverse"
    gone = [e for e in KNOWN_BACK_EDGES if e[1] not in graph.get(e[0], ())]
    assert not gone, f"known back edges that are gone (remove them from KNOWN_BACK_EDGES): {gone}"
    cut = {a: {b for b in targets if (a, b) not in KNOWN_BACK_EDGES} for a, targets in graph.items()}
    circles = _circles(cut)
    assert not circles, (f"import circles between gonio's subpackages: {[sorted(c) for c in circles]} "
                         f"({ {k: sorted(v) for k, v in cut.items() if k in set().union(*circles)} })")


def test_no_cli_module_imports_another_ones_private_helpers_and_no_circle_between_them():
    root = Path(gonio.__file__).parent / "cli"
    private, graph = [], {}
    for path in sorted(root.glob("*.py")):
        me = path.stem
        graph[me] = set()
        for node in _nodes(path):
            if not isinstance(node, ast.ImportFrom) or not node.module:
                continue
            if node.module.startswith("gonio.cli."):
                other, names = node.module.split(".")[2], [a.name for a in node.names]
            elif node.module == "gonio.cli":
                other, names = None, [a.name for a in node.names]
            else:
                continue
            for name in names:
                target = other or name
                if target != me:
                    graph[me].add(target)
                    if other and name.startswith("_"):
                        private.append(f"cli/{path.name}: {other}.{name}")
    assert not private, f"CLI modules importing another command's private helpers: {private}"
    circles = _circles(graph)
    assert not circles - KNOWN_CLI_CIRCLES, f"import circles between CLI modules: {circles - KNOWN_CLI_CIRCLES}"
    assert not KNOWN_CLI_CIRCLES - circles, f"known CLI circles that are gone (remove them): {KNOWN_CLI_CIRCLES - circles}"


def test_the_commands_are_thin_shells():
    """Issue 31: gonio measure's module parses, calls the session API, prints — no more than 300 lines — and
    calibrate no longer reaches into it (measure imports calibrate's printing, one way)."""
    cli = Path(gonio.__file__).parent / "cli"
    assert len((cli / "measure.py").read_text(encoding="utf-8").splitlines()) <= 300
    calibrate = {m for m in _imported_modules(cli / "calibrate.py", "gonio.cli.calibrate")}
    assert not any(m.startswith("gonio.cli.measure") for m in calibrate)
    assert any(m.startswith("gonio.cli.calibrate") for m in _imported_modules(cli / "measure.py", "gonio.cli.measure"))
