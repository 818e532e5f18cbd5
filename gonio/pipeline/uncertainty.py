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
"""

from __future__ import annotations

import numpy as np

from gonio.geometry import normalize
from gonio.pipeline.target import CameraPose

__all__ = ["local_h_gradient", "plane_transfer", "plane_transfer_many", "geometry_variance"]


def _half(wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    return normalize(wi + wo)


#: The 8 neighbours (Δi, Δj) of a tile, in the order their terms are added up.
_NEIGHBOURS = tuple((dx, dy) for dy in (-1, 0, 1) for dx in (-1, 0, 1) if dx or dy)


def _neighbour_table(n: int) -> tuple[np.ndarray, np.ndarray]:
    """For an ``n × n`` tile grid: ``j`` (8, n²), the index of each tile's neighbour :data:`_NEIGHBOURS`[k] (0 where
    outside the grid), and ``inside`` (8, n²), whether it is in the grid. Depends on n only (cached)."""
    hit = _TABLES.get(n)
    if hit is None:
        iy, ix = np.divmod(np.arange(n * n), n)
        jx = ix + np.array([dx for dx, _ in _NEIGHBOURS])[:, None]
        jy = iy + np.array([dy for _, dy in _NEIGHBOURS])[:, None]
        inside = (jx >= 0) & (jx < n) & (jy >= 0) & (jy < n)
        j = np.where(inside, jy * n + jx, 0)
        j.flags.writeable = inside.flags.writeable = False
        hit = _TABLES[n] = (j, inside)
    return hit


_TABLES: dict[int, tuple[np.ndarray, np.ndarray]] = {}


def local_h_gradient(f: np.ndarray, h: np.ndarray, n: int) -> np.ndarray:
    """Per-tile gradient of ``f`` (nt, C) with respect to ``(h_x, h_y)`` on an ``n × n`` tile grid.

    Least squares over each tile's valid neighbours (|Δi|, |Δj| ≤ 1): ``G = (Σ Δh Δhᵀ)⁺ Σ Δh Δf``.
    Tiles with no valid neighbour get 0. Returns (nt, C, 2). The neighbours' terms are computed as one
    stack (elementwise: the same numbers as one neighbour at a time) and added up one neighbour after
    the other, in :data:`_NEIGHBOURS` order, from zero: the same sums as a loop over the neighbours.
    """
    nt, chans = f.shape
    ok = np.isfinite(f).all(axis=1) & np.isfinite(h[:, :2]).all(axis=1)
    hxy = np.where(ok[:, None], h[:, :2], 0.0)
    f = np.where(ok[:, None], f, 0.0)
    j, inside = _neighbour_table(n)
    use = inside & ok & ok[j]  # (8, nt)
    dh = np.where(use[..., None], hxy[j] - hxy, 0.0)  # (8, nt, 2)
    df = np.where(use[..., None], f[j] - f, 0.0)  # (8, nt, C)
    dA = dh[..., :, None] * dh[..., None, :]  # (8, nt, 2, 2)
    db = df[..., :, None] * dh[..., None, :]  # (8, nt, C, 2)
    A = np.zeros((nt, 2, 2))
    b = np.zeros((nt, chans, 2))
    for k in range(len(_NEIGHBOURS)):
        A += dA[k]
        b += db[k]
    G = np.einsum("tcj,tij->tci", b, np.linalg.pinv(A, rcond=1e-9, hermitian=True))
    G[~ok] = 0.0
    return G


def plane_transfer(points: np.ndarray, src: CameraPose, dst: CameraPose) -> np.ndarray:
    """Where the pixels that see ``points`` (on z = 0) under pose ``src`` meet z = 0 under ``dst``.

    The plane-to-image map of a pinhole is the homography ``[r₁ r₂ t]`` (Hartley & Zisserman §8.1.1);
    intrinsics and distortion cancel. Returns (..., 3) with z = 0 (:func:`plane_transfer_many` for one pose).
    """
    return plane_transfer_many(points, src, [dst])[0]


def plane_transfer_many(points: np.ndarray, src: CameraPose, dsts) -> np.ndarray:
    """:func:`plane_transfer` of ``points`` to each pose of ``dsts``, a stack (len(dsts), ..., 3): the
    homographies ``[r₁ r₂ t]_dst⁻¹ [r₁ r₂ t]_src`` solved as one stack, then one 2-D product per pose."""
    return _apply_homographies(_plane_homographies(src, dsts), points)


def _plane_homographies(src: CameraPose, dsts) -> np.ndarray:
    """The plane-to-plane homographies ``[r₁ r₂ t]_dst⁻¹ [r₁ r₂ t]_src`` of each pose of ``dsts`` (Hartley &
    Zisserman §8.1.1), solved as one stack: (len(dsts), 3, 3)."""
    Hs = np.column_stack([src.R[:, 0], src.R[:, 1], src.t])
    Hd = np.stack([np.column_stack([d.R[:, 0], d.R[:, 1], d.t]) for d in dsts])
    return np.linalg.solve(Hd, np.broadcast_to(Hs, Hd.shape))


def _apply_homographies(H: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Plane points (..., 3), z = 0, mapped by each homography of ``H`` (K, 3, 3): (K, ..., 3), z = 0."""
    p = np.asarray(points, dtype=np.float64)
    ph = np.concatenate([p[..., :2], np.ones(p.shape[:-1] + (1,))], axis=-1)
    out = np.zeros((len(H),) + p.shape)
    for k in range(len(H)):
        q = ph @ H[k].T
        out[k, ..., :2] = q[..., :2] / q[..., 2:3]
    return out


