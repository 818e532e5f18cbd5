"""The camera model: the EMVA 1288 noise model, pinhole intrinsics with OpenCV distortion, a rigid pose, and
the 8-bit inverse-response lookup.

A device-level concept shared by the rig layer (the camera file, :mod:`gonio.rig.calibration`), the
pipeline (:mod:`gonio.pipeline.target` re-exports these, :mod:`gonio.pipeline.hdr`) and the simulator, so it
sits below both (docs/architecture.md §1: layers point one way; issue 31 cut rig → pipeline here).
Frames: *camera frame* (OpenCV pinhole): x right, y down, z forward; ``X_cam = R X_world + t``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from gonio.errors import ConfigError
from gonio.geometry import normalize

__all__ = ["NoiseModel", "CameraCalibration", "CameraPose", "lookup_response"]


def lookup_response(pixels: np.ndarray, response: np.ndarray) -> np.ndarray:
    """Map 8-bit values through an inverse response (256 × C table, per channel; Debevec & Malik 1997's g
    exponentiated): ``out[..., c] = response[pixels[..., c], c]`` (a single-channel table serves every channel)."""
    lut = response.reshape(256, -1).astype(np.float64)
    px = pixels if pixels.ndim == 3 else pixels[..., None]
    return np.stack([lut[px[..., c], min(c, lut.shape[1] - 1)] for c in range(px.shape[2])], axis=-1)


@dataclass(frozen=True)
class NoiseModel:
    """Sensor noise model used to propagate uncertainty (EMVA 1288 linear camera model).

    Raw value above black level ``y = K·G·(n_e) + noise``; variance
    ``σ_y² = (K G)² (μ_e + σ_read²) + 1/12`` (shot noise of signal and dark electrons, read noise,
    quantization); EMVA Standard 1288 release 4.0, §2 ("Mathematical model").

    Attributes
    ----------
    dn_per_electron : float
        System gain K at analogue gain 1 (DN per electron).
    read_noise_e : float
        Temporal dark (read) noise, electrons.
    full_well_e : float or None
        Saturation capacity in electrons (where the response stops being linear), if known.
    """

    dn_per_electron: float = 0.2
    read_noise_e: float = 3.0
    full_well_e: float | None = None

    def linear_limit(self, saturation_dn: float, black_level: float, gain: float = 1.0) -> float:
        """Largest raw value still on the linear response: ADC saturation or the full well, if lower."""
        if self.full_well_e is None:
            return float(saturation_dn)
        return float(min(saturation_dn, black_level + self.full_well_e * self.dn_per_electron * gain))

    def variance(self, signal_dn, gain: float = 1.0) -> np.ndarray:
        """Variance (DN²) of one raw value whose mean signal above black is ``signal_dn`` (signal + dark)."""
        kg = self.dn_per_electron * gain
        return kg * np.maximum(signal_dn, 0.0) + (kg * self.read_noise_e) ** 2 + 1.0 / 12.0


@dataclass(frozen=True)
class CameraCalibration:
    """Pinhole intrinsics, lens distortion (OpenCV's 5-coefficient model) and the noise model.

    ``radiometric_scale`` (optional, absolute mode): DN per second at gain 1 per unit radiance for
    the calibrated light at photodiode reading 1, per RGB channel.
    """

    K: np.ndarray
    width: int
    height: int
    dist: np.ndarray = field(default_factory=lambda: np.zeros(5))
    noise: NoiseModel = field(default_factory=NoiseModel)
    radiometric_scale: tuple[float, float, float] | None = None

    def __post_init__(self):
        K = np.asarray(self.K, dtype=np.float64)
        if K.shape != (3, 3) or not np.isfinite(K).all() or K[0, 0] <= 0 or K[1, 1] <= 0:
            raise ConfigError.field(None, "calibration.K", self.K, "needs a finite 3x3 matrix with fx, fy > 0")
        dist = np.asarray(self.dist, dtype=np.float64).ravel()
        if dist.size not in (4, 5, 8, 12, 14):
            raise ConfigError.field(None, "calibration.dist", self.dist, "needs 4, 5, 8, 12 or 14 coefficients")
        if int(self.width) <= 0 or int(self.height) <= 0:
            raise ConfigError.field(None, "calibration.size", (self.width, self.height), "must be positive")
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "dist", dist)

    @classmethod
    def pinhole(cls, width: int, height: int, focal_px: float, **kw) -> "CameraCalibration":
        """An ideal pinhole with the principal point at the image centre."""
        K = np.array([[focal_px, 0, (width - 1) / 2], [0, focal_px, (height - 1) / 2], [0, 0, 1.0]])
        return cls(K=K, width=width, height=height, **kw)

    def rays(self, u, v) -> np.ndarray:
        """Unit viewing rays (camera frame) through pixel coordinates ``(u, v)`` (pixel centres at integers).

        Distortion is removed with ``cv2.undistortPoints`` when any coefficient is non-zero.
        """
        u = np.asarray(u, dtype=np.float64)
        v = np.asarray(v, dtype=np.float64)
        if np.any(self.dist):
            import cv2

            pts = np.stack([u.ravel(), v.ravel()], axis=-1).reshape(-1, 1, 2)
            xy = cv2.undistortPoints(pts, self.K, self.dist).reshape(u.shape + (2,))
            x, y = xy[..., 0], xy[..., 1]
        else:
            fx, fy, cx, cy = self.K[0, 0], self.K[1, 1], self.K[0, 2], self.K[1, 2]
            x = (u - cx) / fx - self.K[0, 1] * (v - cy) / (fx * fy)
            y = (v - cy) / fy
        return normalize(np.stack([x, y, np.ones_like(x)], axis=-1))


@dataclass(frozen=True)
class CameraPose:
    """Rigid camera pose: ``X_cam = R X_world + t`` (world = sample frame)."""

    R: np.ndarray
    t: np.ndarray

    def __post_init__(self):
        object.__setattr__(self, "R", np.asarray(self.R, dtype=np.float64).reshape(3, 3))
        object.__setattr__(self, "t", np.asarray(self.t, dtype=np.float64).reshape(3))

    @property
    def centre(self) -> np.ndarray:
        """Camera centre in world coordinates, ``−Rᵀ t``."""
        return -self.R.T @ self.t

    @classmethod
    def look_at(cls, eye, target=(0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0)) -> "CameraPose":
        """Camera at ``eye`` looking at ``target``; image 'up' toward ``up`` (falls back to +x if parallel)."""
        eye = np.asarray(eye, dtype=np.float64)
        z = normalize(np.asarray(target, dtype=np.float64) - eye)
        x = np.cross(z, np.asarray(up, dtype=np.float64))
        if np.linalg.norm(x) < 1e-9:
            x = np.cross(z, [1.0, 0.0, 0.0])
        x = normalize(x)
        y = np.cross(z, x)
        R = np.stack([x, y, z])
        return cls(R, -R @ eye)

    def project(self, points, calib: CameraCalibration) -> np.ndarray:
        """Pixel coordinates (..., 2) of world points (..., 3) (pinhole + distortion via OpenCV)."""
        import cv2

        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        rvec, _ = cv2.Rodrigues(self.R)
        uv, _ = cv2.projectPoints(p, rvec, self.t, calib.K, calib.dist)
        return uv.reshape(np.shape(points)[:-1] + (2,))
