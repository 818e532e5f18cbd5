"""Fresnel reflectance: Schlick's approximation, exact dielectric (η), exact conductor (η, k).

All functions take the cosine of the angle between the incident direction and the (micro)normal,
clipped to [0, 1], and broadcast it against the material constants: with RGB constants of shape
``(3,)`` the result has shape ``cos.shape + (3,)``; with scalar constants, ``cos.shape``.
They keep the floating dtype of ``cos_theta``.
"""

from __future__ import annotations

import numpy as np

from gonio._jit import jitable, select

__all__ = ["schlick", "schlick_m", "schlick_weight", "schlick_blend", "one_minus_cos_d", "one_minus_cos_d_xyz",
           "schlick_rational_power", "f0_from_eta", "dielectric", "dielectric_core", "dielectric_parts", "conductor", "conductor_core",
           "gulbrandsen_index", "METAL_F0_MIN", "F0_MAX"]


def _prep(cos_theta, *consts):
    c = np.clip(np.asarray(cos_theta), 0.0, 1.0)
    if not np.issubdtype(c.dtype, np.floating):
        c = c.astype(np.float64)
    out = []
    rgb = False
    for k in consts:
        k = np.asarray(k)
        if k.ndim:
            rgb = True
        out.append(k.astype(c.dtype) if np.issubdtype(k.dtype, np.floating) or k.dtype.kind in "iu" else k)
    if rgb:
        c = c[..., None]
    return c, out


def schlick(f0, cos_theta, one_minus_cos=None) -> np.ndarray:
    """Schlick's approximation F = f0 + (1 − f0)(1 − cos θ)⁵.

    C. Schlick, "An Inexpensive BRDF Model for Physically-based Rendering", Computer Graphics Forum
    13(3), 1994, eq. 15; lecture notes ``004_6b0fa14dcb48ed2f.txt`` ("Fresnel(F0, V·H)").

    Near normal incidence ``1 − cos θ`` cancels catastrophically (relative error ε/θ², raised to the
    5th power); callers that have the vectors pass ``one_minus_cos`` computed without the
    cancellation (see :func:`one_minus_cos_d`), and ``cos_theta`` is then only used for its shape.
    """
    c, (f0,) = _prep(cos_theta if one_minus_cos is None else one_minus_cos, f0)
    return schlick_m(f0, 1.0 - c if one_minus_cos is None else c)


@jitable
def schlick_m(f0, m):
    """Schlick's F = f0 + (1 − f0) m⁵ from m = 1 − cos θ (Schlick 1994, eq. 15; see :func:`schlick`):
    :func:`schlick_blend` of :func:`schlick_weight`. Arrays (broadcasting) or scalars."""
    return schlick_blend(f0, schlick_weight(m))


@jitable
def schlick_weight(m):
    """The angular factor m⁵ = (1 − cos θ)⁵ of Schlick's approximation (Schlick 1994, eq. 15), from m = 1 − cos θ:
    what does not depend on f0 (a fit keeps it per dataset)."""
    m2 = m * m
    return m2 * m2 * m


@jitable
def schlick_blend(f0, w):
    """Schlick's F = f0 + (1 − f0) w from its angular factor w = (1 − cos θ)⁵ (:func:`schlick_weight`;
    Schlick 1994, eq. 15): affine in f0."""
    return f0 + (1.0 - f0) * w


def one_minus_cos_d(wi, wo, h) -> np.ndarray:
    """1 − cos θ_d for unit wi, wo and their half vector h, without cancellation near θ_d = 0
    (:func:`one_minus_cos_d_xyz` on the components)."""
    return one_minus_cos_d_xyz(wi[..., 0], wi[..., 1], wi[..., 2], wo[..., 0], wo[..., 1], wo[..., 2],
                               h[..., 0], h[..., 1], h[..., 2])


