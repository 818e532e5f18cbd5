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


def footprint_average(model, wi_local, wo_local, footprint, k: int = 4, shift=(0.0, 0.0)) -> np.ndarray:
    """``f̄`` (n, 3) of the module docstring: ``model`` (a :class:`gonio.brdf.BRDF`) averaged over each pixel's
    footprint of normals on a ``k × k`` midpoint grid; ``wi_local``/``wo_local`` (n, 3) in the pixel centre's
    normal frame, ``footprint`` from :func:`pixel_footprint` (NaN rows, pixels whose footprint leaves the sphere,
    give NaN). ``shift`` (pixels, u and v): the sphere's image where the geometry puts it less where it is — each
    pixel's footprint of normals moved by it (the same Taylor expansion of the normal about the pixel centre)."""
    wi = np.asarray(wi_local, dtype=np.float64)
    wo = np.asarray(wo_local, dtype=np.float64)
    fp0 = np.asarray(footprint, dtype=np.float64)
    bad = ~np.all(np.isfinite(fp0), axis=(1, 2))
    fp = np.nan_to_num(fp0)
    off = (np.arange(k) + 0.5) / k - 0.5
    a, b = (x.ravel() for x in np.meshgrid(off, off, indexing="ij"))
    a, b = a + float(shift[0]), b + float(shift[1])
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


#: the registration's bound (pixels): the sphere's image offset :func:`fit_footprint` may fit
MAX_SHIFT_PX = 1.0


def fit_footprint(name: str, start: dict, wi_local, wo_local, footprint, f, sigma, *, free=("ks", "alpha"),
                  k: int = 4, scan: bool = True, scan_per_decade: int = 6,
                  register: bool = True) -> tuple[dict, dict]:
    """Refine a fitted model's parameters ``free`` (``start``: all its parameters, e.g. a
    :func:`gonio.fit` result's) so that :func:`footprint_average` matches the pixels' values ``f`` (n, 3) with
    their σ: weighted least squares (``scipy.optimize.least_squares``, trust-region reflective within the
    parameters' bounds). With ``alpha`` free and ``scan`` (the default) the local solve starts from the best point of
    a coarse scan over log α (:func:`_scan_alpha`), not from ``start``'s α (an ordinary fit's α of a lobe narrower
    than a pixel can be ten times too wide).

    ``register`` (the default): the sphere's image offset ``shift`` (u, v pixels, within ±:data:`MAX_SHIFT_PX`;
    :func:`footprint_average`) is fitted with the model, a nuisance parameter shared by all the pixels (the camera
    of a sphere plan stays still: one offset). A lobe narrower than a pixel turns a registration error of a few
    hundredths of a pixel (the camera pose from the board) into a wider, dimmer lobe: on the benchmark's 34-pose
    chrome sweep at 320×240 (GGX α = 0.01) the fit without it gave α +4 %, ks −11 %, the peak −18 % and a reduced
    χ² of 12; with it an offset of (0.008, −0.028) px, α −0.4 %, the peak +0.7 %, χ² 0.5. Fitting the
    geometry's nuisance parameters jointly with the reflectance is the joint (bundle) estimation of photogrammetry
    (Triggs et al. 2000, "Bundle adjustment — a modern synthesis", §2: all parameters that the observations
    depend on estimated together); here two.

    Returns ``(params, info)``: info holds the standard uncertainty of each free scalar (``sigma``, from
    ``(JᵀJ)⁻¹``, scaled by the reduced χ² when above 1; ``shift_u``, ``shift_v`` too), which ended on a bound, the
    offset (``shift_px``, None without ``register``) and the scan (``alpha_scan``, None without one)."""
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
    if register:
        for p in ("shift_u", "shift_v"):
            layout.append((p, None))
            x0.append(0.0)
            lo.append(-MAX_SHIFT_PX)
            hi.append(MAX_SHIFT_PX)
    n_model = len(x0) - (2 if register else 0)
    fixed = {p: v for p, v in start.items() if p not in free}
    f = np.asarray(f, dtype=np.float64)
    s = np.asarray(sigma, dtype=np.float64)
    keep = np.all(np.isfinite(np.asarray(footprint, dtype=np.float64)), axis=(1, 2)) & np.all(
        np.isfinite(f) & np.isfinite(s) & (s > 0), axis=1)  # pixels whose footprint leaves the sphere: not used
    wi_local, wo_local, footprint = (np.asarray(a)[keep] for a in (wi_local, wo_local, footprint))
    f, s = f[keep], s[keep]

    def params(x):
        out = dict(fixed)
        for (p, i), v in zip(layout[:n_model], x[:n_model]):
            if i is None:
                out[p] = float(v)
            else:
                arr = np.atleast_1d(np.asarray(out.get(p, start[p]), dtype=np.float64)).copy()
                arr[i] = v
                out[p] = arr.tolist()
        return out

    def resid(x):
        shift = (x[n_model], x[n_model + 1]) if register else (0.0, 0.0)
        return ((footprint_average(make(name, **params(x)), wi_local, wo_local, footprint, k, shift) - f) / s).ravel()

    x0 = np.array(x0)
    scanned = None
    if scan and "alpha" in free:  # the start from a coarse scan over log α (the module docstring of _scan_alpha)
        a = [i for i, (p, _) in enumerate(layout) if p == "alpha"][0]
        x0, scanned = _scan_alpha(resid, x0, np.array(lo), np.array(hi), a, per_decade=scan_per_decade)
    fit = least_squares(resid, x0, bounds=(np.array(lo), np.array(hi)), x_scale="jac")
    dof = max(fit.fun.size - len(x0), 1)
    chi2 = float(fit.fun @ fit.fun / dof)
    try:
        cov = np.linalg.inv(fit.jac.T @ fit.jac) * max(chi2, 1.0)
        sig = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    except np.linalg.LinAlgError:
        sig = np.full(len(x0), np.nan)
    names = [p if i is None else f"{p}[{i}]" for p, i in layout]
    on_bound = [nm for nm, x, a, b in zip(names, fit.x, lo, hi) if x <= a * (1 + 1e-9) or x >= b * (1 - 1e-9)]
    shift = [float(v) for v in fit.x[n_model:]] if register else None
    return params(fit.x), {"sigma": dict(zip(names, sig.tolist())), "chi2_reduced": chi2, "on_bound": on_bound,
                           "n": int(len(f)), "alpha_scan": scanned, "shift_px": shift}


