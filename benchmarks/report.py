"""The speed-versus-accuracy report behind ``gonio bench``: runs every trade (each against a baseline
measured in the same run), writes ``REPORT.md`` (tables, date, machine, durations) and one PNG plot per
trade (matplotlib, the ``plots`` extra; without it the report is written without plots and says so).

The measurements live in the benchmark modules; this module only runs them and presents the results.
"""

from __future__ import annotations

import os
import platform
import sys
import time
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, TextIO

import numpy as np

from benchmarks.common import Size, Table, size


@dataclass(frozen=True)
class Trade:
    """One section of the report: a trade, the function producing its tables, and its plot."""

    name: str
    title: str
    tables: Callable[[Size], list[Table]]  #: (size: a Size, true at quick and smoke) -> tables
    plot: Callable[[object, list[Table]], bool]  # (matplotlib Axes, tables) -> drew something


def _col(t: Table, name: str) -> np.ndarray:
    i = list(t.columns).index(name)
    return np.array([r[i] for r in t.rows], dtype=object)


def _find(tables: list[Table], *columns: str) -> Table | None:
    return next((t for t in tables if all(c in t.columns for c in columns)), None)


def _mark_default(ax, t: Table, x, y) -> None:
    if t.default is not None:
        ax.plot([x[t.default]], [y[t.default]], "o", ms=14, mfc="none", mec="k", label="default")


# -- the trades -----------------------------------------------------------------------------------
def _plans(q):
    from benchmarks.bench_tradeoffs import plan_table

    return [plan_table(q)]


def _plot_plans(ax, tables) -> bool:
    t = _find(tables, "plan", "lab s", "BRDF rel RMS err")
    if t is None:
        return False
    from benchmarks.bench_tradeoffs import knee, pareto_front

    kind, lab, err = _col(t, "plan"), _col(t, "lab s").astype(float), _col(t, "BRDF rel RMS err").astype(float)
    for k in dict.fromkeys(kind):
        sel = kind == k
        order = np.argsort(lab[sel])
        ax.plot(lab[sel][order], err[sel][order], "s--" if k == "adaptive" else "o-", label=k)
    front = pareto_front(lab, err)
    ax.plot(lab[front], err[front], ":", color="0.4", lw=2, label="Pareto front")
    k = knee(lab, err)
    ax.plot([lab[k]], [err[k]], "*", ms=16, mfc="none", mec="r", label="knee")
    _mark_default(ax, t, lab, err)
    ax.set(xlabel="lab time (s)", ylabel="BRDF relative RMS error", yscale="log",
           title="Plan density and kind: lab time vs BRDF error")
    return True


def _capture(q):
    from benchmarks.bench_tradeoffs import capture_table

    return [capture_table(q)]


def _plot_capture(ax, tables) -> bool:
    t = _find(tables, "capture", "lab s/pose", "median σ/f")
    if t is None:
        return False
    x, y = _col(t, "lab s/pose").astype(float), _col(t, "median σ/f").astype(float)
    flagged = _col(t, "flagged %").astype(float)
    ax.scatter(x, y, c=flagged, cmap="viridis", s=60, zorder=3)
    for xi, yi, label, fl in zip(x, y, _col(t, "capture"), flagged):
        ax.annotate(f"{label} ({fl:.0f} % flagged)", (xi, yi), textcoords="offset points", xytext=(6, 4), fontsize=7)
    _mark_default(ax, t, x, y)
    ax.margins(x=0.45, y=0.1)  # room for the labels right of the points
    ax.set(xlabel="lab time per pose (s)", ylabel="median σ/f of usable samples",
           title="Exposure bracket and frames: lab time vs noise")
    return True


def _brdf(q):
    from benchmarks import bench_brdf
    from benchmarks.bench_tradeoffs import precision_table

    tables = bench_brdf.run(q)
    summary = precision_table(tables)
    return tables + ([summary] if summary is not None else [])


def _plot_brdf(ax, tables) -> bool:
    s = _find(tables, "s", "method", "Meval/s", "max rel err (t^s > 1e-3)")
    p = _find(tables, "model", "float64 Meval/s", "float32 Meval/s", "f32 max rel err")
    if s is None and p is None:
        return False
    if s is not None:
        for method in dict.fromkeys(_col(s, "method")):
            sel = _col(s, "method") == method
            err = np.maximum(_col(s, "max rel err (t^s > 1e-3)")[sel].astype(float), 1e-17)
            ax.plot(_col(s, "Meval/s")[sel].astype(float), err, "o", label=f"t^s: {method}")
    if p is not None:
        ax.plot(_col(p, "float64 Meval/s").astype(float), np.full(len(p.rows), 1e-17), "^", label="models, float64")
        ax.plot(_col(p, "float32 Meval/s").astype(float), _col(p, "f32 max rel err").astype(float), "v",
                label="models, float32")
    ax.set(xlabel="million evaluations / s", ylabel="max relative error (exact = 1e-17)", xscale="log",
           yscale="log", title="Schlick vs pow, float32 vs float64: speed vs error")
    return True


