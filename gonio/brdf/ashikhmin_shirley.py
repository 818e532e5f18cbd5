"""Ashikhmin-Shirley anisotropic Phong model."""

from __future__ import annotations

import numpy as np

from gonio._jit import jitable, select
from gonio.brdf.base import BRDF, Param
from gonio.brdf.pairs import Lobe, cos_d, split_value
from gonio.brdf.phong import EXPONENT_MAX

__all__ = ["AshikhminShirley", "ashikhmin_shirley_spec", "ashikhmin_shirley_spec_split", "ashikhmin_shirley_diffuse"]


@jitable
def ashikhmin_shirley_spec(p, nu, nv):
    """The specular lobe of :class:`AshikhminShirley` without its constant √((n_u + 1)(n_v + 1)) / (8π) and
    Fresnel factor (Ashikhmin & Shirley 2000, eq. 4): (n·h)^((n_u h_x² + n_v h_y²)/(1 − (n·h)²)) /
    ((h·k) max(n·k_1, n·k_2)), on the shared geometry ``p`` (:func:`gonio.brdf.pairs.pair_geometry`).

    The exponent n_u cos²φ_h + n_v sin²φ_h is written with h_x, h_y (over h_x² + h_y² = sin²θh; 0 at h = n,
    where the power is 1), the power in log space (:func:`gonio._jit.power`) with n·h clamped to [tiny, 1]; h·k and the larger cosine
    are guarded at tiny. The :func:`~gonio.brdf.pairs.split_value` of :func:`ashikhmin_shirley_spec_split`."""
    return split_value(*ashikhmin_shirley_spec_split(p, nu, nv))


@jitable
def ashikhmin_shirley_spec_split(p, nu, nv):
    """:func:`ashikhmin_shirley_spec` as ``(base, exponent, factor)`` (:func:`gonio.brdf.pairs.split_value`):
    n·h clamped to [tiny, 1], the exponent, and 1 / ((h·k) max(n·k_1, n·k_2))."""
    tiny = p.tiny
    expo = select(p.s2h > 0.0, (nu * (p.hx * p.hx) + nv * (p.hy * p.hy)) / np.maximum(p.s2h, tiny), 0.0)
    return (np.minimum(np.maximum(p.hz, tiny), 1.0), expo,
            1.0 / (np.maximum(cos_d(p), tiny) * np.maximum(np.maximum(p.iz, p.oz), tiny)))


@jitable
def ashikhmin_shirley_diffuse(p):
    """The angular factor of :class:`AshikhminShirley`'s diffuse term (Ashikhmin & Shirley 2000, eq. 5):
    (1 − (1 − n·k_1/2)⁵)(1 − (1 − n·k_2/2)⁵). Each factor is written 1 − c⁵ = (1 − c)(1 + c + c² + c³ + c⁴)
    with 1 − c = n·k/2: a sum of positive terms, so grazing directions (n·k → 0, where 1 − c⁵ would cancel
    to a relative error ε / (5 n·k / 2)) keep full precision."""
    ci = 1.0 - 0.5 * p.iz
    co = 1.0 - 0.5 * p.oz
    return ((0.5 * p.iz) * (1.0 + ci * (1.0 + ci * (1.0 + ci * (1.0 + ci))))
            * ((0.5 * p.oz) * (1.0 + co * (1.0 + co * (1.0 + co * (1.0 + co))))))


class AshikhminShirley(BRDF):
    r"""Anisotropic Phong BRDF of M. Ashikhmin, P. Shirley, "An Anisotropic Phong BRDF Model",
    Journal of Graphics Tools 5(2), 2000, eqs. 4 and 5:

    f_s = √((n_u + 1)(n_v + 1)) / (8π) · (n·h)^((n_u h_x² + n_v h_y²)/(1 − (n·h)²))
          / ((h·k) max(n·k_1, n·k_2)) · F(k·h),   F = r_s + (1 − r_s)(1 − k·h)⁵,

    f_d = 28 r_d / (23π) · (1 − r_s) · (1 − (1 − n·k_1/2)⁵) · (1 − (1 − n·k_2/2)⁵),   f = f_s + f_d.

    The exponent (n_u cos²φ_h + n_v sin²φ_h) is written with h_x, h_y and the power in log space:
    at h = n (no azimuth) the power is 1. The exponents n_u (along local x) and n_v (along y) are in
    [0, 1e6]. Reciprocal; energy conserving for r_d, r_s ≤ 1 (the paper's design; checked in
    tests/brdf/test_energy.py). Evaluated as two lobes on shared geometry (:mod:`gonio.brdf.pairs`):
    f_s = :func:`ashikhmin_shirley_spec` × its constant × Schlick's F (1 − k·h without cancellation,
    :func:`gonio.brdf.fresnel.one_minus_cos_d_xyz`), f_d = :func:`ashikhmin_shirley_diffuse` × its weight;
    so it has a compiled form (:mod:`gonio.brdf.compiled`).

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

    def _lobes(self):
        nu, nv, rs = self.nu, self.nv, self.rs
        norm = np.sqrt((nu + 1.0) * (nv + 1.0)) / (8.0 * np.pi)
        return 0.0, [Lobe(ashikhmin_shirley_spec, (nu, nv), np.full(3, norm, dtype=rs.dtype), rs),
                     Lobe(ashikhmin_shirley_diffuse, (), (28.0 / (23.0 * np.pi)) * self.rd * (1.0 - rs))]
