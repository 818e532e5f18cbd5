"""Plan generators: which poses (θi, φi, θo, φo) to measure, before anything moves.

Each generator is a pure function of its parameters (angles in radians) returning an ``(N, 4)`` array
of poses in a raster order; :func:`make_plan` validates the parameters, drops the poses the rig cannot
reach (with the reason), orders the rest for lab time and returns a :class:`~gonio.plan.plan.Plan`.

Registry :data:`GENERATORS` (names are a contract: CLI, manifests):

``grid``       full 4-D grid of both hemispheres (anisotropic materials);
``isotropic``  φi = 0, φo ∈ [0, π] (isotropy + mirror symmetry about the plane of incidence);
``in_plane``   φi = 0, φo ∈ {0, π}: the plane of incidence only;
``half_diff``  uniform in Rusinkiewicz (θd, φd) with θh spaced like MERL's θh axis (denser near the
               specular peak; Rusinkiewicz 1998; Matusik et al. 2003, θh index = √(θh/(π/2))·90).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Mapping

import numpy as np

from gonio.errors import ConfigError
from gonio.geometry import angles_from_dirs, dirs_from_half_diff
from gonio.plan.ordering import MotionModel, optimize_order, raster_order
from gonio.plan.plan import CaptureSettings, Plan

__all__ = ["PlanParam", "Generator", "GENERATORS", "make_plan", "solve_plan_joints", "candidate_count",
           "MAX_PLAN_CANDIDATES", "grid_poses", "isotropic_poses", "in_plane_poses", "half_diff_poses"]

_TOL = 1e-9
#: Most candidate poses a generator may produce, checked before they are built. The densest grid of
#: benchmarks/bench_plan.py (5°/20°) has 73,441; 10⁶ poses already take ~16 days at the default plan's
#: ~1.4 s per pose. Past it a step typed in radians where degrees are expected (``--theta-step 0.17``)
#: would build tens of millions of poses and their drop records and exhaust the memory.
MAX_PLAN_CANDIDATES = 1_000_000


@dataclass(frozen=True)
class PlanParam:
    """One generator parameter: ``kind`` is ``angle`` (radians; degrees on the CLI), ``int`` or ``float``."""

    kind: str
    default: float
    lo: float
    hi: float
    doc: str

    def coerce(self, gen: str, name: str, value: Any, source: str | None) -> float | int:
        field = f"{gen}.{name}"
        try:
            v = float(value)
        except (TypeError, ValueError):
            raise ConfigError.field(source, field, value, "must be a number") from None
        if self.kind == "int":
            if v != int(v):
                raise ConfigError.field(source, field, value, "must be an integer")
            v = int(v)
        if not math.isfinite(v) or not (self.lo <= v <= self.hi):
            lo, hi = (math.degrees(self.lo), math.degrees(self.hi)) if self.kind == "angle" else (self.lo, self.hi)
            unit = " deg" if self.kind == "angle" else ""
            shown = math.degrees(v) if self.kind == "angle" and math.isfinite(v) else value
            raise ConfigError.field(source, field, shown, f"must be in [{lo:g}, {hi:g}]{unit}")
        return v


@dataclass(frozen=True)
class Generator:
    """A registered generator: the pose function and its parameter specifications."""

    name: str
    fn: Callable[..., np.ndarray]
    params: Mapping[str, PlanParam]
    doc: str


def _steps(hi: float, step: float, start: float = 0.0) -> np.ndarray:
    """``start, start+step, ...`` up to ``hi`` inclusive (within rounding)."""
    n = int(math.floor((hi - start) / step + 1e-9)) + 1
    return start + step * np.arange(max(n, 0))


def _hemisphere(theta_step: float, phi_step: float, theta_max: float) -> np.ndarray:
    """(θ, φ) pairs: θ on a grid, φ ∈ [0, 2π) on a grid, a single φ = 0 at the pole; shape (M, 2)."""
    out = []
    n_phi = max(1, int(round(2 * math.pi / phi_step)))
    for t in _steps(theta_max, theta_step):
        phis = [0.0] if t < _TOL else (2 * math.pi / n_phi) * np.arange(n_phi)
        out.extend((t, p) for p in phis)
    return np.array(out, dtype=np.float64).reshape(-1, 2)


def grid_poses(theta_step: float, phi_step: float, theta_max: float) -> np.ndarray:
    """Every pair of directions of a (θ, φ) grid on the hemisphere, light × camera (anisotropic).

    θ = 0, Δθ, ... ≤ θmax; φ = k·2π/round(2π/Δφ); the pole appears once.
    """
    h = _hemisphere(theta_step, phi_step, theta_max)
    i, o = np.meshgrid(np.arange(len(h)), np.arange(len(h)), indexing="ij")
    return np.column_stack([h[i.ravel()], h[o.ravel()]])


def isotropic_poses(theta_step: float, phi_step: float, theta_max: float) -> np.ndarray:
    """φi = 0; θi, θo on a grid; φo ∈ [0, π] (an isotropic BRDF depends on φo − φi only, and is
    symmetric about the plane of incidence, so φo ∈ (π, 2π) repeats φo ∈ (0, π))."""
    thetas = _steps(theta_max, theta_step)
    n_phi = max(1, int(round(math.pi / phi_step)))
    phis = (math.pi / n_phi) * np.arange(n_phi + 1)
    rows = []
    for ti in thetas:
        for to in thetas:
            for po in ([0.0] if to < _TOL else phis):
                rows.append((ti, 0.0, to, po))
    return np.array(rows, dtype=np.float64).reshape(-1, 4)


def in_plane_poses(theta_i_step: float, theta_o_step: float, theta_max: float) -> np.ndarray:
    """φi = 0 and the camera in the plane of incidence: signed θo ∈ [−θmax, θmax]; θo > 0 is the
    specular side (φo = π), θo < 0 the retro side (φo = 0)."""
    rows = []
    for ti in _steps(theta_max, theta_i_step):
        for so in _steps(theta_max, theta_o_step, start=-theta_o_step * math.floor(theta_max / theta_o_step + 1e-9)):
            rows.append((ti, 0.0, abs(so), math.pi if so > _TOL else 0.0))
    return np.array(rows, dtype=np.float64).reshape(-1, 4)


def half_diff_poses(n_theta_h: int, theta_d_step: float, phi_d_step: float, theta_max: float) -> np.ndarray:
    """Poses uniform in Rusinkiewicz (θd, φd), with θh_k = (k/n)²·π/2 (MERL's θh spacing, denser near
    the specular peak θh = 0), φh = 0 (isotropic), φd ∈ [0, π) (reciprocity + isotropy).

    Directions come from :func:`gonio.geometry.dirs_from_half_diff` (Rusinkiewicz 1998); pairs with a
    direction beyond ``theta_max`` are returned too and dropped by :func:`make_plan` as ``horizon``.
    """
    th = (np.arange(n_theta_h) / n_theta_h) ** 2 * (math.pi / 2)
    td = _steps(math.pi / 2 - _TOL, theta_d_step)
    n_phi = max(1, int(round(math.pi / phi_d_step)))
    pd = (math.pi / n_phi) * np.arange(n_phi)
    TH, TD, PD = np.meshgrid(th, td, pd, indexing="ij")
    wi, wo = dirs_from_half_diff(TH.ravel(), 0.0, TD.ravel(), PD.ravel())
    return np.column_stack(angles_from_dirs(wi, wo))


def sphere_poses(theta_o: float, theta_i_step: float, phi_i_step: float, theta_max: float) -> np.ndarray:
    """A sphere's plan (image-based acquisition, :mod:`gonio.sphere`): the camera fixed at (θo, φo = 0) and the
    light over a (θi, φi) grid of the hemisphere — each frame holds every (θh, φd) the sphere's pixels see at the
    θd the light–camera angle γ sets (θd ≈ γ/2, cos γ = cos θi cos θo + sin θi sin θo cos φi), so sweeping the
    light fills the table's θd range (Matusik et al. 2003's rig: a light arm around a fixed camera)."""
    h = _hemisphere(theta_i_step, phi_i_step, theta_max)
    return np.column_stack([h, np.full(len(h), theta_o), np.zeros(len(h))])


def _n_steps(hi: float, step: float, start: float = 0.0) -> int:
    """``len(_steps(hi, step, start))`` without building the array."""
    return max(int(math.floor((hi - start) / step + 1e-9)) + 1, 0)


def candidate_count(name: str, values: Mapping[str, Any]) -> int:
    """How many poses generator ``name`` returns for ``values`` (radians), counted as its pose
    function builds them (the pole once; see each function above), without building them."""
    v = values
    if name == "grid":
        nt = _n_steps(v["theta_max"], v["theta_step"])
        n_phi = max(1, int(round(2 * math.pi / v["phi_step"])))
        per_side = (1 + (nt - 1) * n_phi) if nt else 0
        return per_side * per_side
    if name == "isotropic":
        nt = _n_steps(v["theta_max"], v["theta_step"])
        n_phi = max(1, int(round(math.pi / v["phi_step"])))
        return nt * ((1 + (nt - 1) * (n_phi + 1)) if nt else 0)
    if name == "in_plane":
        so = v["theta_o_step"]
        return _n_steps(v["theta_max"], v["theta_i_step"]) * _n_steps(
            v["theta_max"], so, start=-so * math.floor(v["theta_max"] / so + 1e-9))
    if name == "sphere":
        nt = _n_steps(v["theta_max"], v["theta_i_step"])
        n_phi = max(1, int(round(2 * math.pi / v["phi_i_step"])))
        return (1 + (nt - 1) * n_phi) if nt else 0
    if name == "half_diff":
        return int(v["n_theta_h"]) * _n_steps(math.pi / 2 - _TOL, v["theta_d_step"]) * max(
            1, int(round(math.pi / v["phi_d_step"])))
    raise KeyError(f"candidate_count: no pose count for generator {name!r}")


_A = math.radians
GENERATORS: dict[str, Generator] = {g.name: g for g in (
    Generator("grid", grid_poses, {
        "theta_step": PlanParam("angle", _A(15), _A(0.1), _A(90), "zenith step of both directions"),
        "phi_step": PlanParam("angle", _A(45), _A(0.1), _A(360), "azimuth step of both directions"),
        "theta_max": PlanParam("angle", _A(75), 0.0, _A(89), "largest zenith angle"),
    }, "full 4-D grid, light x camera directions (anisotropic materials)"),
    Generator("isotropic", isotropic_poses, {
        "theta_step": PlanParam("angle", _A(10), _A(0.1), _A(90), "zenith step of light and camera"),
        "phi_step": PlanParam("angle", _A(15), _A(0.1), _A(180), "camera azimuth step over [0, 180] deg"),
        "theta_max": PlanParam("angle", _A(80), 0.0, _A(89), "largest zenith angle"),
    }, "phi_i = 0, phi_o in [0, 180] deg (isotropic materials)"),
    Generator("in_plane", in_plane_poses, {
        # defaults: the in-plane sweep of benchmarks/report/REPORT.md's plan table (56 poses on the default rig)
        "theta_i_step": PlanParam("angle", _A(20), _A(0.1), _A(90), "light zenith step"),
        "theta_o_step": PlanParam("angle", _A(10), _A(0.1), _A(90), "camera zenith step (signed, both sides)"),
        "theta_max": PlanParam("angle", _A(70), 0.0, _A(89), "largest zenith angle"),
    }, "plane of incidence only"),
    Generator("half_diff", half_diff_poses, {
        # defaults: gonio measure's default plan, on the Pareto front of benchmarks/report/REPORT.md's plan table
        "n_theta_h": PlanParam("int", 6, 1, 90, "number of theta_h values, spaced (k/n)^2 * 90 deg"),
        "theta_d_step": PlanParam("angle", _A(20), _A(0.1), _A(90), "difference zenith step"),
        "phi_d_step": PlanParam("angle", _A(60), _A(0.1), _A(180), "difference azimuth step over [0, 180) deg"),
        "theta_max": PlanParam("angle", _A(70), 0.0, _A(89), "largest zenith angle of light and camera"),
    }, "uniform in Rusinkiewicz half/difference angles, denser near the specular peak"),
    Generator("sphere", sphere_poses, {
        "theta_o": PlanParam("angle", _A(60), 0.0, _A(85), "the fixed camera's zenith angle"),
        "theta_i_step": PlanParam("angle", _A(10), _A(0.5), _A(90), "light zenith step"),
        "phi_i_step": PlanParam("angle", _A(20), _A(0.5), _A(360), "light azimuth step"),
        "theta_max": PlanParam("angle", _A(85), 0.0, _A(89), "largest light zenith angle"),
    }, "a sphere target (--target with [sphere]): fixed camera, the light swept over the hemisphere"),
)}


def _canonical(poses: np.ndarray) -> np.ndarray:
    """φ = 0 where θ = 0 (φ is undefined at the pole), φ wrapped to [0, 2π)."""
    p = poses.copy()
    for t, f in ((0, 1), (2, 3)):
        p[:, f] = np.where(p[:, t] < _TOL, 0.0, np.mod(p[:, f], 2 * math.pi))
        p[:, f] = np.where(p[:, f] > 2 * math.pi - _TOL, 0.0, p[:, f])
    return p


def solve_plan_joints(rig, poses: np.ndarray, current=None) -> tuple[np.ndarray, list[str | None]]:
    """Joint angles of every pose on ``rig`` and, per pose, ``None`` or the reason it is unreachable."""
    from gonio.rig.kinematics import REASONS

    joints, code = rig.solve_many(poses[:, 0], poses[:, 1], poses[:, 2], poses[:, 3], current)
    return joints, [None if c == 0 else REASONS[int(c)] for c in code]


def make_plan(name: str, *, rig=None, capture: CaptureSettings | None = None, order: str = "optimized",
              seed: int = 0, time_budget: float | None = None, source: str | None = None, **params: Any) -> Plan:
    """Generate, filter and order a plan.

    Parameters
    ----------
    name : str
        A generator of :data:`GENERATORS`.
    rig : Rig or str or None
        The rig whose kinematics decide reachability and joint angles
        (:func:`gonio.rig.kinematics.load_rig`; default: the shipped ``default`` rig).
    capture : CaptureSettings
        Exposure bracket etc. (default :class:`CaptureSettings()`).
    order : {"optimized", "raster"}
        ``optimized`` orders for lab time (:func:`gonio.plan.ordering.optimize_order`); ``raster``
        keeps the lexicographic (θi, φi, θo, φo) order.
    **params
        Generator parameters, angles in radians; missing ones take their defaults.

    Poses beyond the generator's ``theta_max`` are dropped as ``horizon``, repeated poses as
    ``duplicate``, poses the rig refuses with its reason (``limits``, ``collision``, ``shadow``).
    """
    from gonio.rig.kinematics import Rig, load_rig

    gen = GENERATORS.get(name)
    if gen is None:
        raise ConfigError.field(source, "plan", name, f"unknown plan; known: {', '.join(GENERATORS)}")
    unknown = sorted(set(params) - set(gen.params))
    if unknown:
        raise ConfigError.field(source, f"{name}.{unknown[0]}", params[unknown[0]],
                                f"unknown parameter; {name} takes {', '.join(gen.params)}")
    if order not in ("optimized", "raster"):
        raise ConfigError.field(source, "order", order, "must be 'optimized' or 'raster'")
    values = {k: spec.coerce(name, k, params.get(k, spec.default), source) for k, spec in gen.params.items()}
    n = candidate_count(name, values)
    if n > MAX_PLAN_CANDIDATES:
        shown = ", ".join(f"{k} {math.degrees(values[k]):g} deg" if spec.kind == "angle" else f"{k} {values[k]:g}"
                          for k, spec in gen.params.items())
        raise ConfigError.field(source, "plan", name, f"{shown} gives {n:,} poses, more than {MAX_PLAN_CANDIDATES:,} "
                                "(on the command line plan angles are in degrees: a 10 deg step is --theta-step 10, not 0.17)")
    rig = rig if isinstance(rig, Rig) else load_rig(rig)
    capture = capture or CaptureSettings()

    poses = _canonical(np.asarray(gen.fn(**values), dtype=np.float64).reshape(-1, 4))
    dropped: list[dict[str, Any]] = []
    tmax = values.get("theta_max", math.pi / 2)
    beyond = (poses[:, 0] > tmax + _TOL) | (poses[:, 2] > tmax + _TOL)
    dropped += [{"pose": p.tolist(), "reason": "horizon"} for p in poses[beyond]]
    poses = poses[~beyond]
    _, first = np.unique(np.round(poses, 9), axis=0, return_index=True)
    keep = np.zeros(len(poses), bool)
    keep[first] = True
    dropped += [{"pose": p.tolist(), "reason": "duplicate"} for p in poses[~keep]]
    poses = poses[keep]
    joints, reasons = solve_plan_joints(rig, poses)
    ok = np.array([r is None for r in reasons], dtype=bool)
    dropped += [{"pose": p.tolist(), "reason": r} for p, r in zip(poses, reasons) if r is not None]
    poses, joints = poses[ok], joints[ok]
    if len(poses) == 0:
        raise ConfigError.field(source, "plan", name, f"no reachable pose on rig {rig.name!r} with these parameters")

    params_out = {**values, "rig": rig.name, "seed": seed}
    plan = Plan(poses=poses, capture=capture, generator=name, params=params_out, dropped=tuple(dropped),
                joints=joints)
    raster = raster_order(poses)
    plan = plan.reordered(raster, "raster")
    if order == "optimized":
        model = MotionModel.from_rig(rig)
        perm = optimize_order(plan.joints, model, seed=seed, time_budget=time_budget,
                              initial=np.arange(len(plan)))
        plan = plan.reordered(perm, "optimized")
    return plan
