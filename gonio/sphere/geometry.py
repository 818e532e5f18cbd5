"""A spherical sample seen by a camera: which pixels see it, the surface normal each sees, and the BRDF directions
there (image-based acquisition: Marschner et al. 1999, "Image-based BRDF measurement including human skin",
EGWR; Matusik et al. 2003, "A data-driven reflectance model", SIGGRAPH — the MERL rig photographed spheres).

Frames: the sample (world) frame of gonio (docs/architecture.md §2): the board in z = 0, z up. A sphere of radius
``radius`` with centre ``centre`` (metres, in that frame; a ball resting on the board's centre has centre
``(0, 0, radius)``). Every formula is closed-form:

* ray ``C + t d`` (|d| = 1) meets the sphere where ``t² + 2 t b + c = 0``, ``b = d·(C − P)``,
  ``c = |C − P|² − r²``; the nearer root ``t = −b − √(b² − c)`` (the ray hits iff ``b² − c ≥ 0`` and ``t > 0``);
* the outward normal at ``X`` is ``(X − P)/r``;
* a point is lit iff ``n·(S − X) > 0`` (a convex sphere shadows only itself: no other occluder on it) and seen iff
  ``n·(C − X) > 0`` (true for every first hit);
* for an isotropic BRDF the Rusinkiewicz angles (θh, θd, φd) do not depend on the tangent chosen at ``n``
  (a rotation about n changes φh only), so no tangent field is needed to bin the samples.

The *silhouette* is where θo → 90°: there a pixel's footprint spans a large range of normals and the pixel mixes
sphere and background; the *terminator* is θi → 90°. Both are rejected at ``grazing_deg``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from gonio.errors import ConfigError

__all__ = ["Sphere", "ray_sphere", "SphereHits", "sphere_hits"]


@dataclass(frozen=True)
class Sphere:
    """A sphere: ``centre`` (3,) and ``radius`` in metres, in the sample frame."""

    centre: tuple[float, float, float]
    radius: float

    def __post_init__(self):
        c = np.asarray(self.centre, dtype=np.float64)
        if c.shape != (3,) or not np.all(np.isfinite(c)):
            raise ConfigError.field(None, "sphere.centre", self.centre, "expected three finite numbers (metres)")
        r = self.radius
        if isinstance(r, bool) or not isinstance(r, (int, float)) or not (1e-4 <= r <= 1.0):
            raise ConfigError.field(None, "sphere.radius", r, "expected metres in [1e-4, 1]")
        object.__setattr__(self, "centre", tuple(float(x) for x in c))
        object.__setattr__(self, "radius", float(r))

    @property
    def P(self) -> np.ndarray:
        return np.asarray(self.centre, dtype=np.float64)

    def normal(self, points) -> np.ndarray:
        """Outward unit normals ``(X − P)/r`` at points on the sphere (``(..., 3)``)."""
        return (np.asarray(points, dtype=np.float64) - self.P) / self.radius

    def intersect(self, origin, dirs) -> tuple[np.ndarray, np.ndarray]:
        """``(t, hit)`` of unit rays ``origin + t·dirs`` (origins (3,) or one per ray): the nearer root of the module
        docstring's quadratic, NaN where the ray misses."""
        d = np.asarray(dirs, dtype=np.float64)
        oc = np.asarray(origin, dtype=np.float64) - self.P
        b = np.einsum("...i,...i->...", d, oc)
        c = np.einsum("...i,...i->...", oc, oc) - self.radius ** 2
        disc = b * b - c
        hit = disc >= 0.0
        with np.errstate(invalid="ignore"):
            t = -b - np.sqrt(np.where(hit, disc, np.nan))
        hit &= t > 0.0
        return np.where(hit, t, np.nan), hit

    def frames(self, points, n) -> np.ndarray:
        """Per-point frames (..., 3, 3), rows (t, b, n): any tangent serves an isotropic BRDF (:func:`_local`)."""
        return _local(n)

    def corners(self) -> np.ndarray:
        """(8, 3): the corners of a box holding the sphere."""
        return self.P + self.radius * np.array([[a, b, c] for a in (-1, 1) for b in (-1, 1) for c in (-1, 1)], float)

    def grown(self, by: float) -> "Sphere":
        """The same sphere ``by`` metres larger in radius."""
        return Sphere(self.centre, self.radius + by)

    def silhouette_angle(self, eye) -> float:
        """Half-angle (rad) of the cone the sphere subtends from ``eye``: ``asin(r/|C − P|)``."""
        d = float(np.linalg.norm(np.asarray(eye, dtype=np.float64) - self.P))
        if d <= self.radius:
            raise ConfigError.field(None, "sphere", self.centre, f"the camera at {d:.4g} m from the centre is inside it")
        return math.asin(self.radius / d)