#: the coarse α scan's lowest value: a lobe this narrow is a point in any camera's pixel (GGX α = 0.001: 0.06°)
SCAN_ALPHA_MIN = 1e-3


def _scan_alpha(resid, x0, lo, hi, a: int, *, per_decade: int = 6) -> tuple[np.ndarray, dict]:
    """The start of the local solve: χ²(α) profiled on a grid over log α, the other free parameters solved at each α
    (a short ``least_squares`` with α held; for ks, kd a linear problem, one or two steps).

    The footprint-averaged χ² need not be convex in α over decades (a lobe several pixels wide and one narrower than
    a pixel make different images; an earlier benchmark run's local solve from the ordinary fit's α = 0.12 stopped at
    0.11 for a truth of 0.01 — on later data it converged from every start tried, 0.002 to 0.95: the scan is the
    guarantee, not the usual path). Profiling the nonlinear parameter over a grid with
    the others eliminated at each point is the separable least-squares idea (Golub & Pereyra 1973, "The
    differentiation of pseudo-inverses and nonlinear least squares problems whose variables separate", SIAM J.
    Numer. Anal. 10(2)); the grid is coarse to fine: ``per_decade`` points a decade from :data:`SCAN_ALPHA_MIN` (or
    α's lower bound) to its upper bound, and the local solve refines the best. Returns ``(x, info)``: the start
    and the scan (``alpha``, ``chi2`` at each grid point, ``best``)."""
    from scipy.optimize import least_squares

    lo_a, hi_a = max(float(lo[a]), SCAN_ALPHA_MIN), float(hi[a])
    grid = np.geomspace(lo_a, hi_a, max(int(round(per_decade * np.log10(hi_a / lo_a))) + 1, 2))
    others = np.array([i for i in range(len(x0)) if i != a], dtype=np.intp)
    best, chi2s = None, []
    for g in grid:
        x = x0.copy()
        x[a] = g
        if others.size:
            def sub(y, x=x):
                z = x.copy()
                z[others] = y
                return resid(z)

            r = least_squares(sub, np.clip(x0[others], lo[others], hi[others]), bounds=(lo[others], hi[others]),
                              x_scale="jac", max_nfev=20)
            x[others], c = r.x, 2 * r.cost
        else:
            rr = resid(x)
            c = float(rr @ rr)
        chi2s.append(float(c))
        if best is None or c < best[0]:
            best = (c, x)
    return best[1], {"alpha": grid.tolist(), "chi2": chi2s, "best": float(best[1][a])}
