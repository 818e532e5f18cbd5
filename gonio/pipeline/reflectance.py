"""From a merged radiometric image to BRDF samples: per-pixel geometry, the white reference, binning.

Per pixel x on its surface — the board plane z = 0 for the white reference, the sample's own plane
for the sample (the declared :class:`~gonio.pipeline.target.SampleMount`: the viewing ray meets the
plane ``n·(x − o) = 0``, n by the inverse-transpose; flat by default) —
``wo = (C − x)/|C − x|``, ``wi = (S − x)/|S − x|`` (C camera centre, S light position),
irradiance per unit source intensity ``E = (wi·n) / r²`` (point source; lecture notes 004, "point
light"). The samples' wi/wo are then expressed in the sample's own frame
(:func:`~gonio.pipeline.target.surface_frame`). The camera measures ``rate = k I L`` with
``L = f E`` (lecture notes 004: reflected radiance = BRDF × irradiance). The white reference
(Lambertian, albedo ρ_w) gives ``k I = rate_w / (ρ_w/π · E_w)`` at its own pixels (its own wi,
distance to the light), so ``f = rate / (k I · E)`` — light intensity, lens and sensor responsivity
cancel; only ρ_w must be known. In absolute mode ``k I`` comes from the calibration instead.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gonio import samples as S
from gonio.geometry import dot, normalize, to_local
from gonio.pipeline.hdr import HdrImage
from gonio.pipeline.target import CameraCalibration, CameraPose, TargetLayout
from gonio.pipeline.footprint import footprint_correction, tile_half_moments
from gonio.pipeline.uncertainty import geometry_variance, light_offsets
from gonio.samples import SampleSet

__all__ = ["Roi", "build_roi", "reflectance_samples", "used_pixel_samples"]


@dataclass
class Roi:
    """Pixels of the frame that see the sample or the white reference.

    ``rows``/``cols`` crop the frame; ``p`` (h, w, 3) are the surface points of the crop's pixels
    (sample frame: on the mounted sample's plane where ``label`` ≥ 0, on the board plane elsewhere);
    ``label`` (h, w) is the sample tile index (−1 elsewhere); ``white`` (h, w) marks white-patch pixels.
    """

    rows: slice
    cols: slice
    p: np.ndarray
    label: np.ndarray
    white: np.ndarray
    n_tiles: int

    @property
    def region(self) -> tuple[slice, slice]:
        return self.rows, self.cols

    @property
    def empty(self) -> bool:
        return not (self.label >= 0).any() or not self.white.any()


def _angle_span(vectors: np.ndarray) -> float:
    """Largest angle (radians) between any two of a few unit vectors."""
    c = np.clip(vectors @ vectors.T, -1.0, 1.0)
    return float(np.arccos(c.min()))


def _pose_in_frame(pose: CameraPose, origin: np.ndarray, frame: np.ndarray) -> CameraPose:
    """The camera pose relative to a local frame (``X_world = origin + frameᵀ X_local``):
    ``X_cam = R frameᵀ X_local + (R origin + t)``."""
    return CameraPose(pose.R @ frame.T, pose.R @ origin + pose.t)


def _pixel_rays(calib: CameraCalibration, rows: slice, cols: slice) -> np.ndarray:
    """``calib.rays`` of the pixel centres in ``rows`` × ``cols`` (a C-contiguous (h, w, 3) array). The whole
    frame's rays are computed once per calibration (kept on it, keyed by its intrinsics, distortion and size) and
    cropped: each ray depends on its own pixel only, so the crop holds the very numbers ``calib.rays`` computes for
    the region (a pose's ROI needed ~0.7 ms for them, every pose)."""
    key = (calib.K.tobytes(), calib.dist.tobytes(), int(calib.width), int(calib.height))
    cached = calib.__dict__.get("_pixel_rays")
    if cached is None or cached[0] != key:
        v, u = np.mgrid[0:calib.height, 0:calib.width].astype(np.float64)
        rays = calib.rays(u, v)
        rays.flags.writeable = False
        cached = (key, rays)
        object.__setattr__(calib, "_pixel_rays", cached)
    return np.ascontiguousarray(cached[1][rows, cols])


def build_roi(pose: CameraPose, calib: CameraCalibration, layout: TargetLayout, light_position, *,
              margin_px: float = 3.0, max_bin_deg: float = 2.0, max_bins: int = 8, nominal=None) -> Roi:
    """Region of interest, per-pixel plane points and tiles for one camera pose.

    The sample patch is cut into n × n tiles (n ≤ ``max_bins``) so that each tile spans at most
    ``max_bin_deg`` of wi and of wo (estimated from the patch corners); a margin of ``margin_px``
    pixel footprints is dropped along every patch edge (pixels there mix patch and board).
    ``nominal = (camera centre, light position)`` of the *planned* pose, if given, fixes n: the
    tiling then depends on the pose only, not on encoder noise or the board estimate (a span near a
    multiple of ``max_bin_deg`` would otherwise give n × n or (n+1) × (n+1) tiles from run to run).
    """
    C = pose.centre
    S_ = np.asarray(light_position, dtype=np.float64)
    sc = layout.sample_corners()
    corners = np.concatenate([sc, layout.white.corners()])
    uv = pose.project(corners, calib)
    in_front = (corners @ pose.R.T + pose.t)[:, 2] > 0
    if not in_front.all() or not np.isfinite(uv).all():
        z = np.zeros((0, 0))
        return Roi(slice(0, 0), slice(0, 0), np.zeros((0, 0, 3)), z.astype(int) - 1, z.astype(bool), 1)
    c0, r0 = np.floor(uv.min(axis=0)).astype(int) - 2
    c1, r1 = np.ceil(uv.max(axis=0)).astype(int) + 3
    rows = slice(int(np.clip(r0, 0, calib.height)), int(np.clip(r1, 0, calib.height)))
    cols = slice(int(np.clip(c0, 0, calib.width)), int(np.clip(c1, 0, calib.width)))
    d = _pixel_rays(calib, rows, cols) @ pose.R
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(d[..., 2] < -1e-12, -C[2] / d[..., 2], np.nan)
    p = C + t[..., None] * d
    foot = np.linalg.norm(C) / calib.K[0, 0]
    m = margin_px * foot
    white = layout.white.contains(p[..., 0], p[..., 1], m)
    sr = layout.sample
    if layout.mount.is_flat:
        x, y = p[..., 0], p[..., 1]
    else:  # the ray meets the mounted sample's plane n·(x − o) = 0 at t = n·(o − C) / (n·d)
        o, nrm, _ = layout.mount.frame()
        dn = d @ nrm
        with np.errstate(divide="ignore", invalid="ignore"):
            ts = np.where(dn < -1e-12, np.dot(o - C, nrm) / dn, np.nan)
        ts = np.where(ts > 0, ts, np.nan)
        ps = C + ts[..., None] * d
        q = layout.mount.to_patch(ps)
        x, y = q[..., 0], q[..., 1]
    in_sample = sr.contains(x, y, m)
    if not layout.mount.is_flat:
        p = np.where(in_sample[..., None], ps, p)
        white &= ~in_sample  # the sample, if raised, hides what is behind it
    Cn, Sn = (C, S_) if nominal is None else (np.asarray(nominal[0], float), np.asarray(nominal[1], float))
    span = max(_angle_span(normalize(Cn - sc)), _angle_span(normalize(Sn - sc)))
    n = int(np.clip(np.ceil(np.degrees(span) / max_bin_deg), 1, max_bins))
    with np.errstate(invalid="ignore"):
        ix = np.clip(((x - sr.x0) / (sr.x1 - sr.x0) * n).astype(int), 0, n - 1)
        iy = np.clip(((y - sr.y0) / (sr.y1 - sr.y0) * n).astype(int), 0, n - 1)
    label = np.where(in_sample, iy * n + ix, -1)
    return Roi(rows, cols, p, label, white, n * n)


def _tile_sums(lab: np.ndarray, values: np.ndarray, nt: int) -> np.ndarray:
    """Per-tile sums ``np.bincount(lab, values[:, k], minlength=nt)`` of every column k of ``values`` (N, m), as
    one (nt, m) array, in one pass: bin ``lab·m + k`` of a combined index. ``np.bincount`` adds a bin's weights
    one after the other in input order (numpy's ``arr_bincount``: ``out[idx[i]] += w[i]``), and a bin of the
    combined index holds exactly column k's weights of tile ``lab`` in the same order: the very sums of the
    per-column calls, bit for bit. ``lab`` ≥ 0."""
    m = values.shape[1]
    idx = (lab[:, None] * m + np.arange(m)).ravel()
    return np.bincount(idx, np.asarray(values, dtype=np.float64).ravel(), minlength=nt * m).reshape(nt, m)


def _in_frame(light_sigma, frame):
    """The light position's uncertainty in the mounted sample's frame (rows of ``frame``: its axes): a
    per-coordinate σ is the same in any frame, a covariance turns, ``F C Fᵀ``."""
    a = np.asarray(light_sigma, dtype=np.float64)
    return light_sigma if a.ndim == 0 else frame @ a @ frame.T


def reflectance_samples(hdr: HdrImage, roi: Roi, pose: CameraPose, light_position, layout: TargetLayout, *,
                        absolute_scale=None, min_snr: float = 10.0, pose_index: int = -1, flags: int = 0,
                        light_rel_sigma: float = 0.0, pose_perturbations=(), light_sigma=0.0) -> SampleSet:
    """BRDF samples (one per tile) from a merged image over ``roi`` (see the module docstring).

    Uncertainty: per pixel ``σ_f² = σ²_rate / (kI E)²``; per tile the mean's variance
    ``Σσ_f²/n²`` plus the white reference's relative variance (and ``light_rel_sigma``, the light
    normalization's) times f², per RGB channel (GUM, JCGM 100:2008, eq. 10, uncorrelated inputs);
    plus the photodiode readings' noise, correlated between sample and white: with ``α_k`` the share
    of exposure k in a value (:attr:`HdrImage.light_weight`), ``f² Σ_k (α_k,tile − α_k,white)² ε_k²``
    (ε_k the reading's relative uncertainty; it cancels where both come from the same exposures);
    plus the geometry's (:func:`gonio.pipeline.uncertainty.geometry_variance`: the camera pose's
    ``pose_perturbations`` and the light position's ``light_sigma``, metres per coordinate, or its (3, 3)
    covariance in m²), which is also returned alone as ``sigma_pose``: shared by all the pose's samples.
    Pixels saturated in every exposure are excluded and their tile flagged ``SATURATED``; a tile
    with no usable pixel gets f = σ = NaN (flagged). SNR below ``min_snr`` → ``LOW_SIGNAL``.
    ``flags`` (e.g. ``NO_BOARD``, ``DRIFT``) are set on every sample.
    """
    # only the sample's and the white's pixels count (a quarter of the ROI's box, typically): every per-pixel
    # quantity is computed for them alone, in the box's C order (the order the sums have always used)
    used = np.flatnonzero((roi.label >= 0) | roi.white)
    C = hdr.rate.shape[-1]
    lw = hdr.light_weight
    merged = HdrImage(rate=hdr.rate.reshape(-1, C)[used], var=hdr.var.reshape(-1, C)[used],
                      saturated=hdr.saturated.reshape(-1, C)[used], used=hdr.used.reshape(-1, C)[used],
                      light_weight=None if lw is None else lw.reshape(len(lw), -1, C)[:, used],
                      light_rel_var=hdr.light_rel_var)
    return used_pixel_samples(merged, roi, pose, light_position, layout, absolute_scale=absolute_scale,
                              min_snr=min_snr, pose_index=pose_index, flags=flags, light_rel_sigma=light_rel_sigma,
                              pose_perturbations=pose_perturbations, light_sigma=light_sigma)


def used_pixel_samples(hdr: HdrImage, roi: Roi, pose: CameraPose, light_position, layout: TargetLayout, *,
                       absolute_scale=None, min_snr: float = 10.0, pose_index: int = -1, flags: int = 0,
                       light_rel_sigma: float = 0.0, pose_perturbations=(), light_sigma=0.0) -> SampleSet:
    """:func:`reflectance_samples` from a merge of the ROI's used pixels only — the sample's and the white's
    (``(roi.label >= 0) | roi.white``), in the box's C order: ``hdr``'s arrays are (n, C) or (n, 1, C), its
    ``light_weight`` (K, n, C) or (K, n, 1, C), what :func:`~gonio.pipeline.hdr.merge_linear` returns for those
    pixels as an (n, 1, C) image (:meth:`gonio.pipeline.acquire.Pipeline.measure`: no box to scatter them into
    and gather them back from). Same formulas, same samples (see :func:`reflectance_samples`)."""
    C = pose.centre
    S_ = np.asarray(light_position, dtype=np.float64)
    nt = roi.n_tiles
    used = np.flatnonzero((roi.label >= 0) | roi.white)
    p = roi.p.reshape(-1, 3)[used]
    lab = roi.label.reshape(-1)[used]
    white = roi.white.reshape(-1)[used]
    chans_in = hdr.rate.shape[-1]
    h_rate, h_var = hdr.rate.reshape(-1, chans_in), hdr.var.reshape(-1, chans_in)
    h_sat = hdr.saturated.reshape(-1, chans_in)
    h_lw = None if hdr.light_weight is None else hdr.light_weight.reshape(len(hdr.light_weight), -1, chans_in)
    if len(h_rate) != len(used):
        raise ValueError(f"used_pixel_samples: {len(h_rate)} merged pixels for the ROI's {len(used)} used pixels")
    flat = layout.mount.is_flat
    origin, nrm, frame = layout.mount.frame()
    to_l = S_ - p
    r2 = dot(to_l, to_l)
    with np.errstate(invalid="ignore", divide="ignore"):
        wi = to_l / np.sqrt(r2)[..., None]
        wo = normalize(C - p)
        # cosines against each pixel's own surface normal: the board's z, the mounted sample's n
        cos_i = wi[..., 2] if flat else np.where(lab >= 0, wi @ nrm, wi[..., 2])
        cos_o = wo[..., 2] if flat else np.where(lab >= 0, wo @ nrm, wo[..., 2])
        E = np.maximum(cos_i, 0.0) / r2
    finite = np.isfinite(p).all(axis=-1) & (cos_i > 0) & (cos_o > 0)
    sat_px = h_sat.any(axis=-1)
    # --- white reference: k·I per channel ------------------------------------------------------
    rho = np.asarray(layout.white_albedo) / np.pi
    white_flags = 0
    p_white = None
    alpha_w = 0.0
    if absolute_scale is None:
        wmask = white & finite
        if (wmask & sat_px).any():
            white_flags |= S.SATURATED
        wmask &= ~sat_px
        if wmask.any():
            iw = np.flatnonzero(wmask)  # the white's pixels: x[wmask] is np.take(x, iw, axis=0)
            den = rho * np.take(E, iw)[:, None]
            kI_px = np.take(h_rate, iw, axis=0) / den
            kI = kI_px.mean(axis=0)
            kI_var = (np.take(h_var, iw, axis=0) / den**2).sum(axis=0) / len(iw) ** 2
            p_white = np.take(p, iw, axis=0).mean(axis=0)
            if h_lw is not None:  # (K, C): the white's share of each exposure
                alpha_w = (np.take(h_lw, iw, axis=1) * kI_px).sum(axis=1) / kI_px.sum(axis=0)
        else:
            kI = np.full(3 if h_rate.shape[-1] == 3 else 1, np.nan)
            kI_var = kI.copy()
            white_flags |= S.SATURATED
    else:
        kI = np.asarray(absolute_scale, dtype=np.float64)
        kI_var = np.zeros_like(kI)
    # --- sample pixels -> tiles ----------------------------------------------------------------
    in_s = (lab >= 0) & finite
    good = in_s & ~sat_px
    ig = np.flatnonzero(good)  # the sample's unsaturated pixels: x[good] is np.take(x, ig, axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        den = kI * np.take(E, ig)[:, None]
        f_px = np.take(h_rate, ig, axis=0) / den
        v_px = np.take(h_var, ig, axis=0) / den**2
    lg = np.take(lab, ig)
    n = np.bincount(lg, minlength=nt).astype(np.float64)
    nsat = np.bincount(lab[in_s & sat_px], minlength=nt)
    nany = np.bincount(lab[in_s], minlength=nt)
    chans = f_px.shape[-1]
    # the tiles' sums of f and of its variance (one bincount per column, in one pass: _tile_sums)
    sums = _tile_sums(lg, np.concatenate([f_px, v_px], axis=1), nt)
    fsum, vsum = np.ascontiguousarray(sums[:, :chans]), np.ascontiguousarray(sums[:, chans:])
    # directions: mean over all sample pixels of the tile (saturated ones included: same geometry); the tiles'
    # mean plane points too when the geometry's uncertainty needs them
    geometry = bool((pose_perturbations or len(light_offsets(light_sigma))) and chans == 3)
    lab_s = lab[in_s]
    vecs = _tile_sums(lab_s, np.concatenate([wi, wo, p] if geometry else [wi, wo], axis=1)[in_s], nt)
    wi_t = normalize(np.ascontiguousarray(vecs[:, 0:3]))
    wo_t = normalize(np.ascontiguousarray(vecs[:, 3:6]))
    if not flat:  # into the mounted sample's frame (docs/architecture.md §3: z = its normal)
        wi_t, wo_t = to_local(wi_t, frame), to_local(wo_t, frame)
    with np.errstate(invalid="ignore", divide="ignore"):
        f = fsum / n[:, None]
        var = vsum / n[:, None] ** 2 + f**2 * (kI_var / kI**2 + light_rel_sigma**2)
    n_side = int(round(np.sqrt(nt)))
    if n_side * n_side == nt and n_side >= 3:  # the mean over a tile's directions is not the value at its mean
        # direction where the BRDF curves: second-order correction (gonio.pipeline.footprint)
        h_px = normalize(wi[in_s] + wo[in_s])
        hm, hc = tile_half_moments(h_px if flat else to_local(h_px, frame), lab[in_s], nt)
        with np.errstate(invalid="ignore", divide="ignore"):
            delta, dvar = footprint_correction(f, var, hm, hc, n_side)
        f, var = f - delta, var + dvar
    if h_lw is not None and hdr.light_rel_var is not None and hdr.light_rel_var.any():
        aw = np.take(h_lw, ig, axis=1) * f_px  # (K, Ngood, C)
        K = aw.shape[0]
        with np.errstate(invalid="ignore", divide="ignore"):
            # per exposure k and channel c the tiles' sums of aw[k, :, c] (columns k·C + c), as (K, nt, C)
            alpha_t = np.ascontiguousarray(_tile_sums(lg, aw.transpose(1, 0, 2).reshape(len(lg), K * chans), nt)
                                           .reshape(nt, K, chans).transpose(1, 0, 2)) / fsum
            alpha_w_ = np.asarray(alpha_w, dtype=np.float64)
            d = alpha_t - (alpha_w_[:, None, :] if alpha_w_.ndim == 2 else alpha_w_)
            var = var + f**2 * np.einsum("ktc,k->tc", d**2, hdr.light_rel_var)
    if geometry:
        p_tile = np.ascontiguousarray(vecs[:, 6:9])
        with np.errstate(invalid="ignore", divide="ignore"):
            p_tile = p_tile / nany[:, None]
        n_grid = int(round(np.sqrt(nt)))
        okt = np.isfinite(p_tile).all(axis=1)
        p_tile[~okt] = 0.0
        if flat:
            gv = geometry_variance(np.where(np.isfinite(f), f, np.nan), p_tile, p_white, pose, S_, n_grid,
                                   pose_perturbations=pose_perturbations, light_sigma=light_sigma)
        else:  # in the mounted sample's frame, where its surface is z = 0. geometry_variance takes
            # every point on z = 0: the white (on the board plane) enters at its (x, y) on the sample's
            # plane — its irradiance's response to a perturbation is then off by O(tilt) of itself, a
            # second-order error of an uncertainty (its z offset kept would be a spurious first-order term)
            loc = lambda x: (x - origin) @ frame.T * np.array([1.0, 1.0, 0.0])  # noqa: E731
            gv = geometry_variance(np.where(np.isfinite(f), f, np.nan), loc(p_tile),
                                   None if p_white is None else loc(p_white), _pose_in_frame(pose, origin, frame),
                                   (S_ - origin) @ frame.T, n_grid, light_sigma=_in_frame(light_sigma, frame),
                                   pose_perturbations=[_pose_in_frame(q, origin, frame) for q in pose_perturbations])
        gv = np.where(okt[:, None], gv, 0.0)
        var = var + gv
    else:
        gv = np.zeros_like(var)
    if chans == 1:
        f, var, gv = np.repeat(f, 3, axis=1), np.repeat(var, 3, axis=1), np.repeat(gv, 3, axis=1)
    sigma = np.sqrt(var)
    sigma_pose = np.sqrt(gv)  # the geometry's part: shared by every tile of the pose (docs/uncertainty.md)
    fl = np.full(nt, int(flags) | white_flags, dtype=np.int64)
    fl[nsat > 0] |= S.SATURATED
    with np.errstate(invalid="ignore", divide="ignore"):
        snr = np.where(sigma > 0, f / sigma, np.inf)
    fl[~(snr.min(axis=1) >= min_snr)] |= S.LOW_SIGNAL
    empty = n == 0
    f[empty] = np.nan
    sigma[empty] = np.nan
    keep = nany > 0  # tiles with no pixel at all (outside the view) are not samples
    if not keep.any():
        keep = np.zeros(nt, bool)
        keep[0] = True
        wi_t[0] = to_local(normalize(S_ - origin), frame)
        wo_t[0] = to_local(normalize(C - origin), frame)
        f[0], sigma[0], sigma_pose[0] = np.nan, np.nan, np.nan
        fl[0] |= S.BAD_FRAME
    return SampleSet(wi=wi_t[keep], wo=wo_t[keep], f=f[keep], sigma=sigma[keep], n_pixels=n[keep].astype(np.int64),
                     flags=fl[keep], pose=np.full(int(keep.sum()), pose_index),
                     sigma_pose=np.where(np.isfinite(sigma_pose[keep]), sigma_pose[keep], 0.0))