def _log_irradiance(p: np.ndarray, S: np.ndarray) -> np.ndarray:
    """ln(cos θ / r²) at plane points ``p`` for a point light at ``S`` (z = 0 plane: cos θ = S_z / r)."""
    d = S - p
    r2 = np.sum(d * d, axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.log(np.maximum(d[..., 2], 1e-300)) - 1.5 * np.log(r2)


def light_offsets(light_sigma) -> np.ndarray:
    """The light position's perturbations one σ along each principal axis, (k, 3) metres: ``light_sigma`` a
    standard uncertainty per coordinate (metres) or a (3, 3) covariance (m²; e.g. the servos' scatter plus the
    geometric calibration's, :func:`gonio.rig.geocov.light_position_covariance`): ``√λ v`` per eigenpair."""
    a = np.asarray(light_sigma, dtype=np.float64)
    if a.ndim == 0:
        return np.eye(3) * float(a) if a > 0 else np.zeros((0, 3))
    w, V = np.linalg.eigh(0.5 * (a + a.T))
    keep = w > 1e-12 * max(float(w.max()), 1e-300)
    return (V[:, keep] * np.sqrt(w[keep])).T


def geometry_variance(f: np.ndarray, p_tile: np.ndarray, p_white: np.ndarray | None, pose: CameraPose,
                      light_position, n_grid: int, *, pose_perturbations=(), light_sigma=0.0) -> np.ndarray:
    """Variance (nt, C) of the tiles' residuals from the uncertain camera pose and light position.

    Parameters
    ----------
    f : (nt, C) tile values; p_tile : (nt, 3) mean plane point of each tile's pixels;
    p_white : (3,) mean plane point of the white reference's pixels (None in absolute mode);
    pose : the estimated camera pose; light_position : (3,) the assumed light position;
    n_grid : tiles per side; pose_perturbations : camera poses one σ away (principal axes);
    light_sigma : standard uncertainty (metres) of each coordinate of the light position, or its (3, 3)
        covariance (m²): :func:`light_offsets`.

    Every case moves all tiles of the pose together: the variance returned is the part of each tile's σ²
    that the pose's samples share (fully correlated within the pose; the store's ``sigma_pose``).
    """
    S = np.asarray(light_position, dtype=np.float64)
    C = pose.centre
    wi, wo = normalize(S - p_tile), normalize(C - p_tile)
    h0 = _half(wi, wo)
    G = local_h_gradient(f, h0, n_grid)
    lE_t = _log_irradiance(p_tile, S)
    lE_w = _log_irradiance(p_white, S) if p_white is not None else 0.0
    # every case at once (the same operations per case and tile as one case at a time; the homographies solved as
    # one stack): camera poses one σ away first, then the light moved one σ along each axis
    qs = list(pose_perturbations)
    Sq = [S] * len(qs)
    Sq += [S + d for d in light_offsets(light_sigma)]
    nq = len(qs)
    nc = len(Sq)
    var = np.zeros_like(f)
    if nc == 0:
        return var
    Sq = np.asarray(Sq)[:, None, :]  # (cases, 1, 3)
    Cq = np.asarray([q.centre for q in qs] + [C] * (nc - nq))[:, None, :]
    pt = np.broadcast_to(p_tile, (nc,) + p_tile.shape).copy()
    pw = None if p_white is None else np.broadcast_to(p_white, (nc,) + np.shape(p_white)).copy()
    if nq:
        H = _plane_homographies(pose, qs)  # the tiles' and the white's points move by the same homographies
        pt[:nq] = _apply_homographies(H, p_tile)
        if pw is not None:
            pw[:nq] = _apply_homographies(H, p_white)
    h = _half(normalize(Sq - pt), normalize(Cq - pt))
    dlnE = _log_irradiance(pt, Sq) - lE_t
    if pw is not None:
        dlnE = dlnE - (_log_irradiance(pw, Sq[:, 0]) - lE_w)[:, None]
    dh = (h - h0)[..., :2]
    for k in range(nc):
        dr = np.einsum("tci,ti->tc", G, dh[k]) + f * dlnE[k][:, None]
        var += dr**2
    return np.where(np.isfinite(var), var, 0.0)
