"""The detector solid angle of a session: over which directions one BRDF sample integrates reflected light.

A camera-based rig has no single detector: each *sample* the pipeline reports
(:func:`gonio.pipeline.reflectance.build_roi` / ``reflectance_samples``) is the mean over a *tile* of
sample pixels, each pixel seeing its own direction ``wo``. So one sample integrates reflected light
over

* the **angular bin** of its tile: the directions ``wo = (C − x)/|C − x|`` of the tile's points ``x``,
  i.e. (antipodally) the solid angle the tile subtends at the camera centre ``C``. For a pinhole
  camera that is the sum of its pixels' solid angles, ``Ω_px = (1 + x² + y²)^(-3/2) / (f_x f_y)``
  with ``(x, y, 1)`` the pixel's normalized ray (Hartley & Zisserman, *Multiple View Geometry*, 2nd
  ed., §6.1: pinhole projection; the solid angle of a small area ``dA`` at distance ``r`` seen at
  angle ``θ`` is ``dA cos θ / r²``, lecture notes 004, "radiometry": here ``dA = du dv / (f_x f_y)``
  on the plane z = 1, ``r = √(1 + x² + y²)``, ``cos θ = 1/r``);
* the **lens aperture** as seen from a surface point: a disc of diameter ``D`` at the camera
  distance ``R``, a cone of half-angle ``atan(D / 2R)``, ``Ω_ap = 2π (1 − R / √(R² + D²/4))``
  (solid angle of a right circular cone, lecture notes 004, "radiometry": ``Ω = 2π(1 − cos α)``).

``detector_solid_angle_sr`` is the combined extent, ``(√Ω_bin + √Ω_ap)²`` (the Brunn–Minkowski bound
for the bin widened by the pupil: exact for similar shapes, a lower bound otherwise; it is ``Ω_bin``
for the simulator's ideal pinhole). The bin is evaluated at the *reference view* — camera on the
sample normal at the rig's camera distance, light at 30° incidence — for the largest tile (an
interior one; tiles along the patch edges lose the pipeline's margin pixels);
at a view angle θo a tile's bin shrinks roughly as cos θo (foreshortening) while the pipeline's
tiling rule keeps each tile within ``max_bin_deg`` of ``wo``. Lens distortion is ignored (the
simulator has none). When the aperture is unknown (a hardware calibration without
``aperture_diameter_m`` or ``f_number`` + ``focal_length_m``) the value is ``None`` and
``reason`` says why; the bin part is still recorded.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from gonio.geometry import from_spherical

__all__ = ["pixel_solid_angles", "aperture_solid_angle", "aperture_from_calibration", "detector_solid_angle",
           "REFERENCE_THETA_I_DEG"]

#: Incidence of the reference view's light (it only chooses the tiling, through the wi span).
REFERENCE_THETA_I_DEG = 30.0


def pixel_solid_angles(calib, u, v) -> np.ndarray:
    """Solid angle (sr) of pinhole pixels ``(u, v)``: ``(1 + x² + y²)^(-3/2) / (f_x f_y)`` (module
    docstring), with ``(1 + x² + y²)^(-1/2)`` the z component of the pixel's unit ray
    (:meth:`gonio.pipeline.target.CameraCalibration.rays`, distortion removed); any shape."""
    K = calib.K
    return calib.rays(u, v)[..., 2] ** 3 / (K[0, 0] * K[1, 1])


def aperture_solid_angle(diameter_m: float, distance_m: float) -> float:
    """Solid angle (sr) of a lens aperture of ``diameter_m`` seen from ``distance_m``:
    ``2π (1 − R / √(R² + D²/4))`` (cone, module docstring)."""
    R, D = float(distance_m), float(diameter_m)
    return 2.0 * math.pi * (1.0 - R / math.sqrt(R * R + D * D / 4.0))


def _reference_bin(calib, layout, rig, max_bin_deg: float, max_bins: int, margin_px: float) -> tuple[float, int]:
    """Largest tile solid angle (sr: a full interior tile) and tile count at the reference view."""
    from gonio.pipeline.reflectance import build_roi
    from gonio.pipeline.target import CameraPose

    pose = CameraPose.look_at((0.0, 0.0, float(rig.camera_radius)))  # on the normal, image x = sample x
    light = float(rig.light_radius) * from_spherical(math.radians(REFERENCE_THETA_I_DEG), 0.0)
    roi = build_roi(pose, calib, layout, light, margin_px=margin_px, max_bin_deg=max_bin_deg, max_bins=max_bins)
    if roi.empty:
        return math.nan, 0
    v, u = np.mgrid[roi.rows, roi.cols].astype(np.float64)
    om = pixel_solid_angles(calib, u, v)
    lab = roi.label
    per_tile = np.bincount(lab[lab >= 0], om[lab >= 0], minlength=roi.n_tiles)
    per_tile = per_tile[per_tile > 0]
    return float(per_tile.max()), int(roi.n_tiles)


def detector_solid_angle(calib, layout, rig, *, aperture_diameter_m: float | None, pinhole: bool = False,
                         settings=None, aperture_source: str = "") -> dict[str, Any]:
    """The manifest's ``detector`` entry: ``solid_angle_sr`` (or ``None`` with ``reason``), its bin and
    aperture parts, and the definition. ``pinhole`` = an ideal pinhole camera (the simulator): ``Ω_ap = 0``."""
    from gonio.pipeline.acquire import PipelineSettings

    st = settings or PipelineSettings()
    bin_sr, n_tiles = _reference_bin(calib, layout, rig, st.max_bin_deg, st.max_bins, st.margin_px)
    out: dict[str, Any] = {
        "definition": "solid angle of reflected directions one sample integrates: the angular bin of the "
                      "pixels the pipeline averages per sample (tile), widened by the lens aperture; "
                      "(sqrt(bin) + sqrt(aperture))^2, see gonio/session/detector.py",
        "reference_view": f"camera on the sample normal at {float(rig.camera_radius):g} m, light at "
                          f"{REFERENCE_THETA_I_DEG:g} deg incidence; bins shrink ~cos(theta_o) elsewhere",
        "bin_sr": bin_sr if math.isfinite(bin_sr) else None,
        "tiles": n_tiles,
        "max_bin_deg": st.max_bin_deg,
        "aperture_diameter_m": 0.0 if pinhole else aperture_diameter_m,
        "aperture_sr": None,
        "solid_angle_sr": None,
        "reason": None,
    }
    if pinhole:
        out["aperture_sr"] = 0.0
        out["aperture_source"] = "ideal pinhole (simulated camera)"
    elif aperture_diameter_m is not None:
        out["aperture_sr"] = aperture_solid_angle(aperture_diameter_m, rig.camera_radius)
        out["aperture_source"] = aperture_source
    else:
        out["reason"] = ("the camera calibration gives no aperture_diameter_m (or f_number and focal_length_m), "
                         "so the lens aperture's solid angle is unknown")
    if not math.isfinite(bin_sr):
        out["reason"] = "the sample patch is not in view at the reference view"
    elif out["aperture_sr"] is not None:
        out["solid_angle_sr"] = (math.sqrt(bin_sr) + math.sqrt(out["aperture_sr"])) ** 2
    return out


def aperture_from_calibration(data: dict, source: str) -> tuple[float | None, str]:
    """Aperture diameter (m) from a calibration table: ``aperture_diameter_m``, or ``focal_length_m /
    f_number``; ``(None, "")`` if neither is given. Bad values: one-line ConfigError naming the field."""
    from gonio.errors import ConfigError

    def num(key):
        v = data[key]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not (math.isfinite(v) and v > 0):
            raise ConfigError.field(source, key, v, "must be a positive number")
        return float(v)

    if "aperture_diameter_m" in data:
        return num("aperture_diameter_m"), "aperture_diameter_m"
    if "f_number" in data or "focal_length_m" in data:
        for key in ("f_number", "focal_length_m"):
            if key not in data:
                raise ConfigError.field(source, key, None, "missing (f_number and focal_length_m go together)")
        return num("focal_length_m") / num("f_number"), "focal_length_m / f_number"
    return None, ""
