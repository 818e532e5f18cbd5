"""Ashikhmin-Shirley anisotropic Phong model."""

from __future__ import annotations

import numpy as np

from gonio.brdf.base import BRDF, Param
from gonio.brdf.fresnel import one_minus_cos_d, schlick
from gonio.brdf.microfacet import _tiny, half_vector
from gonio.brdf.phong import EXPONENT_MAX

__all__ = ["AshikhminShirley"]


class AshikhminShirley(BRDF):
    r"""Anisotropic Phong BRDF of M. Ashikhmin, P. Shirley, "An Anisotropic Phong BRDF Model",
    Journal of Graphics Tools 5(2), 2000, eqs. 4 and 5:

    f_s = √((n_u + 1)(n_v + 1)) / (8π) · (n·h)^((n_u h_x² + n_v h_y²)/(1 − (n·h)²))
          / ((h·k) max(n·k_1, n·k_2)) · F(k·h),   F = r_s + (1 − r_s)(1 − k·h)⁵,

    f_d = 28 r_d / (23π) · (1 − r_s) · (1 − (1 − n·k_1/2)⁵) · (1 − (1 − n·k_2/2)⁵),   f = f_s + f_d.

    The exponent (n_u cos²φ_h + n_v sin²φ_h) is written with h_x, h_y and the power in log space:
    at h = n (no azimuth) the power is 1. The exponents n_u (along local x) and n_v (along y) are in
    [0, 1e6]. Reciprocal; energy conserving for r_d, r_s ≤ 1 (the paper's design; checked in
    tests/brdf/test_energy.py).

    Parameters
    ----------
    rd : float or 3 floats
        Diffuse reflectance r_d in [0, 1].
    rs : float or 3 floats
        Specular reflectance at normal incidence r_s in [0, 1].
    nu, nv : float
        Phong-like exponents along x and y.
    """

    name = "ashikhmin-shirley"
    PARAMS = {
        "rd": Param("rgb", 0.0, 1.0, 0.5, doc="diffuse reflectance r_d, per RGB channel"),
        "rs": Param("rgb", 0.0, 1.0, 0.05, doc="specular reflectance at normal incidence r_s"),
        "nu": Param("scalar", 0.0, EXPONENT_MAX, 100.0, doc="exponent along the local x axis"),
        "nv": Param("scalar", 0.0, EXPONENT_MAX, 100.0, doc="exponent along the local y axis"),
    }
    isotropic = False

    def _eval(self, wi, wo):
        nu, nv = self.nu, self.nv
        h = half_vector(wi, wo)
        tiny = _tiny(wi)
        hz = np.clip(h[..., 2], tiny, 1.0)
        sxy = h[..., 0] ** 2 + h[..., 1] ** 2
        expo = np.where(sxy > 0.0, (nu * h[..., 0] ** 2 + nv * h[..., 1] ** 2) / np.maximum(sxy, tiny), 0.0)
        power = np.exp(expo * np.log(hz))
        kh = np.maximum(wi[..., 0] * h[..., 0] + wi[..., 1] * h[..., 1] + wi[..., 2] * h[..., 2], tiny)
        big = np.maximum(np.maximum(wi[..., 2], wo[..., 2]), tiny)
        spec = np.sqrt((nu + 1.0) * (nv + 1.0)) / (8.0 * np.pi) * power / (kh * big)
        fs = spec[..., None] * schlick(self.rs, kh, one_minus_cos_d(wi, wo, h))
        ci = 1.0 - 0.5 * wi[..., 2]
        co = 1.0 - 0.5 * wo[..., 2]
        shape = (1.0 - ci ** 5) * (1.0 - co ** 5)
        fd = (28.0 / (23.0 * np.pi)) * self.rd * (1.0 - self.rs) * shape[..., None]
        return fs + fd
