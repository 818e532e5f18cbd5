"""Error measures users compare BRDF fits with, whatever loss the fit minimized.

* :func:`cbrt_error` — the cube-root cosine-weighted RMS error
  E = √( Σ (∛(f_m cos θi) − ∛(f cos θi))² / Σ (∛(f cos θi))² ), relative, over samples and channels:
  the cosine-weighted error of Ngan, Durand & Matusik, "Experimental Analysis of BRDF Models", EGSR 2005
  (their Eq. 3) taken on cube roots of the values, the compression Forés, Ferwerda & Gu (CIC 2012) found
  closest to perceived differences, so a metal's specular peak does not decide everything.
* :func:`image_error` — the relative RMS difference of rendered images: a sphere seen from +z under one
  distant point light at each of a few light–view angles (the lecture notes' "Phong examples",
  ``004_6b0fa14dcb48ed2f.txt``), pixel radiance L = f(wi, wo) cos θi per unit irradiance, rendered once
  with the model and once with the measurement itself (each pixel takes the nearest measured sample in
  Rusinkiewicz's (h, d) coordinates, φh ignored: isotropic), over the pixels where the measurement has
  a sample within :data:`IMAGE_MAX_GAP` and θi, θo are within the fit's range.
* :func:`delta_e` — the mean CIELAB colour difference ΔE*ab of the same sphere images: the perceptual
  measure (a difference of 1 is about the smallest one sees).
"""

from __future__ import annotations

import numpy as np

from gonio.geometry import frame_from_normal, half_diff_from_dirs, to_local

__all__ = ["cbrt_error", "image_error", "delta_e", "sphere_pixels", "sphere_targets", "sphere_sample_index", "metrics", "IMAGE_ANGLES_DEG", "IMAGE_PIXELS", "IMAGE_MAX_GAP"]

#: Light–view angles of the rendered spheres (degrees).
IMAGE_ANGLES_DEG = (0.0, 30.0, 60.0)
#: Sphere image size (pixels on a side).
IMAGE_PIXELS = 64
#: Largest distance in (h, d) coordinates (≈ radians) between a pixel's geometry and its measured sample.
IMAGE_MAX_GAP = 0.03


def cbrt_error(m: np.ndarray, y: np.ndarray, cos_i: np.ndarray) -> float:
    """Relative cube-root cosine-weighted RMS error of model values ``m`` against data ``y`` (N, 3)."""
    c = cos_i[:, None]
    a, b = np.cbrt(m * c), np.cbrt(y * c)
    return float(np.sqrt(np.sum((a - b) ** 2) / max(np.sum(b * b), 1e-300)))


def _hd_coords(wi, wo) -> np.ndarray:
    """Points (N, 5) in which Euclidean distance ≈ angular distance of isotropic geometries: the half
    vector in the (x, z) plane and the difference vector, folded to φd ∈ [0, π) (reciprocity)."""
    th, _, td, pd = half_diff_from_dirs(wi, wo)
    pd = np.mod(pd, np.pi)
    sd = np.sin(td)
    return np.stack([np.sin(th), np.cos(th), sd * np.cos(pd), sd * np.sin(pd), np.cos(td)], axis=-1)


def sphere_geometry(angle_deg: float, pixels: int = IMAGE_PIXELS):
    """``(wi, wo, mask)`` of the pixels of a sphere seen from +z, lit from ``angle_deg`` off the view
    direction in the x–z plane, in each pixel's local frame (z = the sphere's normal)."""
    u = (np.arange(pixels) + 0.5) / pixels * 2.0 - 1.0
    x, y = np.meshgrid(u, -u)
    inside = x * x + y * y < 1.0
    n = np.stack([x[inside], y[inside], np.sqrt(1.0 - x[inside] ** 2 - y[inside] ** 2)], axis=-1)
    a = np.radians(angle_deg)
    frame = frame_from_normal(n, np.array([1.0, 0.0, 0.0]))
    wi = to_local(np.array([np.sin(a), 0.0, np.cos(a)]), frame)
    wo = to_local(np.array([0.0, 0.0, 1.0]), frame)
    return wi, wo, inside


def image_error(model, data, angles_deg=IMAGE_ANGLES_DEG, pixels: int = IMAGE_PIXELS, _tree=None) -> float | None:
    """Relative RMS difference √(Σ (L_model − L_data)² / Σ L_data²) of the sphere images (module
    docstring); ``None`` when the data cover no pixel."""
    pairs = sphere_pixels(model, data, angles_deg, pixels, _tree)
    if pairs is None:
        return None
    lm, ld = pairs
    den = float(np.sum(ld * ld))
    return None if den == 0.0 else float(np.sqrt(np.sum((lm - ld) ** 2) / den))


