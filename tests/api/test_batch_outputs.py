"""Outputs of one batch never collide, an interrupted batch still writes its summary, and the outputs of one
command stand alone (gonio fit --json/--mitsuba/--pbrt/--gltf: one refused export does not stop the others)."""

from __future__ import annotations

import csv
import json
import os
import signal
import threading
from pathlib import Path

import numpy as np
import pytest

from gonio.batch import INTERRUPTED, unique_names
from gonio.brdf import make
from gonio.cli.main import main
from gonio.io.merl import MerlTable, cell_directions, write_merl


def _table(path: Path, alpha: float) -> Path:
    """A sparse MERL table (every 4th θd and φd cell) of a known lambert+ggx: fits in a second."""
    wi, wo, *_ = cell_directions()
    skip = np.ones(wi.shape[:-1], dtype=bool)
    skip[:, ::4, ::4] = False
    v = make("lambert+ggx", **{"diffuse.albedo": [0.3, 0.2, 0.1], "lobe1.alpha": alpha, "lobe1.f0": 0.9}).eval(wi, wo)
    v[skip | (wi[..., 2] <= 0) | (wo[..., 2] <= 0)] = np.nan
    path.parent.mkdir(parents=True, exist_ok=True)
    write_merl(path, MerlTable(v))
    return path


@pytest.fixture(scope="module")
def same_names(tmp_path_factory):
    """Two different tables with the same file name in two directories: A/S.binary and B/S.binary."""
    d = tmp_path_factory.mktemp("same")
    return [_table(d / "A" / "S.binary", 0.1), _table(d / "B" / "S.binary", 0.3)]


def _rows(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def test_unique_names_prefix_parents_until_they_differ():
    def name(s):
        return Path(s).name + ".json"

    names, renamed = unique_names(["/d/A/S", "/d/B/S", "/d/C/T"], name)
    assert names == ["A-S.json", "B-S.json", "T.json"] and renamed == [0, 1]
    names, _ = unique_names(["/x/A/S", "/y/A/S", "/y/B/S"], name)  # one level is not enough for the first two
    assert names == ["x-A-S.json", "y-A-S.json", "B-S.json"]
    names, _ = unique_names(["/d/A/s", "/d/A/S"], name)  # only the case differs: numbered
    assert len({n.casefold() for n in names}) == 2
    assert unique_names(["/d/a", "/d/b"], name) == (["a.json", "b.json"], [])


def test_fit_of_two_sources_with_one_name_writes_two_results(same_names, tmp_path, capsys):
    out = tmp_path / "out"
    args = ["fit", *map(str, same_names), "--model", "lambert+ggx", "--max-theta", "60", "--jobs", "2", "--quiet",
            "--json", str(out), "--summary", str(tmp_path / "s.csv")]
    assert main([*args, "--force"]) == 0
    said = capsys.readouterr().out
    assert "each is named with its parent directories" in said and "A-S.binary.json" in said
    assert sorted(p.name for p in out.iterdir()) == ["A-S.binary.json", "B-S.binary.json"]
    alphas = [json.loads((out / n).read_text())["params"]["lobe1.alpha"] for n in ("A-S.binary.json", "B-S.binary.json")]
    np.testing.assert_allclose(alphas, [0.1, 0.3], rtol=1e-3)  # each result is its own source's
    rows = _rows(tmp_path / "s.csv")
    assert [Path(r["output"]).name for r in rows] == ["A-S.binary.json", "B-S.binary.json"]
    # run again without --force: refused before anything runs (no summary, nothing rewritten), one line
    before = {p.name: p.stat().st_mtime_ns for p in out.iterdir()}
    (tmp_path / "s.csv").unlink()
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "A-S.binary.json" in err and "exists (use --force" in err
    assert not (tmp_path / "s.csv").exists()
    assert {p.name: p.stat().st_mtime_ns for p in out.iterdir()} == before


def test_export_and_plot_of_two_sources_with_one_name(same_names, tmp_path, capsys):
    assert main(["export", *map(str, same_names), "--format", "npz", "-o", str(tmp_path / "npz"), "--jobs", "1",
                 "--quiet", "--summary", str(tmp_path / "e.csv")]) == 0
    assert sorted(p.name for p in (tmp_path / "npz").iterdir()) == ["A-S.npz", "B-S.npz"]
    rows = _rows(tmp_path / "e.csv")
    assert [Path(r["output"]).name for r in rows] == ["A-S.npz", "B-S.npz"] and {r["status"] for r in rows} == {"ok"}
    # the summary may not be one of the outputs
    capsys.readouterr()
    (tmp_path / "c").mkdir()
    assert main(["export", *map(str, same_names), "--format", "csv", "-o", str(tmp_path / "c"), "--jobs", "1",
                 "--quiet", "--summary", str(tmp_path / "c" / "A-S.csv")]) == 2
    assert "is also the summary" in capsys.readouterr().err
    assert not any((tmp_path / "c").iterdir())


def _stop_after_first(tmp_path, signum):
    """A thread that sends ``signum`` to this process once two sources have started (what kill/Ctrl-C would)."""
    done = threading.Event()

    def watch():
        while len(list(tmp_path.glob("*.started"))) < 2:
            if done.wait(0.02):
                return
        os.kill(os.getpid(), signum)

    t = threading.Thread(target=watch, daemon=True)
    t.start()
    return done, t


@pytest.mark.parametrize("jobs, signum", [(1, signal.SIGTERM), (2, signal.SIGINT)])
def test_interrupted_batch_writes_the_summary_of_what_finished(tmp_path, jobs, signum):
    """SIGTERM (kill, a scheduler's time limit) or Ctrl-C during a batch: the sources that finished are in
    the summary as ok, the others as interrupted; the command then stops as interrupted."""
    import argparse

    from _batch_slow import slow_job

    from gonio.cli import many

    sources = [f"s{k}" for k in range(8)]
    summary = tmp_path / "summary.csv"
    args = argparse.Namespace(jobs=jobs, scheduler=None, summary=str(summary), force=False)
    old = {s: signal.signal(s, signal.default_int_handler) for s in (signal.SIGINT,)}
    mask = signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT, signal.SIGTERM})
    done, watcher = _stop_after_first(tmp_path, signum)
    try:
        with pytest.raises(KeyboardInterrupt):
            many.run("fit", args, slow_job, sources, {"dir": str(tmp_path), "seconds": 0.3}, summary=summary)
    finally:
        done.set()
        watcher.join()
        signal.pthread_sigmask(signal.SIG_SETMASK, mask)
        for s, h in old.items():
            signal.signal(s, h)
    assert signal.getsignal(signal.SIGTERM) is not signal.default_int_handler  # restored after the batch
    rows = _rows(summary)
    assert [r["source"] for r in rows] == sources
    status = [r["status"] for r in rows]
    started = {p.name.removesuffix(".started") for p in tmp_path.glob("*.started")}
    ok = {r["source"] for r in rows if r["status"] == "ok"}
    # worker processes finish what they run; in this process (--jobs 1) the running source is stopped with it
    assert ok == started if jobs > 1 else ok == started - {max(started)}
    assert 1 <= status.count("ok") < len(sources) and status.count(INTERRUPTED) == len(sources) - status.count("ok")


