"""docs/architecture.md §1: gonio never imports sim (nor the benchmarks); they are found through gonio.plugins."""

from __future__ import annotations

import ast
from pathlib import Path

import gonio
from gonio.plugins import plugin

FORBIDDEN = ("sim", "benchmarks", "tests")


def _imports(path: Path):
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
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
