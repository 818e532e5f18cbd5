"""Many sources at once: expand paths and globs, run one function per source on the local cores or a
Dask cluster, and collect one summary row per source.

A failing source is a row with ``status = "failed"`` and its one-line error; it never stops the
others. Rows come back in the order of the sources, whatever order the workers finish in, so a
parallel run prints and writes exactly what a serial one does.
"""

from __future__ import annotations

import csv
import glob
import os
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path
from typing import Any, Callable, Sequence

from gonio.childproc import worker_init
from gonio.errors import ConfigError, GonioError
from gonio.progress import progress

__all__ = ["expand_sources", "default_jobs", "run_batch", "write_summary_csv", "format_table", "unique_names",
           "BatchInterrupted", "INTERRUPTED"]

#: The status of a source an interrupted batch did not finish (not started, or cancelled).
INTERRUPTED = "interrupted"


class BatchInterrupted(KeyboardInterrupt):
    """Ctrl-C or SIGTERM during :func:`run_batch`: :attr:`rows` holds the row of every source that finished
    and an ``"interrupted"`` row for each other one, in the order of the sources, so the caller can still
    write the summary of what was done."""

    def __init__(self, rows: list[dict]):
        super().__init__("interrupted")
        self.rows = rows

#: File name endings that are read as data sources when a directory of them is given.
DATA_SUFFIXES = (".binary", ".npz", ".csv", ".bsdf")


def _is_session(p: Path) -> bool:
    return (p / "manifest.json").is_file()


def expand_sources(specs: Sequence[str]) -> list[Path]:
    """Paths of every source named by ``specs``: files, session directories, directories holding
    data files or sessions (their entries, sorted), and glob patterns (``*``, ``?``, ``[``). Duplicates
    are dropped; a name that matches nothing is a one-line :class:`ConfigError`."""
    out: list[Path] = []
    for spec in specs:
        if any(c in spec for c in "*?[") and not Path(spec).exists():
            matches = sorted(glob.glob(spec))
            if not matches:
                raise ConfigError.field(None, "SOURCE", spec, "matches no file or directory")
            paths = [Path(m) for m in matches]
        else:
            paths = [Path(spec)]
        for p in paths:
            if p.is_dir() and not _is_session(p):
                inner = sorted(q for q in p.iterdir()
                               if (q.is_file() and q.suffix.lower() in DATA_SUFFIXES) or (q.is_dir() and _is_session(q)))
                out.extend(inner if inner else [p])  # an empty or foreign directory: let the reader say why
            else:
                out.append(p)
    seen, unique = set(), []
    for p in out:
        key = os.path.abspath(p)
        if key not in seen:
            seen.add(key)
            unique.append(p)
    return unique


def unique_names(sources: Sequence[Path | str], name_of: Callable[[str], str]) -> tuple[list[str], list[int]]:
    """The output file name of each source, ``name_of(str(source))``, made unique within the batch: sources
    whose names clash (``A/S`` and ``B/S`` both give ``S.json``; compared without case, as a case-insensitive
    file system would) are named as if their parent directories were part of their name, one level more
    until they differ (``A-S.json``, ``B-S.json``), and numbered (``S-2.json``) if even their full paths do
    not separate them. Returns the names and the indices of the renamed sources (for the caller to say)."""
    paths = [Path(os.path.abspath(s)) for s in sources]
    base = [name_of(str(s)) for s in sources]
    names, depth = list(base), [0] * len(base)
    while True:
        groups: dict[str, list[int]] = {}
        for k, n in enumerate(names):
            groups.setdefault(n.casefold(), []).append(k)
        clashing = [k for g in groups.values() if len(g) > 1 for k in g]
        if not clashing:
            break
        grew = False
        for k in clashing:
            parents = paths[k].parent.parts[1:]  # without the root
            if depth[k] < len(parents):
                depth[k] += 1
                grew = True
                prefix = "-".join(parents[len(parents) - depth[k]:])
                names[k] = name_of(str(paths[k].parent / f"{prefix}-{paths[k].name}"))
        if not grew:  # the full paths do not separate them (e.g. only their case differs): numbered
            for g in groups.values():
                for j, k in enumerate(g[1:], start=2):
                    stem, dot, ext = names[k].partition(".")
                    names[k] = f"{stem}-{j}{dot}{ext}"
            break
    return names, [k for k in range(len(names)) if names[k] != base[k]]


