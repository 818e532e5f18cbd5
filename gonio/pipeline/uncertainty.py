"""Uncertainty of a pose's samples from its geometry: where the camera and the light really were.

A tile's value is reported at the directions the pipeline computed from the estimated camera pose
(ChArUco PnP) and the light position (rig kinematics). If the truth is off by a small δ, the
residual against the true BRDF at the reported directions is, to first order (GUM, JCGM 100:2008,
eq. 10; perturbations as in JCGM 101 §5),

    δr = ∇_h f · δh  +  f · (δ ln E_tile − δ ln E_white)

— the BRDF's change across the shift of the half vector h (Rusinkiewicz 1998; the variable that
carries a glossy lobe's variation), plus the change of the irradiance ratio sample/white that the
value was normalised with (E = I cos θ / r², lecture notes 004, "point light"). ``∇_h f`` is not known
a priori: it is estimated per tile from the pose's own tiles (a local linear fit over the 3 × 3
neighbouring tiles in (h_x, h_y)). Each perturbation is one standard deviation along a principal
axis of the pose covariance (:meth:`gonio.pipeline.markers.BoardPose.perturbed`) or of the light
position's; the variance is the sum of the squared responses.

A tile's value is also the *mean* of the BRDF over its pixels' directions, reported at their *mean*
direction: on a curved lobe these differ by ``½ tr(H Σ_h)`` to second order (the bias of a nonlinear
function of a spread variable, the second-order Taylor term of JCGM 100:2008 §5.1.2), with ``H`` the
Hessian of f in (h_x, h_y) and ``Σ_h`` the covariance of the tile's pixels' half vectors. At a glossy
peak (GGX α = 0.25, 2° tiles) that is ~0.1 % of f, a third of a sample's σ: the stated σ looked too small
(p95 |z| 2.16 on the simulated default plan, mean z −0.37) because the values sat systematically below
the lobe. :func:`tile_average_bias` estimates it from the pose's own tiles, and the pipeline reports
the value at the mean direction (:func:`gonio.pipeline.reflectance.reflectance_samples`).
"""

from __future__ import annotations

import numpy as np

from gonio.geometry import normalize
from gonio.pipeline.target import CameraPose

__all__ = ["local_h_gradient", "tile_average_bias", "plane_transfer", "geometry_variance"]


