"""Parameter covariance of a fit to a session's samples, whose errors are correlated within a pose.

The samples of one pose share the geometry's error — the camera pose (ChArUco) and the light position (the
servos, the geometric calibration) move all of them together — and whatever else a pose gets wrong as a
whole (its white reference, its exposure bracket, a model that misfits where the pose looks). Gauss–Newton's
``s² (JᵀJ)⁻¹`` takes every sample as independent and is then too small by about the square root of the
samples per pose. Two estimates that do not assume independence, the larger of which is reported
(:func:`pose_covariance`):

* **stated**: the residuals' correlation as the samples state it, ``ρ_ij = s_i s_j`` for two samples of one
  pose (``s = sigma_pose / sigma``, :class:`gonio.samples.SampleSet`), 1 on the diagonal, 0 across poses —
  ``cov = A⁻¹ Jᵀ R J A⁻¹`` (the covariance of a least-squares estimate whose weights ignore the correlation
  ``R``: Seber & Wild 1989, *Nonlinear Regression*, §2.1.4), with ``A = JᵀJ``; ``JᵀRJ`` is
  ``Σ_i J_iᵀJ_i (1 − s_i²) + Σ_poses (Σ_{i∈pose} s_i J_i)ᵀ(Σ_{i∈pose} s_i J_i)``, times the Birge factor
  ``max(1, χ²_red)`` like the independent one;
* **cluster-robust** (one cluster per pose: Liang & Zeger 1986, *Biometrika* 73(1); White 1980): ``A⁻¹ (Σ_poses
  g gᵀ) A⁻¹ · G/(G − 1)`` with ``g = Σ_{i∈pose} J_iᵀ r_i`` and G poses — what the residuals themselves show,
  whatever its cause, once there are enough poses (it is noisy with few: it is never the only estimate).

``J`` is the Jacobian of the fit's residual vector in the packed parameters (central differences).
"""

from __future__ import annotations

import numpy as np

__all__ = ["pose_covariance"]


def _jacobian(prob, p: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """∂r/∂p_k for the packed parameters ``idx``: (N, C, len(idx)), central differences."""
    cols = []
    for k in idx:
        h = 1e-6 * max(abs(float(p[k])), 1e-3)
        e = np.zeros_like(p)
        e[k] = h
        cols.append((prob.residuals(p + e) - prob.residuals(p - e)) / (2 * h))
    return np.stack(cols, axis=-1)


def pose_covariance(prob, p: np.ndarray, idx: np.ndarray, s2: float) -> tuple[np.ndarray, str] | None:
    """``(cov, note)`` of the packed parameters ``idx`` at ``p`` from the pose-correlated residuals (module
    docstring), or ``None`` when the data carry no poses (or one pose only). ``s2``: the Birge factor of the
    stated estimate (1 when the scatter is within the stated σ)."""
    d = prob.d
    pose = getattr(d, "pose", None)
    if pose is None or len(idx) == 0:
        return None
    poses, inv = np.unique(pose, return_inverse=True)
    G = len(poses)
    if G < 2:
        return None
    r = np.asarray(prob.residuals(p), dtype=np.float64).reshape(len(pose), -1)
    J = _jacobian(prob, p, idx).reshape(len(pose), r.shape[1], len(idx))
    A = np.einsum("ncj,nck->jk", J, J)
    Ainv = np.linalg.pinv(A)
    # stated correlation: 1 − s² on the diagonal, s_i s_j within a pose
    if getattr(d, "sigma_pose", None) is not None and d.sigma is not None:
        s = np.clip(np.nan_to_num(d.sigma_pose / d.sigma), 0.0, 1.0)
    else:
        s = np.zeros_like(r)
    M = np.einsum("ncj,nck,nc->jk", J, J, 1.0 - s ** 2)
    gs = np.zeros((G, len(idx)))
    np.add.at(gs, inv, np.einsum("ncj,nc->nj", J, s))
    M += gs.T @ gs
    stated = s2 * Ainv @ M @ Ainv
    # cluster-robust: one cluster per pose
    gr = np.zeros((G, len(idx)))
    np.add.at(gr, inv, np.einsum("ncj,nc->nj", J, r))
    robust = Ainv @ (gr.T @ gr) @ Ainv * G / (G - 1)
    var = np.maximum(np.diag(stated), np.diag(robust))
    sd = np.sqrt(np.clip(np.diag(stated), 1e-300, None))
    cov = stated / np.outer(sd, sd) * np.sqrt(np.outer(var, var))
    which = "the residuals' scatter between poses" if np.any(np.diag(robust) > np.diag(stated)) else \
        "the stated geometry error shared within each pose"
    note = (f"uncertainties include errors correlated within each of the {G} poses (largest from {which}; "
            f"gonio.fit.correlated)")
    return cov, note
