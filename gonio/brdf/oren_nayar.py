"""Oren-Nayar rough diffuse reflection (qualitative model)."""

from __future__ import annotations

import numpy as np

from gonio.brdf.base import BRDF, Param
from gonio.brdf.microfacet import _tiny

__all__ = ["OrenNayar"]


class OrenNayar(BRDF):
    r"""Qualitative Oren-Nayar model (M. Oren, S. Nayar, "Generalization of Lambert's Reflectance
    Model", SIGGRAPH 1994, eq. 30):

    f = ρ/π · (A + B · max(0, cos(φ_i − φ_o)) · sin α · tan β),
    A = 1 − 0.5 σ²/(σ² + 0.33),  B = 0.45 σ²/(σ² + 0.09),  α = max(θ_i, θ_o),  β = min(θ_i, θ_o).

    Evaluated without angles: cos(φ_i − φ_o) sin θ_i sin θ_o = wi_x wo_x + wi_y wo_y and
    sin α tan β / (sin θ_i sin θ_o) = 1 / cos β = 1 / max(cos θ_i, cos θ_o), so
    the term is max(0, wi_x wo_x + wi_y wo_y) / max(cos θ_i, cos θ_o): defined at the pole, no
    0·∞ at grazing. σ = 0 is Lambert. Reciprocal. The qualitative model is not exactly energy
    conserving: its directional albedo reaches ~1.007 ρ near σ = 0.15, θ_i = 80° (tests/brdf/test_energy.py),
    so it is not marked energy conserving.

    Parameters
    ----------
    albedo : float or 3 floats
        ρ in [0, 1].
    sigma : float
        Standard deviation of the facet slope angle, radians, in [0, π/2].
    """

    name = "oren-nayar"
    PARAMS = {
        "albedo": Param("rgb", 0.0, 1.0, 0.8, doc="albedo rho, per RGB channel"),
        "sigma": Param("scalar", 0.0, np.pi / 2, 0.3, doc="facet slope angle std. deviation, radians"),
    }
    energy_conserving = False

    def _eval(self, wi, wo):
        s2 = self.sigma * self.sigma
        a = 1.0 - 0.5 * s2 / (s2 + 0.33)
        b = 0.45 * s2 / (s2 + 0.09)
        p = np.maximum(wi[..., 0] * wo[..., 0] + wi[..., 1] * wo[..., 1], 0.0)
        term = p / np.maximum(np.maximum(wi[..., 2], wo[..., 2]), _tiny(wi))
        return self.albedo / np.pi * (a + b * term)[..., None]