def _half(wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    return normalize(wi + wo)


def local_h_gradient(f: np.ndarray, h: np.ndarray, n: int) -> np.ndarray:
    """Per-tile gradient of ``f`` (nt, C) with respect to ``(h_x, h_y)`` on an ``n × n`` tile grid.

    Least squares over each tile's valid neighbours (|Δi|, |Δj| ≤ 1): ``G = (Σ Δh Δhᵀ)⁺ Σ Δh Δf``.
    Tiles with no valid neighbour get 0. Returns (nt, C, 2).
    """
    nt, chans = f.shape
    ok = np.isfinite(f).all(axis=1) & np.isfinite(h[:, :2]).all(axis=1)
    hxy = np.where(ok[:, None], h[:, :2], 0.0)
    f = np.where(ok[:, None], f, 0.0)
    iy, ix = np.divmod(np.arange(nt), n)
    A = np.zeros((nt, 2, 2))
    b = np.zeros((nt, chans, 2))
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            if dx == 0 and dy == 0:
                continue
            jx, jy = ix + dx, iy + dy
            inside = (jx >= 0) & (jx < n) & (jy >= 0) & (jy < n)
            j = np.where(inside, jy * n + jx, 0)
            use = inside & ok & ok[j]
            dh = np.where(use[:, None], hxy[j] - hxy, 0.0)
            df = np.where(use[:, None], f[j] - f, 0.0)
            A += dh[:, :, None] * dh[:, None, :]
            b += df[:, :, None] * dh[:, None, :]
    G = np.einsum("tcj,tij->tci", b, np.linalg.pinv(A, rcond=1e-9, hermitian=True))
    G[~ok] = 0.0
    return G


def tile_average_bias(f: np.ndarray, h: np.ndarray, h_cov: np.ndarray, n: int) -> np.ndarray:
    """Per-tile ``½ tr(H Σ_h)`` (nt, C): how much the mean of ``f`` over a tile's pixels exceeds ``f`` at
    their mean half vector (module docstring).

    ``f`` (nt, C) tile means, ``h`` (nt, ≥2) tile mean half vectors, ``h_cov`` (nt, 2, 2) the covariance of
    each tile's pixels' (h_x, h_y), ``n`` tiles per side. ``H`` is the quadratic term of a least-squares fit
    ``f_j − f_t = g·Δh + ½ Δhᵀ H Δh`` over the tile's valid neighbours (|Δi|, |Δj| ≤ 1, as
    :func:`local_h_gradient`); a tile with fewer than 6 valid neighbours (5 unknowns: the border) takes the
    Hessian of the nearest interior tile (a lobe's curvature changes over its width, not over a tile), or 0.
    """
    nt, chans = f.shape
    ok = np.isfinite(f).all(axis=1) & np.isfinite(h[:, :2]).all(axis=1) & np.isfinite(h_cov).all(axis=(1, 2))
    hxy = np.where(ok[:, None], h[:, :2], 0.0)
    f = np.where(ok[:, None], f, 0.0)
    iy, ix = np.divmod(np.arange(nt), n)
    A = np.zeros((nt, 5, 5))
    b = np.zeros((nt, chans, 5))
    count = np.zeros(nt, np.int64)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            if dx == 0 and dy == 0:
                continue
            jx, jy = ix + dx, iy + dy
            inside = (jx >= 0) & (jx < n) & (jy >= 0) & (jy < n)
            j = np.where(inside, jy * n + jx, 0)
            use = inside & ok & ok[j]
            d = np.where(use[:, None], hxy[j] - hxy, 0.0)
            x = np.stack([d[:, 0], d[:, 1], 0.5 * d[:, 0] ** 2, d[:, 0] * d[:, 1], 0.5 * d[:, 1] ** 2], axis=-1)
            df = np.where(use[:, None], f[j] - f, 0.0)
            A += x[:, :, None] * x[:, None, :]
            b += df[:, :, None] * x[:, None, :]
            count += use
    # scale the unknowns so the normal equations are well conditioned (Δh ~ 1e-2, Δh² ~ 1e-4)
    scale = np.sqrt(np.maximum(np.einsum("tii->ti", A), 1e-300))
    As = A / (scale[:, :, None] * scale[:, None, :])
    theta = np.einsum("tcj,tij->tci", b / scale[:, None, :], np.linalg.pinv(As, rcond=1e-9, hermitian=True))
    theta = theta / scale[:, None, :]
    H = theta[..., 2:]  # (nt, C, 3): Hxx, Hxy, Hyy
    H[count < 6] = np.nan
    if n >= 3:  # a border tile (3 or 5 neighbours) takes the curvature of the nearest interior tile
        inner = np.clip(iy, 1, n - 2) * n + np.clip(ix, 1, n - 2)
        H = np.where(np.isfinite(H), H, H[inner])
    cov = np.where(ok[:, None, None], h_cov, 0.0)
    bias = 0.5 * (H[..., 0] * cov[:, None, 0, 0] + 2.0 * H[..., 1] * cov[:, None, 0, 1] + H[..., 2] * cov[:, None, 1, 1])
    bias[~ok] = 0.0
    return np.where(np.isfinite(bias), bias, 0.0)


def plane_transfer(points: np.ndarray, src: CameraPose, dst: CameraPose) -> np.ndarray:
    """Where the pixels that see ``points`` (on z = 0) under pose ``src`` meet z = 0 under ``dst``.

    The plane-to-image map of a pinhole is the homography ``[r₁ r₂ t]`` (Hartley & Zisserman §8.1.1);
    intrinsics and distortion cancel. Returns (..., 3) with z = 0.
    """
    Hs = np.column_stack([src.R[:, 0], src.R[:, 1], src.t])
    Hd = np.column_stack([dst.R[:, 0], dst.R[:, 1], dst.t])
    p = np.asarray(points, dtype=np.float64)
    q = np.concatenate([p[..., :2], np.ones(p.shape[:-1] + (1,))], axis=-1) @ (np.linalg.solve(Hd, Hs)).T
    out = np.zeros_like(p)
    out[..., :2] = q[..., :2] / q[..., 2:3]
    return out


def _log_irradiance(p: np.ndarray, S: np.ndarray) -> np.ndarray:
    """ln(cos θ / r²) at plane points ``p`` for a point light at ``S`` (z = 0 plane: cos θ = S_z / r)."""
    d = S - p
    r2 = np.sum(d * d, axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.log(np.maximum(d[..., 2], 1e-300)) - 1.5 * np.log(r2)


def geometry_variance(f: np.ndarray, p_tile: np.ndarray, p_white: np.ndarray | None, pose: CameraPose,
                      light_position, n_grid: int, *, pose_perturbations=(), light_sigma: float = 0.0) -> np.ndarray:
    """Variance (nt, C) of the tiles' residuals from the uncertain camera pose and light position.

    Parameters
    ----------
    f : (nt, C) tile values; p_tile : (nt, 3) mean plane point of each tile's pixels;
    p_white : (3,) mean plane point of the white reference's pixels (None in absolute mode);
    pose : the estimated camera pose; light_position : (3,) the assumed light position;
    n_grid : tiles per side; pose_perturbations : camera poses one σ away (principal axes);
    light_sigma : standard uncertainty (metres) of each coordinate of the light position.
    """
    S = np.asarray(light_position, dtype=np.float64)
    C = pose.centre
    wi, wo = normalize(S - p_tile), normalize(C - p_tile)
    h0 = _half(wi, wo)
    G = local_h_gradient(f, h0, n_grid)
    lE_t = _log_irradiance(p_tile, S)
    lE_w = _log_irradiance(p_white, S) if p_white is not None else 0.0
    cases = [(q, S) for q in pose_perturbations]
    if light_sigma > 0:
        cases += [(pose, S + light_sigma * e) for e in np.eye(3)]
    var = np.zeros_like(f)
    for q, S_q in cases:
        pt = plane_transfer(p_tile, pose, q) if q is not pose else p_tile
        h = _half(normalize(S_q - pt), normalize(q.centre - pt))
        dlnE = _log_irradiance(pt, S_q) - lE_t
        if p_white is not None:
            pw = plane_transfer(p_white, pose, q) if q is not pose else p_white
            dlnE = dlnE - (_log_irradiance(pw, S_q) - lE_w)
        dr = np.einsum("tci,ti->tc", G, (h - h0)[:, :2]) + f * dlnE[:, None]
        var += dr**2
    return np.where(np.isfinite(var), var, 0.0)
