"""Published / independently computed values (kept apart from regression values).

Mitsuba 3 values come from tests/data/mitsuba_roughconductor.json, written by
tests/data/gen_mitsuba_reference.py (not run in CI; mitsuba is not a dependency).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from gonio.brdf import make
from gonio.brdf.fresnel import conductor, dielectric, f0_from_eta, schlick

DATA = json.loads((Path(__file__).parents[1] / "data" / "mitsuba_roughconductor.json").read_text())


@pytest.mark.parametrize("dist", ["ggx", "beckmann"])
def test_microfacet_matches_mitsuba_roughconductor(dist):
    rows = [r for r in DATA["rows"] if r["distribution"] == dist]
    assert len(rows) > 80
    for alpha in sorted({r["alpha"] for r in rows}):
        sub = [r for r in rows if r["alpha"] == alpha]
        model = make("microfacet", kd=0, ks=1, f0=1, alpha=alpha, distribution=dist)
        f = model.eval(np.array([r["wi"] for r in sub]), np.array([r["wo"] for r in sub]))
        ref = np.array([r["f"] for r in sub])
        np.testing.assert_allclose(f[:, 0], ref, rtol=1e-5, err_msg=f"{dist} alpha={alpha}")
        assert np.all(f[:, 0] == f[:, 2])


def test_fresnel_matches_mitsuba():
    for r in DATA["fresnel"]:
        if r["kind"] == "dielectric":
            f = dielectric(r["cos"], r["eta"])
        else:
            f = conductor(r["cos"], r["eta"], r["k"])
        assert f == pytest.approx(r["F"], abs=2e-6), r


def test_fresnel_textbook_values():
    # Normal incidence: ((n-1)/(n+1))^2 = 0.04 for glass n = 1.5; ((n-1)^2 + k^2)/((n+1)^2 + k^2) for metals.
    assert dielectric(1.0, 1.5) == pytest.approx(0.04)
    assert f0_from_eta(1.5) == pytest.approx(0.04)
    assert conductor(1.0, 0.2, 3.0) == pytest.approx((0.8**2 + 9) / (1.2**2 + 9))
    # Total internal reflection past the critical angle asin(1/1.5) = 41.8 deg, going out of glass.
    assert dielectric(np.cos(np.radians(45)), 1 / 1.5) == 1.0
    # Grazing incidence: F -> 1 for all three.
    assert dielectric(0.0, 1.5) == pytest.approx(1.0)
    assert conductor(0.0, 0.2, 3.0) == pytest.approx(1.0)
    assert np.all(schlick([0.04, 0.5, 1.0], 0.0) == 1.0)
    # Brewster angle (atan 1.5): r_p = 0 so F = r_s^2 / 2.
    tb = np.arctan(1.5)
    ct = np.cos(np.arcsin(np.sin(tb) / 1.5))
    rs = (np.cos(tb) - 1.5 * ct) / (np.cos(tb) + 1.5 * ct)
    assert dielectric(np.cos(tb), 1.5) == pytest.approx(rs**2 / 2)


def test_lambert_and_phong_closed_forms():
    n = np.array([0, 0, 1.0])
    assert make("lambert", albedo=0.5).eval(n, n)[0] == pytest.approx(0.5 / np.pi)
    # Phong at the mirror direction: kd/pi + ks (n+2)/(2 pi).
    wi = np.array([np.sin(0.4), 0, np.cos(0.4)])
    wo = wi * [-1, -1, 1]
    assert make("phong", kd=0.2, ks=0.5, exponent=10).eval(wi, wo)[1] == pytest.approx(0.2 / np.pi + 0.5 * 12 / (2 * np.pi))
    assert make("blinn-phong", kd=0.0, ks=1.0, exponent=10).eval(wi, wo)[2] == pytest.approx(18 / (8 * np.pi))