def ray_sphere(origin, dirs, sphere: Sphere) -> tuple[np.ndarray, np.ndarray]:
    """Distance ``t`` along unit rays ``origin + t·dirs`` to their first hit of ``sphere`` (or any curved target with
    an ``intersect`` method, :class:`gonio.sphere.cylinder.Cylinder`) and whether they hit (``t`` is NaN where they
    miss). Vectorized over ``dirs`` (..., 3); ``origin`` (3,) or one per ray."""
    return sphere.intersect(origin, dirs)


@dataclass(frozen=True)
class SphereHits:
    """Per hit ray: the point ``x``, the unit normal ``n``, the unit directions to the light ``wi`` and to the
    camera ``wo`` (world frame), the cosines ``cos_i = n·wi``, ``cos_o = n·wo``, the light distance² ``r2``, and
    the Rusinkiewicz angles (θh, θd, φd) of (wi, wo) about ``n``."""

    x: np.ndarray
    n: np.ndarray
    wi: np.ndarray
    wo: np.ndarray
    cos_i: np.ndarray
    cos_o: np.ndarray
    r2: np.ndarray
    theta_h: np.ndarray
    theta_d: np.ndarray
    phi_d: np.ndarray
    wi_local: np.ndarray = None  #: wi in the per-normal frame (t, b, n) of the target's ``frames``
    wo_local: np.ndarray = None
    phi_h: np.ndarray = None  #: the half vector's azimuth from the tangent t (a cylinder: from its axis)


def _local(n: np.ndarray) -> np.ndarray:
    """Per-normal orthonormal frames (..., 3, 3), rows (t, b, n): Duff et al. 2017 ("Building an orthonormal
    basis, revisited", JCGT 6(1)) branchless construction; any tangent serves an isotropic BRDF."""
    sign = np.where(n[..., 2] >= 0.0, 1.0, -1.0)
    a = -1.0 / (sign + n[..., 2])
    b = n[..., 0] * n[..., 1] * a
    t = np.stack([1.0 + sign * n[..., 0] ** 2 * a, sign * b, -sign * n[..., 0]], axis=-1)
    bb = np.stack([b, sign + n[..., 1] ** 2 * a, -n[..., 1]], axis=-1)
    return np.stack([t, bb, n], axis=-2)


def sphere_hits(eye, dirs, sphere: Sphere, light) -> tuple[SphereHits, np.ndarray]:
    """The sphere as the rays ``dirs`` (..., 3, unit) from ``eye`` see it, lit by a point light at ``light``:
    ``(SphereHits of the hit rays, hit mask of dirs' shape)``."""
    from gonio.geometry import half_diff_from_dirs

    eye = np.asarray(eye, dtype=np.float64)
    S = np.asarray(light, dtype=np.float64)
    t, hit = ray_sphere(eye, dirs, sphere)
    d = np.asarray(dirs, dtype=np.float64)[hit]
    x = eye + t[hit][:, None] * d
    n = sphere.normal(x)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    to_light = S - x
    r2 = np.einsum("ij,ij->i", to_light, to_light)
    wi = to_light / np.sqrt(r2)[:, None]
    wo = -d
    frame = sphere.frames(x, n)
    wi_l = np.einsum("nij,nj->ni", frame, wi)
    wo_l = np.einsum("nij,nj->ni", frame, wo)
    th, ph, td, pd = half_diff_from_dirs(wi_l, wo_l)
    return SphereHits(x=x, n=n, wi=wi, wo=wo, cos_i=wi_l[:, 2], cos_o=wo_l[:, 2], r2=r2, theta_h=th,
                      theta_d=td, phi_d=pd, wi_local=wi_l, wo_local=wo_l, phi_h=ph), hit