def _merl(q):
    from benchmarks.bench_tradeoffs import merl_table

    return [merl_table(q)]


def _plot_merl(ax, tables) -> bool:
    t = _find(tables, "material", "method", "Mlookups/s", "rel RMS err")
    if t is None:
        return False
    x, y = _col(t, "Mlookups/s").astype(float), _col(t, "rel RMS err").astype(float)
    for mat in dict.fromkeys(_col(t, "material")):
        sel = _col(t, "material") == mat
        ax.plot(x[sel], y[sel], "o-", label=mat)
        for xi, yi, m in zip(x[sel], y[sel], _col(t, "method")[sel]):
            ax.annotate(m, (xi, yi), textcoords="offset points", xytext=(6, 4), fontsize=8)
    _mark_default(ax, t, x, y)
    ax.set(xlabel="million lookups / s", ylabel="relative RMS error", yscale="log",
           title="MERL lookup: nearest vs trilinear")
    return True


def _fit(q):
    from benchmarks import bench_fit

    return bench_fit.run(q)


def _plot_fit(ax, tables) -> bool:
    t = _find(tables, "fraction", "CPU s", "alpha rel err")
    if t is None:
        return False
    x = _col(t, "CPU s").astype(float)
    for name in ("alpha rel err", "kd max rel err"):
        if name in t.columns:
            y = _col(t, name).astype(float)
            ax.plot(x, y, "o-", label=name)
            if name == "alpha rel err":
                for xi, yi, fr in zip(x, y, _col(t, "fraction")):
                    ax.annotate(f"{float(fr):g} of cells", (xi, yi), textcoords="offset points", xytext=(6, 4),
                                fontsize=8)
                _mark_default(ax, t, x, y)
    ax.set(xlabel="fit CPU time (s)", ylabel="parameter relative error", xscale="log", yscale="log",
           title="Fit data subsampling: fit time vs parameter error")
    return True


def _realdata(q):
    from benchmarks import bench_realdata

    return bench_realdata.run(q)


def _plot_realdata(ax, tables) -> bool:
    t = _find(tables, "material", "cbrt", "ABC cbrt", "SGD cbrt")
    if t is None or not t.rows:
        return False
    x = np.arange(len(t.rows))
    for k, (name, label) in enumerate((("cbrt", "gonio --select"), ("ABC cbrt", "Löw 2012 ABC"),
                                       ("SGD cbrt", "Bagher 2012 SGD"))):
        ax.bar(x + (k - 1) * 0.27, _col(t, name).astype(float), width=0.27, label=label)
    ax.set_xticks(x, [str(m) for m in _col(t, "material")], rotation=60, ha="right", fontsize=7)
    ax.set(ylabel="cube-root cosine-weighted error", title="Real materials: selected fit vs published fits")
    ax.legend()
    return True


def _calibration(q):
    from benchmarks import bench_calibration

    if size(q) is Size.SMOKE:  # one rendered rig (the default row), no honesty table: seconds, not a minute
        return bench_calibration.run(q, jobs=1, seeds=1, rendered=1, honesty=0)
    return bench_calibration.run(q)


def _plot_calibration(ax, tables) -> bool:
    t = _find(tables, "geometry used by the host", "wi median", "wi p95")
    if t is None or not t.rows:
        return False
    keep = [i for i, v in enumerate(_col(t, "wi median")) if isinstance(v, float)]  # not the goal row (text)
    x = np.arange(len(keep))
    for k, name in enumerate(("wi median", "wi p95", "wo median", "wo p95")):
        ax.bar(x + (k - 1.5) * 0.2, _col(t, name)[keep].astype(float), width=0.2, label=name)
    ax.set_xticks(x, [str(m) for m in _col(t, "geometry used by the host")[keep]], rotation=15, ha="right", fontsize=7)
    ax.set(ylabel="angular error vs truth (°)", yscale="log", title="As-built rigs: declared vs calibrated geometry")
    ax.legend()
    return True


