"""Shared pieces of the benchmarks: a result table that prints as Markdown, and a timer."""

from __future__ import annotations

import enum
import math
import time
from dataclasses import dataclass, field
from typing import Callable, Sequence


class Size(enum.IntEnum):
    """How big a benchmark run is. The runs' ``quick`` argument takes one (or a bool: ``False`` is
    :attr:`FULL`, ``True`` :attr:`QUICK`); :attr:`SMOKE` is true like :attr:`QUICK`, so a benchmark that
    has no smaller size runs its quick size.

    - ``FULL``: the published numbers;
    - ``QUICK`` (``--quick``): small sizes whose tables still say something (CI, a first look);
    - ``SMOKE`` (``gonio bench --smoke``, the test suite): each benchmark at its smallest size, seconds:
      every table and plot is made by the same code, the numbers mean little.
    """

    FULL = 0
    QUICK = 1
    SMOKE = 2


def size(quick) -> Size:
    """``quick`` (a bool or a :class:`Size`) as a :class:`Size`."""
    return Size(int(quick)) if not isinstance(quick, Size) else quick


@dataclass
class Table:
    """One benchmark table.

    ``columns`` name the cells of each row; ``baseline`` is the index of the row others are compared
    with (the ratios are computed by the benchmark itself, from the same run); ``default`` marks the
    row that is gonio's default, and ``why_default`` says why (e.g. the knee of the curve).
    """

    title: str
    columns: Sequence[str]
    rows: list[Sequence[object]] = field(default_factory=list)
    baseline: int | None = None
    default: int | None = None
    why_default: str = ""
    notes: list[str] = field(default_factory=list)

    def add(self, *cells: object) -> None:
        if len(cells) != len(self.columns):
            raise ValueError(f"{self.title}: row has {len(cells)} cells, table has {len(self.columns)} columns")
        self.rows.append(cells)

    def to_markdown(self) -> str:
        def fmt(x: object) -> str:
            if isinstance(x, float):
                if x == 0 or math.isnan(x) or math.isinf(x):
                    return f"{x:g}"
                return f"{x:.4g}" if 1e-3 <= abs(x) < 1e6 else f"{x:.3e}"
            return str(x)

        head = ["", *self.columns]
        lines = [f"### {self.title}", "", "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        for i, row in enumerate(self.rows):
            mark = []
            if i == self.baseline:
                mark.append("baseline")
            if i == self.default:
                mark.append("**default**")
            lines.append("| " + " | ".join([" ".join(mark), *map(fmt, row)]) + " |")
        if self.default is not None and self.why_default:
            lines += ["", f"Default: {self.why_default}"]
        lines += ["", *[f"- {n}" for n in self.notes]] if self.notes else []
        return "\n".join(lines) + "\n"


def round_time(quick) -> float:
    """``min_time`` of :func:`time_call` at the run's :class:`Size`: 0.3 s a round, 0.05 s at the quick size, 0 at
    the smoke size (one call a round: a smoke run checks that every table is made from the same calls on the same
    inputs; its timings mean little)."""
    return {Size.FULL: 0.3, Size.QUICK: 0.05, Size.SMOKE: 0.0}[size(quick)]


def timed_calls(quick, full: int = 5, quick_n: int = 3) -> int:
    """``repeat`` of :func:`time_median` at the run's :class:`Size`: ``full`` calls, ``quick_n`` at the quick size,
    1 at the smoke size (after the warm-up call, as at every size; see :func:`round_time`)."""
    return {Size.FULL: full, Size.QUICK: quick_n, Size.SMOKE: 1}[size(quick)]


def time_call(fn: Callable[[], object], *, min_time: float = 0.2, repeat: int = 3) -> float:
    """Seconds per call of ``fn``: best of ``repeat`` rounds, each running ≥ ``min_time`` seconds."""
    fn()  # warm up (imports, caches)
    best = math.inf
    for _ in range(repeat):
        n, start = 0, time.perf_counter()
        while True:
            fn()
            n += 1
            elapsed = time.perf_counter() - start
            if elapsed >= min_time:
                break
        best = min(best, elapsed / n)
    return best


def time_median(fn: Callable[[], object], *, repeat: int = 5, cpu: bool = True) -> float:
    """Median seconds per call of ``fn`` over ``repeat`` calls after one warm-up call (compilation, caches).

    ``cpu``: CPU time of this process (``time.process_time``: what one core spends, less disturbed by
    other users of a shared machine than wall time); else wall time.
    """
    clock = time.process_time if cpu else time.perf_counter
    fn()
    times = []
    for _ in range(repeat):
        start = clock()
        fn()
        times.append(clock() - start)
    return sorted(times)[len(times) // 2]
