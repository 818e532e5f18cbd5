"""The geometric calibration's covariance (:mod:`gonio.rig.geocal`) after the calibration: stored with the
calibrated rig file, propagated to where the light and the camera are at any joints, to wi, and to the wi
error a calibration leaves over the reachable poses.

The calibrated rig file's ``[calibration.covariance]`` holds ``names`` (the identified
:class:`gonio.rig.chain.ChainErrors` fields, ``light.arc_x_mm``...) and ``matrix`` (their covariance in deg²,
mm², deg·mm); :func:`gonio.rig.kinematics.load_rig` reads it into ``Rig.geometry_covariance``.

Propagation is first order (GUM, JCGM 100:2008 §5.2, correlated inputs: ``C_y = J C_x Jᵀ``) with ``J`` the
chain's Jacobian (:func:`gonio.rig.chain.chain_forward`) by central differences at the calibrated errors. The
light's position at a pose is where every sample of that pose takes its irradiance and its wi from, so its
covariance enters each sample's σ (:func:`gonio.pipeline.uncertainty.geometry_variance`) as an error shared by
all samples of the pose. The wi error over the reachable poses (:func:`wi_error_p95`) is Monte-Carlo
(JCGM 101:2008 §7): parameter vectors drawn from N(0, C), the p95 of the angle between the drawn and the
estimated chain's wi over random reachable poses — the error the calibration's own uncertainty allows, which
``gonio calibrate rig`` compares with the goal and ``gonio calibrate check``'s verdict includes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from gonio.errors import ConfigError

__all__ = ["GeometryCovariance", "light_jacobian", "light_position_covariance", "wi_covariance_sigma_deg", "wi_error_p95",
           "workspace_joints", "WI_GOAL_DEG", "with_calibration", "goal_line"]

#: The wi goal after calibration (README, issue 15: 0.25° on the 95th percentile over the reachable poses).
WI_GOAL_DEG = 0.25
#: Finite-difference step of the chain's Jacobian (degrees or millimetres): linear far beyond any σ.
_STEP = 1e-3


@dataclass(frozen=True)
class GeometryCovariance:
    """Covariance ``matrix`` of the identified chain parameters ``names`` (module docstring)."""

    names: tuple
    matrix: np.ndarray

    @classmethod
    def from_table(cls, d, source: str = "calibration.covariance") -> "GeometryCovariance":
        """From the rig file's ``[calibration.covariance]``; ConfigError (one line naming the field) unless the names
        are chain fields, once each, and the matrix is finite, square of their size, symmetric, with a diagonal >= 0."""
        from gonio.rig.chain import ChainErrors

        if not isinstance(d, dict) or set(d) != {"names", "matrix"}:
            raise ConfigError(f"{source}: expected a table with names and matrix")
        names = d["names"]
        known = set(ChainErrors().names())
        if not isinstance(names, list) or not all(isinstance(n, str) and n in known for n in names) \
                or len(set(names)) != len(names):
            raise ConfigError(f"{source}.names: expected distinct chain fields (light.d_el_deg, ...), got {str(names)[:60]}")
        try:
            M = np.asarray(d["matrix"], dtype=np.float64)
        except (TypeError, ValueError):
            raise ConfigError(f"{source}.matrix: not a matrix of numbers") from None
        n = len(names)
        if M.shape != (n, n) or not np.isfinite(M).all():
            raise ConfigError(f"{source}.matrix: expected {n} x {n} finite numbers (one row per name), got shape {M.shape}")
        if not np.allclose(M, M.T, rtol=1e-4, atol=1e-12 * max(float(np.abs(M).max()), 1e-300)) or (np.diag(M) < 0).any():
            raise ConfigError(f"{source}.matrix: not a covariance (asymmetric or a negative variance)")
        M = 0.5 * (M + M.T)
        M.setflags(write=False)
        return cls(tuple(names), M)

    def toml_lines(self) -> list[str]:
        """The ``[calibration.covariance]`` table (what :meth:`from_table` reads)."""
        rows = ",\n  ".join("[" + ", ".join(f"{v:.6g}" for v in row) + "]" for row in self.matrix)
        return ["[calibration.covariance]", "names = [" + ", ".join(f'"{n}"' for n in self.names) + "]",
                f"matrix = [\n  {rows}\n]"]

    def factor(self) -> np.ndarray:
        """``L`` with ``L Lᵀ = matrix`` (symmetric square root; a rounding-negative eigenvalue taken as 0)."""
        w, V = np.linalg.eigh(self.matrix)
        return V * np.sqrt(np.clip(w, 0.0, None))


def _errors_vector(rig) -> np.ndarray:
    from gonio.rig.chain import ChainErrors

    return (rig.geometry_errors or ChainErrors()).vector()


def _jacobian(rig, cov: GeometryCovariance, joints, which: int) -> np.ndarray:
    """∂(chain_forward(...)[which]) / ∂(each named parameter): (..., 3, P), per degree or millimetre."""
    from gonio.rig.chain import ChainErrors, chain_forward

    names = ChainErrors().names()
    x0 = _errors_vector(rig)
    cols = []
    for n in cov.names:
        e = np.zeros_like(x0)
        e[names.index(n)] = _STEP
        plus = chain_forward(rig, ChainErrors.from_vector(x0 + e), joints)[which]
        minus = chain_forward(rig, ChainErrors.from_vector(x0 - e), joints)[which]
        cols.append((plus - minus) / (2 * _STEP))
    return np.stack(cols, axis=-1)


def light_jacobian(rig, joints) -> np.ndarray:
    """∂(light position, m)/∂(each parameter of ``rig.geometry_covariance``, per degree or millimetre) at
    ``joints``: (..., 3, P), central differences of the chain (module docstring)."""
    return _jacobian(rig, rig.geometry_covariance, np.asarray(joints, dtype=np.float64), 0)


def light_position_covariance(rig, joints) -> np.ndarray | None:
    """Covariance (m², (..., 3, 3)) of the light's position at ``joints`` from ``rig.geometry_covariance``
    (``None``: the rig file has none)."""
    cov = getattr(rig, "geometry_covariance", None)
    if cov is None:
        return None
    J = _jacobian(rig, cov, np.asarray(joints, dtype=np.float64), 0)
    return J @ cov.matrix @ np.swapaxes(J, -1, -2)


def wi_covariance_sigma_deg(rig, joints) -> np.ndarray | None:
    """Standard uncertainty (degrees; the largest principal axis) of wi at ``joints`` from the calibration's
    covariance: the light position's covariance across the line of sight, over the distance."""
    C = light_position_covariance(rig, joints)
    if C is None:
        return None
    from gonio.rig.chain import ChainErrors, chain_forward

    p = chain_forward(rig, rig.geometry_errors or ChainErrors(), joints)[0]
    r = np.linalg.norm(p, axis=-1)
    u = p / r[..., None]
    P = np.eye(3) - u[..., :, None] * u[..., None, :]  # across the line of sight
    lam = np.linalg.eigvalsh(P @ C @ P)[..., -1]
    return np.degrees(np.sqrt(np.clip(lam, 0, None)) / r)


