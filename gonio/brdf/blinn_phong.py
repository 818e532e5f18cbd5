"""Normalized Blinn-Phong reflection model (half-vector cosine lobe)."""

from __future__ import annotations

import numpy as np

from gonio.brdf.base import BRDF, Param
from gonio.brdf.microfacet import half_vector
from gonio.brdf.phong import EXPONENT_MAX, cosine_power

__all__ = ["BlinnPhong"]


class BlinnPhong(BRDF):
    """Blinn's half-vector variant of Phong's model, with the usual (n + 8)/(8π) normalization.

    f(wi, wo) = kd/π + ks · (n + 8)/(8π) · max(0, n·h)^n,   h = normalize(wi + wo)

    (J. Blinn, "Models of Light Reflection for Computer Synthesized Pictures", SIGGRAPH 1977;
    normalization from Akenine-Möller, Haines, Hoffman, *Real-Time Rendering* 3rd ed., eq. 7.49;
    lecture notes ``000_b5f942c329dc4daf.txt`` and ``004_6b0fa14dcb48ed2f.txt``, "Blinn-Torrance
    Variation of Phong"). The normalization is approximate: the lobe's directional albedo stays
    below ks·1.1 or so at grazing incidence (measured in tests/brdf/test_energy.py), so the model
    is not marked energy conserving. For wi = −wo, h is +z by convention.

    Parameters
    ----------
    kd, ks : float or 3 floats
        Diffuse and specular weights in [0, 1].
    exponent : float
        Blinn exponent n in [0, 1e6].
    """

    name = "blinn-phong"
    PARAMS = {
        "kd": Param("rgb", 0.0, 1.0, 0.0, doc="diffuse albedo, per RGB channel"),
        "ks": Param("rgb", 0.0, 1.0, 1.0, doc="specular weight, per RGB channel"),
        "exponent": Param("scalar", 0.0, EXPONENT_MAX, 50.0, doc="Blinn exponent n (lobe sharpness)"),
    }
    energy_conserving = False

    def _eval(self, wi, wo):
        h = half_vector(wi, wo)
        n = self.exponent
        lobe = (n + 8.0) / (8.0 * np.pi) * cosine_power(h[..., 2], n)
        return self.kd / np.pi + self.ks * lobe[..., None]
