"""EMVA 1288 R4.0 analysis (gonio.pipeline.emva1288) against series computed from the standard's own model, and
the two-frame variance against a fixed pattern."""

from __future__ import annotations

import numpy as np
import pytest

from gonio.errors import DataError
from gonio.pipeline.emva1288 import QUANTIZATION_VAR, EmvaData, Step, analyse, pair_stats


def test_the_difference_of_two_frames_removes_the_fixed_pattern():
    rng = np.random.default_rng(0)
    pattern = rng.normal(1000.0, 50.0, (200, 300))  # a fixed pattern far larger than the noise
    a = pattern + rng.normal(0.0, 2.0, pattern.shape)
    b = pattern + rng.normal(0.0, 2.0, pattern.shape) + 0.5  # and an offset between the frames
    mean, var = pair_stats(a, b)
    assert mean == pytest.approx(1000.25, abs=0.5)
    assert var == pytest.approx(4.0, rel=0.02)


def model_series(K=0.2, sigma_d=3.0, sat_e=20000.0, dark=64.0, dark_current=20.0, steps=30, reach=1.2):
    """The R4.0 model's exact μ and σ² (no sampling noise) up to ``reach`` × saturation: linear, then the variance
    collapsing past the full well."""
    out = []
    rate = sat_e / 0.01
    for t in np.linspace(1e-4, reach * 0.01, steps):
        e = min(rate * t, sat_e)
        dm = dark + K * dark_current * t
        dv = K * K * (sigma_d ** 2 + dark_current * t) + QUANTIZATION_VAR
        var = dv + K * K * e if rate * t < sat_e else 0.5
        out.append(Step(float(t), dm + K * e, var, dm, dv))
    return out


def data(steps, **stack):
    st = {"frames": 16, "exposure": 0.005, "mean": 1000.0, "spatial_var": 100.0, "temporal_var": 200.0,
          "dark_mean": 64.0, "dark_spatial_var": 0.04 + 0.3 / 16, "dark_temporal_var": 0.3, **stack}
    return EmvaData(tuple(steps), (), st, 76800, 4095.0, 12)


def test_gain_dark_noise_dark_current_and_saturation_from_the_standards_model():
    r = analyse(data(model_series()))
    assert r.gain == pytest.approx(0.2, rel=1e-9)
    assert r.read_noise_e == pytest.approx(np.sqrt(9.0 + 20.0 * 1e-4), rel=1e-6)  # σ_d at the shortest exposure
    assert r.dark_current_e_s == pytest.approx(20.0, rel=1e-6)
    assert r.saturation_capacity_e == pytest.approx(20000.0, rel=0.05) and not r.notes
    assert r.linearity_error_percent < 1e-6
    assert r.dsnu_e == pytest.approx(0.2 / 0.2, rel=1e-6)  # s_y.dark = 0.2 DN → 1 e⁻
    # PRNU: √(s²_50 − s²_dark) / (μ_50 − μ_dark), the temporal parts removed
    s50, sd = 100.0 - 200.0 / 16, 0.04
    assert r.prnu_percent == pytest.approx(np.sqrt(s50 - sd) / 936.0 * 100, rel=1e-6)


def test_what_the_series_cannot_give_is_said():
    r = analyse(data(model_series(reach=0.6)))
    assert any("saturation not reached" in n for n in r.notes) and r.saturation_capacity_e is None
    r = analyse(data(model_series(K=0.02, sigma_d=3.0)))  # σ_y.dark ≈ 0.29 DN: hidden by the quantization
    assert any("upper bound" in n for n in r.notes)
    with pytest.raises(DataError, match="at least 5"):
        analyse(data(model_series(steps=4)))
