"""The CLI turns user errors into one-line messages and non-zero exits, never tracebacks."""

import subprocess
import sys

from gonio.cli.main import main


def test_models_lists_registry(capsys):
    assert main(["models"]) == 0
    assert "lambert" in capsys.readouterr().out


def test_unknown_model_is_one_line_error(capsys):
    assert main(["models", "--eval", "nosuch"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "nosuch" in err and "unknown model" in err


def test_bad_parameter_names_field_and_value(capsys):
    assert main(["models", "--eval", "lambert", "--param", "albedo=1.5"]) == 2
    err = capsys.readouterr().err
    assert "lambert.albedo" in err and "1.5" in err


def test_console_script_help_runs():
    out = subprocess.run([sys.executable, "-m", "gonio.cli.main", "--help"], capture_output=True, text=True)
    assert out.returncode == 0 and "usage: gonio" in out.stdout


def _subcommand_paths():
    """Every command and sub-action of the CLI (``["calibrate", "rig"]``, ...), from the parser itself."""
    import argparse

    from gonio.cli.main import build_parser

    def walk(parser, prefix):
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, sp in action.choices.items():
                    yield [*prefix, name]
                    yield from walk(sp, [*prefix, name])

    return list(walk(build_parser(), []))


def test_every_subcommand_help_is_plain_text(capsys):
    """``--help`` of every (sub)command exits 0 and shows no Sphinx markup (``x``, :func:) to a lab user."""
    import pytest

    paths = _subcommand_paths()
    assert ["calibrate", "check"] in paths and ["export"] in paths
    for path in paths:
        with pytest.raises(SystemExit) as exc:
            main([*path, "--help"])
        out = capsys.readouterr().out
        assert exc.value.code == 0 and "usage: gonio" in out, path
        for markup in ("``", ":func:", ":mod:", ":class:", ":data:"):
            assert markup not in out, (path, markup)
