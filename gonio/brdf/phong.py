"""Normalized Phong reflection model (mirror-direction cosine lobe)."""

from __future__ import annotations

import numpy as np

from gonio.brdf.base import BRDF, Param

__all__ = ["Phong", "EXPONENT_MAX", "cosine_power"]

#: Largest lobe exponent accepted (a practically perfect mirror); larger values are a ConfigError.
EXPONENT_MAX = 1e6


def cosine_power(t, exponent) -> np.ndarray:
    """max(0, t)^exponent for t ≤ 1 (rounding above 1 is clipped), finite for exponents in [0, 1e6].

    0^0 is taken as 1, the limit of the lobe as the exponent goes to 0 (a constant lobe).
    """
    return np.clip(t, 0.0, 1.0) ** exponent


class Phong(BRDF):
    """Phong's model (Phong 1975) with the energy normalization of Lewis 1994.

    f(wi, wo) = kd/π + ks · (n + 2)/(2π) · max(0, r·wo)^n,   r = 2(n·wi)n − wi

    (B. T. Phong, "Illumination for Computer Generated Pictures", CACM 18(6), 1975; R. Lewis,
    "Making Shaders More Physically Plausible", Computer Graphics Forum 13(2), 1994; lecture notes
    ``000_b5f942c329dc4daf.txt``). r·wo = 2 (n·wi)(n·wo) − wi·wo is used directly. Reciprocal; the
    directional albedo of the lobe is ≤ ks (= ks at normal incidence), so kd + ks ≤ 1 conserves energy.

    Parameters
    ----------
    kd, ks : float or 3 floats
        Diffuse and specular weights in [0, 1].
    exponent : float
        Phong exponent n in [0, 1e6]; 0 gives a constant lobe.
    """

    name = "phong"
    PARAMS = {
        "kd": Param("rgb", 0.0, 1.0, 0.0, doc="diffuse albedo, per RGB channel"),
        "ks": Param("rgb", 0.0, 1.0, 1.0, doc="specular weight, per RGB channel"),
        "exponent": Param("scalar", 0.0, EXPONENT_MAX, 50.0, doc="Phong exponent n (lobe sharpness)"),
    }

    def _eval(self, wi, wo):
        rdotv = 2.0 * wi[..., 2] * wo[..., 2] - (wi[..., 0] * wo[..., 0] + wi[..., 1] * wo[..., 1] + wi[..., 2] * wo[..., 2])
        n = self.exponent
        lobe = (n + 2.0) / (2.0 * np.pi) * cosine_power(rdotv, n)
        return self.kd / np.pi + self.ks * lobe[..., None]
