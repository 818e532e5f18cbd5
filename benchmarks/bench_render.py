"""Lit spheres (gonio.render.render_sphere): the vectorized renderer against a per-pixel Python loop of the
same formula (baseline), for an analytic model and for a MERL table, and the cost of one ``gonio view``
sphere request (render + tonemap + PNG) at the viewer's 128² pixels."""

from __future__ import annotations

import numpy as np

from benchmarks.common import Table, time_call
from gonio.brdf import make
from gonio.geometry import frame_from_normal, to_local
from gonio.io.merl import MerlTable, cell_directions
from gonio.render import light_from_angles, render_sphere, sphere_points, tonemap


def _loop(brdf, lights, size: int, limit: int) -> tuple[np.ndarray, np.ndarray]:
    """Baseline: the same sum of f(wi, wo) E over lights, one pixel (and one light) at a time."""
    mask, normals = sphere_points(size)
    idx = np.argwhere(mask)[:limit]
    f = getattr(brdf, "eval", None) or brdf.lookup
    out = np.zeros((len(idx), 3))
    for k, (r, c) in enumerate(idx):
        n = normals[r, c]
        frame = frame_from_normal(n)
        wo = to_local(np.array([0.0, 0.0, 1.0]), frame)
        for light in lights:
            d, e = light.illuminate(0.05 * n, n)
            if np.any(e > 0):
                out[k] += f(to_local(d, frame), wo) * e
    return idx, out


def _table(model) -> MerlTable:
    wi, wo, *_ = cell_directions()
    v = model.eval(wi, wo)
    v[(wi[..., 2] <= 0) | (wo[..., 2] <= 0)] = np.nan
    return MerlTable(v)


def run(quick: bool = False) -> list[Table]:
    model = make("microfacet", kd=0.2, ks=0.6, alpha=0.2, f0=0.9)
    lights = [light_from_angles(35, 0), light_from_angles(60, 120, 0.5)]
    sizes = (64, 128) if quick else (64, 128, 256)
    limit = 300 if quick else 1000
    t = Table("Lit sphere, 2 directional lights: vectorized render_sphere vs a per-pixel loop (same formula)",
              ["BRDF", "method", "size", "Mpixel/s", "× baseline", "max |Δ| vs baseline (1/sr × E)"])
    for name, brdf in (("microfacet (analytic)", model), ("MERL table (trilinear)", _table(model))):
        sec = time_call(lambda: _loop(brdf, lights, 64, limit), min_time=0.1, repeat=1) / limit
        idx, ref = _loop(brdf, lights, 64, limit)
        t.add(name, "per-pixel loop (baseline)", 64, 1e-6 / sec, 1.0, 0.0)
        base = sec
        for size in sizes:
            n_px = int(sphere_points(size)[0].sum())
            s = time_call(lambda: render_sphere(brdf, lights, size=size), min_time=0.2, repeat=2) / n_px
            diff = float(np.max(np.abs(render_sphere(brdf, lights, size=64).radiance[idx[:, 0], idx[:, 1]] - ref))) \
                if size == 64 else float("nan")
            t.add(name, "render_sphere (vectorized)", size, 1e-6 / s, base / s, diff)
    t.baseline = 0
    t.notes.append(f"baseline timed on the first {limit} pixels of the 64² disc; × baseline = per-pixel time ratio; "
                   "each BRDF has its own loop row, and its ratios are against that row")
    from gonio.render import png_bytes

    v = Table("One gonio view sphere request (128², render + tonemap + PNG)", ["BRDF", "ms per request"])
    for name, brdf in (("microfacet (analytic)", model),):
        def request():
            r = render_sphere(brdf, [light_from_angles(35, 0)], size=128)
            return png_bytes(tonemap(r.radiance), r.mask)
        v.add(name, 1e3 * time_call(request, min_time=0.2, repeat=2))
    return [t, v]