#: sRGB (linear, D65) to CIE XYZ (IEC 61966-2-1).
_RGB_TO_XYZ = np.array([[0.4124, 0.3576, 0.1805], [0.2126, 0.7152, 0.0722], [0.0193, 0.1192, 0.9505]])
_WHITE_D65 = _RGB_TO_XYZ.sum(axis=1)


def _lab(rgb: np.ndarray, white: float) -> np.ndarray:
    """CIE 1976 L*a*b* of linear sRGB radiances scaled so that ``white`` (a radiance) is the reference white
    (CIE 15:2004, §8.2.1), values above white allowed (L* > 100)."""
    xyz = (rgb / white) @ _RGB_TO_XYZ.T / _WHITE_D65
    e = 216 / 24389
    f = np.where(xyz > e, np.cbrt(np.maximum(xyz, 0.0)), (24389 / 27 * xyz + 16) / 116)
    return np.stack([116 * f[:, 1] - 16, 500 * (f[:, 0] - f[:, 1]), 200 * (f[:, 1] - f[:, 2])], axis=-1)


def delta_e(model, data, angles_deg=IMAGE_ANGLES_DEG, pixels: int = IMAGE_PIXELS) -> float | None:
    """Mean CIE 1976 colour difference ΔE*ab (CIE 15:2004, §8.2.1; 1 ≈ a just-noticeable difference,
    Sharma, *Digital Color Imaging Handbook*, 2003, ch. 1) between the sphere images of the model and of the
    data (:func:`image_error`'s pixels), each image's reference white the 99th percentile of the data image's
    luminance (a highlight may exceed it, as in a displayed photograph); ``None`` when the data cover no pixel."""
    pairs = sphere_pixels(model, data, angles_deg, pixels)
    if pairs is None:
        return None
    lm, ld = pairs
    lum = ld @ _RGB_TO_XYZ[1]
    white = float(np.percentile(lum, 99)) if lum.size else 0.0
    if white <= 0.0:
        return None
    return float(np.mean(np.linalg.norm(_lab(lm, white) - _lab(ld, white), axis=-1)))


def sphere_targets(data, angles_deg=IMAGE_ANGLES_DEG, pixels: int = IMAGE_PIXELS, _tree=None):
    """The sphere pixels of :func:`image_error` that have a measured sample within :data:`IMAGE_MAX_GAP`, over
    all ``angles_deg``, as samples: ``(wi, wo, f)`` (P, 3) each, ``f`` the nearest measured sample's value at
    the pixel's own geometry — what the rendering of the measurement shows there; ``None`` when there is none.
    A least-squares fit to them with weights cos²θi minimizes the image error itself (:mod:`gonio.fit.dupuy`).

    Remembered on the data (read-only arrays) when the data's own tree is used: a report asks for them twice (the
    image error and ΔE) and a selection once per candidate."""
    if _tree is not None:
        return _sphere_targets(data, angles_deg, pixels, _tree)
    cache = data.__dict__.setdefault("_kernel_cache", {})
    key = ("sphere_targets", tuple(float(a) for a in angles_deg), int(pixels))
    if key not in cache:
        out = _sphere_targets(data, angles_deg, pixels, data_tree(data))
        for a in out or ():
            a.setflags(write=False)
        cache[key] = out
    return cache[key]


def _sphere_hits(data, angles_deg, pixels, tree):
    """Per angle of ``angles_deg`` with a pixel inside the data's range of cos θ: the pixels of :func:`image_error`'s
    sphere whose nearest measured sample (k-d tree ``tree`` of the data's geometry) lies within
    :data:`IMAGE_MAX_GAP`, as ``(wi, wo, index of that sample)``."""
    cmin = float(min(data.cos_i.min(), data.cos_o.min()))
    for angle in angles_deg:
        wi, wo, _ = sphere_geometry(angle, pixels)
        ok = (wi[:, 2] >= cmin) & (wo[:, 2] >= cmin)
        if not ok.any():
            continue
        wi, wo = wi[ok], wo[ok]
        dist, idx = tree.query(_hd_coords(wi, wo), distance_upper_bound=IMAGE_MAX_GAP)
        hit = np.isfinite(dist)
        yield wi[hit], wo[hit], idx[hit]


def _sphere_targets(data, angles_deg, pixels, tree):
    """:func:`sphere_targets` with the k-d tree ``tree`` of the data's geometry."""
    out = [(wi, wo, data.y[idx]) for wi, wo, idx in _sphere_hits(data, angles_deg, pixels, tree) if len(idx)]
    if not out:
        return None
    return tuple(np.concatenate(a) for a in zip(*out))