def _labtime(q):
    from benchmarks import bench_labtime

    return bench_labtime.run(q)


def _plot_labtime(ax, tables) -> bool:
    t = _find(tables, "strategy", "lab/bound", "p95 rel err")
    if t is None or not t.rows:
        return False
    x = _col(t, "lab/bound").astype(float)
    y = _col(t, "p95 rel err").astype(float)
    ax.plot(x, y, "o")
    for xi, yi, name in zip(x, y, _col(t, "strategy")):
        ax.annotate(str(name).split(":")[0].split(",")[0][:28], (xi, yi), textcoords="offset points", xytext=(6, 4),
                    fontsize=7)
    _mark_default(ax, t, x, y)
    ax.set(xlabel="simulated lab time / lower bound", ylabel="p95 relative error vs true BRDF", xscale="log",
           title="Light warm-up and dark frames: lab time vs accuracy")
    return True


def _sphere(q):
    from benchmarks import bench_sphere

    return bench_sphere.trade(q)


def _plot_sphere(ax, tables) -> bool:
    t = _find(tables, "camera", "cells / lab min")
    if t is None or not t.rows:
        return False
    names = [str(c) for c in _col(t, "camera")]
    ax.bar(range(len(names)), _col(t, "cells / lab min").astype(float))
    ax.set_xticks(range(len(names)), names, rotation=15, ha="right", fontsize=7)
    ax.set(ylabel="MERL cells filled per lab minute", yscale="log", title="Sphere vs flat sample (geometry)")
    return True


def _sparse(q):
    from benchmarks.sparse_trade import trade_tables

    return trade_tables(q)


def _plot_sparse(ax, tables) -> bool:
    t = _find(tables, "method", "lab s", "median cbrt")
    if t is None or not t.rows:
        return False
    keep = [i for i, v in enumerate(_col(t, "lab s")) if not isinstance(v, str)]
    x, y = _col(t, "lab s")[keep].astype(float), _col(t, "median cbrt")[keep].astype(float)
    ax.plot(x, np.maximum(y, 1e-3), "o-", label="median over the held-out materials")
    for xi, yi, n in zip(x, y, _col(t, "poses")[keep]):
        ax.annotate(f"{n} poses", (xi, max(yi, 1e-3)), textcoords="offset points", xytext=(6, 4), fontsize=8)
    ax.set(xlabel="lab time (s)", ylabel="cube-root error of the whole table (0 plotted at 1e-3)", xscale="log",
           yscale="log", title="Sparse measurement under a prior vs a dense table")
    return True


TRADES = [
    Trade("plans", "Plan density and kind → lab time vs BRDF error", _plans, _plot_plans),
    Trade("capture", "Exposure brackets and frames averaged → lab time vs noise", _capture, _plot_capture),
    Trade("brdf", "Schlick's rational approximation vs pow, float32 vs float64 → evaluations/s vs error", _brdf,
          _plot_brdf),
    Trade("merl", "Interpolation in MERL lookup → speed vs error", _merl, _plot_merl),
    Trade("fit", "Fit data subsampling → fit time vs parameter error", _fit, _plot_fit),
    Trade("realdata", "Real measured materials → selected fit and time vs published fits", _realdata, _plot_realdata),
    Trade("calibration", "Rig geometric calibration → lab time vs wi/wo and lobe error on as-built rigs", _calibration,
          _plot_calibration),
    Trade("sparse", "Sparse poses under a data-driven prior → lab time vs the whole table's error", _sparse,
          _plot_sparse),
    Trade("labtime", "Light warm-up and dark frames → lab time vs its lower bound vs accuracy", _labtime,
          _plot_labtime),
    Trade("sphere", "Sphere vs flat sample → MERL cells per lab minute", _sphere, _plot_sphere),
]


# -- the report -----------------------------------------------------------------------------------
def cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo`` on Linux, else :func:`platform.processor`)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.lower().startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def machine() -> dict[str, str]:
    """What the numbers depend on: CPU, cores, OS, Python and library versions."""
    import scipy

    info = {"CPU": cpu_model(), "cores": str(os.cpu_count()), "OS": platform.platform(),
            "Python": platform.python_version(), "numpy": np.__version__, "scipy": scipy.__version__}
    try:
        import matplotlib

        info["matplotlib"] = matplotlib.__version__
    except ImportError:
        info["matplotlib"] = "not installed (no plots)"
    return info


def _pyplot():
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return None
    return plt


