"""One merged (HDR) frame of a sphere → one BRDF sample per pixel that sees it, in the white reference's units.

Radiometry (lecture notes 004, "point light" and "the BRDF"; the flat pipeline's, :mod:`gonio.pipeline.reflectance`):
a point source of intensity I at S gives a surface point X with unit normal n the irradiance
``E = I (n·wi) / |S − X|²``, and the camera sees the radiance ``L = f(wi, wo) E``. The frame's rate image is
``k L`` (k the camera's responsivity, per channel). The Lambertian white reference (albedo ρ, normal +z, on the
board) seen in the same frame gives ``k I = π rate_w |S − X_w|³ / (ρ S_z')`` per white pixel (S_z' the light's
height above it); their inverse-variance mean is the frame's ``kI``. Per sphere pixel then

    f = rate |S − X|² / (kI · (n·wi)),      σ_f² = σ²_rate / (kI (n·wi)/|S − X|²)² + f² (σ_kI / kI)²

(GUM, JCGM 100:2008, eq. 10, independent inputs). Pixels are rejected, and counted, where the BRDF sample would
not be what the formula says: ``silhouette`` (θo above ``grazing_deg``: the pixel's footprint spans many normals
and the background; or the footprint leaves the target, :func:`gonio.sphere.footprint.pixel_footprint` — a
cylinder's ends), ``terminator`` (θi above ``grazing_deg``), ``saturated`` (no exposure left unsaturated),
``dark`` (SNR below ``min_snr``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from gonio.errors import DataError
from gonio.sphere.geometry import Sphere, sphere_hits

__all__ = ["SphereFrameSamples", "sphere_frame_samples", "centre_perturbations", "white_scale", "white_box",
           "sphere_lit_pixels", "white_seen",
           "pixel_rays_world", "sphere_box"]


@dataclass
class SphereFrameSamples:
    """A frame's per-pixel samples (the used pixels): angles about each pixel's normal, f and σ (n, 3), the
    pixels' (row, col), and the counts of every rejection."""

    theta_h: np.ndarray
    theta_d: np.ndarray
    phi_d: np.ndarray
    f: np.ndarray
    sigma: np.ndarray
    pixels: np.ndarray
    wi: np.ndarray
    wo: np.ndarray
    counts: dict = field(default_factory=dict)
    wi_local: np.ndarray = None  #: wi, wo in each pixel's per-normal frame (z = the normal)
    wo_local: np.ndarray = None
    #: (n, 2, 3) ∂n/∂u, ∂n/∂v in each pixel's normal frame (:func:`gonio.sphere.footprint.pixel_footprint`)
    footprint: np.ndarray = None


def pixel_rays_world(calib, pose, rows: slice, cols: slice) -> tuple[np.ndarray, np.ndarray]:
    """Unit world-frame rays (h, w, 3) of the pixel centres in the box and their (row, col) grid."""
    v, u = np.mgrid[rows, cols].astype(np.float64)
    d_cam = calib.rays(u, v)
    d = d_cam @ pose.R  # world = Rᵀ camera (CameraPose: x_cam = R x_world + t)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    return d, np.stack([v, u], axis=-1).astype(np.int64)


def sphere_box(calib, pose, sphere: Sphere, pad: int = 2) -> tuple[slice, slice] | None:
    """Pixel box (rows, cols) holding the sphere's projection (its bounding cube's corners), padded; None if
    it is not in view."""
    corners = sphere.corners()
    pc = corners @ pose.R.T + pose.t
    if (pc[:, 2] <= 0).any():
        return None
    uv = pose.project(corners, calib)
    c0, r0 = np.floor(uv.min(axis=0)).astype(int) - pad
    c1, r1 = np.ceil(uv.max(axis=0)).astype(int) + pad + 1
    rows = slice(max(int(r0), 0), min(int(r1), calib.height))
    cols = slice(max(int(c0), 0), min(int(c1), calib.width))
    if rows.stop <= rows.start or cols.stop <= cols.start:
        return None
    return rows, cols