def default_jobs() -> int:
    """The cores this process may use (its CPU affinity where the OS tells it)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def _guarded(fn: Callable[..., dict], source: str, options: dict) -> dict:
    """``fn(source, options)`` as a row; a gonio error (bad input, hardware, data) becomes a failed row."""
    try:
        row = dict(fn(source, options))
        row.setdefault("status", "ok")
    except GonioError as exc:
        row = {"status": "failed", "error": str(exc)}
    except Exception as exc:  # one source's bug must not lose the others' results; the row says what
        row = {"status": "failed", "error": f"{type(exc).__name__}: {exc}"}
    return {"source": source, **row}


#: Environment variables that set the thread count of the BLAS/OpenMP libraries NumPy and SciPy load.
THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "BLIS_NUM_THREADS")


def _spawn():
    import multiprocessing

    return multiprocessing.get_context("spawn")


class _one_thread_workers:
    """While worker processes start, their BLAS/OpenMP libraries are told to use one thread each (the
    workers already share the cores between them: N workers × N BLAS threads would oversubscribe them, as
    Dask's workers avoid by the same setting). Started by ``spawn``, the workers read these variables
    when they load NumPy; a forked worker would inherit the parent's already-started thread pools."""

    def __enter__(self):
        self._saved = {k: os.environ.get(k) for k in THREAD_VARS}
        for k in THREAD_VARS:
            os.environ.setdefault(k, "1")
        return self

    def __exit__(self, *exc):
        for k, v in self._saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
        return False


def run_batch(fn: Callable[[str, dict], dict], sources: Sequence[Path | str], options: dict, *,
              jobs: int | None = None, scheduler: str | None = None, desc: str = "") -> list[dict]:
    """One row per source from ``fn(str(source), options)`` (a module-level function, so it can be
    sent to another process), in the order of ``sources``.

    ``scheduler`` (``tcp://host:port``) runs them on a Dask distributed cluster (``pip install
    'gonio[dask]'``); else ``jobs`` worker processes on this machine (default: every core; 1 runs in
    this process).

    Ctrl-C or SIGTERM: no further source starts, the running ones finish, and :class:`BatchInterrupted`
    carries the rows (finished ones, and ``"interrupted"`` for the others).
    """
    names = [str(s) for s in sources]
    with _stop_on_sigterm():
        if scheduler:
            return _run_dask(fn, names, options, scheduler, desc)
        jobs = default_jobs() if jobs is None else jobs
        if jobs < 1:
            raise ConfigError.field("--jobs", "jobs", jobs, "must be at least 1")
        jobs = min(jobs, len(names))
        rows: list[dict | None] = [None] * len(names)
        if jobs <= 1:
            try:
                for k, s in enumerate(progress(names, total=len(names), desc=desc, unit="source")):
                    rows[k] = _guarded(fn, s, options)
            except KeyboardInterrupt:
                raise BatchInterrupted(_with_interrupted(rows, names)) from None
            return rows  # type: ignore[return-value]
        with _one_thread_workers(), ProcessPoolExecutor(max_workers=jobs, mp_context=_spawn(),
                                                        initializer=_worker_ignores_sigint) as pool:
            futures = {pool.submit(_guarded, fn, s, options): k for k, s in enumerate(names)}
            try:
                for fut in progress(as_completed(futures), total=len(futures), desc=desc, unit="source"):
                    rows[futures[fut]] = fut.result()
            except BaseException as exc:
                # Ctrl-C, SIGTERM (or any error here): no source not yet started is started; the ones running
                # finish (their outputs are written atomically) before this returns, so no worker writes afterwards
                pool.shutdown(wait=True, cancel_futures=True)
                if not isinstance(exc, KeyboardInterrupt):
                    raise
                for fut, k in futures.items():  # what finished, also while shutting down, is in the summary
                    if rows[k] is None and fut.done() and not fut.cancelled() and fut.exception() is None:
                        rows[k] = fut.result()
                raise BatchInterrupted(_with_interrupted(rows, names)) from None
        return rows  # type: ignore[return-value]


def _with_interrupted(rows: list[dict | None], names: list[str]) -> list[dict]:
    """``rows`` with an :data:`INTERRUPTED` row for each source that has none."""
    return [r if r is not None else {"source": s, "status": INTERRUPTED} for r, s in zip(rows, names)]


def _worker_ignores_sigint() -> None:
    """A worker process ignores SIGINT: Ctrl-C at a terminal reaches the whole process group, and the parent,
    not each worker, decides (the running sources finish, the queued ones are cancelled). And it dies with the
    parent, however that dies (kill -9 included: :func:`gonio.childproc.worker_init`)."""
    import signal

    worker_init()
    signal.signal(signal.SIGINT, signal.SIG_IGN)


class _stop_on_sigterm:
    """While a batch runs in the main thread, SIGTERM (``kill``, a scheduler's time limit, a service manager)
    stops it as Ctrl-C does, so the summary of the finished sources is still written; the previous handler
    is restored afterwards."""

    def __enter__(self):
        import signal
        import threading

        self._old = None
        if threading.current_thread() is threading.main_thread():
            self._old = signal.signal(signal.SIGTERM, signal.default_int_handler)
        return self

    def __exit__(self, *exc):
        import signal

        if self._old is not None:
            signal.signal(signal.SIGTERM, self._old)
        return False


#: The address schemes a Dask distributed scheduler listens on (a bare HOST:PORT means tcp); ``inproc``
#: (a scheduler in this process, ``inproc://HOST/PID/N``) has no port
SCHEDULER_SCHEMES = ("tcp", "tls", "ws", "wss", "ucx", "inproc")


def scheduler_address(text: str) -> str:
    """``text`` checked as a Dask scheduler address ``[SCHEME://]HOST:PORT`` and returned as given; a
    malformed one (no host, no port, a port outside 1..65535, another scheme) is a one-line ConfigError
    naming it, decided before Dask is imported or any connection or event loop is started (Dask's own
    refusal of "tcp://localhost" came from inside its loop thread, and under load as an assertion there)."""
    from urllib.parse import urlsplit

    def bad(why: str) -> ConfigError:
        return ConfigError.field("--scheduler", "scheduler", text, f"not a scheduler address tcp://HOST:PORT ({why})")

    if not isinstance(text, str) or not text.strip() or any(c.isspace() for c in text):
        raise bad("empty or has spaces")
    parts = urlsplit(text if "://" in text else "tcp://" + text)
    if parts.scheme not in SCHEDULER_SCHEMES:
        raise bad(f"scheme {parts.scheme!r}: one of {', '.join(SCHEDULER_SCHEMES)}")
    if parts.scheme == "inproc":
        if not parts.hostname or parts.path.count("/") != 2:
            raise bad("inproc://HOST/PID/N")
        return text
    if parts.path not in ("", "/") or parts.query or parts.fragment or parts.username or parts.password:
        raise bad("only SCHEME://HOST:PORT")
    try:
        port = parts.port
    except ValueError:
        raise bad("the port is not a number in 1..65535") from None
    if not parts.hostname:
        raise bad("no host")
    if port is None or not 1 <= port <= 65535:
        raise bad("no port" if port is None else "the port is not a number in 1..65535")
    return text


def _run_dask(fn, names: list[str], options: dict, scheduler: str, desc: str) -> list[dict]:
    scheduler_address(scheduler)
    try:
        from distributed import Client, as_completed as dask_completed
    except ImportError:
        raise ConfigError.field("--scheduler", "scheduler", scheduler,
                                "needs Dask: pip install 'gonio[dask]'") from None
    try:
        client = Client(scheduler, timeout="10s")
    except (OSError, TimeoutError) as exc:
        raise ConfigError.field("--scheduler", "scheduler", scheduler, f"cannot connect ({exc})") from None
    except ValueError as exc:  # a malformed address, e.g. no port ("localhost")
        raise ConfigError.field("--scheduler", "scheduler", scheduler,
                                f"not a scheduler address tcp://HOST:PORT ({exc})") from None
    try:
        futures = [client.submit(_guarded, fn, s, options, key=f"gonio-{k}-{os.getpid()}-{id(options)}")
                   for k, s in enumerate(names)]
        index = {f.key: k for k, f in enumerate(futures)}
        rows: list[dict | None] = [None] * len(names)
        try:
            for fut in progress(dask_completed(futures), total=len(futures), desc=desc, unit="source"):
                rows[index[fut.key]] = fut.result()
        except KeyboardInterrupt:
            client.cancel([f for f in futures if not f.done()])
            raise BatchInterrupted(_with_interrupted(rows, names)) from None
        return rows  # type: ignore[return-value]
    finally:
        client.close()


def _columns(rows: list[dict]) -> list[str]:
    cols: list[str] = []
    for r in rows:
        for k in r:
            if k not in cols:
                cols.append(k)
    return cols


def _cell(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.5g}"
    if isinstance(v, (list, tuple)):
        return " ".join(_cell(x) for x in v)
    return "" if v is None else str(v)


def format_table(rows: list[dict], columns: Sequence[str] | None = None) -> list[str]:
    """Rows as an aligned text table (one line per row, a header first)."""
    cols = list(columns or _columns(rows))
    cells = [[_cell(r.get(c)) for c in cols] for r in rows]
    width = [max([len(c)] + [len(row[j]) for row in cells]) for j, c in enumerate(cols)]
    out = ["  ".join(c.ljust(width[j]) for j, c in enumerate(cols)).rstrip()]
    out += ["  ".join(v.ljust(width[j]) for j, v in enumerate(row)).rstrip() for row in cells]
    return out


def write_summary_csv(path: Path | str, rows: list[dict]) -> Path:
    """The summary rows as CSV (a header of every key that occurs; lists space-separated)."""
    p = Path(path)
    cols = _columns(rows)
    try:
        with open(p, "w", newline="", encoding="utf-8") as fh:
            w = csv.writer(fh)
            w.writerow(cols)
            for r in rows:
                w.writerow([_cell(r.get(c)) for c in cols])
    except OSError as exc:
        raise ConfigError.field("--summary", "summary", str(p), f"cannot write ({exc.strerror or exc})") from None
    return p
