"""Lit spheres: how a material looks under a few lights (the lecture notes' "Lambertian sphere at several
lighting angles" and "Phong examples", lecture notes ``000_b5f942c329dc4daf.txt`` and
``004_6b0fa14dcb48ed2f.txt``).

An orthographic camera looks at a sphere along −z (the viewer is at +z). Each pixel inside the disc is a
surface point with normal n; its local shading frame has z = n (:func:`gonio.geometry.frame_from_normal`).
The radiance toward the viewer is the reflection equation summed over point-like lights (lecture notes
004, "The BRDF"; pbrt-v4 §4.3 and §12):

    L(x → v) = L_a(x) + Σ_l f(ω_l, v) E_l(x),     E_l = e_l · max(0, n · ω_l)

with ω_l the direction to light l and e_l its normal irradiance (:mod:`gonio.lights`: point,
directional and spot lights with their distance and cone falloff). The ambient term L_a = a · π f(n, v)
is the radiance reflected under a uniform ambient radiance a *for a Lambertian surface* (exact there,
an approximation otherwise — the lecture notes' k_a c_a). Pixels outside the disc are 0 and flagged
in the mask. The BRDF is anything with ``eval(wi, wo)`` in the local frame — a :mod:`gonio.brdf`
model, a :class:`gonio.io.source.Measured` — or ``lookup(wi, wo)`` (a MERL table); values that are not
finite (cells never measured) render as 0 and are counted in :attr:`Render.missing`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable

import numpy as np

from gonio.errors import ConfigError
from gonio.geometry import frame_from_normal, to_local
from gonio.lights import DirectionalLight, Light

__all__ = ["Render", "render_sphere", "sphere_points", "tonemap", "light_from_angles", "png_bytes", "white_point"]


@dataclass(frozen=True)
class Render:
    """A rendered sphere: ``radiance`` (size, size, 3) in the lights' units × 1/sr, ``mask`` (size, size)
    of pixels on the sphere, and ``missing``: pixels whose BRDF value was not finite (rendered as 0).

    In a notebook it displays itself (``_repr_png_``: :meth:`to_srgb` with the default white, the
    pixels off the sphere transparent); :meth:`save` writes the same PNG."""

    radiance: np.ndarray
    mask: np.ndarray
    missing: int = 0

    def to_srgb(self, white: float | None = None) -> np.ndarray:
        """The 8-bit sRGB image (:func:`tonemap`)."""
        return tonemap(self.radiance, white=white)

    def png(self, white: float | None = None) -> bytes:
        """PNG bytes of :meth:`to_srgb`, transparent off the sphere."""
        return png_bytes(self.to_srgb(white), self.mask)

    def save(self, path, white: float | None = None):
        """Write :meth:`png` to ``path`` (a ``.png`` file); returns the path."""
        from pathlib import Path

        path = Path(path)
        if path.suffix.lower() != ".png":
            raise ConfigError.field(None, "path", str(path), "a rendered sphere is written as .png")
        path.write_bytes(self.png(white))
        return path

    def _repr_png_(self) -> bytes:
        return self.png()


def png_bytes(img: np.ndarray, mask: np.ndarray | None = None) -> bytes:
    """An 8-bit RGB image as PNG bytes; with ``mask``, RGBA with the pixels off the sphere transparent."""
    import cv2

    bgr = img[..., ::-1]
    if mask is not None:
        bgr = np.concatenate([bgr, np.where(mask, 255, 0).astype(np.uint8)[..., None]], axis=-1)
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(bgr))
    if not ok:
        raise RuntimeError("PNG encoding failed")
    return buf.tobytes()


def sphere_points(size: int) -> tuple[np.ndarray, np.ndarray]:
    """``(mask, normals)`` of an orthographic unit sphere filling a ``size`` × ``size`` image: pixel
    centres mapped to x, y ∈ (−1, 1) (row 0 at the top, y up), n = (x, y, √(1 − x² − y²))."""
    if isinstance(size, bool) or not isinstance(size, (int, np.integer)) or not 8 <= size <= 4096:
        raise ConfigError.field(None, "size", size, "must be an integer in [8, 4096] pixels")
    c = (np.arange(size) + 0.5) / size * 2.0 - 1.0
    x, y = np.meshgrid(c, -c)
    r2 = x * x + y * y
    mask = r2 < 1.0
    z = np.sqrt(np.clip(1.0 - r2, 0.0, None))
    return mask, np.stack([x, y, z], axis=-1)


def light_from_angles(theta_deg: float, phi_deg: float = 0.0, irradiance=1.0) -> DirectionalLight:
    """A directional light arriving from polar angle θ (from the view axis +z) and azimuth φ (from +x
    toward +y), degrees: the "light at several angles" of the lecture notes."""
    t, p = np.radians(theta_deg), np.radians(phi_deg)
    to_light = np.array([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)])
    return DirectionalLight(-to_light, irradiance)


def _evaluate(brdf, wi, wo) -> np.ndarray:
    if hasattr(brdf, "eval"):
        return np.asarray(brdf.eval(wi, wo), dtype=np.float64)
    if hasattr(brdf, "lookup"):
        return np.asarray(brdf.lookup(wi, wo), dtype=np.float64)
    raise TypeError(f"{type(brdf).__name__} has neither eval(wi, wo) nor lookup(wi, wo)")


def render_sphere(brdf, lights: Iterable[Light], *, size: int = 128, ambient=0.0, radius: float = 0.05) -> Render:
    """Render ``brdf`` on a sphere of ``radius`` metres at the origin under ``lights`` (module
    docstring); vectorized over all pixels and lights."""
    lights = list(lights)
    mask, normals = sphere_points(size)
    n = normals[mask]
    points = radius * n
    frame = frame_from_normal(n)
    view = np.broadcast_to(np.array([0.0, 0.0, 1.0]), n.shape)
    wo = to_local(view, frame)
    out = np.zeros(n.shape[:-1] + (3,))
    bad = np.zeros(n.shape[0], dtype=bool)
    if lights:
        dirs, irr = zip(*(light.illuminate(points, n) for light in lights))
        wi = to_local(np.stack(dirs), frame[None])  # (lights, pixels, 3)
        f = _evaluate(brdf, wi, np.broadcast_to(wo, wi.shape))
        e = np.stack(irr)
        lit = e > 0
        contrib = np.where(lit, f * e, 0.0)
        bad |= np.any(~np.isfinite(contrib), axis=(0, 2))
        out += np.nansum(np.where(np.isfinite(contrib), contrib, 0.0), axis=0)
    a = np.asarray(ambient, dtype=np.float64)
    if np.any(a != 0):
        up = np.broadcast_to(np.array([0.0, 0.0, 1.0]), wo.shape)  # the normal, in every pixel's local frame
        amb = np.pi * _evaluate(brdf, up, wo) * a
        bad |= np.any(~np.isfinite(amb), axis=-1)
        out += np.where(np.isfinite(amb), amb, 0.0)
    image = np.zeros((size, size, 3))
    image[mask] = out
    return Render(image, mask, int(bad.sum()))


def white_point(radiance: np.ndarray) -> float:
    """The radiance :func:`tonemap` maps to white by default: the 99.5th percentile of the lit pixels'
    values (1 when nothing is lit). Images meant to be compared are tonemapped with the same one."""
    r = np.asarray(radiance, dtype=np.float64)
    lit = r[np.any(r > 0, axis=-1)]
    return float(np.percentile(lit, 99.5)) if lit.size else 1.0


def tonemap(radiance: np.ndarray, *, white: float | None = None) -> np.ndarray:
    """An 8-bit sRGB image for display: ``radiance / white`` (default: the 99.5th percentile of the
    lit pixels, so a specular highlight may clip), clipped to [0, 1], sRGB transfer function (IEC
    61966-2-1), rounded."""
    r = np.asarray(radiance, dtype=np.float64)
    if white is None:
        white = white_point(r)
    x = np.clip(r / max(white, 1e-300), 0.0, 1.0)
    srgb = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return np.rint(srgb * 255.0).astype(np.uint8)

