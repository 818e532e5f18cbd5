"""What ``gonio fit``, ``export`` and ``plot`` share when given many sources: the options (``--jobs``,
``--scheduler``, ``--summary``, ``--quiet``) and the summary they print and write (:mod:`gonio.batch`)."""

from __future__ import annotations

import time
from functools import partial
from pathlib import Path


def add_options(p) -> None:
    p.add_argument("--jobs", type=int, default=None, metavar="N",
                   help="with several sources: worker processes (default: every core; 1 = one after another)")
    p.add_argument("--scheduler", default=None, metavar="tcp://HOST:PORT",
                   help="with several sources: run them on this Dask distributed cluster (pip install 'gonio[dask]')")
    p.add_argument("--summary", default=None, metavar="OUT.csv",
                   help="with several sources: write the summary table here (default ./gonio-COMMAND-summary-"
                        "YYYYmmdd-HHMMSS.csv)")
    p.add_argument("--quiet", action="store_true", help="no progress display")


def sources(args):
    """The expanded list of sources of ``args.source`` (:func:`gonio.batch.expand_sources`)."""
    from gonio import progress
    from gonio.batch import expand_sources

    progress.set_quiet(getattr(args, "quiet", False))
    return expand_sources(args.source)


def is_batch(args, paths) -> bool:
    return len(paths) > 1 or args.jobs is not None or args.scheduler is not None


def output_dir(flag: str, value: str | None, required: bool = True) -> Path | None:
    """The directory that receives one output per source (created if missing)."""
    from gonio.errors import ConfigError

    if value is None:
        if required:
            raise ConfigError.field(flag, flag.lstrip("-"), None, "with several sources, name a directory for the outputs")
        return None
    d = Path(value)
    if d.exists() and not d.is_dir():
        raise ConfigError.field(flag, flag.lstrip("-"), value, "with several sources this must be a directory")
    d.mkdir(parents=True, exist_ok=True)
    return d


def run(command: str, args, fn, paths, options: dict, columns=None) -> int:
    """Run ``fn`` over ``paths`` (:func:`gonio.batch.run_batch`), print the summary table, write its
    CSV; exit code 1 if any source failed, else 0."""
    from gonio.batch import format_table, run_batch, write_summary_csv

    rows = run_batch(fn, paths, options, jobs=args.jobs, scheduler=args.scheduler, desc=f"gonio {command}")
    print("\n".join(format_table(rows, columns)))
    summary = args.summary or f"gonio-{command}-summary-{time.strftime('%Y%m%d-%H%M%S')}.csv"
    write_summary_csv(summary, rows)
    failed = sum(r.get("status") == "failed" for r in rows)
    print(f"{len(rows)} sources, {len(rows) - failed} ok, {failed} failed; summary written to {summary}")
    return 1 if failed else 0


def run_each(command: str, args, run_one, output_name) -> int:
    """A command with one output per source (``gonio export``, ``gonio plot``): one source runs
    ``run_one(args)``; several write ``output_name(source, opts)`` each into the directory ``-o``
    names (:func:`output_row`) and print the summary (:func:`run`)."""
    paths = sources(args)
    if not is_batch(args, paths):
        args.source = str(paths[0])
        return run_one(args)
    out_dir = output_dir("-o", args.output)
    opts = {k: v for k, v in vars(args).items() if k not in ("func", "source", "output")}
    opts["out_dir"] = str(out_dir)
    return run(command, args, partial(output_row, run_one, output_name), paths, opts,
               ["source", "status", "output", "error"])


def output_row(run_one, output_name, source: str, opts: dict) -> dict:
    """One source of a batch: ``run_one`` with its output in ``opts["out_dir"]`` (its own printing
    suppressed: the summary speaks for it); its summary row."""
    import argparse
    import contextlib
    import io

    out = Path(opts["out_dir"]) / output_name(source, opts)
    ns = argparse.Namespace(**{k: v for k, v in opts.items() if k != "out_dir"}, source=source, output=str(out))
    with contextlib.redirect_stdout(io.StringIO()):
        run_one(ns)
    return {"output": str(out)}
