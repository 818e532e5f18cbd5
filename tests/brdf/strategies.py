"""Shared hypothesis strategies and special directions for the BRDF tests."""

from __future__ import annotations

import numpy as np
from hypothesis import strategies as st

from gonio.brdf import MODELS, make

#: Every registered model plus sums and a multi-lobe Lafortune not in MODELS.
NAMES = sorted(MODELS) + ["lafortune2", "oren-nayar+ggx+blinn-phong", "lambert+2cook-torrance+ward"]
HALF_PI = np.pi / 2


def build(name: str, values: dict):
    if name == "lafortune2":
        return make("lafortune", **values)
    return make(name, **values)


def param_specs(name: str):
    if name == "lafortune2":
        return make("lafortune", lobes=2).PARAMS
    return MODELS[name].PARAMS if name in MODELS else _sum_params(name)


def _sum_params(name):
    from gonio.brdf.lobes import lobe_sum

    return lobe_sum(name).PARAMS


def _value(spec):
    hi = spec.hi if np.isfinite(spec.hi) else 1e3
    edge = st.sampled_from([spec.lo, hi])
    scalar = st.one_of(edge, st.floats(spec.lo, hi, allow_nan=False))
    if spec.kind == "rgb":
        return st.one_of(scalar, st.lists(scalar, min_size=3, max_size=3))
    if spec.kind == "table":  # a tabulated function (dupuy2015): its default scaled, or every entry at one value > 0
        shape = np.shape(spec.default)
        flat = st.floats(max(spec.lo, 1e-3), hi, allow_nan=False).map(lambda v: np.full(shape, v).tolist())
        return st.one_of(st.just(spec.default), flat)
    return scalar


@st.composite
def models(draw, names=NAMES):
    name = draw(st.sampled_from(names))
    values = {}
    for key, spec in param_specs(name).items():
        if spec.kind == "choice":
            values[key] = draw(st.sampled_from(spec.choices))
        else:
            values[key] = draw(_value(spec))
    return build(name, values)


def special_directions() -> np.ndarray:
    """Directions at the extremes: the pole, θ = 90° exactly (as computed and as z = 0), near both."""
    thetas = [0.0, 1e-9, 0.3, 1.0, HALF_PI - 1e-7, HALF_PI]
    phis = [0.0, 1.0, HALF_PI, np.pi]
    d = [[np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)] for t in thetas for p in phis]
    d += [[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]
    return np.array(d)


def special_pairs():
    """(wi, wo) arrays: all pairs of special directions, plus wi = wo, mirror and wi = -wo in plane."""
    d = special_directions()
    wi = np.concatenate([np.repeat(d, len(d), axis=0), d, d])
    wo = np.concatenate([np.tile(d, (len(d), 1)), d, d * [-1, -1, 1]])
    return wi, wo


unit_angles = st.tuples(st.floats(0.0, HALF_PI), st.floats(0.0, 2 * np.pi))
