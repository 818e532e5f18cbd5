"""Residuals of the geometric calibration (:mod:`gonio.rig.geocal`) and their Jacobian, for one parameter vector or
a batch of them at once.

The observations are stacked into arrays once (:class:`Observed`), not at every evaluation. Every function here
takes :class:`gonio.rig.chain.ChainErrors` with numbers (one chain) or with (K, 1) arrays (K chains,
:meth:`ChainErrors.from_vectors`) and gives, in the batch case, a leading axis of K whose rows are the same numbers,
bit for bit, as the K chains evaluated one by one. :func:`forward_jacobian` uses it to take the least squares'
forward differences — the very steps and quotients of :func:`scipy.optimize.least_squares`'s default ``'2-point'``
Jacobian (``scipy.optimize._numdiff.approx_derivative``: ``h = √ε · sign(x) · max(1, |x|)``, column
``(r(x + h e_j) − r(x)) / ((x_j + h_j) − x_j)``; Nocedal & Wright 2006, *Numerical Optimization*, §8.1, eq. 8.1) —
with all columns in one vectorized evaluation instead of one evaluation per parameter: the same Jacobian, hence
the same solution, a few times faster.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gonio.rig.chain import ChainErrors, chain_forward

__all__ = ["Observed", "rotvec", "extended_source_shift", "residual_blocks", "batch_shape", "errors_at",
           "forward_jacobian"]


@dataclass(frozen=True)
class Observed:
    """The camera and highlight observations of a calibration (:class:`gonio.rig.geocal.CameraObservation`,
    :class:`gonio.rig.geocal.HighlightObservation`) as stacked arrays, in their order."""

    cam_joints: np.ndarray      # (Nc, 4) rad
    cam_position: np.ndarray    # (Nc, 3) m
    cam_R: np.ndarray           # (Nc, 3, 3)
    high_joints: np.ndarray     # (Nh, 4) rad
    high_xy: np.ndarray         # (Nh, 2)
    high_position: np.ndarray   # (Nh, 3)
    high_R: np.ndarray          # (Nh, 3, 3)
    high_f0: np.ndarray         # (Nh,)
    high_radius: np.ndarray     # (Nh,) m

    @classmethod
    def of(cls, cams, highs) -> "Observed":
        def stack(obs, name, shape):
            return np.stack([getattr(o, name) for o in obs]) if obs else np.zeros((0,) + shape)

        return cls(stack(cams, "joints", (4,)), stack(cams, "position", (3,)), stack(cams, "R", (3, 3)),
                   stack(highs, "joints", (4,)), stack(highs, "xy", (2,)), stack(highs, "position", (3,)),
                   stack(highs, "R", (3, 3)), np.array([h.f0 for h in highs], dtype=np.float64),
                   np.array([h.source_radius_m for h in highs], dtype=np.float64))

    @property
    def n_cams(self) -> int:
        return self.cam_joints.shape[-2]

    @property
    def n_highs(self) -> int:
        return self.high_joints.shape[-2]

    def shifted(self, joints_delta) -> "Observed":
        """The same observations with every joint vector shifted by ``joints_delta`` (rad): (4,), or (B, 1, 4) for
        B shifts at once (the joints then (B, N, 4), every residual with a leading axis of B)."""
        from dataclasses import replace

        return replace(self, cam_joints=self.cam_joints + joints_delta, high_joints=self.high_joints + joints_delta)


def rotvec(R):
    """Rotation vector (rad) of rotation matrices ``(..., 3, 3)`` near the identity (small angle:
    the antisymmetric part, exact to second order; Murray, Li & Sastry 1994, §2.2)."""
    return 0.5 * np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1)


def extended_source_shift(image, C, R, f0, radius_m) -> np.ndarray:
    """Shift (N, 2), in normalized image coordinates, of the intensity centroid of the light's reflection off the
    projection of its centre's mirror image ``image`` (N, 3), seen from camera centres ``C`` (N, 3) with rotations
    ``R`` (N, 3, 3), for a reflector of Schlick reflectance ``F(cos θ) = f0 + (1 − f0)(1 − cos θ)⁵`` (Schlick
    1994, eq. 15) and a uniform (Lambertian) emitting disc of radius ``radius_m`` (N,) facing the camera
    (``image``, ``C``, ``R`` may carry a leading batch axis: (K, N, ...) then).

    Across the disc's image (radius ``ρ = radius / depth``) the reflectance varies with the ray's incidence on
    the plane z = 0, ``cos θ = −u_z`` for the ray ``u ∝ Rᵀ (x, y, 1)``: at first order the weights are
    ``1 + g·(x − x₀)`` with ``g = ∇ ln F`` at the centre, and the first moment of a uniform disc so weighted is
    ``ρ² g / 4`` (the centroid of a linearly weighted disc: ``∫ x (1 + g x) dA / ∫ (1 + g x) dA = g ⟨x²⟩``,
    ``⟨x²⟩ = ρ²/4``). On black glass (f0 0.04) at 65° incidence with a 10 mm disc at 0.8 m this is ~0.05 px at a
    380 px focal length: larger than the centroid's own σ, and the same sign at every azimuth (the bias of the light
    arm's parameters it otherwise causes: docs/uncertainty.md). The disc's foreshortening (its normal within a
    few degrees of the line of sight on a calibration plan) changes ``ρ²`` by < 1 %, and the terms of order ρ⁴ are
    far below the centroid's noise."""
    v = np.einsum("...ij,...j->...i", R, image - C)
    x0 = v[..., :2] / v[..., 2:3]
    f0 = np.broadcast_to(np.asarray(f0, dtype=np.float64), v.shape[:-1])

    def ln_f(xy):
        ray = np.concatenate([xy, np.ones(xy.shape[:-1] + (1,))], axis=-1)
        u = np.einsum("...ji,...j->...i", R, ray)          # Rᵀ ray: the ray in the sample frame
        cos_t = np.clip(-u[..., 2] / np.linalg.norm(u, axis=-1), 0.0, 1.0)
        return np.log(f0 + (1.0 - f0) * (1.0 - cos_t) ** 5)

    h = 1e-4
    g = np.stack([(ln_f(x0 + e) - ln_f(x0 - e)) / (2 * h) for e in (np.array([h, 0.0]), np.array([0.0, h]))], axis=-1)
    rho = np.asarray(radius_m, dtype=np.float64) / v[..., 2]
    return (rho ** 2 / 4.0)[..., None] * g


