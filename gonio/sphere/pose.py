"""One pose of a sphere, after its bracket is merged: the centre refined from the silhouette, then one BRDF sample
per pixel with the refined centre (issue 30: a sphere declared a millimetre off biases every pixel's normal).

The centre a pose's samples use is the declared one combined with the silhouettes of the poses stored before it and
its own (:func:`gonio.sphere.refine.centre_in_use`) when they contradict the declared centre (more than 3σ and
:data:`USE_FOUND_M` off), else the declared one; that centre's uncertainty is carried into every sample's σ
(:func:`gonio.sphere.pixels.sphere_frame_samples`). The poses before it come from the session's records (the
runner reads them back on a resume), so a resumed session uses, pose by pose, the very centre an uninterrupted one
used: bit-identical samples.
"""

from __future__ import annotations

import numpy as np

from gonio.sphere.geometry import Sphere
from gonio.sphere.pixels import SphereFrameSamples, sphere_frame_samples
from gonio.sphere.refine import centre_in_use, centre_note, refine_centre, session_centre

__all__ = ["sphere_pose_samples", "save_pixels", "load_pixels", "PIXEL_KEYS", "USE_FOUND_M"]

#: The samples move to the centre found only when it is this far (and 3σ) from the declared one: one fixed camera's
#: silhouettes share their errors (the same rim against the same board), a bias of a few tenths of a millimetre at
#: 320×240 that the poses' scatter does not show (benchmarks sphere: using it below this made the cells worse)
USE_FOUND_M = 5e-4

#: What a kept pose's NPZ holds per used pixel (``gonio measure --keep-pixels``; docs/formats.md)
PIXEL_KEYS = ("pixels", "wi_local", "wo_local", "f", "sigma", "footprint")


def sphere_pose_samples(rate, var, calib, cam_pose, declared: Sphere, light_position, layout, *, history=(),
                        min_snr: float = 5.0, pose_perturbations=()) -> SphereFrameSamples:
    """The pose's samples (``rate``/``var`` (H, W, C), NaN where not measured); ``history``: the earlier poses'
    record metas (their ``sphere_centre``), in pose order. The counts get ``centre`` (this pose's silhouette
    estimate, when found) and ``centre_used`` (the centre and σ its samples used)."""
    if not isinstance(declared, Sphere):  # a cylinder: its declared pose (the silhouette refinement is a sphere's)
        return sphere_frame_samples(rate, var, calib, cam_pose, declared, light_position, layout, min_snr=min_snr,
                                    pose_perturbations=pose_perturbations)
    history = list(history)
    prior = session_centre(history, declared)
    current, _ = centre_in_use(prior, declared)
    # the edges searched around the best centre so far, away from the terminator
    est = refine_centre(rate, calib, cam_pose, current, light_position=light_position,
                        pose_perturbations=pose_perturbations)
    mine = None
    if est is not None:
        mine = {"centre_m": est.centre.tolist(), "sigma_m": est.sigma.tolist(), "edges": est.n_edges}
        if est.cov_pose is not None:
            mine["sigma_pose_m"] = np.sqrt(np.clip(np.diag(est.cov_pose), 0.0, None)).tolist()
        history.append({"sphere_centre": mine})
    found = session_centre(history, declared) if mine else prior
    used, sigma = centre_in_use(found, declared)
    off = np.abs(np.asarray(found["offset_m"])) if found else np.zeros(3)
    if not (centre_note(found) and off.max() > USE_FOUND_M):  # the silhouettes do not contradict the declaration
        used = declared
        sigma = np.asarray(found["sigma_m"], dtype=np.float64) if found else sigma
    fs = sphere_frame_samples(rate, var, calib, cam_pose, used, light_position, layout, min_snr=min_snr,
                              pose_perturbations=pose_perturbations, centre_sigma=sigma)
    if mine is not None:
        fs.counts["centre"] = mine
    fs.counts["centre_used"] = {"centre_m": list(used.centre), "sigma_m": np.asarray(sigma).tolist()}
    return fs


def save_pixels(directory, index: int, fs: SphereFrameSamples) -> None:
    """Keep pose ``index``'s per-pixel samples in ``directory/pose-NNNNN.npz`` (:data:`PIXEL_KEYS`; written to a
    temporary name and renamed, so a file there is whole). A resume writes the same pose's file again."""
    import os
    from pathlib import Path

    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    tmp = d / f".pose-{index:05d}.npz.tmp"
    with open(tmp, "wb") as fh:
        np.savez_compressed(fh, **{k: np.asarray(getattr(fs, k)) for k in PIXEL_KEYS})
    os.replace(tmp, d / f"pose-{index:05d}.npz")


def load_pixels(directory) -> dict:
    """The kept per-pixel samples of a session's ``pixels`` directory (or the directory itself), concatenated in
    pose order, with ``pose`` (n,); a file that is not a kept pose's is refused in one line naming it."""
    from pathlib import Path

    from gonio.errors import DataError

    d = Path(directory)
    if (d / "pixels").is_dir():
        d = d / "pixels"
    files = sorted(d.glob("pose-*.npz"))
    if not files:
        raise DataError(f"{d}: no kept per-pixel samples (measure with --keep-pixels)")
    parts = {k: [] for k in (*PIXEL_KEYS, "pose")}
    shapes = {"pixels": (2,), "wi_local": (3,), "wo_local": (3,), "f": (3,), "sigma": (3,), "footprint": (5, 3)}
    for fp in files:
        try:
            idx = int(fp.stem.split("-")[1])
            with np.load(fp, allow_pickle=False) as z:
                arrs = {k: np.asarray(z[k]) for k in PIXEL_KEYS}
        except (OSError, ValueError, KeyError, IndexError) as exc:
            raise DataError(f"{fp}: not a kept pose's per-pixel samples ({type(exc).__name__})") from None
        n = len(arrs["f"])
        for k, shp in shapes.items():
            if arrs[k].shape != (n, *shp) or arrs[k].dtype.kind not in "fiu":
                raise DataError(f"{fp}: field {k!r} has shape {arrs[k].shape}, expected {(n, *shp)}")
            parts[k].append(arrs[k].astype(np.int64 if k == "pixels" else np.float64))
        parts["pose"].append(np.full(n, idx, dtype=np.int64))
    return {k: np.concatenate(v) for k, v in parts.items()}