def sphere_lit_pixels(calib, pose, sphere: Sphere, light_position, box, grazing_deg: float = 80.0) -> np.ndarray:
    """(H, W) bool: the pixels of ``box`` whose centre sees the sphere lit and not grazing (θi and θo below
    ``grazing_deg``): the pixels that give samples, whose range the bracket must cover (a sphere's frame also
    holds its dark side, its shadow and the board, which give none)."""
    rows, cols = box
    d, rc = pixel_rays_world(calib, pose, rows, cols)
    hits, hit = sphere_hits(pose.centre, d, sphere, light_position)
    c = math.cos(math.radians(grazing_deg))
    ok = (hits.cos_i >= c) & (hits.cos_o >= c)
    out = np.zeros((calib.height, calib.width), dtype=bool)
    px = rc[hit][ok]
    out[px[:, 0], px[:, 1]] = True
    return out


def white_box(calib, pose, layout) -> tuple[slice, slice] | None:
    """Pixel box (rows, cols) of the white reference's projection; None if it is not in view."""
    corners = layout.white.corners()
    pc = corners @ pose.R.T + pose.t
    if (pc[:, 2] <= 0).any():
        return None
    uv = pose.project(corners, calib)
    c0, r0 = np.ceil(uv.min(axis=0)).astype(int)
    c1, r1 = np.floor(uv.max(axis=0)).astype(int) + 1
    rows = slice(max(int(r0), 0), min(int(r1), calib.height))
    cols = slice(max(int(c0), 0), min(int(c1), calib.width))
    if rows.stop <= rows.start or cols.stop <= cols.start:
        return None
    return rows, cols


def white_seen(calib, pose, layout, light_position, sphere=None):
    """The white reference's pixels a frame can use, from the geometry alone: ``(box, points (h, w, 3), mask)`` —
    inside the patch clear of its edges, not hidden by the sphere (or cylinder) and not in its shadow (both grown by
    3 pixel footprints: a pixel straddling the silhouette or the shadow's edge mixes them in); None when the patch
    is not in view. A plan uses it to leave out light positions that shadow the white (gonio.session.sphere_plan)."""
    S = np.asarray(light_position, dtype=np.float64)
    box = white_box(calib, pose, layout)
    if box is None:
        return None
    rows, cols = box
    d, _ = pixel_rays_world(calib, pose, rows, cols)
    C = pose.centre
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -C[2] / d[..., 2]
    p = C + t[..., None] * d
    inside = (t > 0) & layout.white.contains(p[..., 0], p[..., 1])
    # stay clear of the patch's edges (a pixel straddling the edge mixes board and white)
    inside &= layout.white.contains(p[..., 0] + 1e-3, p[..., 1] + 1e-3) & layout.white.contains(
        p[..., 0] - 1e-3, p[..., 1] - 1e-3)
    if sphere is not None:
        # grown by 3 pixel footprints at the sphere's distance: a pixel straddling its silhouette or its shadow's
        # edge mixes the sphere (or the shade) into the white
        grow = 3.0 * float(np.linalg.norm(C - np.mean(sphere.corners(), axis=0))) / float(calib.K[0, 0])
        big = sphere.grown(grow)
        _, hidden = big.intersect(C, d)  # the camera sees the sphere, not the white, through these pixels
        inside &= ~hidden
        to_s = S - p
        dist = np.linalg.norm(to_s, axis=-1)
        t_s, shade = big.intersect(p, to_s / np.maximum(dist, 1e-12)[..., None])
        with np.errstate(invalid="ignore"):
            inside &= ~(shade & (t_s < dist))  # in the sphere's shadow
    return box, p, inside


