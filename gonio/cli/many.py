"""What ``gonio fit``, ``export`` and ``plot`` share when given many sources: the options (``--jobs``,
``--scheduler``, ``--summary``, ``--quiet``) and the summary they print and write (:mod:`gonio.batch`)."""

from __future__ import annotations

import os
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
    from gonio.batch import expand_sources, scheduler_address

    progress.set_quiet(getattr(args, "quiet", False))
    if getattr(args, "scheduler", None) is not None:
        scheduler_address(args.scheduler)  # a malformed address is refused before any source is read
    return expand_sources(args.source)


def is_batch(args, paths) -> bool:
    return len(paths) > 1 or args.jobs is not None or args.scheduler is not None


def output_dir(flag: str, value: str | None, required: bool = True) -> Path | None:
    """The directory that receives one output per source (created if missing)."""
    from gonio.errors import ConfigError
    from gonio.io.outputs import check_output_dir

    if value is None:
        if required:
            raise ConfigError.field(flag, flag.lstrip("-"), None, "with several sources, name a directory for the outputs")
        return None
    d = check_output_dir(value, option=flag)  # never a session directory or inside one
    try:
        d.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError.field(None, flag, value, f"cannot create the directory ({exc.strerror or exc})") from None
    return d


def summary_path(command: str, args, paths) -> Path:
    """Where the summary CSV goes, checked before the batch runs (:func:`gonio.io.outputs.check_output`):
    ``--summary``, never a session's file or one of the sources, an existing file only with ``--force``; by
    default a new ``./gonio-COMMAND-summary-DATE.csv``."""
    from gonio.io.outputs import check_output

    if args.summary:
        return check_output(args.summary, option="--summary", force=getattr(args, "force", False),
                            suffixes=(".csv",), inputs=paths)
    stem = f"gonio-{command}-summary-{time.strftime('%Y%m%d-%H%M%S')}"
    name, n = f"{stem}.csv", 1
    while Path(name).exists():  # two batches in the same second: never over the first one's summary
        name, n = f"{stem}-{n}.csv", n + 1
    return check_output(name, option="--summary", inputs=paths)


def output_targets(flag: str, out_dir: Path, paths, name_of, force: bool, summary: Path | None = None) -> dict[str, str]:
    """Where each source's output goes in ``out_dir``: names from ``name_of(source)`` made unique within the
    batch (:func:`gonio.batch.unique_names`: sources whose names clash are named with their parent
    directories, and this says so), each checked before anything runs (:func:`gonio.io.outputs.check_output`:
    an existing file only with ``force``, never one of the batch's sources, never the summary)."""
    from gonio.batch import unique_names
    from gonio.errors import ConfigError
    from gonio.io.outputs import check_output

    names, renamed = unique_names(paths, name_of)
    targets = {str(p): str(out_dir / n) for p, n in zip(paths, names)}
    if renamed:
        print(f"note: {len(renamed)} sources would share an output name in {out_dir}; each is named with its parent "
              "directories: " + ", ".join(f"{paths[k]} -> {names[k]}" for k in renamed))
    for p in paths:
        target = check_output(targets[str(p)], option=flag, force=force, inputs=paths)
        if summary is not None and os.path.realpath(target) == os.path.realpath(summary):
            raise ConfigError.field(None, flag, str(target), "is also the summary (--summary): name another one")
    return targets


def run(command: str, args, fn, paths, options: dict, columns=None, summary: Path | None = None) -> int:
    """Run ``fn`` over ``paths`` (:func:`gonio.batch.run_batch`), print the summary table, write its
    CSV (``summary``, else :func:`summary_path`); exit code 1 if any source failed, else 0. Interrupted
    (Ctrl-C, SIGTERM): the summary of the sources that finished is still written (the others say
    ``interrupted``), then the command stops as interrupted (exit code 130)."""
    from gonio.batch import INTERRUPTED, BatchInterrupted, format_table, run_batch, write_summary_csv

    if summary is None:
        summary = summary_path(command, args, paths)  # refused before the batch runs, not after
    interrupted = False
    try:
        rows = run_batch(fn, paths, options, jobs=args.jobs, scheduler=args.scheduler, desc=f"gonio {command}")
    except BatchInterrupted as exc:
        rows, interrupted = exc.rows, True
    print("\n".join(format_table(rows, columns)))
    write_summary_csv(summary, rows)
    failed = sum(r.get("status") == "failed" for r in rows)
    stopped = sum(r.get("status") == INTERRUPTED for r in rows)
    done = len(rows) - failed - stopped
    print(f"{len(rows)} sources, {done} ok, {failed} failed" + (f", {stopped} not run (interrupted)" if stopped else "")
          + f"; summary written to {summary}")
    if interrupted:
        raise KeyboardInterrupt
    return 1 if failed else 0


def run_each(command: str, args, run_one, output_name) -> int:
    """A command with one output per source (``gonio export``, ``gonio plot``): one source runs
    ``run_one(args)``; several write ``output_name(source, opts)`` each (made unique within the batch:
    :func:`output_targets`) into the directory ``-o`` names (:func:`output_row`) and print the summary
    (:func:`run`)."""
    paths = sources(args)
    if not is_batch(args, paths):
        args.source = str(paths[0])
        return run_one(args)
    opts = {k: v for k, v in vars(args).items() if k not in ("func", "source", "output")}
    summary = summary_path(command, args, paths)  # all refused before anything is created
    out_dir = output_dir("-o", args.output)
    opts["outputs"] = output_targets("-o", out_dir, paths, partial(_call_name, output_name, opts),
                                     getattr(args, "force", False), summary)
    return run(command, args, partial(output_row, run_one), paths, opts,
               ["source", "status", "output", "error"], summary=summary)


def _call_name(output_name, opts: dict, source: str) -> str:
    return output_name(source, opts)


def output_row(run_one, source: str, opts: dict) -> dict:
    """One source of a batch: ``run_one`` with its output ``opts["outputs"][source]`` (its own printing
    suppressed: the summary speaks for it); its summary row."""
    import argparse
    import contextlib
    import io

    out = opts["outputs"][source]
    ns = argparse.Namespace(**{k: v for k, v in opts.items() if k != "outputs"}, source=source, output=out)
    with contextlib.redirect_stdout(io.StringIO()):
        run_one(ns)
    return {"output": out}
