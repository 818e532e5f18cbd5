"""Fitting a real simulated session (``gonio measure --sim``, the README's default material: GGX
kd = [0.3, 0.12, 0.06], ks = 0.8, alpha = 0.25, f0 = 0.04): f0 is fitted, selection picks one lobe."""

from __future__ import annotations

import numpy as np
import pytest

from gonio.cli.fit import load_source
from gonio.fit import fit
from gonio.fit.select import select

KD, KS, ALPHA, F0 = [0.3, 0.12, 0.06], 0.8, 0.25, 0.04


@pytest.fixture(scope="module")
def session(default_session_measured):
    """The quick start's session (tests/conftest.py, shared with tests/api/test_readme.py)."""
    return load_source(str(default_session_measured))


def test_selection_on_the_default_session_is_one_lobe_with_the_true_parameters(session):
    sel = select(session)
    assert sel.winner.model_name == "microfacet"
    p = sel.winner.params
    assert p["alpha"] == pytest.approx(ALPHA, rel=0.02)
    np.testing.assert_allclose(p["kd"], KD, rtol=0.01)
    np.testing.assert_allclose(p["ks"], KS, rtol=0.02)
    assert p["f0"] == pytest.approx(F0, rel=0.1)
    # every row says how the scores were made comparable and why it lost or won
    rows = {r["model"]: r for r in sel.candidates}
    assert rows["microfacet"]["status"] == "chosen" and rows["lambert+2ggx"]["status"] == "rejected"
    assert all(r["chi2_scale"] == rows["lambert+2ggx"]["chi2_scale"] for r in sel.candidates)


def test_f0_cannot_be_fitted_from_near_normal_data_and_is_held(session):
    # both directions within 30° of the normal (273 of the quick start's samples, measured once for the run):
    # θd ≤ 30°, where the Fresnel rise (1 − cos θd)⁵ ≤ 5e-5 cannot be told from ks
    d = session
    near = (d.wi[:, 2] > np.cos(np.radians(30))) & (d.wo[:, 2] > np.cos(np.radians(30)))
    r = fit(d.subset(near), "microfacet")
    assert r.params["f0"] == [1.0, 1.0, 1.0] and not r.identifiable
    assert any("f0" in n and "not identifiable" in n for n in r.notes)
    # ks is then the normal-incidence specular reflectance ks·f0
    np.testing.assert_allclose(r.params["ks"], KS * F0, rtol=0.15)
