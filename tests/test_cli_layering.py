"""Issue 31: the commands are thin shells over the API — no command module imports another command module's
private helpers, and the command modules' imports form no circle (gonio/cli/measure.py and calibrate.py imported
each other's internals before the session API)."""

from __future__ import annotations

import ast
from pathlib import Path

import gonio

CLI = Path(gonio.__file__).parent / "cli"


def _cli_imports(path: Path):
    """``(module, name)`` of every ``from gonio.cli.X import name`` / ``import gonio.cli.X`` in ``path``."""
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and (node.module or "").startswith("gonio.cli"):
            for a in node.names:
                if node.module == "gonio.cli":  # from gonio.cli import many
                    yield f"gonio.cli.{a.name}", None
                else:
                    yield node.module, a.name
        elif isinstance(node, ast.Import):
            for a in node.names:
                if a.name.startswith("gonio.cli."):
                    yield a.name, None


def _graph() -> dict[str, set[str]]:
    return {f"gonio.cli.{p.stem}": {m for m, _ in _cli_imports(p)} - {f"gonio.cli.{p.stem}"}
            for p in sorted(CLI.glob("*.py")) if p.stem != "__init__"}


def test_no_command_imports_another_commands_private_helpers():
    bad = [f"{p.name}: {m}.{n}" for p in sorted(CLI.glob("*.py")) for m, n in _cli_imports(p)
           if n is not None and n.startswith("_") and m != f"gonio.cli.{p.stem}"]
    assert not bad, bad


def test_no_import_circle_between_command_modules():
    graph = _graph()
    cycles = []

    def visit(node, path):
        for nxt in sorted(graph.get(node, ())):
            if nxt in path:
                cycles.append(" -> ".join(path[path.index(nxt):] + [nxt]))
            elif nxt in graph:
                visit(nxt, path + [nxt])

    for start in graph:
        visit(start, [start])
    assert not cycles, sorted(set(cycles))


def test_the_graph_sees_the_imports_it_checks():
    """The check reads what it should: measure imports plan's option parsing (a function-level import) and the
    calibration's printing; calibrate no longer imports measure."""
    graph = _graph()
    assert {"gonio.cli.plan", "gonio.cli.calibrate"} <= graph["gonio.cli.measure"]
    assert "gonio.cli.measure" not in graph["gonio.cli.calibrate"]


def test_measure_is_a_thin_shell():
    assert len((CLI / "measure.py").read_text(encoding="utf-8").splitlines()) <= 300
