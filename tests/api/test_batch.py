"""Many sources at once: gonio fit / export / plot over files, directories and globs, serially, on
local worker processes and on a Dask LocalCluster; one failing source does not stop the others."""

from __future__ import annotations

import csv
import json
import os
import signal
import threading
import time

import numpy as np
import pytest

from gonio.batch import expand_sources
from gonio.brdf import make
from gonio.cli.main import main
from gonio.errors import ConfigError
from gonio.io.merl import MerlTable, cell_directions, write_merl


@pytest.fixture(scope="module")
def tables(tmp_path_factory):
    """Three MERL tables of known Lambert + GGX materials and one broken file. The tables hold every
    4th θd and every 4th φd cell (a table with unmeasured cells, as the format allows): exact values,
    so every mode must recover the same parameters, at 1/16 of the fitting cost of full tables."""
    d = tmp_path_factory.mktemp("many")
    wi, wo, *_ = cell_directions()
    below = (wi[..., 2] <= 0) | (wo[..., 2] <= 0)
    sparse = np.ones(below.shape, dtype=bool)
    sparse[:, ::4, ::4] = False
    below |= sparse
    for k, alpha in enumerate((0.1, 0.2, 0.3)):
        v = make("lambert+ggx", **{"diffuse.albedo": [0.3, 0.2, 0.1], "lobe1.alpha": alpha,
                                   "lobe1.f0": [0.9, 0.9, 0.9]}).eval(wi, wo)
        v[below] = np.nan
        write_merl(d / f"m{k}.binary", MerlTable(v))
    (d / "broken.binary").write_bytes(b"not a table")
    return d


def _read(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def test_expand_sources_directories_globs_and_no_match(tables):
    assert [p.name for p in expand_sources([str(tables)])] == ["broken.binary", "m0.binary", "m1.binary", "m2.binary"]
    assert [p.name for p in expand_sources([str(tables / "m*.binary"), str(tables / "m0.binary")])] == \
        ["m0.binary", "m1.binary", "m2.binary"]
    with pytest.raises(ConfigError, match="matches no file"):
        expand_sources([str(tables / "z*.binary")])


@pytest.mark.parametrize("mode", ["serial", "jobs2", "dask"])
def test_fit_many_same_rows_in_every_mode(tables, tmp_path, mode, capsys):
    args = ["fit", str(tables), "--model", "lambert+ggx", "--max-theta", "60", "--quiet",
            "--summary", str(tmp_path / "s.csv"), "--json", str(tmp_path / "json")]
    cluster = None
    if mode == "serial":
        args += ["--jobs", "1"]
    elif mode == "jobs2":
        args += ["--jobs", "2"]
    else:
        distributed = pytest.importorskip("distributed", reason="the dask extra is part of gonio[dev]")
        cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False,
                                           dashboard_address=None)
        args += ["--scheduler", cluster.scheduler_address]
    try:
        code = main(args)
    finally:
        if cluster is not None:
            cluster.close()
    out = capsys.readouterr().out
    assert code == 1  # the broken file failed, the others did not stop
    rows = _read(tmp_path / "s.csv")
    assert [r["source"].rsplit("/", 1)[1] for r in rows] == ["broken.binary", "m0.binary", "m1.binary", "m2.binary"]
    assert rows[0]["status"] == "failed" and "broken.binary" in rows[0]["error"]
    alphas = []
    for r in rows[1:]:
        assert r["status"] == "ok" and r["model"] == "lambert+ggx"
        alphas.append(json.loads((tmp_path / "json" / (r["source"].rsplit("/", 1)[1] + ".json")).read_text())
                      ["params"]["lobe1.alpha"])
    np.testing.assert_allclose(alphas, [0.1, 0.2, 0.3], rtol=1e-3)
    assert "4 sources, 3 ok, 1 failed" in out


def test_export_and_plot_many(tables, tmp_path, capsys):
    pytest.importorskip("matplotlib", reason="plots need the plots extra, part of gonio[dev]")
    srcs = [str(tables / f"m{k}.binary") for k in range(2)]
    assert main(["export", *srcs, "--format", "npz", "-o", str(tmp_path / "npz"), "--jobs", "1", "--quiet",
                 "--summary", str(tmp_path / "e.csv")]) == 0
    assert sorted(p.name for p in (tmp_path / "npz").iterdir()) == ["m0.npz", "m1.npz"]
    assert main(["plot", str(tmp_path / "npz"), "--kind", "coverage", "-o", str(tmp_path / "png"), "--jobs", "1",
                 "--quiet", "--summary", str(tmp_path / "p.csv")]) == 0
    assert sorted(p.name for p in (tmp_path / "png").iterdir()) == ["m0.npz-coverage.png", "m1.npz-coverage.png"]
    # several sources need a directory for -o, not a file
    (tmp_path / "file.txt").write_text("x")
    assert main(["export", *srcs, "--format", "npz", "-o", str(tmp_path / "file.txt"), "--quiet"]) != 0
    assert "must be a directory" in capsys.readouterr().err


def test_interrupted_batch_starts_nothing_more_and_leaves_no_worker(tmp_path):
    """Ctrl-C during a batch on worker processes: the sources not yet started never start, and when
    run_batch returns (raising KeyboardInterrupt) no worker is left running to write after it."""
    from _batch_slow import slow_job

    from gonio.batch import run_batch

    sources = [f"s{k}" for k in range(12)]
    first = threading.Event()

    def interrupt_when_one_started():
        while not any(tmp_path.glob("*.started")):
            if first.wait(0.02):
                return
        os.kill(os.getpid(), signal.SIGINT)  # what Ctrl-C sends to the parent

    # Ctrl-C as a terminal delivers it to a fresh `gonio` process: Python's handler armed and SIGINT unblocked in
    # this thread, whatever earlier tests in this worker process left behind
    old = signal.signal(signal.SIGINT, signal.default_int_handler)
    mask = signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    watcher = threading.Thread(target=interrupt_when_one_started, daemon=True)
    watcher.start()
    try:
        with pytest.raises(KeyboardInterrupt):
            run_batch(slow_job, sources, {"dir": str(tmp_path), "seconds": 0.3}, jobs=2)
    finally:
        first.set()
        watcher.join()
        signal.pthread_sigmask(signal.SIG_SETMASK, mask)
        signal.signal(signal.SIGINT, old)
    started = sorted(tmp_path.glob("*.started"))
    assert 1 <= len(started) < len(sources)  # running ones finished; queued ones were cancelled
    time.sleep(0.5)  # a worker still running would start another source within this
    assert sorted(tmp_path.glob("*.started")) == started