def batch_shape(errors: ChainErrors) -> tuple:
    """``(K,)`` for a batch of K chains (:meth:`ChainErrors.from_vectors`), ``()`` for one."""
    return np.shape(errors.sample_height_mm)[:-1]


def errors_at(x: np.ndarray, idx, p) -> ChainErrors:
    """The chain(s) whose parameter vector is ``x`` with ``x[idx]`` replaced by ``p`` (n,), or by each row of
    ``p`` (K, n): a batch of K chains."""
    p = np.asarray(p, dtype=np.float64)
    if p.ndim == 1:
        v = x.copy()
        v[idx] = p
        return ChainErrors.from_vector(v)
    V = np.repeat(x[None, :], len(p), axis=0)
    V[:, idx] = p
    return ChainErrors.from_vectors(V)


def residual_blocks(rig, errors: ChainErrors, obs: Observed, *, highlight_camera: str = "chain", white=None):
    """Residuals per observation kind, (..., m_kind) (a leading batch axis for a batch of chains, or for a batch of
    joint shifts: :meth:`Observed.shifted`).
    ``highlight_camera``: ``"chain"`` projects the light's mirror image with the camera pose of the chain being
    estimated (the board poses of those frames are camera observations too), ``"board"`` with each frame's own
    ChArUco pose. ``white``: per-kind whitening matrices (:func:`gonio.rig.geocal._whiteners`); a whitened block is
    named ``*_w`` (unitless)."""
    out = {}
    white = white or {}
    if obs.n_cams:
        _, pc, R = chain_forward(rig, errors, obs.cam_joints)
        dp = (pc - obs.cam_position) * 1e3
        dr = np.degrees(rotvec(R @ np.swapaxes(obs.cam_R, -1, -2)))
        batch = dp.shape[:-2]
        if white.get("camera") is not None:
            out["camera_w"] = (white["camera"] @ np.concatenate([dp, dr], axis=-1)[..., None])[..., 0].reshape(batch + (-1,))
        else:
            out["camera_mm"] = dp.reshape(batch + (-1,))
            out["camera_deg"] = dr.reshape(batch + (-1,))
    if obs.n_highs:
        pl, pc, Rc = chain_forward(rig, errors, obs.high_joints)
        image = pl * np.array([1.0, 1.0, -1.0])  # mirror image in the sample plane z = 0
        if highlight_camera == "board":
            pc, Rc = obs.high_position, obs.high_R
        v = (Rc @ (image - pc)[..., None])[..., 0]
        xy = v[..., :2] / v[..., 2:3]
        if np.any(obs.high_radius > 0):  # an extended source's centroid is not its centre's image (extended_source_shift)
            xy = xy + extended_source_shift(image, pc, Rc, obs.high_f0, obs.high_radius)
        d = (xy - obs.high_xy) * 1e3
        batch = d.shape[:-2]
        if white.get("highlight") is not None:
            out["highlight_w"] = (white["highlight"] @ d[..., None])[..., 0].reshape(batch + (-1,))
        else:
            out["highlight_mrad"] = d.reshape(batch + (-1,))
    return out


def forward_jacobian(fun, p, *args) -> np.ndarray:
    """Forward-difference Jacobian (m, n) of ``fun`` at ``p`` (n,) with :func:`scipy.optimize.least_squares`'s
    default steps and quotients (module docstring), taking ``fun`` at ``p`` and at the n shifted points as one
    batch ``fun(P (n + 1, n), *args) -> (n + 1, m)`` — so with a ``fun`` whose batch rows equal its single
    evaluations, the same matrix, in the same memory order, as scipy's ``'2-point'``."""
    p = np.asarray(p, dtype=np.float64)
    sign = (p >= 0).astype(float) * 2 - 1
    h = np.finfo(np.float64).eps ** 0.5 * sign * np.maximum(1.0, np.abs(p))
    P = np.repeat(p[None, :], len(p) + 1, axis=0)
    P[1 + np.arange(len(p)), np.arange(len(p))] = p + h
    F = fun(P, *args)
    dx = (p + h) - p
    Jt = (F[1:] - F[0]) / dx[:, None]
    return Jt.T
