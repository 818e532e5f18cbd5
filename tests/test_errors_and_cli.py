"""The CLI turns user errors into one-line messages and non-zero exits, never tracebacks."""

import subprocess
import sys

import pytest

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


@pytest.mark.parametrize("argv, where, hint", [
    (["fit", "demo", "--modle", "lambert"], "gonio fit: error:", "--modle: did you mean --model?"),
    (["export", "demo", "--format", "csv", "-o", "x.csv", "--froce"], "gonio export: error:", "did you mean --force?"),
    (["servo", "scan", "--port", "/dev/null", "--bauds", "1"], "gonio servo scan: error:", "did you mean --baud"),
    (["measure", "--sim", "extra"], "gonio measure: error: unrecognized arguments: extra", ""),
])
def test_an_unknown_option_names_its_command_and_the_option_it_resembles(capsys, argv, where, hint):
    """Typos printed the top-level usage and 'gonio: error: unrecognized arguments' (found by QA, qa-user)."""
    from gonio.cli.main import main

    with pytest.raises(SystemExit) as stop:
        main(argv)
    err = capsys.readouterr().err
    assert stop.value.code == 2 and where in err and hint in err, err
    assert err.count("error:") == 1
