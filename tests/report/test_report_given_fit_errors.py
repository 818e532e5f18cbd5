"""A saved fit (``--model FIT.json``) shown for several inputs is scored on each input: the comparison
table's errors are the model's on that input's samples, not the numbers the JSON holds from the data it
was fitted to (which made a model look as good on another material as on its own)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from gonio.brdf import make
from gonio.fit.data import prepare
from gonio.report import comparison_table, load_entries


def _rms_rel(model, samples):
    d = prepare(samples)
    m, c = model.eval(d.wi, d.wo), d.wi[:, 2:3]
    return float(np.sqrt(np.sum((c * (m - d.y)) ** 2) / np.sum((c * d.y) ** 2)))


def test_given_fit_is_scored_on_each_input(inputs, fit_json):
    session, table = inputs
    saved = json.loads(fit_json.read_text())
    model = make(saved["model"], **saved["params"])
    own, other = load_entries([str(session), str(table)], [str(fit_json)])
    (_, rep_own), = own.fits.values()
    (_, rep_other), = other.fits.values()
    # on the data it was fitted to, the fit's own numbers come back
    assert rep_own["error"]["rms_rel"] == pytest.approx(saved["error"]["rms_rel"], rel=1e-9)
    assert rep_own["error"]["chi2_red"] == pytest.approx(saved["error"]["chi2_red"], rel=1e-9)
    # on another material, the model's error there (a table has no sigma: no chi2)
    expected = _rms_rel(model, other.data.to_samples())
    assert expected > 10 * saved["error"]["rms_rel"]
    assert rep_other["error"]["rms_rel"] == pytest.approx(expected, rel=1e-9)
    assert rep_other["error"]["chi2_red"] is None
    html = comparison_table([own, other])
    assert f"{expected:.5g}" in html
