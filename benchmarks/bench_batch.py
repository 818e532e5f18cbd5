"""Many materials at once: ``gonio fit`` over N full MERL tables one after another, on the local cores
(``--jobs 2``) and on a 2-worker Dask ``LocalCluster`` (``--scheduler``), through the same
:func:`gonio.batch.run_batch` the CLI uses and the same per-source function (:func:`gonio.cli.fit.fit_row`).

The sources are the real materials of ``../shared/realdata`` when present (MERL tables generated once
into a cache outside the repository, as :mod:`benchmarks.bench_realdata` does; the full run takes all 12,
``--quick`` two and only with ``$GONIO_REALDATA`` set), else full synthetic MERL tables tabulated from
gonio's own models (said in the table's notes). Every way must give the same results: the fitted
parameters of each source are compared with the serial run's. They agree to 1e-6 relative, far inside
any fit's uncertainty, not bit for bit: Dask's workers run with one BLAS/OpenMP thread
(``distributed``'s default ``OMP_NUM_THREADS=1``), so sums in the solver add in another order. The ratio is the serial wall time over each way's.
"""

from __future__ import annotations

import ast
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks.common import Table

#: Synthetic sources when the real ones are absent: (model, parameters) tabulated on the full MERL grid.
SYNTHETIC = (
    ("lambert+ggx", {"diffuse.albedo": [0.5, 0.3, 0.2], "lobe1.ks": [0.4, 0.4, 0.4], "lobe1.alpha": 0.2}),
    ("lambert+ggx", {"diffuse.albedo": [0.05, 0.05, 0.05], "lobe1.ks": [0.8, 0.6, 0.3], "lobe1.alpha": 0.08}),
    ("lambert", {"albedo": [0.6, 0.6, 0.55]}),
    ("lambert+ggx", {"diffuse.albedo": [0.1, 0.4, 0.1], "lobe1.ks": [0.2, 0.2, 0.2], "lobe1.alpha": 0.4}),
)


def _synthetic_tables(n: int, where: Path) -> list[Path]:
    from gonio.brdf import make
    from gonio.io.merl import MerlTable, cell_directions, write_merl

    wi, wo, above = cell_directions()
    paths = []
    for k in range(n):
        name, params = SYNTHETIC[k % len(SYNTHETIC)]
        path = where / f"synthetic-{k}-{name.replace('+', '_')}.binary"
        if not path.is_file():
            model = make(name, **params)
            values = np.zeros(wi.shape[:-1] + (3,))
            values[above] = model.eval(wi[above], wo[above])
            write_merl(path, MerlTable(values))
        paths.append(path)
    return paths


def _sources(quick: bool) -> tuple[list[Path], str]:
    from benchmarks.bench_realdata import MATERIALS, QUICK, find_realdata, merl_tables

    use_real = not quick or bool(os.environ.get("GONIO_REALDATA"))  # a quick run never reads the folder unasked
    src = find_realdata() if use_real else None
    if src is not None:
        names = QUICK if quick else MATERIALS
        tables = merl_tables(src, names)
        return [tables[n] for n in names], f"{len(names)} real MERL materials ({src})"
    where = Path(tempfile.gettempdir()) / "gonio-bench-batch"
    where.mkdir(parents=True, exist_ok=True)
    n = 2 if quick else 6
    why = "quick run without GONIO_REALDATA" if not use_real else "../shared/realdata not found"
    return _synthetic_tables(n, where), f"{n} synthetic full MERL tables ({why})"


def _params(row: dict) -> dict[str, np.ndarray]:
    out = {}
    for item in row.get("params", "").split("; "):
        if "=" in item:
            k, v = item.split("=", 1)
            try:
                out[k] = np.atleast_1d(np.asarray(ast.literal_eval(v), dtype=float))
            except (SyntaxError, TypeError, ValueError, NameError):
                continue
    return out


def _agree(a: list[dict], b: list[dict]) -> tuple[bool, float]:
    """True when every source has the same status, model and parameters (relative 1e-6, see the module
    docstring); the worst relative parameter difference."""
    worst = 0.0
    for x, y in zip(a, b):
        if (x.get("status"), x.get("model")) != (y.get("status"), y.get("model")):
            return False, float("inf")
        px, py = _params(x), _params(y)
        if px.keys() != py.keys():
            return False, float("inf")
        for k in px:
            if px[k].shape != py[k].shape:
                return False, float("inf")
            scale = np.maximum(np.abs(px[k]), 1e-300)
            worst = max(worst, float(np.max(np.abs(px[k] - py[k]) / scale, initial=0.0)))
    return worst <= 1e-6, worst


def run(quick: bool = False) -> list[Table]:
    from gonio.batch import run_batch
    from gonio.cli.fit import fit_row

    paths, what = _sources(quick)
    opts = {"select": False, "model": "lambert+ggx", "candidates": None, "criterion": "cv", "loss": "robust",
            "fixed": {}, "seed": 0, "max_theta_deg": None, "force": False}
    t = Table(f"Fitting {len(paths)} full MERL tables (lambert+ggx): one after another vs 2 local processes vs a "
              f"2-worker Dask LocalCluster", ["way", "wall s", "ratio vs serial", "failed", "same results",
                                              "worst rel. param diff"], baseline=0)
    t.notes.append(f"sources: {what}; {os.cpu_count()} cores on this machine")
    start = time.perf_counter()
    serial = run_batch(fit_row, paths, opts, jobs=1)
    t_serial = time.perf_counter() - start
    t.add("serial (--jobs 1)", t_serial, 1.0, sum(r.get("status") == "failed" for r in serial), "reference", 0.0)

    start = time.perf_counter()
    local = run_batch(fit_row, paths, opts, jobs=2)
    t_local = time.perf_counter() - start
    same, worst = _agree(serial, local)
    t.add("--jobs 2", t_local, t_serial / t_local, sum(r.get("status") == "failed" for r in local),
          "yes" if same else "NO", worst)

    try:
        from distributed import LocalCluster
    except ImportError:
        t.notes.append("Dask not installed (pip install 'gonio[dask]'): no cluster row")
        return [t]
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        start = time.perf_counter()
        dask = run_batch(fit_row, paths, opts, scheduler=cluster.scheduler_address)
        t_dask = time.perf_counter() - start
    same, worst = _agree(serial, dask)
    t.add("--scheduler (Dask LocalCluster, 2 workers)", t_dask, t_serial / t_dask,
          sum(r.get("status") == "failed" for r in dask), "yes" if same else "NO", worst)
    t.notes.append("the Dask time includes shipping each task to a worker; the cluster's start-up is not timed")
    return [t]
