"""Directions, frames and angle parametrizations (docs/architecture.md §3). Pure, vectorized over ``(..., 3)``.

Conventions
-----------
Local frame: z = surface normal, x = the sample's reference direction, y = z × x.
Spherical angles: θ from +z, φ from +x toward +y; ``(sinθ cosφ, sinθ sinφ, cosθ)``; radians.
``wi`` points from the surface toward the light, ``wo`` toward the camera.

Every function returns a defined, documented value at its singular points (the pole, where φ is
undefined; ``wi = -wo``, where there is no half vector; zero-length input) instead of NaN.
"""

from __future__ import annotations

import numpy as np

from gonio._jit import jitable, select
from gonio.errors import ConfigError

__all__ = [
    "Z",
    "normalize",
    "dot",
    "from_spherical",
    "to_spherical",
    "reflect",
    "half_vector",
    "half_vector_xyz",
    "orthonormal_basis",
    "frame_from_normal",
    "to_local",
    "to_world",
    "rotate_y",
    "rotate_z",
    "half_diff_from_dirs",
    "dirs_from_half_diff",
    "dirs_from_angles",
    "angles_from_dirs",
    "transform_normals",
]

#: The surface normal of the local frame.
Z = np.array([0.0, 0.0, 1.0])


def _vec(v) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    if v.shape[-1:] != (3,):
        raise ValueError(f"expected vectors of shape (..., 3), got shape {v.shape}")
    return v


def dot(a, b) -> np.ndarray:
    """Dot product over the last axis, broadcasting: ``sum(a * b, axis=-1)``."""
    return np.einsum("...i,...i->...", *np.broadcast_arrays(_vec(a), _vec(b)))


def normalize(v, fallback=Z) -> np.ndarray:
    """Unit vectors along ``v``.

    Vectors of zero (or sub-normal) length have no direction; they map to ``fallback``
    (default +z, the surface normal) instead of NaN.

    The length is ``np.linalg.norm(v, axis=-1)``'s, ``√((x² + y²) + z²)``, computed on the components
    (numpy sums a last axis of three in that order: the same numbers, without its slow reduction over
    a short axis); vectors all of usable length skip the fallback's selection.
    """
    v = _vec(v)
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    n = np.sqrt((x * x + y * y) + z * z)[..., None]
    ok = n > 1e-300
    with np.errstate(invalid="ignore", divide="ignore"):
        if ok.all():
            return v / n
        u = v / np.where(ok, n, 1.0)
    return np.where(ok, u, np.broadcast_to(_vec(fallback), v.shape))


def from_spherical(theta, phi) -> np.ndarray:
    """Unit vectors ``(sinθ cosφ, sinθ sinφ, cosθ)`` for angles in radians; shape ``(..., 3)``."""
    theta = np.asarray(theta, dtype=np.float64)
    phi = np.asarray(phi, dtype=np.float64)
    s = np.sin(theta)
    return np.stack(np.broadcast_arrays(s * np.cos(phi), s * np.sin(phi), np.cos(theta)), axis=-1)


def to_spherical(v) -> tuple[np.ndarray, np.ndarray]:
    """Angles ``(θ, φ)`` of vectors ``v`` (need not be unit length).

    θ = atan2(√(x²+y²), z) ∈ [0, π] (accurate near the pole, unlike ``arccos(z)``);
    φ = atan2(y, x) wrapped to [0, 2π). At the pole (x = y = 0) φ is undefined and returned as 0.
    """
    v = _vec(v)
    return _spherical_xyz(v[..., 0], v[..., 1], v[..., 2])


def _spherical_xyz(x, y, z) -> tuple[np.ndarray, np.ndarray]:
    """:func:`to_spherical` of the vectors with components ``x``, ``y``, ``z``."""
    theta = np.arctan2(np.hypot(x, y), z)
    phi = np.mod(np.arctan2(y, x), 2.0 * np.pi)
    # mod can return exactly 2π for tiny negative angles; keep the half-open interval.
    phi = np.where(phi >= 2.0 * np.pi, 0.0, phi)
    return theta, phi


def reflect(v, n=Z) -> np.ndarray:
    """Mirror direction of ``v`` about the normal ``n``: ``R = 2(v·n)n − v``.

    Reference: lecture notes ``000_b5f942c329dc4daf.txt`` ("Law of Reflection").
    ``v`` points away from the surface (as ``wi`` does) and so does the result.
    """
    v = _vec(v)
    n = _vec(n)
    return 2.0 * dot(v, n)[..., None] * n - v