@jitable
def one_minus_cos_d_xyz(ix, iy, iz, ox, oy, oz, hx, hy, hz):
    """1 − cos θ_d from the components of unit wi, wo and their half vector h (arrays or scalars).

    1 − cos θ = |w − h|²/2 for unit vectors (law of cosines), free of the cancellation of 1 − w·h near
    θ_d = 0; averaging the wi and wo forms makes the result exactly symmetric in (wi, wo), so
    Fresnel-weighted models stay reciprocal to the last bit.
    """
    ax = ix - hx
    ay = iy - hy
    az = iz - hz
    bx = ox - hx
    by = oy - hy
    bz = oz - hz
    return 0.25 * ((ax * ax + ay * ay + az * az) + (bx * bx + by * by + bz * bz))


def schlick_rational_power(t, s) -> np.ndarray:
    """Schlick's rational approximation of a power: t^s ≈ t / (s − s t + t), for t in [0, 1], s ≥ 0.

    C. Schlick, "A Fast Alternative to Phong's Specular Model", Graphics Gems IV, 1994; lecture notes
    ``000_b5f942c329dc4daf.txt`` ("replace t^s with t/(s − st + t)"). Exact at t = 0 and t = 1.
    The denominator vanishes only for t = 0 and s = 0 where t^0 = 1 is returned.
    """
    t = np.clip(t, 0.0, 1.0)
    den = s - s * t + t
    ok = den > 0.0
    return np.where(ok, t / np.where(ok, den, 1.0), 1.0)


def f0_from_eta(eta) -> np.ndarray:
    """Normal-incidence reflectance of a dielectric interface, ((η − 1)/(η + 1))² (Fresnel)."""
    eta = np.asarray(eta, dtype=np.float64)
    return ((eta - 1.0) / (eta + 1.0)) ** 2


def dielectric(cos_theta, eta) -> np.ndarray:
    """Exact unpolarized Fresnel reflectance of a dielectric interface.

    η = n_t / n_i (relative index of refraction, > 0). With cos θ_t = √(1 − (1 − cos²θ_i)/η²):

    r_s = (cos θ_i − η cos θ_t) / (cos θ_i + η cos θ_t),
    r_p = (η cos θ_i − cos θ_t) / (η cos θ_i + cos θ_t),   F = (r_s² + r_p²) / 2,

    and F = 1 under total internal reflection (η < 1 past the critical angle).
    (M. Born, E. Wolf, *Principles of Optics*, §1.5; Walter et al. 2007, eq. 22 is the same function.)
    """
    c, (eta,) = _prep(cos_theta, eta)
    return dielectric_core(c, eta)


@jitable
def dielectric_core(c, eta):
    """:func:`dielectric` for ``c`` = cos θ_i already in [0, 1] (arrays broadcasting against ``eta``, or
    scalars): the quotient of :func:`dielectric_parts`."""
    num, den = dielectric_parts(c, eta)
    return num / den


@jitable
def dielectric_parts(c, eta):
    """The exact dielectric Fresnel reflectance of :func:`dielectric` (Born & Wolf §1.5) as num / den, for
    c = cos θ_i in [0, 1]: with B = max(c + η cos θ_t, 1e-30), D = max(η c + cos θ_t, 1e-30),
    F = (r_s² + r_p²)/2 = ((c − η cos θ_t)² D² + (η c − cos θ_t)² B²) / (2 B² D²), clamped to [0, 1];
    (1, 1) under total internal reflection. A fraction so a lobe divides once."""
    s2t = (1.0 - c * c) * (1.0 / (eta * eta))
    ct = np.sqrt(np.maximum(1.0 - s2t, 0.0))
    a = c - eta * ct
    b = np.maximum(c + eta * ct, 1e-30)
    p = eta * c - ct
    d = np.maximum(eta * c + ct, 1e-30)
    b2 = b * b
    d2 = d * d
    den = 2.0 * b2 * d2
    num = np.minimum(np.maximum(a * a * d2 + p * p * b2, 0.0), den)
    tir = s2t >= 1.0
    return select(tir, 1.0, num), select(tir, 1.0, den)


