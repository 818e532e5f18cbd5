"""One pose of a geometric calibration session: what the camera sees, turned into the observations of
:mod:`gonio.rig.geocal` — the camera's pose from the ChArUco board (with its covariance) and, with the
glossy black tile (or mirror) on the stage, the light's highlight in it (detected, sub-pixel, with its
covariance). The same code runs on the simulated rig's rendered frames and on a real camera's.

Frames per pose: one board frame at ``board_exposure`` (the highlight saturates there; it lies on the
tile, where the board has no corners), then the highlight frames at a short exposure chosen by
:func:`gonio.pipeline.highlight.find_highlight` (board and tile then black). A highlight is kept only
if the board pose of the same frame puts it inside the tile, clear of its edges
(:func:`gonio.pipeline.highlight.clear_of_edges`).
"""

from __future__ import annotations

import numpy as np

from gonio.rig.geocal import CameraObservation, HighlightObservation, rotvec

__all__ = ["board_observation", "observe_pose", "metered_board_frame", "calibration_layout", "BOARD_EXPOSURE", "TILE",
           "TILE_F0", "EMITTER_RADIUS_M"]

#: First exposure (s) of the board frame (then metered: one retake if its 99th percentile is outside 30–85 %
#: of the range).
BOARD_EXPOSURE = 0.005
#: The calibration tile (an 80 mm × 80 mm polished black glass tile or front-surface mirror) centred on
#: the sample area, in the sample plane (metres): larger hides too many of the board's markers.
TILE = (-0.04, -0.04, 0.04, 0.04)
#: The tile's reflectance at normal incidence (Schlick's f0): polished black glass, n ≈ 1.5, ((n − 1)/(n + 1))² =
#: 0.04 (a front-surface aluminium mirror: ~0.9). With the emitter's size it sets the highlight centroid's offset
#: from the light's mirror image (:func:`gonio.rig.geocal.extended_source_shift`).
TILE_F0 = 0.04
#: Radius (m) of the light's emitting disc (the lamp's exit aperture: its datasheet or a ruler; the simulated
#: light's is 10 mm).
EMITTER_RADIUS_M = 0.01


def calibration_layout(layout=None):
    """``layout`` (default: the default target) with the calibration tile (:data:`TILE`) as its sample patch."""
    from dataclasses import replace

    from gonio.pipeline.target import Rect, TargetLayout

    return replace(layout or TargetLayout(), sample=Rect(*TILE))


def board_observation(board_pose, joints) -> CameraObservation:
    """A :class:`CameraObservation` from a :class:`gonio.pipeline.markers.BoardPose`: the camera centre (m)
    and rotation in the sample frame, with the 6 × 6 covariance of (centre in mm, rotation vector in deg)
    propagated from the PnP covariance through its principal perturbations (:meth:`BoardPose.perturbed`)."""
    pose = board_pose.pose
    cov = None
    pert = board_pose.perturbed()
    if pert:
        d = np.array([np.concatenate([(p.centre - pose.centre) * 1e3, np.degrees(rotvec(p.R @ pose.R.T))]) for p in pert])
        cov = d.T @ d
    return CameraObservation(np.asarray(joints, dtype=np.float64), pose.centre, pose.R, cov)


def metered_board_frame(camera, exposure: float = BOARD_EXPOSURE, gain: float = 1.0, min_exposure: float = 1e-5):
    """A frame of the board at ``exposure``, retaken once at a metered exposure if its 99th percentile is outside
    30–85 % of the range (the board's bright squares brought to ~60 %)."""
    f = camera.capture(exposure, gain)
    p99 = float(np.percentile(np.asarray(f.pixels)[::2, ::2], 99.0)) - f.black_level
    full = (1 << f.bit_depth) - 1 - f.black_level
    if not 0.3 * full <= p99 <= 0.85 * full:
        t = float(np.clip(exposure * 0.6 * full / max(p99, 1.0), min_exposure, 0.25))
        f = camera.capture(t, gain)
    return f


def observe_pose(camera, calibration, layout, joints, *, highlight: bool, tile=None, board_exposure: float = BOARD_EXPOSURE,
                 gain: float = 1.0, bit_depth: int | None = None, min_exposure: float = 1e-5,
                 tile_f0: float = TILE_F0, emitter_radius_m: float = EMITTER_RADIUS_M):
    """``(CameraObservation | None, HighlightObservation | None, reason)`` at the rig's current pose
    (``joints``: the measured joint angles, rad). ``tile``: the tile's rectangle in the sample plane
    (default: the layout's sample patch); ``tile_f0``, ``emitter_radius_m``: the tile's reflectance and the
    light's emitting disc (:data:`TILE_F0`, :data:`EMITTER_RADIUS_M`), recorded with the highlight."""
    from gonio.pipeline.highlight import clear_of_edges, find_highlight
    from gonio.pipeline.covers import cover_points
    from gonio.pipeline.markers import detect_board_pose, to_gray8

    f = metered_board_frame(camera, board_exposure, gain, min_exposure)
    bp = detect_board_pose(to_gray8(f.pixels, bit_depth or f.bit_depth, f.black_level), calibration, layout.charuco,
                           covers=cover_points(layout), flat_field=True)
    if bp is None:
        return None, None, "ChArUco board not found"
    cam = board_observation(bp, joints)
    if not highlight:
        return cam, None, ""
    search = find_highlight(camera, calibration, gain=gain, min_exposure=min_exposure)
    hl = search.highlight
    if hl is None:
        return cam, None, search.reason
    why = clear_of_edges(hl, bp.pose, calibration, tile if tile is not None else layout.sample)
    if why:
        return cam, None, why
    return cam, HighlightObservation(cam.joints, hl.xy, cam.position, cam.R, hl.cov_xy, f0=tile_f0,
                                     source_radius_m=emitter_radius_m), ""