def test_interrupted_cli_batch_exits_130_after_the_summary(same_names, tmp_path, capsys, monkeypatch):
    """Through `gonio fit`: the interruption (here raised by the second source's fit) still leaves the summary
    of the first, the command says interrupted and exits 130."""
    from gonio.cli import fit as fit_cli

    real = fit_cli.fit_one

    def fit_then_interrupt(source, opts):
        if source == str(same_names[1]):
            raise KeyboardInterrupt
        return real(source, opts)

    monkeypatch.setattr(fit_cli, "fit_one", fit_then_interrupt)
    code = main(["fit", *map(str, same_names), "--model", "lambert+ggx", "--max-theta", "60", "--jobs", "1",
                 "--quiet", "--summary", str(tmp_path / "s.csv")])
    captured = capsys.readouterr()
    assert code == 130 and "interrupted" in captured.err
    assert "2 sources, 1 ok, 0 failed, 1 not run (interrupted)" in captured.out
    assert [r["status"] for r in _rows(tmp_path / "s.csv")] == ["ok", INTERRUPTED]


# --- several outputs of one command ---------------------------------------------------------------------
@pytest.fixture(scope="module")
def plastic(tmp_path_factory):
    return _table(tmp_path_factory.mktemp("plastic") / "plastic.binary", 0.2)


def test_each_export_stands_alone(plastic, tmp_path, capsys):
    """The instance of the issue: --mitsuba refused stopped --pbrt and --gltf (rc 2, never written)."""
    f = {k: tmp_path / f"f.{k}" for k in ("json", "xml", "pbrt", "gltf")}
    code = main(["fit", str(plastic), "--model", "lambert+ggx", "--max-theta", "60", "--fix", "f0=0.04",
                 "--json", str(f["json"]), "--mitsuba", str(f["xml"]), "--pbrt", str(f["pbrt"]), "--gltf", str(f["gltf"])])
    out, err = capsys.readouterr()
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 4  # one line per refused export, and one saying what was not written
    assert lines[0].startswith("gonio fit: error: --mitsuba") and lines[1].startswith("gonio fit: error: --pbrt")
    assert lines[2].startswith("gonio fit: error: --gltf")
    assert "3 of 4 outputs not written (--mitsuba, --pbrt, --gltf); 1 written" in lines[3]
    assert f["json"].exists() and not f["xml"].exists() and not f["pbrt"].exists() and not f["gltf"].exists()
    # the first one failing (a name Mitsuba cannot take) does not stop the renderers after it
    g = {k: tmp_path / f"g.{k}" for k in ("txt", "pbrt", "gltf")}
    code = main(["fit", str(plastic), "--model", "lambert+ggx", "--max-theta", "60", "--approx",
                 "--mitsuba", str(g["txt"]), "--pbrt", str(g["pbrt"]), "--gltf", str(g["gltf"])])
    out, err = capsys.readouterr()
    assert code == 2 and "--mitsuba" in err and "must end in .xml or .json" in err
    assert g["pbrt"].stat().st_size > 0 and g["gltf"].stat().st_size > 0 and not g["txt"].exists()
    assert f"wrote {g['pbrt']}" in out and f"wrote {g['gltf']}" in out


def test_two_outputs_of_one_command_may_not_share_a_file(plastic, tmp_path, capsys):
    same = tmp_path / "m.json"
    assert main(["fit", str(plastic), "--json", str(same), "--mitsuba", str(same), "--force"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--mitsuba" in err and "also --json's output" in err
    assert not same.exists()  # refused before the fit