def sphere_sample_index(data, angles_deg=IMAGE_ANGLES_DEG, pixels: int = IMAGE_PIXELS) -> np.ndarray:
    """Indices (sorted, unique) of the samples :func:`image_error`'s spheres show: each pixel's nearest measured
    sample within :data:`IMAGE_MAX_GAP` (the k-d tree is the one the error measures use, cached on the data)."""
    out = [idx for _, _, idx in _sphere_hits(data, angles_deg, pixels, data_tree(data))]
    return np.unique(np.concatenate(out)) if out else np.zeros(0, dtype=np.intp)


def sphere_cover(data, angles_deg=IMAGE_ANGLES_DEG, pixels: int = IMAGE_PIXELS) -> np.ndarray:
    """Per sample (N,), the sum of cos²θi over the pixels of :func:`image_error`'s spheres whose nearest measured
    sample (within :data:`IMAGE_MAX_GAP`) it is: Σ cover · (f_model − f)² over the samples approximates the squared
    numerator of the image error with each pixel compared at its sample's own geometry (0 for a sample no pixel
    shows)."""
    cover = np.zeros(len(data))
    for wi, _, idx in _sphere_hits(data, angles_deg, pixels, data_tree(data)):
        cover += np.bincount(idx, wi[:, 2] ** 2, len(data))
    return cover


def sphere_pixels(model, data, angles_deg=IMAGE_ANGLES_DEG, pixels: int = IMAGE_PIXELS, _tree=None):
    """``(L_model, L_data)`` (P, 3) of the sphere pixels of :func:`image_error` that have a measured sample
    within :data:`IMAGE_MAX_GAP` (:func:`sphere_targets`), L = f cos θi; ``None`` when there is none."""
    t = sphere_targets(data, angles_deg, pixels, _tree)
    if t is None:
        return None
    wi, wo, f = t
    c = wi[:, 2][:, None]
    return model.eval(wi, wo) * c, f * c


#: Data sets with at least this many samples share what their directions alone decide (:func:`geometry_cache`).
SHARED_GEOMETRY_MIN = 100_000
#: The last large data set's geometry products, by a SHA-1 digest of its directions (one entry: a MERL table's
#: k-d tree is ~60 MB).
_SHARED_GEOMETRY: dict[bytes, dict] = {}


def geometry_cache(data) -> dict:
    """A dict for what the data's directions alone decide (the k-d tree of :func:`data_tree`, the neighbours of
    :mod:`gonio.fit.gof`), cached on the data and, from :data:`SHARED_GEOMETRY_MIN` samples on, shared with the last
    data set whose directions are the very same bits (a digest of ``wi`` and ``wo``, ~0.02 s for a MERL table's
    9·10⁵ samples): the fits of one table read from a file and from its samples, a selection's candidates after a
    fit, the tables of the same MERL cells measured or made from other materials all build the tree once (~0.3 s)."""
    import hashlib

    cache = data.__dict__.setdefault("_kernel_cache", {})
    if "geometry" not in cache:
        if len(data) < SHARED_GEOMETRY_MIN:
            cache["geometry"] = {}
        else:
            h = hashlib.sha1(repr((data.wi.shape, data.wo.shape)).encode())
            for a in (data.wi, data.wo):
                h.update(np.ascontiguousarray(a, dtype=np.float64).data)
            key = h.digest()
            shared = _SHARED_GEOMETRY.get(key)
            if shared is None:
                shared = {}
                _SHARED_GEOMETRY.clear()
                _SHARED_GEOMETRY[key] = shared
            cache["geometry"] = shared
    return cache["geometry"]


def data_tree(data):
    """k-d tree of the data's geometry in the coordinates of :func:`image_error` (cached: :func:`geometry_cache`).
    Built with sliding-midpoint splits and uncompacted nodes (``balanced_tree=False, compact_nodes=False``): 2.5×
    faster to build on a MERL table's 9·10⁵ samples, and a nearest-neighbour query's answer does not depend on the
    splits."""
    from scipy.spatial import cKDTree

    cache = geometry_cache(data)
    if "hd_tree" not in cache:
        cache["hd_tree"] = cKDTree(_hd_coords(data.wi, data.wo), balanced_tree=False, compact_nodes=False)
    return cache["hd_tree"]


def metrics(model, data, values: np.ndarray | None = None) -> dict[str, float | None]:
    """Both measures of ``model`` on prepared ``data`` (:class:`gonio.fit.data.FitData`):
    ``{"cbrt_rel": ..., "image_rel": ...}``."""
    m = model.eval(data.wi, data.wo) if values is None else values
    return {"cbrt_rel": cbrt_error(m, data.y, data.cos_i), "image_rel": image_error(model, data),
            "delta_e": delta_e(model, data)}
