"""A finite BRDF value whose square overflows float64 (a hand-edited CSV or session record with f = 1e308, a MERL
cell of 1e300) is left out of a fit like a non-finite one: it was a TypeError traceback in the bounded
least-squares step (no candidate with a finite cost), or a fit 'succeeding' with rms_rel nan and cbrt_rel 1
(found by QA, qa-hostile)."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from gonio.brdf import make
from gonio.errors import DataError
from gonio.fit.data import prepare
from gonio.fit.fit import fit
from gonio.samples import SampleSet


def samples(n=400, seed=0):
    rng = np.random.default_rng(seed)
    th_i, th_o = rng.uniform(0.1, 1.2, n), rng.uniform(0.1, 1.2, n)
    ph_i, ph_o = rng.uniform(0, 2 * np.pi, n), rng.uniform(0, 2 * np.pi, n)
    s = SampleSet.from_angles(th_i, ph_i, th_o, ph_o, np.zeros((n, 3)), np.zeros((n, 3)))
    f = make("microfacet", kd=0.3, ks=0.5, alpha=0.3).eval(s.wi, s.wo)
    return SampleSet(s.wi, s.wo, f, 0.01 * f + 1e-4)


@pytest.mark.parametrize("model", ["lambert", "microfacet"])
@pytest.mark.parametrize("value", [1e308, 1e300, -1e200])
def test_one_overflowing_value_is_dropped_and_the_fit_is_finite(model, value):
    s = samples()
    f = s.f.copy()
    f[7, 0] = value
    r = fit(SampleSet(s.wi, s.wo, f, s.sigma), model)
    assert r.n_used == len(s) - 1
    assert math.isfinite(r.rms_rel)


def test_only_overflowing_values_is_a_data_error_naming_why():
    from gonio.fit.data import MAX_ABS_F

    s = samples(20)
    with pytest.raises(DataError, match=re.escape(f"beyond {MAX_ABS_F:g} 1/sr")):
        prepare(SampleSet(s.wi, s.wo, np.full_like(s.f, 1e308), s.sigma))
