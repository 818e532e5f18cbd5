"""Ward's anisotropic Gaussian reflection model."""

from __future__ import annotations

import numpy as np

from gonio.brdf.base import BRDF, Param
from gonio.brdf.microfacet import ALPHA_MIN, _tiny, clamp_alpha, half_vector

__all__ = ["Ward"]


class Ward(BRDF):
    r"""Anisotropic Ward model (G. Ward, "Measuring and Modeling Anisotropic Reflection",
    SIGGRAPH 1992, eq. 5a):

    f = kd/π + ks · exp(−tan²θ_h (cos²φ_h/α_x² + sin²φ_h/α_y²)) / (4π α_x α_y √(cos θ_i cos θ_o))

    evaluated as exp(−(h_x²/α_x² + h_y²/α_y²) / h_z²) so it is exact at θ_h = 0 and underflows to
    0 (not 0/0) at grazing half vectors. α_x is the slope width along the local x axis (the sample's
    reference direction, e.g. brushing), α_y along y; both clamped at 1e-4. Reciprocal. The
    1/√(cos θ_i cos θ_o) factor lets the directional albedo exceed 1 at grazing incidence for rough
    parameters (a known property of the original model), so it is not marked energy conserving.

    Parameters
    ----------
    kd, ks : float or 3 floats
        Diffuse albedo ρ_d and specular weight ρ_s in [0, 1].
    alpha_x, alpha_y : float
        RMS slopes along x and y, in [1e-4, 1].
    """

    name = "ward"
    PARAMS = {
        "kd": Param("rgb", 0.0, 1.0, 0.0, doc="diffuse albedo rho_d, per RGB channel"),
        "ks": Param("rgb", 0.0, 1.0, 1.0, doc="specular weight rho_s, per RGB channel"),
        "alpha_x": Param("scalar", ALPHA_MIN, 1.0, 0.1, doc="RMS slope along the local x axis"),
        "alpha_y": Param("scalar", ALPHA_MIN, 1.0, 0.1, doc="RMS slope along the local y axis"),
    }
    isotropic = False
    energy_conserving = False

    def _eval(self, wi, wo):
        ax, ay = clamp_alpha(self.alpha_x), clamp_alpha(self.alpha_y)
        h = half_vector(wi, wo)
        tiny = _tiny(wi)
        e = ((h[..., 0] / ax) ** 2 + (h[..., 1] / ay) ** 2) / np.maximum(h[..., 2] ** 2, tiny)
        root = np.sqrt(np.maximum(wi[..., 2] * wo[..., 2], tiny))
        spec = np.exp(-e) / (4.0 * np.pi * ax * ay * root)
        return self.kd / np.pi + self.ks * spec[..., None]
