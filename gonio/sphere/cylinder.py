"""A cylinder coated with the material (image-based acquisition, issue 30): one frame holds every normal around its
axis, and — unlike a sphere — a direction on the surface that stays the same everywhere, the axis, so an
*anisotropic* material's slices (the half vector's azimuth φh from the axis) are measured too (Ngan et al. 2005,
"Experimental analysis of BRDF models", EGSR, measured anisotropic materials on cylinders: one strip of the
material's orientation per frame).

Frames as :mod:`gonio.sphere.geometry`: the sample frame, board in z = 0. A cylinder of radius ``r`` and length
``length`` with axis unit vector ``a`` through ``centre`` P (a cylinder lying on the board has a horizontal axis and
``P_z = r``). Every formula is closed form:

* the ray ``C + t d`` meets the infinite cylinder where ``A t² + 2 B t + c = 0`` with ``d⊥ = d − (d·a) a``,
  ``w⊥ = (C − P) − ((C − P)·a) a``: ``A = d⊥·d⊥``, ``B = d⊥·w⊥``, ``c = w⊥·w⊥ − r²``; the nearer root
  ``t = (−B − √(B² − A c)) / A`` is on the cylinder when ``|(C + t d − P)·a| ≤ length/2`` (a hit beyond an end is
  counted as a miss: the end caps are not part of the sample);
* the outward normal at X is ``(X − P)⊥ / r``, ⊥ the component across the axis;
* the local frame is (t, b, n) with ``t = a`` (the axis is across every normal), ``b = n × t``: φ is measured from
  the axis (the material's orientation when its grooves or fibres run along the cylinder).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from gonio.errors import ConfigError

__all__ = ["Cylinder", "cylinder_from_table", "check_on_board"]


@dataclass(frozen=True)
class Cylinder:
    """A cylinder: ``centre`` (3,) on its axis at mid-length, unit ``axis`` (3,), ``radius`` and ``length`` (m)."""

    centre: tuple[float, float, float]
    axis: tuple[float, float, float]
    radius: float
    length: float

    def __post_init__(self):
        c = np.asarray(self.centre, dtype=np.float64)
        if c.shape != (3,) or not np.all(np.isfinite(c)):
            raise ConfigError.field(None, "cylinder.centre", self.centre, "expected three finite numbers (metres)")
        a = np.asarray(self.axis, dtype=np.float64)
        if a.shape != (3,) or not np.all(np.isfinite(a)) or not np.linalg.norm(a) > 1e-9:
            raise ConfigError.field(None, "cylinder.axis", self.axis, "expected a non-zero direction [x, y, z]")
        for name, lo, hi in (("radius", 1e-4, 1.0), ("length", 1e-4, 2.0)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not (lo <= v <= hi):
                raise ConfigError.field(None, f"cylinder.{name}", v, f"expected metres in [{lo:g}, {hi:g}]")
        object.__setattr__(self, "centre", tuple(float(x) for x in c))
        object.__setattr__(self, "axis", tuple(float(x) for x in a / np.linalg.norm(a)))
        object.__setattr__(self, "radius", float(self.radius))
        object.__setattr__(self, "length", float(self.length))

    @property
    def P(self) -> np.ndarray:
        return np.asarray(self.centre, dtype=np.float64)

    @property
    def a(self) -> np.ndarray:
        return np.asarray(self.axis, dtype=np.float64)

    def _across(self, v) -> np.ndarray:
        v = np.asarray(v, dtype=np.float64)
        return v - np.einsum("...i,i->...", v, self.a)[..., None] * self.a

    def intersect(self, origin, dirs) -> tuple[np.ndarray, np.ndarray]:
        """``(t, hit)`` of unit rays ``origin + t·dirs`` (origins (3,) or one per ray; see the module docstring),
        NaN where they miss."""
        d = np.asarray(dirs, dtype=np.float64)
        w = np.asarray(origin, dtype=np.float64) - self.P
        dp, wp = self._across(d), self._across(w)
        A = np.einsum("...i,...i->...", dp, dp)
        B = np.einsum("...i,...i->...", dp, wp)
        c = np.einsum("...i,...i->...", wp, wp) - self.radius ** 2
        disc = B * B - A * c
        hit = (disc >= 0.0) & (A > 1e-300)
        with np.errstate(invalid="ignore", divide="ignore"):
            t = (-B - np.sqrt(np.where(hit, disc, np.nan))) / np.where(hit, A, 1.0)
            along = np.einsum("...i,i->...", w + t[..., None] * d, self.a)
            hit &= (t > 0.0) & (np.abs(along) <= 0.5 * self.length)
        return np.where(hit, t, np.nan), hit

    def normal(self, points) -> np.ndarray:
        """Outward unit normals ``(X − P)⊥ / r`` at points on the cylinder (``(..., 3)``)."""
        return self._across(np.asarray(points, dtype=np.float64) - self.P) / self.radius

    def frames(self, points, n) -> np.ndarray:
        """Per-point frames (..., 3, 3), rows (t = axis, b = n × t, n)."""
        n = np.asarray(n, dtype=np.float64)
        t = np.broadcast_to(self.a, n.shape)
        t = t - np.einsum("...i,...i->...", t, n)[..., None] * n  # exact orthogonality against rounding
        t = t / np.linalg.norm(t, axis=-1, keepdims=True)
        return np.stack([t, np.cross(n, t), n], axis=-2)

    def corners(self) -> np.ndarray:
        """(8, 3): the corners of a box holding the cylinder."""
        a = self.a
        u = np.cross(a, [0.0, 0.0, 1.0])
        if np.linalg.norm(u) < 1e-6:
            u = np.cross(a, [1.0, 0.0, 0.0])
        u /= np.linalg.norm(u)
        v = np.cross(a, u)
        h, r = 0.5 * self.length, self.radius
        return np.array([self.P + i * h * a + j * r * u + k * r * v for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)])

    def grown(self, by: float) -> "Cylinder":
        """The same cylinder ``by`` metres larger in radius and at each end."""
        return Cylinder(self.centre, self.axis, self.radius + by, self.length + 2 * by)

    def silhouette_angle(self, eye) -> float:
        """Half-angle (rad) the cylinder's cross-section subtends from ``eye``: ``asin(r/d⊥)``."""
        d = float(np.linalg.norm(self._across(np.asarray(eye, dtype=np.float64) - self.P)))
        if d <= self.radius:
            raise ConfigError.field(None, "cylinder", self.centre, f"the camera at {d:.4g} m from the axis is inside it")
        return math.asin(self.radius / d)


