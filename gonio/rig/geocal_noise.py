"""Observation covariances of a geometric calibration (:mod:`gonio.rig.geocal`): what the detectors state, plus
the scatter of the joints themselves, with their sizes estimated from the residuals (variance components).

A calibration frame is taken at joints ``q`` that the servos report; the arms really stand at ``q + δq``
(encoder resolution and noise, the half backlash that the balanced approach turns into scatter). The board
pose and the highlight seen in that frame are *exact* observations of the arms at ``q + δq``, so each
frame's residual ``r(q)`` has, to first order, the covariance

    C = s_board · C_board  ⊕  s_highlight · C_highlight  +  σ_q² · J_q J_qᵀ,        J_q = ∂r/∂q

(the "effective variance" of a regression whose inputs are uncertain: Orear 1982, "Least squares when both
variables have uncertainties", Am. J. Phys. 50(10); Clutton-Brock 1967). ``C_board`` is the board pose's
PnP covariance, ``C_highlight`` the highlight centroid's (:mod:`gonio.pipeline.markers`,
:mod:`gonio.pipeline.highlight`). The joint term couples the board pose and the highlight of the same
frame (the camera really turned, for both of them), so a frame's residuals are whitened together, and
the sandwich covariance of :func:`gonio.rig.geocal.calibrate_geometry` takes one cluster per frame.

The detectors' covariances are right in shape but not in size — the board pose's misses what the corner
residuals cannot show (shared blur, perspective of the squares, worse the more oblique the view), the
highlight's is photon noise only — and the joint scatter is not known beforehand. Their sizes are
*variance components*: ``s_board`` separately for frontal and oblique views of the board
(:data:`OBLIQUE_DEG`), ``s_highlight`` and ``σ_q²``, estimated by maximum likelihood from the residuals at the
current estimate (Koch 1999, *Parameter Estimation and Hypothesis Testing in Linear Models*, 2nd ed., §3.6:
variance components of groups of observations; Förstner 1979; Harville 1977, JASA 72(358)), then the
parameters are solved again with the covariances they give.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize

from gonio.rig.geocal_residuals import Observed, batch_shape, residual_blocks

__all__ = ["FrameNoise", "COMPONENTS", "OBLIQUE_DEG"]

#: Angle (degrees) between the camera's optical axis and the board's normal beyond which a board pose belongs
#: to the "oblique" group of board covariances (its corners foreshortened by cos θ < 0.5).
OBLIQUE_DEG = 60.0
#: The variance components, in the order of :attr:`FrameNoise.components`.
COMPONENTS = ("board_frontal", "board_oblique", "highlight", "joint_deg2")
#: Start of the joint scatter's variance component (deg²): a Dynamixel's 4096-count encoder quantises at
#: 0.088°, i.e. 0.025° standard deviation.
JOINT_SIGMA_START_DEG = 0.025


def cholesky(C: np.ndarray) -> np.ndarray:
    """Lower Cholesky factors of a stack of covariances ``C`` (..., d, d), each with a jitter of 1e-12 of its
    trace on the diagonal (a covariance that is singular to rounding, e.g. a board pose's, still factors)."""
    d = C.shape[-1]
    return np.linalg.cholesky(C + np.eye(d) * 1e-12 * np.trace(C, axis1=-2, axis2=-1)[..., None, None])


def pair_frames(cams, highs) -> np.ndarray:
    """Index of the camera observation taken in the same frame as each highlight (``-1``: none): same joints,
    same camera pose (a highlight observation carries its frame's board pose)."""
    key = {}
    for i, c in enumerate(cams):
        key.setdefault(tuple(np.asarray(c.joints, np.float64).tolist()), []).append(i)
    out = np.full(len(highs), -1, dtype=np.int64)
    used = set()
    for k, h in enumerate(highs):
        for i in key.get(tuple(np.asarray(h.joints, np.float64).tolist()), []):
            if i not in used and np.array_equal(cams[i].position, h.position) and np.array_equal(cams[i].R, h.R):
                out[k] = i
                used.add(i)
                break
    return out


@dataclass
class FrameNoise:
    """Per-frame covariances of the calibration residuals (module docstring) and their whitening.

    Frames are in three groups, each whitened as one stack: board only (6 residuals: camera centre in mm,
    rotation vector in degrees), board + highlight of the same frame (8: + the highlight in mrad),
    highlight only (2)."""

    rig: object
    cams: list
    highs: list

    def __post_init__(self):
        pair = pair_frames(self.cams, self.highs)
        paired = set(pair[pair >= 0].tolist())
        self.cam_only = np.array([i for i in range(len(self.cams)) if i not in paired], dtype=np.int64)
        self.pair_h = np.flatnonzero(pair >= 0)
        self.pair_c = pair[self.pair_h]
        self.high_only = np.flatnonzero(pair < 0)
        self.C_cam = np.stack([np.asarray(c.cov, np.float64) for c in self.cams]) if self.cams else np.zeros((0, 6, 6))
        self.C_high = (np.stack([np.asarray(h.cov, np.float64) * 1e6 for h in self.highs]) if self.highs
                       else np.zeros((0, 2, 2)))
        # viewing angle of the board: optical axis (R's third row) against the sample normal
        view = np.degrees(np.arccos(np.clip(np.abs([c.R[2, 2] for c in self.cams]), 0, 1))) if self.cams else np.zeros(0)
        self.oblique = view > OBLIQUE_DEG
        self.components = np.array([1.0, 1.0, 1.0, JOINT_SIGMA_START_DEG ** 2])
        self.n_frames = len(self.cam_only) + len(self.pair_h) + len(self.high_only)
        self.observed = Observed.of(self.cams, self.highs)

    # -- residuals -------------------------------------------------------------------------------------
    def raw(self, errors, joints_delta=None, obs=None):
        """Raw residuals ``(cams (..., Nc, 6), highs (..., Nh, 2))`` at ``errors`` (one chain, or a batch:
        :mod:`gonio.rig.geocal_residuals`), the joints shifted by ``joints_delta`` (rad, applied to every
        observation: for :meth:`jacobians`; (B, 1, 4): B shifts at once, a leading axis of B); ``obs``: perturbed copies of the observations
        (:class:`gonio.rig.geocal_residuals.Observed`, same frames) in place of the session's."""
        obs = self.observed if obs is None else obs
        batch = batch_shape(errors)
        if joints_delta is not None:
            obs = obs.shifted(joints_delta)
            batch = batch + np.shape(joints_delta)[:-2]
        b = residual_blocks(self.rig, errors, obs)
        rc = (np.concatenate([b["camera_mm"].reshape(batch + (-1, 3)), b["camera_deg"].reshape(batch + (-1, 3))], axis=-1)
              if obs.n_cams else np.zeros(batch + (0, 6)))
        rh = b["highlight_mrad"].reshape(batch + (-1, 2)) if obs.n_highs else np.zeros(batch + (0, 2))
        return rc, rh

    def jacobians(self, errors, h: float = 1e-6):
        """∂r/∂q (per degree of joint) of every observation: ``((Nc, 6, 4), (Nh, 2, 4))`` (central differences;
        the eight shifted joint sets in one evaluation, :meth:`raw`)."""
        steps = []
        for k in range(4):
            e = np.zeros(4)
            e[k] = h
            steps += [e, -e]
        rc, rh = self.raw(errors, np.stack(steps)[:, None, :])
        jc = [(rc[2 * k] - rc[2 * k + 1]) / (2 * h) for k in range(4)]
        jh = [(rh[2 * k] - rh[2 * k + 1]) / (2 * h) for k in range(4)]
        per_deg = math.pi / 180.0
        return np.stack(jc, -1) * per_deg, np.stack(jh, -1) * per_deg

    def group_vectors(self, rc, rh):
        """The residual vectors of the three frame groups (board only, board + highlight, highlight only)."""
        return [rc[..., self.cam_only, :], np.concatenate([rc[..., self.pair_c, :], rh[..., self.pair_h, :]], axis=-1),
                rh[..., self.high_only, :]]

    def group_covariances(self, Jc, Jh, components=None):
        """Covariances of the three frame groups' residual vectors for the variance ``components``."""
        return self._covariances(self._group_parts(Jc, Jh), self.components if components is None else components)

    def _group_parts(self, Jc, Jh):
        """The parts of the three groups' covariances that the components scale, each frame's own (taken once
        for the many component values :meth:`estimate_components` tries): ``(C_board, oblique, J)`` of the
        board-only frames, ``(C_board, oblique, C_highlight, J)`` of the paired ones, ``(C_highlight, J)``."""
        c, pc, ph, h = self.cam_only, self.pair_c, self.pair_h, self.high_only
        return ((self.C_cam[c], self.oblique[c], Jc[c]),
                (self.C_cam[pc], self.oblique[pc], self.C_high[ph], np.concatenate([Jc[pc], Jh[ph]], axis=1)),
                (self.C_high[h], Jh[h]))

    @staticmethod
    def _covariances(parts, components):
        """:meth:`group_covariances` from :meth:`_group_parts`: ``s_board · C_board ⊕ s_highlight · C_highlight +
        σ_q² J Jᵀ`` per frame (module docstring)."""
        sf, so, sh, sq = components
        (Cc, oc, Jc), (Cpc, op, Cph, Jp), (Ch, Jh) = parts
        cam = Cc * np.where(oc, so, sf)[:, None, None] + sq * Jc @ np.swapaxes(Jc, 1, 2)
        Cp = np.zeros((len(Jp), 8, 8))
        Cp[:, :6, :6] = Cpc * np.where(op, so, sf)[:, None, None]
        Cp[:, 6:, 6:] = Cph * sh
        Cp += sq * Jp @ np.swapaxes(Jp, 1, 2)
        return [cam, Cp, Ch * sh + sq * Jh @ np.swapaxes(Jh, 1, 2)]

    # -- variance components --------------------------------------------------------------------------
    def estimate_components(self, errors) -> np.ndarray:
        """Maximum-likelihood variance components (module docstring) from the residuals at ``errors``:
        minimises Σ_frames rᵀ C⁻¹ r + log det C over the components' logarithms. A component no frame
        depends on keeps its value. Sets and returns :attr:`components`."""
        rc, rh = self.raw(errors)
        Jc, Jh = self.jacobians(errors)
        vecs = self.group_vectors(rc, rh)
        free = np.array([np.any(~self.oblique), np.any(self.oblique), len(self.highs) > 0, True])
        parts = self._group_parts(Jc, Jh)

        def nll(logc):
            comp = self.components.copy()
            comp[free] = np.exp(logc)
            total = 0.0
            for r, C in zip(vecs, self._covariances(parts, comp)):
                if not len(r):
                    continue
                L = cholesky(C)
                z = np.linalg.solve(L, r[..., None])[..., 0]
                total += float(np.sum(z ** 2)) + 2.0 * float(np.sum(np.log(np.diagonal(L, axis1=1, axis2=2))))
            return total

        x0 = np.log(self.components[free])
        sol = minimize(nll, x0, method="Nelder-Mead", options={"xatol": 1e-3, "fatol": 1e-3, "maxiter": 2000})
        comp = self.components.copy()
        comp[free] = np.exp(np.clip(sol.x, -30.0, 30.0))
        self.components = comp
        return comp

    def whiteners(self, errors):
        """Per-group matrices ``W`` with ``Wᵀ W = C⁻¹`` at ``errors`` and the current components."""
        Jc, Jh = self.jacobians(errors)
        out = []
        for C in self.group_covariances(Jc, Jh):
            out.append(np.linalg.inv(cholesky(C)) if len(C) else np.zeros(C.shape))
        return out

    def whitened(self, errors, W, obs=None):
        """The whitened residual vector (all frames) at ``errors`` ((K, ...) for a batch of K chains); ``obs``:
        perturbed copies of the observations (same frames), for the systematic errors' propagation."""
        rc, rh = self.raw(errors, obs=obs)
        batch = rc.shape[:-2]
        return np.concatenate([(w @ r[..., None])[..., 0].reshape(batch + (-1,))
                               for w, r in zip(W, self.group_vectors(rc, rh))], axis=-1)

    def clusters(self) -> np.ndarray:
        """Frame index of every row of :meth:`whitened`."""
        n0, n1 = len(self.cam_only), len(self.pair_h)
        return np.concatenate([np.repeat(np.arange(n0), 6), n0 + np.repeat(np.arange(n1), 8),
                               n0 + n1 + np.repeat(np.arange(len(self.high_only)), 2)])

    def chi2_by_group(self, errors, W) -> dict[str, tuple[float, int]]:
        """Mean whitened residual² (χ² per residual; ≈ 1 when the covariances are right) and the count of
        residuals for the board poses' frontal and oblique groups and the highlights (their own rows of the
        whitened frame vectors)."""
        rc, rh = self.raw(errors)
        vecs = self.group_vectors(rc, rh)
        z = [(w @ r[..., None])[..., 0] for w, r in zip(W, vecs)]
        ob = [self.oblique[self.cam_only], self.oblique[self.pair_c]]
        out = {}
        for name, rows in (("board_frontal", [z[0][~ob[0]], z[1][~ob[1], :6]]),
                           ("board_oblique", [z[0][ob[0]], z[1][ob[1], :6]]),
                           ("highlight", [z[1][:, 6:], z[2]])):
            v = np.concatenate([r.ravel() for r in rows])
            if v.size:
                out[name] = (float(np.mean(v ** 2)), int(v.size))
        return out

    # -- outlier frames ---------------------------------------------------------------------------------
    def outlier_frames(self, whitened: np.ndarray, p_value: float) -> list[int]:
        """Frames (:meth:`clusters` indices) whose whitened residual χ² has a probability below ``p_value``
        under their covariance (χ² with the frame's residual count as degrees of freedom): a board pose or a
        highlight the detector got wrong (a corner on a reflection, a highlight cut by the tile's edge)."""
        from scipy.special import chdtrc  # χ²'s survival function: scipy.stats.chi2.sf's, without importing scipy.stats

        cid = self.clusters()
        q = np.bincount(cid, whitened ** 2, minlength=self.n_frames)
        dof = np.bincount(cid, minlength=self.n_frames)
        return [int(k) for k in np.flatnonzero(chdtrc(np.maximum(dof, 1), q) < p_value)]

    def without(self, frames) -> tuple[list, list, list[str]]:
        """``(cams, highs, what)``: the observations without the given frames (a board pose and its highlight go
        together) and one description per frame dropped."""
        drop_c, drop_h, what = set(), set(), []
        n0, n1 = len(self.cam_only), len(self.pair_h)
        for k in frames:
            if k < n0:
                drop_c.add(int(self.cam_only[k]))
                what.append(f"board pose at joints {_deg(self.cams[self.cam_only[k]].joints)}")
            elif k < n0 + n1:
                drop_c.add(int(self.pair_c[k - n0]))
                drop_h.add(int(self.pair_h[k - n0]))
                what.append(f"board pose + highlight at joints {_deg(self.highs[self.pair_h[k - n0]].joints)}")
            else:
                drop_h.add(int(self.high_only[k - n0 - n1]))
                what.append(f"highlight at joints {_deg(self.highs[self.high_only[k - n0 - n1]].joints)}")
        return ([c for i, c in enumerate(self.cams) if i not in drop_c],
                [h for i, h in enumerate(self.highs) if i not in drop_h], what)


def _deg(joints) -> str:
    return "(" + ", ".join(f"{math.degrees(a):.1f}" for a in np.asarray(joints)) + ") deg"

