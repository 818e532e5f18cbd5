"""A batch fit's summary says which parameters are at a bound of their range, as the single fit's table
does (``AT BOUND``): the printed table and the CSV showed ``gamma=10.0`` (red-plastic's GTR, at its upper
bound) with nothing to tell it from a determined value; the CSV had it only inside the notes."""

from __future__ import annotations

import csv

import numpy as np

from gonio.brdf import make
from gonio.cli.main import main
from gonio.geometry import from_spherical
from gonio.io.npz import build_metadata, write_npz
from gonio.samples import SampleSet


def test_batch_summary_has_an_at_bound_column(tmp_path, capsys):
    ti, to, po = np.meshgrid(np.radians(np.arange(0, 76, 15.0)), np.radians(np.arange(0, 86, 10.0)),
                             np.radians(np.arange(0, 360, 30.0)), indexing="ij")
    wi, wo = from_spherical(ti.ravel(), 0.0 * ti.ravel()), from_spherical(to.ravel(), po.ravel())
    for name, albedo in (("zero_red", [0.0, 0.4, 0.2]), ("grey", [0.3, 0.3, 0.3])):
        f = make("lambert", albedo=albedo).eval(wi, wo)
        write_npz(tmp_path / f"{name}.npz", SampleSet(wi, wo, f, 0.01 * f + 1e-4), build_metadata({}))
    summary = tmp_path / "s.csv"
    assert main(["fit", str(tmp_path / "zero_red.npz"), str(tmp_path / "grey.npz"), "--model", "lambert",
                 "--jobs", "1", "--summary", str(summary), "--quiet"]) == 0
    printed = capsys.readouterr().out
    rows = {r["source"].rsplit("/", 1)[-1]: r for r in csv.DictReader(summary.open())}
    assert rows["zero_red.npz"]["at_bound"] == "albedo (r lower 0)"
    assert rows["grey.npz"]["at_bound"] == ""
    assert "at_bound" in printed.splitlines()[0] and "albedo (r lower 0)" in printed