def workspace_joints(rig, n: int = 500, seed: int = 0, max_theta_deg: float = 75.0) -> np.ndarray:
    """Joints of up to ``n`` random reachable poses (θi, θo uniform up to ``max_theta_deg``, φ uniform): the
    poses a wi error is judged over."""
    rng = np.random.default_rng(seed)
    ti, to = rng.uniform(0, math.radians(max_theta_deg), (2, n))
    pi_, po = rng.uniform(0, 2 * math.pi, (2, n))
    joints, code = rig.solve_many(ti, pi_, to, po)
    return joints[code == 0]


def wi_error_p95(rig, joints=None, *, draws: int = 64, seed: int = 0) -> float | None:
    """The 95th percentile of the wi error the calibration's covariance allows over ``joints`` (default:
    :func:`workspace_joints`), degrees (module docstring); ``None`` without a covariance."""
    cov = getattr(rig, "geometry_covariance", None)
    if cov is None:
        return None
    from gonio.rig.chain import ChainErrors, angle_between_deg, true_directions

    joints = workspace_joints(rig) if joints is None else np.asarray(joints, dtype=np.float64)
    names = ChainErrors().names()
    x0 = _errors_vector(rig)
    where = [names.index(n) for n in cov.names]
    z = np.random.default_rng(seed).standard_normal((draws, len(cov.names))) @ cov.factor().T
    wi0 = true_directions(rig, ChainErrors.from_vector(x0), joints)[0]
    errs = []
    for dz in z:
        x = x0.copy()
        x[where] += dz
        errs.append(angle_between_deg(true_directions(rig, ChainErrors.from_vector(x), joints)[0], wi0))
    return float(np.percentile(np.concatenate(errs), 95))


def with_calibration(rig, result):
    """``rig`` (declared) with a :class:`gonio.rig.geocal.GeoCalResult`'s errors and covariance, as the
    calibrated rig file it writes loads."""
    from dataclasses import replace

    cov = None if result.cov is None else GeometryCovariance(tuple(result.cov_names), np.asarray(result.cov))
    return replace(rig, geometry_errors=result.errors, geometry_covariance=cov)


def goal_line(rig, goal_deg: float = WI_GOAL_DEG) -> tuple[bool, str]:
    """``(reached, one line)``: the wi error the calibrated ``rig``'s covariance allows over the reachable poses
    (:func:`wi_error_p95`) against ``goal_deg``; when over it, which parameters weigh most and what would help."""
    from gonio.rig.geocheck import CALIBRATION_HELP

    p95 = wi_error_p95(rig)
    if p95 is None:
        return False, "wi error over the reachable poses: unknown (no calibration covariance)"
    if p95 <= goal_deg:
        return True, (f"wi error this calibration's uncertainty allows over the reachable poses: p95 {p95:.3f}° "
                      f"(goal <= {goal_deg:g}°)")
    cov = rig.geometry_covariance
    joints = workspace_joints(rig, 200)
    J = _jacobian(rig, cov, joints, 0)  # light position per parameter: each one's share of the light's variance
    share = np.einsum("npk,k->k", J ** 2, np.diag(cov.matrix))
    top = [cov.names[k] for k in np.argsort(share)[::-1][:3]]
    return False, (f"CANNOT REACH THE GOAL: the wi error this calibration's uncertainty allows over the reachable "
                   f"poses is {p95:.3f}° (p95) > {goal_deg:g}° (most from {', '.join(top)}); {CALIBRATION_HELP}")
