"""A pixel's footprint on a sphere: the normals it integrates, and a model averaged over them (issue 30: a
chrome-like lobe narrower than a pixel's footprint).

A pixel integrates the radiance over its area (a box filter; the sensor's fill factor taken as 1). On a sphere the
normal turns across that area: at the pixel centre ``n``, at ``(u + a, v + b)`` (a, b in pixels) to first order
``n + a ∂n/∂u + b ∂n/∂v`` (the derivatives from the normals at the pixel's edge midpoints, closed form by
:func:`gonio.sphere.geometry.ray_sphere`). For an isotropic BRDF and a light and camera far from the pixel, wi and wo
hardly turn across it (a pixel's angle, 0.1°, against the normal's few degrees), so the pixel's value is

    f̄ = (1/N) Σ_s f(wi, wo; n_s) (n_s·wi) / (n·wi)

over an N = k × k grid of sub-pixel positions (the pipeline divides the pixel's rate by the centre's irradiance,
:mod:`gonio.sphere.pixels`; a midpoint rule of the box filter, as the simulator's supersampling renders it). A
model fitted to such pixels with ``f̄`` (not f at the centre) recovers a lobe narrower than the footprint: the
"footprint-aware" fit of :func:`fit_footprint` (Marschner et al. 1999 fit a sphere's pixels so, each pixel's
normal range known from the geometry).
"""

from __future__ import annotations

import numpy as np

from gonio.sphere.geometry import Sphere, _local, ray_sphere

__all__ = ["pixel_footprint", "footprint_average", "fit_footprint"]


def pixel_footprint(calib, pose, sphere: Sphere, pixels, light=None) -> np.ndarray:
    """(n, 5, 3): ``∂n/∂u``, ``∂n/∂v``, ``∂²n/∂u²``, ``∂²n/∂u∂v``, ``∂²n/∂v²`` (per pixel; central differences on
    a 3 × 3 stencil half a pixel apart) of the pixels ``pixels`` (n, 2) (row, col), in each pixel's normal frame
    (rows t, b, n of :func:`gonio.sphere.geometry._local`); NaN where a stencil point misses the sphere (the
    silhouette). A lobe a tenth of a pixel's footprint wide needs the second order: the normal's curvature across
    half a pixel moves it by a tenth of the lobe's width. With the ``light``'s position the half vector's own
    turn across the pixel (the point moves, the ray turns) is taken off: what a lobe about h sees is the normal's
    turn relative to h, ``∂(n − h)/∂u``."""
    px = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
    v, u = px[:, 0], px[:, 1]
    C = pose.centre

    def at(uu, vv):  # the normal, and the normal less the half vector (light given)
        d = calib.rays(uu, vv) @ pose.R
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
        t, _ = ray_sphere(C, d, sphere)
        x = C + t[:, None] * d
        n = sphere.normal(x)
        if light is None:
            return n, n
        wi = np.asarray(light, dtype=np.float64) - x
        wi /= np.linalg.norm(wi, axis=-1, keepdims=True)
        h = wi - d
        return n, n - h / np.linalg.norm(h, axis=-1, keepdims=True)

    n0, m00 = at(u, v)
    h = 0.5  # the 3 × 3 stencil's step (pixels): the pixel's edge midpoints and corners
    mp0, mm0 = at(u + h, v)[1], at(u - h, v)[1]
    m0p, m0m = at(u, v + h)[1], at(u, v - h)[1]
    mpp, mmm = at(u + h, v + h)[1], at(u - h, v - h)[1]
    mpm, mmp = at(u + h, v - h)[1], at(u - h, v + h)[1]
    d = [(mp0 - mm0) / (2 * h), (m0p - m0m) / (2 * h), (mp0 - 2 * m00 + mm0) / h ** 2,
         (mpp - mpm - mmp + mmm) / (4 * h * h), (m0p - 2 * m00 + m0m) / h ** 2]
    n0 = n0 / np.linalg.norm(n0, axis=-1, keepdims=True)
    frame = sphere.frames(None, n0)  # the pixel centre's frame (a cylinder's: t along its axis)
    return np.stack([np.einsum("nij,nj->ni", frame, x) for x in d], axis=1)