def half_vector(wi, wo) -> np.ndarray:
    """Half vector ``h = normalize(wi + wo)`` (Blinn 1977; lecture notes 000).

    For ``wi = -wo`` there is no half vector; the function returns the surface normal +z
    (where θh = 0, a value every model in :mod:`gonio.brdf` treats as finite). Keeps a float32
    input float32 (the models' float32 evaluation path); anything else is computed in float64.
    The formula is :func:`half_vector_xyz`.
    """
    wi, wo = np.asarray(wi), np.asarray(wo)
    if wi.dtype != np.float32 or wo.dtype != np.float32:
        wi, wo = _vec(wi), _vec(wo)
    elif wi.shape[-1:] != (3,) or wo.shape[-1:] != (3,):
        raise ValueError(f"expected vectors of shape (..., 3), got shapes {wi.shape} and {wo.shape}")
    wi, wo = np.broadcast_arrays(wi, wo)
    tiny = np.finfo(wi.dtype).tiny
    return np.stack(half_vector_xyz(wi[..., 0], wi[..., 1], wi[..., 2], wo[..., 0], wo[..., 1], wo[..., 2], tiny),
                    axis=-1)


@jitable
def half_vector_xyz(ix, iy, iz, ox, oy, oz, tiny):
    """Components ``(hx, hy, hz)`` of the half vector normalize(wi + wo) (Blinn 1977; lecture notes 000),
    from the components of wi and wo (arrays or scalars; ``tiny`` the smallest normal number of their
    dtype). Where |wi + wo|² ≤ 10⁶·tiny (wi = −wo) the result is the normal (0, 0, 1)."""
    sx = ix + ox
    sy = iy + oy
    sz = iz + oz
    n2 = sx * sx + sy * sy + sz * sz
    ok = n2 > tiny * 1e6
    inv = 1.0 / np.sqrt(select(ok, n2, 1.0))
    return select(ok, sx * inv, 0.0), select(ok, sy * inv, 0.0), select(ok, sz * inv, 1.0)


def orthonormal_basis(n) -> tuple[np.ndarray, np.ndarray]:
    """Two unit tangents ``(t, b)`` with ``(t, b, n)`` right-handed and orthonormal.

    Branchless construction of Duff et al., "Building an Orthonormal Basis, Revisited",
    JCGT 6(1), 2017 — continuous except across n_z = 0⁻, and exact at the poles.
    """
    n = normalize(n)
    x, y, z = n[..., 0], n[..., 1], n[..., 2]
    sign = np.where(z >= 0.0, 1.0, -1.0)
    a = -1.0 / (sign + z)
    b = x * y * a
    t = np.stack([1.0 + sign * x * x * a, sign * b, -sign * x], axis=-1)
    bb = np.stack([b, sign + y * y * a, -y], axis=-1)
    return t, bb


def frame_from_normal(normal, tangent=None) -> np.ndarray:
    """Local frame matrices, shape ``(..., 3, 3)``, whose *rows* are the x, y, z axes in world space.

    z = normalized ``normal``; x = ``tangent`` made orthogonal to z by Gram–Schmidt; y = z × x.
    Without a tangent, or where the tangent is (anti)parallel to the normal, x comes from
    :func:`orthonormal_basis` so the frame is always defined.
    """
    z = normalize(normal)
    t_default, _ = orthonormal_basis(z)
    if tangent is None:
        x = t_default
    else:
        t = _vec(tangent)
        t = t - dot(t, z)[..., None] * z
        length = np.linalg.norm(t, axis=-1, keepdims=True)
        x = np.where(length > 1e-9, t / np.where(length > 1e-9, length, 1.0), t_default)
    x, z = np.broadcast_arrays(x, z)
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=-2)


def to_local(v, frame) -> np.ndarray:
    """Express world vectors ``v`` in the local frame (rows of ``frame`` are its axes)."""
    return np.einsum("...ij,...j->...i", np.asarray(frame, dtype=np.float64), _vec(v))


def to_world(v, frame) -> np.ndarray:
    """Inverse of :func:`to_local`: local vectors back to world space."""
    return np.einsum("...ji,...j->...i", np.asarray(frame, dtype=np.float64), _vec(v))


def rotate_z(v, angle) -> np.ndarray:
    """Rotate vectors by ``angle`` (radians, right-handed) about +z."""
    v = _vec(v)
    c, s = np.cos(angle), np.sin(angle)
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    return np.stack(np.broadcast_arrays(c * x - s * y, s * x + c * y, z), axis=-1)


