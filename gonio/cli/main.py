"""Entry point of the ``gonio`` command: builds the parser from the subcommand modules and turns
every :class:`gonio.errors.GonioError` into a one-line message and a non-zero exit code."""

from __future__ import annotations

import argparse
import functools
import importlib
import sys
import warnings

from gonio import __version__
from gonio.errors import GonioError

#: Subcommand modules under gonio.cli, in the order ``--help`` lists them.
COMMANDS = ["models", "servo", "controller", "camera", "measure", "calibrate", "fit", "tabulate", "export", "plot", "plan", "prior", "reconstruct", "status", "repair", "report", "bench"]


def _version_line() -> str:
    """What ``gonio --version`` prints: the version and the BRDF evaluation path
    (:func:`gonio.brdf.compiled.describe_path`), found only when asked."""
    from gonio.brdf.compiled import describe_path

    return f"gonio {__version__}; BRDF evaluation: {describe_path()}"


class _Version(argparse.Action):
    """``gonio --version`` (:func:`_version_line`), then exit."""

    def __call__(self, parser, namespace, values, option_string=None):
        print(_version_line())
        parser.exit()


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="gonio",
        description="Run a gonioreflectometer (or its simulation) and turn measurements into BRDFs.",
    )
    parser.add_argument("--version", action=_Version, nargs=0,
                        help="show gonio's version and which BRDF evaluation path runs (compiled or NumPy), and exit")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMANDS:
        importlib.import_module(f"gonio.cli.{name}").register(sub)
    return parser


@functools.lru_cache(maxsize=1)
def _parser() -> argparse.ArgumentParser:
    """:func:`build_parser`'s parser, built once per process and used by every :func:`main` call: building it
    registers ~300 options (~16 ms of CPU: argparse makes a help formatter, which asks the terminal's size, and
    looks up message translations for each), and a program that calls :func:`main` again and again (a batch
    script, the test suite) paid it every call. Parsing leaves a parser as it was: the values go to a new
    namespace each call (an ``append`` option's list is copied before it grows; no default is mutable otherwise).
    Each command's function is the one its module registered (``set_defaults(func=run)``) when the parser was
    built."""
    return build_parser()


def _unrecognized(parser: argparse.ArgumentParser, args, extra: list[str]) -> None:
    """Refuse arguments no option takes as argparse does (usage, one error line, exit 2), but with the usage of the
    (sub)command they were given to and, for an option, the one it most resembles (``--modle``: ``--model``)."""
    import difflib

    p = parser
    while True:  # down to the deepest subcommand the arguments chose
        subs = [a for a in p._actions if isinstance(a, argparse._SubParsersAction)]
        name = getattr(args, subs[0].dest, None) if subs else None
        if name not in (subs[0].choices if subs else {}):
            break
        p = subs[0].choices[name]
    options = sorted({o for a in p._actions for o in a.option_strings if o.startswith("--")})
    hints = []
    for x in extra:
        if x.startswith("-"):
            near = difflib.get_close_matches(x.split("=", 1)[0], options, n=1)
            if near:
                hints.append(f"{x.split('=', 1)[0]}: did you mean {near[0]}?")
    p.error(f"unrecognized arguments: {' '.join(extra)}" + (f" ({'; '.join(hints)})" if hints else ""))


def _warning_line(message, category, filename, lineno, file=None, line=None) -> None:
    print(f"gonio: warning: {message}", file=sys.stderr)


def _check_common(args) -> None:
    """Options several commands share, checked once: a seed is what NumPy's generators accept."""
    from gonio.errors import ConfigError

    seed = getattr(args, "seed", None)
    if seed is not None and not (isinstance(seed, int) and 0 <= seed < 2 ** 32):
        raise ConfigError.field(None, "--seed", seed, f"must be an integer in 0..{2 ** 32 - 1}")


def main(argv: list[str] | None = None) -> int:
    if list(sys.argv[1:] if argv is None else argv)[:1] == ["--version"]:
        # what the parser does with a first --version (prints, exits), without building it: that imports every
        # command's module (~0.05 CPU s, a third of `gonio --version`)
        print(_version_line())
        raise SystemExit(0)
    parser = _parser()
    args, extra = parser.parse_known_args(argv)
    if extra:
        _unrecognized(parser, args, extra)
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