def footprint_average(model, wi_local, wo_local, footprint, k: int = 4) -> np.ndarray:
    """``f̄`` (n, 3) of the module docstring: ``model`` (a :class:`gonio.brdf.BRDF`) averaged over each pixel's
    footprint of normals on a ``k × k`` midpoint grid; ``wi_local``/``wo_local`` (n, 3) in the pixel centre's
    normal frame, ``footprint`` from :func:`pixel_footprint` (NaN rows, pixels whose footprint leaves the sphere,
    give NaN)."""
    wi = np.asarray(wi_local, dtype=np.float64)
    wo = np.asarray(wo_local, dtype=np.float64)
    fp0 = np.asarray(footprint, dtype=np.float64)
    bad = ~np.all(np.isfinite(fp0), axis=(1, 2))
    fp = np.nan_to_num(fp0)
    off = (np.arange(k) + 0.5) / k - 0.5
    a, b = (x.ravel() for x in np.meshgrid(off, off, indexing="ij"))
    z = np.array([0.0, 0.0, 1.0])
    A, B = a[None, :, None], b[None, :, None]
    ns = (z + A * fp[:, None, 0] + B * fp[:, None, 1] + 0.5 * A * A * fp[:, None, 2] + A * B * fp[:, None, 3]
          + 0.5 * B * B * fp[:, None, 4])  # (n, k², 3): the second-order Taylor expansion of the normal
    ns /= np.linalg.norm(ns, axis=-1, keepdims=True)
    frame = _local(ns.reshape(-1, 3))  # each sub-normal's frame, in the centre's frame's coordinates
    wi_s = np.einsum("mij,mj->mi", frame, np.repeat(wi, k * k, axis=0))
    wo_s = np.einsum("mij,mj->mi", frame, np.repeat(wo, k * k, axis=0))
    ok = (wi_s[:, 2] > 0) & (wo_s[:, 2] > 0)
    f = np.zeros((len(wi_s), 3))
    if ok.any():
        f[ok] = np.asarray(model.eval(wi_s[ok], wo_s[ok]), dtype=np.float64).reshape(-1, 3)
    w = np.where(ok, wi_s[:, 2], 0.0) / np.repeat(np.maximum(wi[:, 2], 1e-12), k * k)
    out = (f * w[:, None]).reshape(len(wi), k * k, 3).mean(axis=1)
    out[bad] = np.nan
    return out


def fit_footprint(name: str, start: dict, wi_local, wo_local, footprint, f, sigma, *, free=("ks", "alpha"),
                  k: int = 4) -> tuple[dict, dict]:
    """Refine a fitted model's parameters ``free`` (``start``: all its parameters, e.g. a
    :func:`gonio.fit` result's) so that :func:`footprint_average` matches the pixels' values ``f`` (n, 3) with
    their σ: weighted least squares (``scipy.optimize.least_squares``, trust-region reflective within the
    parameters' bounds). Returns ``(params, info)``: info holds the standard uncertainty of each free scalar
    (``sigma``, from ``(JᵀJ)⁻¹``, scaled by the reduced χ² when above 1) and which ended on a bound."""
    from scipy.optimize import least_squares

    from gonio.brdf import MODELS, make

    cls = MODELS[name]
    layout = []  # (param, index or None)
    x0, lo, hi = [], [], []
    for p in free:
        spec = cls.PARAMS[p]
        val = np.atleast_1d(np.asarray(start[p], dtype=np.float64))
        for i, x in enumerate(val):
            layout.append((p, i if val.size > 1 else None))
            x0.append(float(np.clip(x, spec.lo, spec.hi)))
            lo.append(spec.lo)
            hi.append(spec.hi)
    fixed = {p: v for p, v in start.items() if p not in free}
    f = np.asarray(f, dtype=np.float64)
    s = np.asarray(sigma, dtype=np.float64)
    keep = np.all(np.isfinite(np.asarray(footprint, dtype=np.float64)), axis=(1, 2)) & np.all(
        np.isfinite(f) & np.isfinite(s) & (s > 0), axis=1)  # pixels whose footprint leaves the sphere: not used
    wi_local, wo_local, footprint = (np.asarray(a)[keep] for a in (wi_local, wo_local, footprint))
    f, s = f[keep], s[keep]

    def params(x):
        out = dict(fixed)
        for (p, i), v in zip(layout, x):
            if i is None:
                out[p] = float(v)
            else:
                arr = np.atleast_1d(np.asarray(out.get(p, start[p]), dtype=np.float64)).copy()
                arr[i] = v
                out[p] = arr.tolist()
        return out

    def resid(x):
        return ((footprint_average(make(name, **params(x)), wi_local, wo_local, footprint, k) - f) / s).ravel()

    fit = least_squares(resid, np.array(x0), bounds=(np.array(lo), np.array(hi)), x_scale="jac")
    dof = max(fit.fun.size - len(x0), 1)
    chi2 = float(fit.fun @ fit.fun / dof)
    try:
        cov = np.linalg.inv(fit.jac.T @ fit.jac) * max(chi2, 1.0)
        sig = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    except np.linalg.LinAlgError:
        sig = np.full(len(x0), np.nan)
    names = [p if i is None else f"{p}[{i}]" for p, i in layout]
    on_bound = [nm for nm, x, a, b in zip(names, fit.x, lo, hi) if x <= a * (1 + 1e-9) or x >= b * (1 - 1e-9)]
    return params(fit.x), {"sigma": dict(zip(names, sig.tolist())), "chi2_reduced": chi2, "on_bound": on_bound,
                           "n": int(len(f))}