def conductor(cos_theta, eta, k) -> np.ndarray:
    """Exact unpolarized Fresnel reflectance of a conductor with complex index η + i k.

    With s² = sin²θ, t = η² − k² − s², a²+b² = √(t² + 4η²k²), a = √((a²+b² + t)/2):

    R_s = (a²+b² + cos²θ − 2a cos θ) / (a²+b² + cos²θ + 2a cos θ),
    R_p = R_s · (cos²θ (a²+b²) + s⁴ − 2a cos θ s²) / (cos²θ (a²+b²) + s⁴ + 2a cos θ s²),
    F = (R_s + R_p) / 2.

    (Cook & Torrance 1982 appendix; the form of Mitsuba 3 ``fresnel_conductor`` and of
    S. Lagarde, "Memo on Fresnel equations", 2013.) η = 0, k = 1 gives F = 1. The formula is
    :func:`conductor_core`.
    """
    c, (eta, k) = _prep(cos_theta, eta, k)
    return conductor_core(c, eta, k)


@jitable
def conductor_core(c, eta, k):
    """:func:`conductor` for ``c`` = cos θ already in [0, 1] (arrays broadcasting against ``eta`` and ``k``, or
    scalars): the same formula (Cook & Torrance 1982 appendix), clamped to [0, 1]."""
    c2 = c * c
    s2 = 1.0 - c2
    t = eta * eta - k * k - s2
    ab = np.sqrt(t * t + 4.0 * eta * eta * k * k)
    a = np.sqrt(np.maximum(0.5 * (ab + t), 0.0))
    t1 = ab + c2
    t2 = 2.0 * c * a
    rs = (t1 - t2) / np.maximum(t1 + t2, 1e-30)
    t3 = ab * c2 + s2 * s2
    t4 = t2 * s2
    rp = rs * (t3 - t4) / np.maximum(t3 + t4, 1e-30)
    return np.minimum(np.maximum(0.5 * (rs + rp), 0.0), 1.0)


#: Lowest normal-incidence reflectance of the model's conductor: a metal's at every visible wavelength is above it
#: (Palik 1985: silver, aluminium, chrome, nickel, iron, copper alloys in red and green), a dielectric's below 0.1.
METAL_F0_MIN = 0.5
#: Highest normal-incidence reflectance a fitted conductor takes: F(0) = 1 is a perfect conductor, whose index
#: :func:`gulbrandsen_index` does not reach (η → 0 or ∞); at 0.99, η ∈ [0.005, 400] and k ≤ 200.
F0_MAX = 0.99


def gulbrandsen_index(r, g):
    """The complex index η + i k of a conductor with normal-incidence reflectance ``r`` and edge tint ``g`` (O.
    Gulbrandsen, "Artist Friendly Metallic Fresnel", JCGT 3(4), 2014, eqs. 3–4):

    η = g (1 − r)/(1 + r) + (1 − g)(1 + √r)/(1 − √r),   k = √((r (η + 1)² − (η − 1)²)/(1 − r)).

    Every (r, g) in [0, 1) × [0, 1] is a valid index with F(0) = r exactly (:func:`conductor`); g = 0 is the
    dielectric of that F(0) (k = 0, its F dips before grazing), g = 1 the lowest η (F rises soonest towards 1): a fit
    searched over r ≥ :data:`METAL_F0_MIN` is searched over metals only. Arrays or scalars. ``(eta, k)``."""
    r = np.asarray(r, dtype=np.float64)
    g = np.asarray(g, dtype=np.float64)
    sr = np.sqrt(r)
    eta = g * (1.0 - r) / (1.0 + r) + (1.0 - g) * (1.0 + sr) / (1.0 - sr)
    k = np.sqrt(np.maximum(r * (eta + 1.0) ** 2 - (eta - 1.0) ** 2, 0.0) / (1.0 - r))
    return eta, k