def write_report(out: Path, *, quick: bool | Size = False, trades: list[Trade] | None = None,
                 stream: TextIO | None = sys.stderr) -> tuple[Path, list[str]]:
    """Run the trades and write ``out/REPORT.md`` and ``out/<trade>.png``.

    ``quick``: the run's :class:`~benchmarks.common.Size` (``True``: quick), handed to every trade.

    Returns ``(path of REPORT.md, names of the trades that failed)``; a failing trade is reported
    (traceback in the report, one line on ``stream``) and the others still run.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    quick = size(quick)
    trades = TRADES if trades is None else trades
    plt = _pyplot()
    if plt is None and stream is not None:
        print("gonio bench: matplotlib is not installed (pip install 'gonio[plots]'): writing the report "
              "without plots", file=stream)
    start, date = time.perf_counter(), time.strftime("%Y-%m-%d %H:%M %Z")
    body, failed, durations = [], [], []
    for tr in trades:
        t0 = time.perf_counter()
        if stream is not None:
            print(f"gonio bench: {tr.name} ...", file=stream, flush=True)
        body.append(f"## {tr.title}\n")
        try:
            tables = tr.tables(quick)
        except Exception:  # a broken trade must not hide the others; it is reported and fails the command
            failed.append(tr.name)
            body.append("**This trade failed:**\n\n```\n" + traceback.format_exc() + "```\n")
            if stream is not None:
                print(f"gonio bench: {tr.name} failed: {sys.exc_info()[1]!r}", file=stream)
            durations.append((tr.name, time.perf_counter() - t0))
            continue
        if plt is not None:
            fig, ax = plt.subplots(figsize=(7.5, 5))
            try:
                if tr.plot(ax, tables):
                    ax.grid(True, which="both", alpha=0.3)
                    ax.legend(fontsize=8)
                    fig.tight_layout()
                    fig.savefig(out / f"{tr.name}.png", dpi=110)
                    body.append(f"![{tr.title}]({tr.name}.png)\n")
            finally:
                plt.close(fig)
        body.extend(t.to_markdown() for t in tables)
        durations.append((tr.name, time.perf_counter() - t0))
        body.append(f"_{tr.name}: {durations[-1][1]:.1f} s_\n")
        if stream is not None:
            print(f"gonio bench: {tr.name} done in {durations[-1][1]:.1f} s", file=stream, flush=True)
    total = time.perf_counter() - start
    option = {Size.FULL: "", Size.QUICK: " --quick", Size.SMOKE: " --smoke"}[quick]
    head = [f"# gonio speed-versus-accuracy report ({quick.name.lower()} run)", "",
            f"Generated by `gonio bench{option}` on {date}; the run took **{total:.0f} s** "
            f"of wall time ({', '.join(f'{n} {d:.0f} s' for n, d in durations)}).", "",
            "| machine | |", "|---|---|", *[f"| {k} | {v} |" for k, v in machine().items()], "",
            "Each table compares every row with a baseline measured in the same run and marks gonio's default "
            "with the reason it is the default. Wall times depend on the machine's load; lab times are the "
            "simulated rig's clock (what the session would take on the real rig).", ""]
    if quick is Size.SMOKE:
        head += ["**Smoke run:** every trade at its smallest size, to check that the report runs end to end; "
                 "its numbers mean little (`--quick` or a full run for those).", ""]
    if plt is None:
        head += ["**No plots:** matplotlib is not installed (`pip install 'gonio[plots]'`).", ""]
    if failed:
        head += [f"**Failed trades:** {', '.join(failed)} (tracebacks below).", ""]
    path = out / "REPORT.md"
    path.write_text("\n".join(head) + "\n" + "\n".join(body), encoding="utf-8")
    return path, failed


def write_robustness(out: Path, *, quick: bool = False, stream: TextIO | None = None) -> Path:
    """``gonio bench --robustness``: :mod:`benchmarks.bench_robustness` (full scale unless ``quick``) as
    ``out/ROBUSTNESS.md``, each table also written to ``stream`` as it is done."""
    from benchmarks import bench_robustness

    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    parts = [f"# gonio robustness ({'quick' if quick else 'full scale'}) — {time.strftime('%Y-%m-%d %H:%M')}, "
             f"{platform.machine()}, Python {platform.python_version()}\n"]
    for t in bench_robustness.run(quick=quick):
        parts.append(t.to_markdown())
        if stream is not None:
            print(parts[-1], file=stream, flush=True)
    parts.append(f"_run: {time.perf_counter() - t0:.0f} s_\n")
    path = out / "ROBUSTNESS.md"
    path.write_text("\n".join(parts), encoding="utf-8")
    return path
