"""Issue 31.5: the default install (``pip install -e .``) gets the compiled BRDF path, and ``gonio --version`` says
which evaluation path runs."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from gonio.brdf import compiled

ROOT = Path(__file__).resolve().parents[1]


def test_numba_is_a_core_dependency_not_only_an_extra():
    try:
        import tomllib
    except ModuleNotFoundError:  # Python 3.10
        import tomli as tomllib
    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    assert any(d.replace(" ", "").startswith("numba>=") for d in project["dependencies"])


def _version(**env) -> str:
    out = subprocess.run([sys.executable, "-m", "gonio.cli.main", "--version"], capture_output=True, text=True,
                         env={**os.environ, "PYTHONPATH": str(ROOT), **env}, timeout=120, check=True).stdout
    assert out.count("\n") == 1
    return out


def test_version_names_the_evaluation_path_that_runs():
    assert compiled.available()  # installed with gonio (test above): the default is the compiled path
    from importlib.metadata import version

    out = _version()
    assert out.startswith("gonio ") and f"BRDF evaluation: compiled (numba {version('numba')})" in out
    assert "BRDF evaluation: NumPy (GONIO_BRDF_BACKEND=numpy)" in _version(GONIO_BRDF_BACKEND="numpy")


def test_without_numba_the_version_says_numpy_and_how_to_get_the_compiled_path(monkeypatch):
    compiled.available.cache_clear()
    monkeypatch.setattr(compiled.importlib.util, "find_spec", lambda name: None)
    try:
        assert compiled.describe_path().startswith("NumPy (numba is not installed")
    finally:
        compiled.available.cache_clear()


def test_a_first_version_option_is_answered_as_the_parser_answers_it(capsys):
    """`gonio --version` is answered before the parser is built (which imports every command's module): the same line
    and the same exit as the parser's own --version action, whatever follows it."""
    from gonio.cli.main import _parser, main

    got = []
    for call in (lambda: main(["--version"]), lambda: main(["--version", "measure", "--bogus"]),
                 lambda: _parser().parse_known_args(["--version"])):
        with pytest.raises(SystemExit) as exit_:
            call()
        got.append((exit_.value.code, capsys.readouterr()))
    assert got[0] == got[1] == got[2] and got[0][0] == 0 and got[0][1].out.startswith("gonio ")
