"""Entry point of the ``gonio`` command: builds the parser from the subcommand modules and turns
every :class:`gonio.errors.GonioError` into a one-line message and a non-zero exit code."""

from __future__ import annotations

import argparse
import importlib
import sys
import warnings

from gonio import __version__
from gonio.errors import GonioError

#: Subcommand modules under gonio.cli, in the order ``--help`` lists them.
COMMANDS = ["models", "servo", "controller", "camera", "measure", "calibrate", "fit", "tabulate", "export", "plot", "plan", "status", "repair", "report", "bench"]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="gonio",
        description="Run a gonioreflectometer (or its simulation) and turn measurements into BRDFs.",
    )
    parser.add_argument("--version", action="version", version=f"gonio {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMANDS:
        importlib.import_module(f"gonio.cli.{name}").register(sub)
    return parser


def _warning_line(message, category, filename, lineno, file=None, line=None) -> None:
    print(f"gonio: warning: {message}", file=sys.stderr)


def _check_common(args) -> None:
    """Options several commands share, checked once: a seed is what NumPy's generators accept."""
    from gonio.errors import ConfigError

    seed = getattr(args, "seed", None)
    if seed is not None and not (isinstance(seed, int) and 0 <= seed < 2 ** 32):
        raise ConfigError.field(None, "--seed", seed, f"must be an integer in 0..{2 ** 32 - 1}")


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        _check_common(args)
        with warnings.catch_warnings():  # a library warning (e.g. damaged records skipped) is one line
            warnings.simplefilter("default")
            warnings.showwarning = _warning_line
            return int(args.func(args) or 0)
    except GonioError as exc:
        print(f"gonio {args.command}: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print(f"gonio {args.command}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # e.g. `gonio ... | head`
        return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
