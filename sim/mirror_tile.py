"""A glossy black tile (or a front-surface mirror) on the sample stage: what the camera sees of the light
in it, for the geometric calibration's light-arm observations (``gonio calibrate rig``, issue 15).

The tile is a flat specular reflector lying in the sample plane z = 0 over :attr:`CalibrationTile.rect`
(sample frame), replacing the sample patch. Its diffuse part is a dark Lambertian albedo
(:attr:`CalibrationTile.diffuse`); its specular part reflects the light's *emitting disc* — a Lambertian
disc of radius :attr:`CalibrationTile.light_radius` centred on the light position and facing the sample
centre, of radiance ``L_e = I / (π r_e²)`` so that its intensity along its axis is the point light's ``I``
(radiant intensity of a Lambertian disc: ``I = L A``; lecture notes 004, "radiometry"). A camera ray
``d`` meeting the tile at ``p`` is mirrored (``d' = d − 2 (d·n) n``, law of reflection) and, where it
meets the disc, carries ``F(cos θ) L_e`` with Schlick's Fresnel approximation
``F = f0 + (1 − f0)(1 − cos θ)⁵`` (Schlick 1994, "An inexpensive BRDF model for physically-based
rendering", eq. 15; lecture notes 000), ``f0`` ≈ 0.04 for black glass, ≈ 0.9 for an aluminium mirror.

The highlight is a few pixels wide, so it is rendered by supersampling (:data:`SUPERSAMPLE`² rays per
pixel, box filter = the pixel's area integration) inside the box around the projection of the light's
mirror image only; the rest of the tile is shaded at pixel centres. The result is written into the
camera's electron-rate image by :func:`shade_tile`, called by :meth:`sim.camera.SimCamera._render` in
place of the sample patch when the scene has a tile.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gonio.pipeline.target import Rect

__all__ = ["CalibrationTile", "shade_tile", "SUPERSAMPLE"]

#: Sub-pixel rays per pixel side in the highlight's box (8 × 8: the centroid's rendering error < 0.01 px).
SUPERSAMPLE = 8


@dataclass(frozen=True)
class CalibrationTile:
    """A flat specular tile on the sample stage (sample frame, metres); see the module docstring."""

    rect: Rect = Rect(-0.05, -0.05, 0.05, 0.05)
    f0: float = 0.04            # reflectance at normal incidence (black glass; ~0.9 for an Al mirror)
    diffuse: float = 0.01       # Lambertian albedo of the tile
    light_radius: float = 0.01  # radius of the light's emitting disc (m)


def _fresnel(f0: float, cos_t):
    return f0 + (1.0 - f0) * (1.0 - np.clip(cos_t, 0.0, 1.0)) ** 5


def _disc_radiance(tile: CalibrationTile, intensity: float, light, C, d):
    """Radiance reaching the camera along world rays ``d`` (..., 3) from ``C`` by reflection in the tile
    (0 where the ray misses the tile or its mirrored ray misses the light's disc)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -C[2] / d[..., 2]
    ok = np.isfinite(t) & (t > 0) & (d[..., 2] < 0)
    p = C + np.where(ok, t, 0.0)[..., None] * d
    ok &= tile.rect.contains(p[..., 0], p[..., 1])
    dm = d * np.array([1.0, 1.0, -1.0])              # mirrored in the plane z = 0
    n = -light / np.linalg.norm(light)               # the disc faces the sample centre
    dn = dm @ n
    with np.errstate(divide="ignore", invalid="ignore"):
        s = ((light - p) @ n) / dn
    q = p + np.where(np.isfinite(s), s, 0.0)[..., None] * dm
    hit = ok & np.isfinite(s) & (s > 0) & (dn < 0) & (np.sum((q - light) ** 2, axis=-1) <= tile.light_radius ** 2)
    cos_t = -d[..., 2] / np.linalg.norm(d, axis=-1)
    L_e = intensity / (np.pi * tile.light_radius ** 2)
    return np.where(hit, _fresnel(tile.f0, cos_t) * L_e, 0.0), ok


def shade_tile(camera, rate: np.ndarray, C: np.ndarray) -> None:
    """Overwrite ``rate`` (H, W, 3 electrons/s) where the camera sees the tile: its dark diffuse part under
    the point light, plus the supersampled reflection of the light's disc (module docstring)."""
    s = camera.scene
    tile: CalibrationTile = s.tile
    calib, pose = camera.calibration, camera._pose
    resp = np.asarray(camera.sensor.responsivity, dtype=np.float64)
    light = camera._light_pos
    box = camera._bbox(tile.rect.corners())
    if box is None:
        return
    d = camera._world_rays(box)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -C[2] / d[..., 2]
    ok = np.isfinite(t) & (t > 0) & (d[..., 2] < 0)
    p = C + np.where(ok, t, 0.0)[..., None] * d
    inside = ok & tile.rect.contains(p[..., 0], p[..., 1])
    if not inside.any():
        return
    to_light = light - p[inside]
    r2 = np.sum(to_light ** 2, axis=-1)
    irr = s.light_intensity * np.maximum(to_light[:, 2], 0.0) / r2 ** 1.5  # I cos θ / r²
    rate[box][inside] = (tile.diffuse / np.pi * irr[:, None] * resp).astype(np.float32)
    # the light's mirror image, and the pixel box its disc can cover
    image = light * np.array([1.0, 1.0, -1.0])
    if (pose.R @ image + pose.t)[2] <= 0:
        return
    dist = np.linalg.norm(image - C)
    r_px = calib.K[0, 0] * tile.light_radius / dist * 1.5 + 3.0
    u, v = pose.project(image, calib)
    c0, c1 = int(np.floor(u - r_px)), int(np.ceil(u + r_px)) + 1
    r0, r1 = int(np.floor(v - r_px)), int(np.ceil(v + r_px)) + 1
    c0, c1 = max(c0, 0), min(c1, calib.width)
    r0, r1 = max(r0, 0), min(r1, calib.height)
    if c1 <= c0 or r1 <= r0:
        return
    n = SUPERSAMPLE
    sub = (np.arange(n) + 0.5) / n - 0.5
    vv, uu = np.mgrid[r0:r1, c0:c1].astype(np.float64)
    us = (uu[..., None, None] + sub[None, None, None, :]) + 0.0 * sub[None, None, :, None]
    vs = (vv[..., None, None] + sub[None, None, :, None]) + 0.0 * sub[None, None, None, :]
    rays = calib.rays(us, vs) @ pose.R                 # world directions of the sub-pixel rays
    L, _ = _disc_radiance(tile, s.light_intensity, light, C, rays)
    spec = L.mean(axis=(-2, -1))
    region = rate[r0:r1, c0:c1]
    region += (spec[..., None] * resp).astype(np.float32)
