"""Progress display for long work (fits of many candidates or sources, planning, tabulation).

One function, :func:`progress`, wraps an iterable in a `tqdm <https://tqdm.github.io>`_ bar on
standard error when that is a terminal, and does nothing otherwise (a log file, CI, a pipe) or when
quiet. Library code reports through it; the CLI's ``--quiet`` sets :func:`set_quiet`.
"""

from __future__ import annotations

import os
import sys
from contextlib import contextmanager
from typing import Callable, Iterable, Iterator, TypeVar

T = TypeVar("T")

_state = {"quiet": False}


def set_quiet(quiet: bool) -> None:
    """Silence every progress bar of this process (``--quiet``)."""
    _state["quiet"] = bool(quiet)


def enabled() -> bool:
    """Bars are drawn only on an interactive standard error, never with ``--quiet`` or ``GONIO_QUIET``."""
    if _state["quiet"] or os.environ.get("GONIO_QUIET"):
        return False
    try:
        return sys.stderr.isatty()
    except (AttributeError, ValueError):
        return False


def progress(iterable: Iterable[T], *, total: int | None = None, desc: str = "", unit: str = "it",
             delay: float = 0.0) -> Iterator[T]:
    """``iterable`` with a progress bar when :func:`enabled`, unchanged otherwise; ``delay``: seconds
    before the bar appears (work that ends sooner shows nothing)."""
    if not enabled():
        yield from iterable
        return
    from tqdm import tqdm

    with tqdm(iterable, total=total, desc=desc, unit=unit, leave=False, file=sys.stderr, dynamic_ncols=True,
              delay=delay) as bar:
        yield from bar


@contextmanager
def progress_counter(*, total: int | None = None, desc: str = "", unit: str = "it",
                     delay: float = 0.0) -> Iterator[Callable[[int], None]]:
    """A function ``tick(done)`` reporting how much of the work is done, drawn as a bar when
    :func:`enabled` (for loops that are not a plain iteration, e.g. a work queue); a no-op otherwise."""
    if not enabled():
        yield lambda done: None
        return
    from tqdm import tqdm

    with tqdm(total=total, desc=desc, unit=unit, leave=False, file=sys.stderr, dynamic_ncols=True,
              delay=delay) as bar:
        def tick(done: int) -> None:
            bar.update(done - bar.n)

        yield tick