def white_scale(rate, var, calib, pose, layout, light_position, sphere: Sphere | None = None
                ) -> tuple[np.ndarray, np.ndarray]:
    """``(kI, σ_kI)`` per channel from the white reference's pixels in the frame (see the module docstring);
    one line naming the reason when no white pixel is usable. With ``sphere``, white pixels the sphere hides from
    the camera, or whose point lies in its shadow, are left out."""
    S = np.asarray(light_position, dtype=np.float64)
    seen = white_seen(calib, pose, layout, light_position, sphere)
    if seen is None:
        raise DataError("sphere frame: the white reference is not in view")
    (rows, cols), p, inside = seen
    r_w = rate[rows, cols][inside]
    v_w = var[rows, cols][inside]
    ok = np.all(np.isfinite(r_w) & np.isfinite(v_w) & (v_w > 0), axis=1)
    if ok.sum() < 4:
        raise DataError("sphere frame: fewer than 4 usable white-reference pixels (saturated or out of view)")
    pw = p[inside][ok]
    to_s = S - pw
    dist = np.linalg.norm(to_s, axis=1)
    geo = to_s[:, 2] / dist ** 3  # cos θ / r² of a point source over the plane z = 0
    rho = np.asarray(layout.white_albedo, dtype=np.float64)
    k = np.pi * r_w[ok] / (rho * geo[:, None])
    kv = v_w[ok] * (np.pi / (rho * geo[:, None])) ** 2
    w = 1.0 / kv
    kI = (w * k).sum(axis=0) / w.sum(axis=0)
    return kI, np.sqrt(1.0 / w.sum(axis=0))


def _geometry_variance(f, px, hits, box, calib, pose, sphere, light_position, perturbations) -> np.ndarray:
    """Variance (n, 3) of the hit pixels' f from the geometry's uncertainty (``perturbations``: ``(camera pose,
    sphere)`` pairs one σ along each principal axis of a covariance — the camera pose's,
    :meth:`gonio.pipeline.markers.BoardPose.perturbed`, with the sphere as used, and the sphere's centre's, with the
    camera pose as used; linear propagation, JCGM 101 / GUM §5.1.2). A pose off by δ, or a centre off by δP, moves
    the surface point with a pixel's normal: the sample's angles belong to a point the image shows
    ``δuv = project_q(x + δP) − u`` pixels away, so its value is off by ``∇f · δuv`` (the image gradient of f,
    central differences over the sphere's pixels), and the irradiance assumed there is off by ``δ ln E`` (E
    recomputed at the point the pixel's ray meets under the perturbed geometry)."""
    var = np.zeros_like(f)
    if not perturbations or len(f) == 0:
        return var
    rows, cols = box
    h, w = rows.stop - rows.start, cols.stop - cols.start
    img = np.full((h, w, f.shape[1]), np.nan)
    r, c = px[:, 0] - rows.start, px[:, 1] - cols.start
    img[r, c] = f
    gy, gx = np.gradient(img, axis=(0, 1)) if min(h, w) > 1 else (np.zeros_like(img), np.zeros_like(img))
    gx, gy = np.nan_to_num(gx[r, c]), np.nan_to_num(gy[r, c])
    lnE = np.log(np.clip(hits.cos_i, 1e-12, None) / hits.r2)
    uv = px[:, ::-1].astype(np.float64)  # (u = col, v = row)
    for q, sq in perturbations:
        duv = q.project(hits.x + (np.mean(sq.corners(), axis=0) - np.mean(sphere.corners(), axis=0)), calib) - uv
        dq = calib.rays(uv[:, 0], uv[:, 1]) @ q.R
        dq /= np.linalg.norm(dq, axis=-1, keepdims=True)
        hq, hit_q = sphere_hits(q.centre, dq, sq, light_position)
        dlnE = np.zeros(len(f))
        if hit_q.any():
            dlnE[hit_q] = np.log(np.clip(hq.cos_i, 1e-12, None) / hq.r2) - lnE[hit_q]
        delta = gx * duv[:, :1] + gy * duv[:, 1:] - f * dlnE[:, None]
        var += np.nan_to_num(delta) ** 2
    return var


