"""``gonio calibrate check``: how far a rig file's directions are from what the camera really sees.

A few poses are re-measured on the rig (:func:`gonio.session.geocal_session.check_session_plan`, run by the
same session runner and capture as ``gonio calibrate rig``: the board pose in every frame, the light's
highlight in the tile on the stage). For each pose the rig file's kinematics give ``wi`` and ``wo``
(:meth:`gonio.rig.kinematics.Rig.directions`, with its ``[calibration]`` if it has one); what the camera
sees gives them independently:

* **wo**: the camera centre from the ChArUco board pose, as a direction from the sample centre;
* **wi**: the light's highlight is its mirror image in the sample plane (law of reflection), which lies
  on the camera ray through the highlight's pixel: ``m = c + s·d`` (``c`` the board's camera centre,
  ``d = Rᵀ·(x, y, 1)/|·|``). Its distance from the sample centre is taken from the rig file (the ray
  meets that sphere; one view cannot give a distance): the rig file's distance error ``δρ`` enters
  ``wi`` only through the angle between the ray and the radius through the tile's centre (a few degrees),
  ``δρ·sin(·)/ρ`` — < 0.01° for a calibrated rig (``δρ`` ≲ 0.2 mm), ~0.05° for a declared one with a 5 mm error.
  Then ``wi = (mx, my, −mz)/|m|``.

The angle between each pair (:func:`gonio.rig.chain.angle_between_deg`) is the error left, plus each
observation's own noise (the board pose's ~0.2 mm / 0.02°, the highlight's sub-pixel centroid: ~0.05° per
pose for wi, ~0.04° for wo at a 0.3 m camera distance — a calibrated rig checks at about that, a rig off by
degrees far above it); the verdict
compares the 95th percentile of each with a threshold (default :data:`THRESHOLD_DEG`, issue 15's goal
after calibration).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gonio.rig.chain import angle_between_deg

__all__ = ["THRESHOLD_DEG", "GeoCheck", "check_geometry", "observed_wi", "observed_wo"]

#: Default verdict threshold (degrees) on the 95th percentile of the wi and wo errors.
THRESHOLD_DEG = 0.25


def observed_wo(cams) -> np.ndarray:
    """Unit directions from the sample centre to the camera centres of board poses ``(n, 3)``."""
    p = np.stack([c.position for c in cams])
    return p / np.linalg.norm(p, axis=-1, keepdims=True)


def observed_wi(highs, light_distance) -> np.ndarray:
    """Unit light directions from highlights (module docstring): the camera ray through each highlight meets the
    sphere of radius ``light_distance`` (m, per observation) about the sample centre at the light's mirror image."""
    o = np.stack([h.position for h in highs])
    xy = np.stack([h.xy for h in highs])
    R = np.stack([h.R for h in highs])
    v = np.concatenate([xy, np.ones((len(highs), 1))], axis=1)
    d = (np.swapaxes(R, -1, -2) @ v[..., None])[..., 0]
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    b = np.sum(o * d, axis=-1)
    rho = np.asarray(light_distance, dtype=np.float64)
    disc = b ** 2 - np.sum(o * o, axis=-1) + rho ** 2
    s = -b + np.sqrt(np.clip(disc, 0.0, None))   # the far root: past the mirror
    m = o + s[:, None] * d
    wi = m * np.array([1.0, 1.0, -1.0])
    return wi / np.linalg.norm(wi, axis=-1, keepdims=True)


@dataclass
class GeoCheck:
    """Errors (degrees) of the rig file's wi (one per highlight) and wo (one per board pose), and the verdict."""

    wi_deg: np.ndarray
    wo_deg: np.ndarray
    threshold_deg: float

    @property
    def ok(self) -> bool:
        return bool(len(self.wi_deg) and len(self.wo_deg) and self.p95("wi") <= self.threshold_deg
                    and self.p95("wo") <= self.threshold_deg)

    def p95(self, which: str) -> float:
        x = self.wi_deg if which == "wi" else self.wo_deg
        return float(np.percentile(x, 95)) if len(x) else float("nan")

    def lines(self, source: str) -> list[str]:
        """The report: one line per direction, then the one-line verdict."""
        out = []
        for name, x, what in (("wi", self.wi_deg, "light's reflection"), ("wo", self.wo_deg, "ChArUco board")):
            if len(x):
                out.append(f"  {name} vs the {what} ({len(x)} poses): median {np.median(x):.3f}°, "
                           f"p95 {self.p95(name):.3f}°, max {x.max():.3f}°")
            else:
                out.append(f"  {name}: no pose gave a {what}")
        if self.ok:
            out.append(f"verdict: OK: {source}'s wi and wo are within {self.threshold_deg:g}° of what the camera sees "
                       f"(p95 {self.p95('wi'):.3f}° and {self.p95('wo'):.3f}°)")
        else:
            worst = max(("wi", "wo"), key=lambda k: np.nan_to_num(self.p95(k), nan=np.inf))
            out.append(f"verdict: RECALIBRATE: {source}'s {worst} is off by {self.p95(worst):.3f}° (p95) > "
                       f"{self.threshold_deg:g}°; run `gonio calibrate rig` from the declared rig file")
        return out


def check_geometry(rig, cams, highs, *, threshold_deg: float = THRESHOLD_DEG) -> GeoCheck:
    """The error of ``rig``'s directions against the observations (module docstring)."""
    wo = np.zeros(0)
    wi = np.zeros(0)
    if cams:
        j = np.stack([c.joints for c in cams])
        wo = angle_between_deg(rig.directions(j)[1], observed_wo(cams))
    if highs:
        j = np.stack([h.joints for h in highs])
        rho = np.linalg.norm(rig.light_position(j), axis=-1)
        wi = angle_between_deg(rig.directions(j)[0], observed_wi(highs, rho))
    return GeoCheck(wi, wo, float(threshold_deg))