def rotate_y(v, angle) -> np.ndarray:
    """Rotate vectors by ``angle`` (radians, right-handed) about +y."""
    v = _vec(v)
    c, s = np.cos(angle), np.sin(angle)
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    return np.stack(np.broadcast_arrays(c * x + s * z, y, -s * x + c * z), axis=-1)


def half_diff_from_dirs(wi, wo) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Rusinkiewicz half/difference angles ``(θh, φh, θd, φd)`` of direction pairs.

    h = normalize(wi + wo); the difference vector d is wi rotated by −φh about z, then by −θh
    about y (Rusinkiewicz, "A New Change of Variables for Efficient BRDF Representation",
    EGWR 1998; the rotation order of the MERL reference code, Matusik et al. 2003).

    Singular points: at θh = 0, φh is returned as 0 (:func:`to_spherical`); for wi = −wo,
    h is taken as +z (:func:`half_vector`), so θh = 0 and d = wi. Inputs need not be unit vectors.
    """
    wi, wo = np.broadcast_arrays(normalize(wi), normalize(wo))
    ix, iy, iz = wi[..., 0], wi[..., 1], wi[..., 2]
    theta_h, phi_h = _spherical_xyz(*half_vector_xyz(ix, iy, iz, wo[..., 0], wo[..., 1], wo[..., 2],
                                                     np.finfo(np.float64).tiny))
    # d = rotate_y(rotate_z(wi, −φh), −θh), component by component (the same operations, without the (..., 3)
    # arrays of each rotation: ~25 % less time on a MERL table's 9·10⁵ pairs)
    c, s = np.cos(-phi_h), np.sin(-phi_h)
    x1, y1 = c * ix - s * iy, s * ix + c * iy
    c, s = np.cos(-theta_h), np.sin(-theta_h)
    theta_d, phi_d = _spherical_xyz(c * x1 + s * iz, y1, -s * x1 + c * iz)
    return theta_h, phi_h, theta_d, phi_d


def dirs_from_half_diff(theta_h, phi_h, theta_d, phi_d) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of :func:`half_diff_from_dirs`: ``(wi, wo)`` from ``(θh, φh, θd, φd)``.

    wi = R_z(φh) R_y(θh) d with d = (θd, φd) in spherical form; wo = 2(wi·h)h − wi.
    Directions may fall below the horizon (cos θ < 0) for large θh + θd; callers that need the
    upper hemisphere check ``wi[..., 2] > 0``.
    """
    d = from_spherical(theta_d, phi_d)
    h = from_spherical(theta_h, phi_h)
    wi = rotate_z(rotate_y(d, theta_h), phi_h)
    wo = reflect(wi, h)
    return wi, wo


def dirs_from_angles(theta_i, phi_i, theta_o, phi_o) -> tuple[np.ndarray, np.ndarray]:
    """``(wi, wo)`` from the four BRDF angles (radians)."""
    return from_spherical(theta_i, phi_i), from_spherical(theta_o, phi_o)


def angles_from_dirs(wi, wo) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The four BRDF angles ``(θi, φi, θo, φo)`` of direction pairs (radians)."""
    ti, pi_ = to_spherical(wi)
    to, po = to_spherical(wo)
    return ti, pi_, to, po


def transform_normals(matrix, normals) -> np.ndarray:
    """Transform surface normals by an affine map: multiply by the inverse-transpose, renormalize.

    Under a non-uniform scale, normals transformed like points stop being perpendicular to the
    surface; the inverse-transpose of the linear part keeps them perpendicular (lecture notes 000,
    "Note on normals and spaces"). ``matrix`` is 3×3, or 4×4 homogeneous (its upper-left 3×3 is
    used; translation does not affect normals). A matrix of another shape, with NaN/inf, or singular
    raises :class:`gonio.errors.ConfigError` (such matrices come from configuration: a sample mount).
    """
    m = np.asarray(matrix, dtype=np.float64)
    if m.shape in ((4, 4),):
        m = m[:3, :3]
    if m.shape != (3, 3):
        raise ConfigError.field(None, "normal transform", f"shape {m.shape}", "needs a 3x3 or 4x4 matrix")
    if not np.all(np.isfinite(m)):
        raise ConfigError.field(None, "normal transform", m.tolist(), "has non-finite entries")
    if abs(np.linalg.det(m)) < 1e-300:
        raise ConfigError.field(None, "normal transform", m.tolist(), "the matrix is singular (no inverse-transpose)")
    inv_t = np.linalg.inv(m).T
    return normalize(np.einsum("ij,...j->...i", inv_t, _vec(normals)))