def centre_perturbations(pose, sphere: Sphere, centre_sigma) -> list:
    """``(pose, sphere)`` pairs with the centre one σ off along each axis whose σ is positive (independent axes:
    a diagonal covariance's principal axes)."""
    if centre_sigma is None or not isinstance(sphere, Sphere):
        return []
    out = []
    for k, s in enumerate(np.asarray(centre_sigma, dtype=np.float64).reshape(3)):
        if s > 0 and np.isfinite(s):
            c = np.array(sphere.centre)
            c[k] += s
            out.append((pose, Sphere(tuple(c), sphere.radius)))
    return out


def sphere_frame_samples(rate, var, calib, pose, sphere: Sphere, light_position, layout, *,
                         grazing_deg: float = 80.0, min_snr: float = 5.0, pose_perturbations=(),
                         centre_sigma=None) -> SphereFrameSamples:
    """Per-pixel BRDF samples of ``sphere`` in one merged frame (``rate``/``var`` (H, W, 3), NaN where saturated
    in every exposure), with the camera ``pose`` and the light at ``light_position`` (sample frame, metres);
    ``pose_perturbations`` (the board pose's, :meth:`~gonio.pipeline.markers.BoardPose.perturbed`) and the sphere
    centre's standard uncertainty ``centre_sigma`` ((3,) metres, per axis) add the geometry's variance
    (:func:`_geometry_variance`) to each σ."""
    rate = np.asarray(rate, dtype=np.float64)
    var = np.asarray(var, dtype=np.float64)
    box = sphere_box(calib, pose, sphere)
    counts = {"hit": 0, "silhouette": 0, "terminator": 0, "saturated": 0, "dark": 0, "used": 0}
    empty = np.zeros(0)
    if box is None:
        z3 = np.zeros((0, 3))
        return SphereFrameSamples(empty, empty, empty, z3, z3, np.zeros((0, 2), int), z3, z3, counts, z3, z3)
    kI, skI = white_scale(rate, var, calib, pose, layout, light_position, sphere)
    d, rc = pixel_rays_world(calib, pose, *box)
    hits, hit = sphere_hits(pose.centre, d, sphere, light_position)
    px = rc[hit]
    r_px = rate[px[:, 0], px[:, 1]]
    v_px = var[px[:, 0], px[:, 1]]
    cos_lim = math.cos(math.radians(grazing_deg))
    sil = hits.cos_o < cos_lim
    from gonio.sphere.footprint import pixel_footprint

    foot = np.full((len(px), 5, 3), np.nan)
    foot[~sil] = pixel_footprint(calib, pose, sphere, px[~sil], light_position)
    sil |= ~np.all(np.isfinite(foot), axis=(1, 2))  # the pixel's footprint leaves the target (a cylinder's ends)
    term = ~sil & (hits.cos_i < cos_lim)
    sat = ~sil & ~term & ~np.all(np.isfinite(r_px), axis=1)
    E = np.clip(hits.cos_i, 0.0, None) / hits.r2
    with np.errstate(invalid="ignore", divide="ignore"):
        f = r_px / (kI * E[:, None])
        sf = np.sqrt(v_px / (kI * E[:, None]) ** 2 + (f * skI / kI) ** 2)
        snr = np.min(np.abs(f) / sf, axis=1)
    dark = ~sil & ~term & ~sat & ~(snr >= min_snr)
    use = ~(sil | term | sat | dark)
    perturb = [(q, sphere) for q in pose_perturbations] + centre_perturbations(pose, sphere, centre_sigma)
    if perturb:
        geo = _geometry_variance(np.where(use[:, None], f, np.nan), px, hits, box, calib, pose, sphere,
                                 light_position, perturb)
        sf = np.sqrt(sf ** 2 + geo)
    counts.update(hit=int(hit.sum()), silhouette=int(sil.sum()), terminator=int(term.sum()), saturated=int(sat.sum()),
                  dark=int(dark.sum()), used=int(use.sum()))
    return SphereFrameSamples(hits.theta_h[use], hits.theta_d[use], hits.phi_d[use], f[use], sf[use], px[use],
                              hits.wi[use], hits.wo[use], counts, hits.wi_local[use], hits.wo_local[use], foot[use])
