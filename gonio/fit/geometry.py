"""A fit's parameter covariance from the geometric calibration's error, which every sample of a session shares.

The calibrated rig file's covariance ``Σ_g`` of the chain parameters (:mod:`gonio.rig.geocov`) says how far
the light may really be from where the host put it, at every pose at once: one calibration error moves the
light of all poses together (a servo zero offset turns every wi the same way). Its part within a pose is in
each sample's ``sigma_pose``; across poses no per-sample σ can hold it, and a fit that takes the poses as
independent states a σ(α) many times too small. Here it is propagated into the fitted parameters
(GUM, JCGM 100:2008 §5.2, correlated inputs, ``Σ_θ,geo = J_θg Σ_g J_θgᵀ``; the perturbations along the principal
axes of ``Σ_g`` of JCGM 101:2008 §5 / JCGM 102:2011 §6.2.1, ``Σ_g = Σ_k δg_k δg_kᵀ`` with ``δg_k = √λ_k v_k``):

* per principal axis ``k`` and pose ``G`` the light's offset ``δS_kG = (∂S/∂g)(joints_G) δg_k``
  (:class:`CalibrationModes`, built from the session by :func:`gonio.session.calibration_modes.session_modes`);
* per sample what the data would have been, had the light been at ``S + δS``: the tile point ``x`` (where the
  sample's wi from ``S`` meets the plane z = 0) sees ``wi' = (S + δS − x)/|S + δS − x|`` and the value
  ``f' = f · E_t(S)/E_t(S + δS) · E_w(S + δS)/E_w(S)`` (the irradiance ``E = cos θ / r²`` of the tile and of the
  white reference, which a value is relative to; ``gonio.pipeline.uncertainty.geometry_variance`` does the
  same per pose);
* the fit's response, linearised at its optimum (implicit function theorem, as
  :mod:`gonio.rig.geocal` propagates its systematic errors): ``δθ_k = −(JᵀJ)⁻¹ Jᵀ (r(θ; data'_+k) − r(θ; data'_−k))/2``
  with ``J = ∂r/∂θ`` (central differences: the light moved +1σ and −1σ); ``Σ_θ,geo = Σ_k δθ_k δθ_kᵀ``, added to the noise's covariance
  (:func:`gonio.fit.correlated.pose_covariance`).

The within-pose part of the same error is also in ``sigma_pose`` (taken there as independent between poses):
counted twice, its share is about 1/G of this term — conservative, never smaller.

The sample frame itself is shared by every pose too: it is the board's, as the corner detector sees it, and the
board may be turned against the sample's surface (:data:`gonio.rig.geocal.BOARD_ROTATION_SIGMA_DEG` about each
axis). Turned by ``D``, a sample the host records at ``(wi, wo)`` with value ``f`` really is at ``(D wi, D wo)`` in
the surface's frame, with the value ``f · cos θi / cos θi'`` (the tile's irradiance, ``cos θi = wi_z``, relative to
a white reference on the board, which turns with it). Each turn (:attr:`CalibrationModes.frame_turns`, one
standard uncertainty) is one more mode, propagated the same way.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["CalibrationModes", "calibration_covariance"]


@dataclass(frozen=True)
class CalibrationModes:
    """The light's offset at each pose along each principal axis of the calibration's covariance (metres).

    ``pose``: (G,) pose indices; ``light``: (G, 3) the light's position the samples were computed with (sample
    frame, m); ``offsets``: (K, G, 3) its offsets one σ along each of the K principal axes; ``white``: (3,) the
    white reference's centre (values are relative to it) or None (absolute values); ``names``: the calibration
    parameters; ``source``: where the covariance comes from (named in the fit's note)."""

    pose: np.ndarray
    light: np.ndarray
    offsets: np.ndarray
    white: np.ndarray | None = None
    names: tuple = ()
    source: str = "the rig file's calibration covariance"
    #: (R, 3) rotation vectors (rad), each one standard uncertainty of a turn of the sample frame shared by every
    #: pose (module docstring); None: none
    frame_turns: np.ndarray | None = None

    @property
    def n_modes(self) -> int:
        """The light's principal axes and the frame's turns."""
        return int(self.offsets.shape[0]) + (0 if self.frame_turns is None else len(self.frame_turns))

    def mode(self, wi: np.ndarray, wo: np.ndarray, pose: np.ndarray, k: int, scale: float = 1.0):
        """``(wi', wo', ln f'/f)`` along mode ``k``: the light's axis ``k`` (:meth:`perturbed`, ``wo`` unchanged)
        or, past them, the frame turned by ``scale`` times turn ``k − K`` (module docstring); ``None`` when no
        sample belongs to a pose of the modes."""
        K = int(self.offsets.shape[0])
        if k < K:
            got = self.perturbed(wi, pose, k, scale)
            return None if got is None else (got[0], wo, got[1])
        known = np.isin(pose, self.pose)
        if not known.any():
            return None
        rv = scale * np.asarray(self.frame_turns[k - K], dtype=np.float64)
        from scipy.spatial.transform import Rotation

        D = Rotation.from_rotvec(rv).as_matrix()  # Rodrigues' formula
        wi2, wo2 = wi @ D.T, wo @ D.T
        with np.errstate(divide="ignore", invalid="ignore"):
            lnf = np.log(wi[:, 2]) - np.log(wi2[:, 2])
        ok = known & np.isfinite(lnf) & (wi2[:, 2] > 0) & (wo2[:, 2] > 0)
        return np.where(ok[:, None], wi2, wi), np.where(ok[:, None], wo2, wo), np.where(ok, lnf, 0.0)

    def perturbed(self, wi: np.ndarray, pose: np.ndarray, k: int, scale: float = 1.0):
        """``(wi', ln f'/f)`` of samples ``wi`` (N, 3) of poses ``pose`` (N,) with the light moved ``scale`` σ along
        axis ``k`` (module docstring); samples of poses not listed are left as they are (``None`` if none is)."""
        order = np.argsort(self.pose)
        at = np.searchsorted(self.pose[order], pose)
        at = np.clip(at, 0, len(order) - 1)
        known = self.pose[order][at] == pose
        if not known.any():
            return None
        g = order[at]
        S = self.light[g]
        dS = np.where(known[:, None], scale * self.offsets[k][g], 0.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = S[:, 2] / wi[:, 2]
        x = S - t[:, None] * wi                      # the tile point: wi from it reaches S, on z = 0
        d2 = S + dS - x
        wi2 = d2 / np.linalg.norm(d2, axis=1, keepdims=True)
        lnf = -(_log_irradiance(x, S + dS) - _log_irradiance(x, S))
        if self.white is not None:
            w = np.broadcast_to(np.asarray(self.white, dtype=np.float64), S.shape)
            lnf = lnf + (_log_irradiance(w, S + dS) - _log_irradiance(w, S))
        ok = known & np.isfinite(lnf) & np.isfinite(wi2).all(axis=1) & (wi2[:, 2] > 0)
        return np.where(ok[:, None], wi2, wi), np.where(ok, lnf, 0.0)


def _log_irradiance(p, S):
    """ln(cos θ / r²) at plane points ``p`` (z = 0) lit by a point light at ``S`` (inverse-square law, Lambert's
    cosine: cos θ = (S − p)_z / r)."""
    d = S - p
    r2 = np.sum(d * d, axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.log(np.maximum(d[..., 2], 1e-300)) - 1.5 * np.log(r2)


def calibration_covariance(prob, p: np.ndarray, idx: np.ndarray, J: np.ndarray | None = None):
    """``(cov, note)``: the covariance of the packed parameters ``idx`` at ``p`` from the calibration's error
    (module docstring), or ``None`` when the data carry no :class:`CalibrationModes`. ``J``: the residuals'
    Jacobian in ``idx`` (N·C, len(idx)) when already computed."""
    d = prob.d
    modes = getattr(d, "geometry", None)
    if modes is None or d.pose is None or len(idx) == 0 or modes.n_modes == 0:
        return None
    from gonio.fit.correlated import _jacobian

    colour, shape = prob.L.unpack(p)
    sigma = d.sigma

    def residual(wi, wo, y):
        return np.asarray(prob.loss.residual(prob.L.eval(colour, shape, wi, wo), y, wi[:, 2].copy(), sigma),
                          dtype=np.float64).ravel()

    if J is None:
        J = _jacobian(prob, p, idx).reshape(-1, len(idx))
    Ainv = np.linalg.pinv(J.T @ J)
    dtheta = []
    for k in range(modes.n_modes):
        rs = []
        for scale in (1.0, -1.0):
            got = modes.mode(d.wi, d.wo, d.pose, k, scale)
            if got is None:
                return None
            wi2, wo2, lnf = got
            rs.append(residual(wi2, wo2, d.y * np.exp(lnf)[:, None]))
        dr = 0.5 * (rs[0] - rs[1])
        dtheta.append(-Ainv @ (J.T @ np.where(np.isfinite(dr), dr, 0.0)))
    D = np.array(dtheta)
    cov = D.T @ D
    turns = 0 if modes.frame_turns is None else len(modes.frame_turns)
    note = (f"uncertainties include the geometric calibration's error shared by all {len(modes.pose)} poses "
            f"({modes.source}, {modes.offsets.shape[0]} principal axes"
            + (f" and {turns} turns of the board's frame against the sample" if turns else "")
            + " propagated through the fit, GUM JCGM 100 §5.2; gonio.fit.geometry)")
    return cov, note
