"""The simulated camera's view of a sphere coated with the material (image-based acquisition, issue 30).

Per pixel in the sphere's projected box, ``n × n`` rays through the pixel (``SimScene.sphere_supersample``; a
box filter over the pixel, the sensor's fill factor taken as 1) are traced to the sphere
(:func:`gonio.sphere.geometry.sphere_hits`): each hit contributes ``f(wi, wo) · I (n·wi) / r²`` (lecture notes 004,
point light), each miss the board's rate at that pixel; the pixel's rate is their mean — so a highlight smaller
than a pixel is integrated over the pixel's footprint of normals, as a real camera integrates it, not sampled at
the pixel centre. The BRDF is evaluated in a per-normal frame (Duff et al. 2017's tangent: irrelevant for an
isotropic material; a cylinder's frame has its tangent along the axis, so an anisotropic material is rendered
in its orientation, :mod:`gonio.sphere.cylinder`). The sphere's shadow on the board (the white reference included) is cast: a board point whose
segment to the light meets the sphere gets no direct light.
"""

from __future__ import annotations

import numpy as np

from gonio.sphere.geometry import sphere_hits
from gonio.sphere.pixels import sphere_box


def _board_shadow(cam, rate, px, py, hit) -> None:
    """Zero the rate of board pixels whose point sees the light through the sphere."""
    s = cam.scene
    sph = s.sphere
    S = cam._light_pos
    X = np.stack([px.astype(np.float64), py.astype(np.float64), np.zeros(px.shape)], axis=-1)
    to_s = S - X
    dist = np.linalg.norm(to_s, axis=-1)
    t, blocked = sph.intersect(X, to_s / np.maximum(dist, 1e-12)[..., None])
    with np.errstate(invalid="ignore"):
        shadow = hit & blocked & (t < dist)
    rate[shadow] = 0.0


def shade_sphere(cam, rate: np.ndarray, px, py, hit) -> None:
    """Overwrite ``rate`` (H, W, 3) where the sphere is seen (see the module docstring)."""
    s = cam.scene
    sph = s.sphere
    _board_shadow(cam, rate, px, py, hit)
    box = sphere_box(cam.calibration, cam._pose, sph)
    if box is None:
        return
    n = max(int(s.sphere_supersample), 1)
    rows, cols = box
    h, w = rows.stop - rows.start, cols.stop - cols.start
    off = (np.arange(n) + 0.5) / n - 0.5
    v, u = np.mgrid[rows, cols].astype(np.float64)
    us = (u[:, :, None, None] + off[None, None, None, :]).repeat(n, axis=2)
    vs = (v[:, :, None, None] + off[None, None, :, None]).repeat(n, axis=3)
    d = cam.calibration.rays(us, vs) @ cam._pose.R
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    hits, mask = sphere_hits(cam._pose.centre, d, sph, cam._light_pos)
    if not mask.any():
        return
    f = s.material.eval(hits.wi_local, hits.wo_local)  # in each point's frame (a cylinder's: t along its axis)
    irr = s.light_intensity * np.clip(hits.cos_i, 0.0, None) / hits.r2
    contrib = np.zeros(mask.shape + (3,))
    contrib[mask] = f * irr[:, None] * np.asarray(cam.sensor.responsivity)
    frac = mask.reshape(h, w, n * n).mean(axis=-1)
    sub = contrib.reshape(h, w, n * n, 3).sum(axis=2) / (n * n)
    region = rate[rows, cols]
    covered = frac > 0
    region[covered] = (sub[covered] + (1.0 - frac[covered])[:, None] * region[covered]).astype(region.dtype)
