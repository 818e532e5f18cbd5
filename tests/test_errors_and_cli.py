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