def cylinder_from_table(v, number) -> Cylinder:
    """The target file's ``[cylinder]`` table: ``radius`` and ``length`` (metres, required), ``axis`` ([x, y, z],
    default [1, 0, 0]: along the board's x) and ``centre`` ([x, y, z] m, default ``[0, 0, radius]``: lying on the
    board's centre); ``number(field, value)`` checks one number. Errors name ``cylinder.<key>`` and the value."""
    keys = ("radius", "length", "axis", "centre")
    if not isinstance(v, dict):
        raise ConfigError.field(None, "cylinder", v, "needs a table: radius, length (m), axis = [x, y, z], centre")
    unknown = sorted(set(v) - set(keys))
    if unknown:
        raise ConfigError.field(None, f"cylinder.{unknown[0]}", v[unknown[0]], f"unknown key ({', '.join(keys)})")
    for k in ("radius", "length"):
        if k not in v:
            raise ConfigError.field(None, f"cylinder.{k}", None, "is required (metres)")
    r = number("cylinder.radius", v["radius"])
    length = number("cylinder.length", v["length"])
    vec = {}
    for k, default in (("axis", [1.0, 0.0, 0.0]), ("centre", [0.0, 0.0, r])):
        x = v.get(k, default)
        if not (isinstance(x, (list, tuple)) and len(x) == 3):
            raise ConfigError.field(None, f"cylinder.{k}", x, "needs [x, y, z]")
        vec[k] = tuple(number(f"cylinder.{k}.{c}", e) for c, e in zip("xyz", x))
    return Cylinder(vec["centre"], vec["axis"], r, length)


def check_on_board(cyl: Cylinder, board, white) -> None:
    """One line naming ``cylinder.<field>`` unless the cylinder lies on the board (axis horizontal, centre at the
    height of its radius), within it, off the white patch."""
    if abs(cyl.a[2]) > 1e-6:
        raise ConfigError.field(None, "cylinder.axis", list(cyl.axis), "must be horizontal: the cylinder lies on the "
                                "board")
    if abs(cyl.centre[2] - cyl.radius) > 1e-9:
        raise ConfigError.field(None, "cylinder.centre", list(cyl.centre),
                                f"z must be the radius {cyl.radius:g} m: the cylinder lies on the board")
    xy = cyl.corners()[:, :2]
    if not all(board.contains(x, y) for x, y in xy):
        raise ConfigError.field(None, "cylinder.centre", list(cyl.centre), "the cylinder must lie on the board")
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    if lo[0] < white.x1 and hi[0] > white.x0 and lo[1] < white.y1 and hi[1] > white.y0:
        raise ConfigError.field(None, "cylinder.centre", list(cyl.centre), "the cylinder lies on the white patch")
