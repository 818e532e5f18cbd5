"""Rig kinematics: BRDF angles (θi, φi, θo, φo) ↔ joint angles, reachability, poses, move times.

Pure code, vectorized over many poses (plans have thousands). The rig is described by a TOML file
whose ``layout`` chooses the joints (:data:`LAYOUTS`; ``Rig.names`` is the joint order of every
joint-angle array, last axis):

``layout = "arms"`` (the default; ``gonio/rig/rigs/default.toml``, joints :data:`JOINT_NAMES`):

* the sample lies flat at the origin of its local frame (docs/architecture.md §3: z = normal, x = reference
  direction); it does not move;
* a *light arm* and a *camera arm* are concentric arcs (radii ``light_arm_radius_m`` >
  ``camera_arm_radius_m``) that each turn about z (joint ``<arm>_az``) and carry a carriage along
  the arc (joint ``<arm>_el``, the *signed* zenith angle). The direction of an arm is
  ``d = R_z(az) · (sin el, 0, cos el)``, so ``(el, az)`` and ``(−el, az + π)`` (and ``az + 2πk``)
  give the same direction: :meth:`Rig.solve` picks, per arm, the solution within the joint limits
  that the trapezoidal profile reaches soonest from the current pose;
* a pose is refused (:class:`gonio.errors.UnreachablePose`, ``reason`` = ``"limits"``,
  ``"collision"`` or ``"shadow"``) when no solution is within the joint limits, when the two carriages
  are closer than ``min_arm_separation_deg``, or when the camera body (a sphere) cuts the light's beam
  (a cylinder around the light → sample segment). The light (outer arc) can never sit between the
  camera and the sample.

``layout = "turntable"`` (``gonio/rig/rigs/turntable.toml``, joints ``sample_az, light_el, camera_az,
camera_el``): the sample turns on a turntable about its normal (``sample_az``); the light arm has an
elevation carriage only, its arc fixed at the lab azimuth ``light_azimuth_deg`` (α); the camera arm
is as above. In the lab frame the light is at ``R_z(α)·(sin el, 0, cos el)``; the sample frame is
the lab frame turned by ``sample_az`` (s) about z, so in the sample frame every arm is turned by
``−s``: the light's azimuth is ``α − s`` (+π past the pole), the camera's ``camera_az − s``. φi is
set by the turntable, φo − φi by the camera azimuth. The ChArUco board turns with the sample, so the
camera pose the pipeline estimates from it is already in the sample frame. Collision and shadow tests
are the same (they depend only on the angle between the arms, which the rotation keeps); the solver
searches the coupled solutions (light sign × turntable turn × camera sign × camera turn) for the one
the trapezoidal profile reaches soonest.

Move time: each joint follows a trapezoidal velocity profile (accelerate at ``a``, cruise at ``v``,
decelerate), joints move concurrently, so a move costs its slowest joint (:func:`trapezoid_time`,
:meth:`Rig.move_time`). The same profile is what Dynamixel servos run in their velocity-based profile
mode (ROBOTIS e-manual, "Profile Velocity(112)"), which the servo emulator uses too.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Mapping

import numpy as np

from gonio.config import parse_toml, read_text
from gonio.errors import ConfigError, UnreachablePose
from gonio.geometry import dirs_from_angles, dot


__all__ = ["Joint", "Rig", "load_rig", "read_rig_text", "trapezoid_time", "trapezoid_progress", "JOINT_NAMES", "LAYOUTS", "REASONS"]

#: Joints of each rig layout, in the order of every joint-angle array (last axis): (name, kind).
LAYOUTS = {
    "arms": (("light_az", "azimuth"), ("light_el", "elevation"), ("camera_az", "azimuth"), ("camera_el", "elevation")),
    "turntable": (("sample_az", "turntable"), ("light_el", "elevation"), ("camera_az", "azimuth"),
                  ("camera_el", "elevation")),
}
#: Joint order of the default ("arms") layout; a rig's own order is :attr:`Rig.names`.
JOINT_NAMES = tuple(n for n, _ in LAYOUTS["arms"])
#: Reason codes of refused poses (index 0 = reachable).
REASONS = ("ok", "limits", "collision", "shadow")
_TWO_PI = 2.0 * math.pi


# -- trapezoidal profile ------------------------------------------------------------------------------
def trapezoid_time(distance, v_max, a_max) -> np.ndarray:
    """Duration of a rest-to-rest move of ``distance`` under a trapezoidal velocity profile.

    With ``d = |distance|``: if ``d ≥ v²/a`` the profile reaches ``v`` and ``t = d/v + v/a``
    (accelerate for ``v/a``, cruise, decelerate for ``v/a``); otherwise it is triangular and
    ``t = 2·√(d/a)``. ``a = inf`` gives ``d/v`` (rectangular profile); ``v = inf`` gives the
    triangular form. Same profile as the Dynamixel velocity-based profile (ROBOTIS e-manual, X series,
    "Profile Velocity(112)": trapezoidal, triangular or rectangular by the move and the two registers).
    """
    d = np.abs(np.asarray(distance, dtype=np.float64))
    v = np.asarray(v_max, dtype=np.float64)
    a = np.asarray(a_max, dtype=np.float64)
    if v.size <= 64 and np.isfinite(v).all() and np.isfinite(a).all():
        # Finite per-joint limits (every real rig): two NumPy passes. This is the inner loop of plan
        # ordering (nearest neighbour, neighbour lists, Prim), so it is kept lean; d = 0 gives 0.
        return np.where(d >= v * v / a, d / v + v / a, np.sqrt(d * (4.0 / a)))
    with np.errstate(divide="ignore", invalid="ignore"):
        v_a = np.where(np.isinf(a), 0.0, v / a)  # time to reach v
        trap = d / v + v_a
        tri = 2.0 * np.sqrt(d / a)
        t = np.where(np.isinf(v), tri, np.where(d >= v * v_a, trap, tri))
    return np.where(d == 0.0, 0.0, t)


def trapezoid_progress(t: float, distance: float, v_max: float, a_max: float,
                       total: float | None = None) -> tuple[float, float]:
    """Position and velocity ``(s, ds/dt)`` at time ``t`` of the move of :func:`trapezoid_time` (Python floats).

    Signed along ``distance``; ``s`` goes from 0 at ``t ≤ 0`` to ``distance`` at the end (``t ≥ total``, the
    move's :func:`trapezoid_time`, computed when not given). The cruise speed is ``v`` if reached, else the
    triangular peak ``√(a·d)``; ``a = inf``: the velocity jumps (rectangular profile). ROBOTIS e-manual, X
    series, "Profile Velocity(112)". Scalar on purpose: the servo emulator (sim/servo_bus.py) evaluates it on
    every read of a moving servo, where NumPy's per-call cost on scalars (~30 µs) would dominate."""
    t, distance, v, a = float(t), float(distance), float(v_max), float(a_max)
    if total is None:
        total = float(trapezoid_time(distance, v, a))
    sign, dist = (1.0 if distance > 0 else -1.0), abs(distance)
    if dist == 0.0 or t >= total:
        return sign * dist, sign * 0.0
    inf_a = math.isinf(a)
    peak = min(v, math.sqrt(a * dist))
    t_acc = 0.0 if inf_a else peak / a
    af = 0.0 if inf_a else a  # infinite acceleration: velocity jumps, no ramp
    tc = max(t, 0.0)
    t_dec0 = total - t_acc  # deceleration starts
    s_acc = 0.5 * af * min(tc, t_acc) ** 2
    s_cruise = peak * max(min(tc, t_dec0) - t_acc, 0.0)
    td = max(tc - t_dec0, 0.0)
    s_dec = peak * td - 0.5 * af * td ** 2
    vel = (peak if inf_a else af * tc) if tc < t_acc else (peak if tc < t_dec0 else peak - af * td)
    return sign * (s_acc + s_cruise + s_dec), sign * vel


# -- rig description ----------------------------------------------------------------------------------
@dataclass(frozen=True)
class Joint:
    """One joint of the rig (angles in radians; speeds in rad/s and rad/s²)."""

    name: str
    servo_id: int
    model: str
    gear_ratio: float
    zero_offset_deg: float
    direction: int
    lower: float
    upper: float
    max_speed: float
    max_accel: float
    kind: str = ""  #: "azimuth", "elevation" or "turntable" (:data:`LAYOUTS`)


def _table(src, where, value) -> dict:
    if not isinstance(value, dict):
        raise ConfigError.field(src, where, str(value)[:60], "must be a table")
    return value


def _int(src, where, table, key, lo: int, hi: int) -> int:
    if key not in table:
        raise ConfigError.field(src, f"{where}.{key}", None, "missing")
    value = table[key]
    if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
        raise ConfigError.field(src, f"{where}.{key}", value, f"must be an integer in [{lo}, {hi}]")
    return value


def _num(src, where, table, key, lo=-math.inf, hi=math.inf):
    if key not in table:
        raise ConfigError.field(src, f"{where}.{key}", None, "missing")
    value = table[key]
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not lo <= value <= hi:
        raise ConfigError.field(src, f"{where}.{key}", value, f"must be a number in [{lo}, {hi}]")
    return float(value)


@dataclass(frozen=True)
class Rig:
    """A light arm + camera arm rig, with or without a sample turntable (see the module docstring);
    load with :func:`load_rig`. ``light_azimuth`` (rad) is the fixed light arc's azimuth of the
    turntable layout."""

    name: str
    joints: tuple[Joint, ...]
    light_radius: float
    camera_radius: float
    camera_body_radius: float
    light_beam_radius: float
    min_separation: float
    baud: int = 1_000_000
    source: str = "<rig>"
    layout: str = "arms"
    light_azimuth: float = 0.0
    #: The rig's estimated assembly errors (:class:`gonio.rig.chain.ChainErrors`, from the ``[calibration]``
    #: table ``gonio calibrate rig`` writes), or ``None``: the declared geometry. When present, the forward
    #: kinematics (:meth:`directions`, :meth:`forward`, :meth:`light_position`, :meth:`camera_pose`) follow
    #: the calibrated chain (:func:`gonio.rig.chain.chain_forward`); the inverse (:meth:`solve_many`) stays the
    #: declared one, so a pose lands within the calibration's corrections of its target and is recorded where it is.
    geometry_errors: object = field(default=None, compare=False)
    #: The calibration's covariance (:class:`gonio.rig.geocov.GeometryCovariance`, the ``[calibration.covariance]``
    #: table), or ``None``: propagated into each pose's light position (every sample's σ) and wi
    geometry_covariance: object = field(default=None, compare=False)

    def within(self, other: "Rig") -> "Rig":
        """This rig with every joint's limits, speed and acceleration no wider than ``other``'s joint of
        the same name (and the larger arm-separation margin): what a session may do when its recorded
        rig (``self``) and the rig file (``other``) disagree. Joints ``other`` lacks are kept."""
        from dataclasses import replace

        theirs = {j.name: j for j in other.joints}
        joints = []
        for j in self.joints:
            o = theirs.get(j.name)
            if o is not None:
                j = replace(j, lower=max(j.lower, o.lower), upper=min(j.upper, o.upper),
                            max_speed=min(j.max_speed, o.max_speed), max_accel=min(j.max_accel, o.max_accel))
            joints.append(j)
        return replace(self, joints=tuple(joints), min_separation=max(self.min_separation, other.min_separation))

    # -- joint arrays ------------------------------------------------------------------------------
    @property
    def names(self) -> tuple[str, ...]:
        return tuple(j.name for j in self.joints)

    @property
    def lower(self) -> np.ndarray:
        return np.array([j.lower for j in self.joints])

    @property
    def upper(self) -> np.ndarray:
        return np.array([j.upper for j in self.joints])

    @property
    def max_speed(self) -> np.ndarray:
        """Per-joint speed limits, rad/s, in :attr:`names` order."""
        return np.array([j.max_speed for j in self.joints])

    @property
    def max_accel(self) -> np.ndarray:
        """Per-joint acceleration limits, rad/s², in :attr:`names` order."""
        return np.array([j.max_accel for j in self.joints])

    def as_array(self, joints) -> np.ndarray:
        """Joint angles as an array ``(..., 4)``; accepts a mapping name → angle too."""
        if isinstance(joints, Mapping):
            try:
                return np.array([float(joints[n]) for n in self.names])
            except KeyError as exc:
                raise ConfigError.field(None, "joints", sorted(joints), f"missing joint {exc.args[0]!r}") from None
        return np.asarray(joints, dtype=np.float64)

    def as_dict(self, joints) -> dict[str, float]:
        j = np.asarray(joints, dtype=np.float64)
        return {n: float(j[i]) for i, n in enumerate(self.names)}

    # -- timing ------------------------------------------------------------------------------------
    def move_time(self, start, end) -> np.ndarray:
        """Seconds to move from joints ``start`` to ``end`` (``(..., 4)``, broadcast): the slowest
        joint's :func:`trapezoid_time`, all joints moving concurrently."""
        delta = self.as_array(end) - self.as_array(start)
        return np.max(trapezoid_time(delta, self.max_speed, self.max_accel), axis=-1)

    # -- forward -----------------------------------------------------------------------------------
    @staticmethod
    def _arm_dir(az, el) -> np.ndarray:
        s = np.sin(el)
        return np.stack(np.broadcast_arrays(s * np.cos(az), s * np.sin(az), np.cos(el)), axis=-1)

    def arm_angles(self, joints) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Each arm's (azimuth, signed elevation) *in the sample frame*: ``(light_az, light_el,
        camera_az, camera_el)`` for joints ``(..., 4)`` of this rig's layout.

        Arms layout: the joints themselves. Turntable layout: the sample frame is the lab frame turned
        by ``sample_az`` about z, so both arms turn by ``−sample_az``: light azimuth ``α − sample_az``,
        camera azimuth ``camera_az − sample_az`` (module docstring).
        """
        j = self.as_array(joints)
        if self.layout == "turntable":
            s = j[..., 0]
            return self.light_azimuth - s, j[..., 1], j[..., 2] - s, j[..., 3]
        return j[..., 0], j[..., 1], j[..., 2], j[..., 3]

    def directions(self, joints) -> tuple[np.ndarray, np.ndarray]:
        """Unit directions ``(wi, wo)`` (toward light, toward camera; sample frame) for joints ``(..., 4)``."""
        if self.geometry_errors is not None:
            from gonio.rig.chain import true_directions

            return true_directions(self, self.geometry_errors, joints)
        laz, lel, caz, cel = self.arm_angles(joints)
        return self._arm_dir(laz, lel), self._arm_dir(caz, cel)

    def forward(self, joints) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """BRDF angles ``(θi, φi, θo, φo)`` of joints ``(..., 4)``: per arm (:meth:`arm_angles`)
        θ = |el|, φ = az (+π if el < 0), φ wrapped to [0, 2π). At the pole (el = 0) φ is the arm's
        azimuth in the sample frame."""
        if self.geometry_errors is not None:  # from the calibrated directions (θ = polar angle, φ in [0, 2π))
            from gonio.geometry import to_spherical

            wi, wo = self.directions(joints)
            ti, pi_ = to_spherical(wi)
            to, po = to_spherical(wo)
            return ti, np.mod(pi_, _TWO_PI), to, np.mod(po, _TWO_PI)
        laz, lel, caz, cel = self.arm_angles(joints)

        def arm(az, el):
            return np.abs(el), np.mod(az + np.where(el < 0, math.pi, 0.0), _TWO_PI)

        ti, pi_ = arm(laz, lel)
        to, po = arm(caz, cel)
        return ti, pi_, to, po

    def light_position(self, joints) -> np.ndarray:
        """Light position in the sample frame, metres, ``(..., 3)``; it points at the origin."""
        if self.geometry_errors is not None:
            from gonio.rig.chain import chain_forward

            return chain_forward(self, self.geometry_errors, joints)[0]
        return self.light_radius * self.directions(joints)[0]

    def camera_pose(self, joints) -> tuple[np.ndarray, np.ndarray]:
        """Camera position (metres) and orientation in the sample frame.

        Returns ``(position (..., 3), R (..., 3, 3))``; the rows of ``R`` are the camera's x (right),
        y (down) and z (optical axis, toward the sample origin) axes in sample coordinates (OpenCV
        convention), so a sample-frame point ``p`` is ``R @ (p - position)`` in camera coordinates.
        x is the camera arm's azimuth tangent (in the sample frame), defined everywhere including the pole.
        """
        if self.geometry_errors is not None:
            from gonio.rig.chain import chain_forward

            _, position, R = chain_forward(self, self.geometry_errors, joints)
            return position, R
        _, _, az, el = self.arm_angles(joints)
        wo = self._arm_dir(az, el)
        z = -wo
        x = np.stack(np.broadcast_arrays(-np.sin(az), np.cos(az), np.zeros_like(az)), axis=-1)
        y = np.cross(z, x)
        return self.camera_radius * wo, np.stack([x, y, z], axis=-2)

    # -- reachability ------------------------------------------------------------------------------
    def check_directions(self, wi, wo) -> np.ndarray:
        """Reason codes (index into :data:`REASONS`) of the collision and shadow tests, ``(...)``.

        A direction with a non-finite component is ``"collision"``: the guard cannot clear what is not a
        direction (NaN compares false with every threshold, so without this it would pass as ``"ok"``)."""
        wi, wo = np.broadcast_arrays(np.asarray(wi, float), np.asarray(wo, float))
        code = np.zeros(wi.shape[:-1], dtype=np.int8)
        finite = np.isfinite(wi).all(axis=-1) & np.isfinite(wo).all(axis=-1)
        with np.errstate(invalid="ignore", over="ignore"):  # non-finite rows: coded below, values unused
            sep = np.arccos(np.clip(dot(wi, wo), -1.0, 1.0))
            # Shadow: distance from the camera centre c to the segment origin -> light position L.
            c, L = self.camera_radius * wo, self.light_radius * wi
            t = np.clip(dot(c, L) / (self.light_radius ** 2), 0.0, 1.0)
            dist = np.linalg.norm(c - t[..., None] * L, axis=-1)
        code[~(sep >= self.min_separation) | ~finite] = 2  # NaN separation included
        code[(code == 0) & (dist < self.camera_body_radius + self.light_beam_radius)] = 3
        return code

    def _solve_arm(self, theta, phi, cur_az, cur_el, jaz: int, jel: int):
        """Per arm: best (az, el) within limits nearest (in profile time) to the current (az, el)."""
        az_lo, az_hi = self.joints[jaz].lower, self.joints[jaz].upper
        el_lo, el_hi = self.joints[jel].lower, self.joints[jel].upper
        theta = np.asarray(theta, float)[..., None, None]
        pole = theta < 1e-12
        sgn = np.array([1.0, -1.0])[:, None]
        k = np.arange(-2, 3)[None, :]
        el = sgn * theta
        az = np.asarray(phi, float)[..., None, None] + np.where(sgn > 0, 0.0, math.pi) + _TWO_PI * k
        az = np.where(pole, np.asarray(cur_az, float)[..., None, None], az)  # at the pole, keep the azimuth
        el, az = np.broadcast_arrays(el, az)
        inside = (az >= az_lo - 1e-12) & (az <= az_hi + 1e-12) & (el >= el_lo - 1e-12) & (el <= el_hi + 1e-12)
        cost = np.maximum(
            trapezoid_time(az - np.asarray(cur_az, float)[..., None, None], self.joints[jaz].max_speed,
                           self.joints[jaz].max_accel),
            trapezoid_time(el - np.asarray(cur_el, float)[..., None, None], self.joints[jel].max_speed,
                           self.joints[jel].max_accel))
        cost = np.where(inside, cost, np.inf).reshape(cost.shape[:-2] + (-1,))
        best = np.argmin(cost, axis=-1)
        pick = lambda a: np.take_along_axis(a.reshape(a.shape[:-2] + (-1,)), best[..., None], axis=-1)[..., 0]
        ok = np.isfinite(np.take_along_axis(cost, best[..., None], axis=-1)[..., 0])
        return pick(az), pick(el), ok

    def _solve_turntable(self, ti, pi_, to, po, cur):
        """Turntable layout: of every joint solution within limits, the one nearest ``cur`` in move time.

        Candidates (module docstring): light ``el = σ·θi`` with the turntable at
        ``s = α + (π if σ < 0) − φi + 2πk``; camera ``el = τ·θo``, ``camera_az = φo + s + (π if τ < 0)
        + 2πm``; σ, τ ∈ {±1}; of the turns k, m only those that can fall within the joint's limits
        (the angle wrapped to [lower, lower + 2π), plus whole turns up to the joint's range). At a pole
        the azimuth is free: the turntable (light at the pole) or the camera azimuth (camera at the pole)
        stays where it is. Returns ``(joints (..., 4), ok (...))``.
        """
        def turns(angle, joint: Joint, axis: int, ndim: int = 4):
            """``angle`` (..., 2 signs, ...) wrapped into the joint's range, with a new turns axis."""
            n = int(math.ceil((joint.upper - joint.lower) / _TWO_PI)) + 1
            shape = [1] * ndim
            shape[axis] = n
            base = joint.lower + np.mod(angle - joint.lower, _TWO_PI)
            return base + _TWO_PI * np.arange(n).reshape(shape)

        sign = np.array([1.0, -1.0])
        e = lambda a: np.asarray(a, dtype=np.float64)[..., None, None, None, None]  # noqa: E731
        sl, sc = sign[:, None, None, None], sign[None, None, :, None]  # light sign, camera sign
        s = turns(self.light_azimuth + np.where(sl < 0, math.pi, 0.0) - e(pi_), self.joints[0], 1)
        s = np.where(e(ti) < 1e-12, e(cur[..., 0]), s)
        caz = turns(e(po) + s + np.where(sc < 0, math.pi, 0.0), self.joints[2], 3)
        caz = np.where(e(to) < 1e-12, e(cur[..., 2]), caz)
        cand = np.stack(np.broadcast_arrays(s, sl * e(ti), caz, sc * e(to)), axis=-1)
        cand = cand.reshape(cand.shape[:-5] + (-1, 4))
        inside = np.all((cand >= self.lower - 1e-12) & (cand <= self.upper + 1e-12), axis=-1)
        cost = np.where(inside, self.move_time(cur[..., None, :], cand), np.inf)
        best = np.argmin(cost, axis=-1)
        ok = np.isfinite(np.take_along_axis(cost, best[..., None], axis=-1)[..., 0])
        return np.take_along_axis(cand, best[..., None, None], axis=-2)[..., 0, :], ok

    def solve_many(self, theta_i, phi_i, theta_o, phi_o, current=None, *, isotropic: bool = False):
        """Vectorized :meth:`solve`: returns ``(joints (..., 4), reason codes (...))``.

        Poses that cannot be reached get joints NaN and a non-zero code (index into :data:`REASONS`).
        ``current`` is one pose ``(4,)`` or one per input ``(..., 4)`` (default: all joints at 0).
        With ``isotropic=True`` the pose may be rotated about z (only φo − φi matters for an isotropic
        material): among keeping the light's azimuth, keeping the camera's azimuth, or the given φi,
        the reachable one with the shortest move time is chosen.
        """
        ti, pi_, to, po = np.broadcast_arrays(*(np.asarray(a, dtype=np.float64) for a in (theta_i, phi_i, theta_o, phi_o)))
        cur = np.zeros(4) if current is None else self.as_array(current)
        cur = np.broadcast_to(cur, ti.shape + (4,))
        if isotropic:
            cur_ti, cur_pi, cur_to, cur_po = self.forward(cur)
            dphi = po - pi_
            options = [pi_, np.where(cur_ti > 1e-9, cur_pi, pi_), np.where(cur_to > 1e-9, cur_po - dphi, pi_)]
            if self.layout == "turntable":  # keep the turntable still: the light on either side of the pole
                keep = self.light_azimuth - cur[..., 0]
                options[1:2] = [keep, keep + math.pi]
            sols = [self.solve_many(ti, psi, to, psi + dphi, cur) for psi in options]
            times = np.stack([np.where(c == 0, self.move_time(cur, np.nan_to_num(j)), np.inf) for j, c in sols])
            best = np.argmin(times, axis=0)
            joints = np.choose(best[..., None], [j for j, _ in sols])
            code = np.choose(best, [c for _, c in sols])
            return joints, code
        finite = np.isfinite(ti) & np.isfinite(pi_) & np.isfinite(to) & np.isfinite(po)
        ti, pi_, to, po = (np.where(finite, a, 0.0) for a in (ti, pi_, to, po))  # refused below, solved quietly
        if self.layout == "turntable":
            joints, ok = self._solve_turntable(ti, pi_, to, po, cur)
        else:
            laz, lel, lok = self._solve_arm(ti, pi_, cur[..., 0], cur[..., 1], 0, 1)
            caz, cel, cok = self._solve_arm(to, po, cur[..., 2], cur[..., 3], 2, 3)
            joints, ok = np.stack([laz, lel, caz, cel], axis=-1), lok & cok
        wi, wo = dirs_from_angles(ti, pi_, to, po)
        # a non-finite angle is no pose at all: refused here, whatever the caller checked (the collision
        # guard must not depend on its callers: a pole solution of an infinite azimuth is not a pose)
        ok = ok & finite & np.all(np.isfinite(joints), axis=-1)
        code = np.where(ok, self.check_directions(wi, wo), np.int8(1)).astype(np.int8)
        # The guard also checks the pose as the servos will hold it (each joint on its encoder's tick): a pose
        # within a tick of a zone's edge would otherwise be commanded inside it.
        held = self.held_joints(np.where(ok[..., None], joints, 0.0))
        held_ok = np.all((held >= self.lower - 1e-12) & (held <= self.upper + 1e-12), axis=-1)
        code_held = np.where(held_ok, self.check_directions(*self.directions(held)), np.int8(1)).astype(np.int8)
        code = np.where(code == 0, code_held, code).astype(np.int8)
        joints = np.where((code == 0)[..., None], joints, np.nan)
        return joints, code

    def held_joints(self, joints) -> np.ndarray:
        """Joint angles ``(..., 4)`` as the servos hold them: each rounded to its encoder's tick, the raw position
        ``zero_offset/360·tpr + direction·gear_ratio·θ·tpr/2π`` rounded to an integer
        (:meth:`gonio.rig.dynamixel.AxisConfig.ticks_of`; tpr from the model's control table, or a control table's
        default, 4096, for a model gonio has none for: opening its servo says so, naming the rig file and joint)."""
        from gonio.errors import ConfigError
        from gonio.rig.control_table import ControlTable, load_control_table

        def ticks_per_rev(model: str) -> int:
            try:
                return load_control_table(model).ticks_per_rev
            except ConfigError:
                return ControlTable.ticks_per_rev

        tpr = np.array([ticks_per_rev(j.model) for j in self.joints], dtype=np.float64)
        off = np.array([j.zero_offset_deg / 360.0 for j in self.joints]) * tpr
        scale = np.array([j.direction * j.gear_ratio for j in self.joints]) * tpr / (2.0 * math.pi)
        return (np.rint(off + scale * np.asarray(joints, dtype=np.float64)) - off) / scale

    def solve(self, theta_i, phi_i, theta_o, phi_o, current=None, *, isotropic: bool = False) -> dict[str, float]:
        """Joint angles (radians, by name) that put the light at (θi, φi) and the camera at (θo, φo).

        Among the equivalent solutions the one nearest ``current`` (mapping or ``(4,)`` array) in
        move time is chosen. Raises :class:`UnreachablePose` with ``reason`` ``"limits"``,
        ``"collision"`` or ``"shadow"``.
        """
        joints, code = self.solve_many(theta_i, phi_i, theta_o, phi_o, current, isotropic=isotropic)
        if joints.ndim != 1:
            raise ConfigError.field(None, "pose", np.shape(theta_i), "solve() takes one pose; use solve_many()")
        if code != 0:
            reason = REASONS[int(code)]
            why = {"limits": "no joint solution within the joint limits",
                   "collision": f"the arms would be closer than {math.degrees(self.min_separation):g} deg",
                   "shadow": "the camera would shadow the light's path to the sample"}[reason]
            pose = ", ".join(f"{math.degrees(float(a)):.2f}" for a in (theta_i, phi_i, theta_o, phi_o))
            raise UnreachablePose(f"{self.name}: pose (theta_i, phi_i, theta_o, phi_o) = ({pose}) deg: {why}",
                                  reason=reason)
        return self.as_dict(joints)


# -- loading -----------------------------------------------------------------------------------------
def read_rig_text(path: str | Path | None = None) -> tuple[str, str]:
    """``(text, source)`` of a rig TOML file (a path, or a shipped rig name, as :func:`load_rig`)."""
    if path is None or (isinstance(path, str) and "/" not in path and not path.endswith(".toml")
                        and not Path(path).is_file()):  # a file of that name is read as the rig file
        name = path or "default"
        rigs = resources.files("gonio.rig") / "rigs"
        res = rigs / f"{name}.toml"
        if not res.is_file():
            shipped = sorted(r.name.removesuffix(".toml") for r in rigs.iterdir() if r.name.endswith(".toml"))
            raise ConfigError.field(None, "rig", name, f"no such file, nor a shipped rig ({', '.join(shipped)})")
        text, src = res.read_text(encoding="utf-8"), f"rigs/{name}.toml"
    else:
        text, src = read_text(path, "--rig"), str(path)
    return text, src


#: The keys a rig file may hold (the shipped ``default.toml`` documents each); anything else is a typo that would
#: otherwise be ignored silently, the key it meant taking its default (``directon = -1``: the joint turns the
#: wrong way). ``calibration`` is checked by :meth:`gonio.rig.chain.ChainErrors.from_dict`.
RIG_KEYS = {"name", "layout", "geometry", "bus", "joints", "calibration"}
GEOMETRY_KEYS = {"light_arm_radius_m", "camera_arm_radius_m", "camera_body_radius_m", "light_beam_radius_m",
                 "min_arm_separation_deg", "light_azimuth_deg"}
BUS_KEYS = {"baud", "protocol"}
JOINT_KEYS = {"name", "arm", "kind", "servo_id", "model", "gear_ratio", "zero_offset_deg", "direction", "min_deg",
              "max_deg", "max_speed_deg_s", "max_accel_deg_s2"}


def _known_keys(src, where: str, table: dict, known: set) -> None:
    """Refuse a key that is not in ``known``, naming it and the known key it most resembles."""
    import difflib

    for key in table:
        if key not in known:
            near = difflib.get_close_matches(str(key), sorted(known), n=1)
            hint = f"did you mean {near[0]!r}?" if near else f"known keys: {', '.join(sorted(known))}"
            raise ConfigError.field(src, f"{where}{key}", table[key], f"unknown key ({hint})")


def load_rig(path: str | Path | None = None, *, text: str | None = None, source: str | None = None,
             strict: bool = True) -> Rig:
    """Load a rig TOML file (a path, or a name of a shipped rig: ``"default"``, ``"turntable"``), or
    parse ``text`` (e.g. the copy a session manifest keeps; ``source`` names it in error messages).

    An unknown key (a typo) is refused, naming it; ``strict=False`` ignores unknown keys — for the rig text a
    session recorded, which was accepted when the session started, so that an older session stays resumable.
    ``bus.protocol``, when given, must be 2.0 (gonio speaks Dynamixel Protocol 2.0 only)."""
    if text is None:
        text, src = read_rig_text(path)
    else:
        src = source or "<rig text>"
    data = parse_toml(text, src)
    geo = _table(src, "geometry", data.get("geometry", {}))
    bus = _table(src, "bus", data.get("bus", {}))
    if strict:
        _known_keys(src, "", data, RIG_KEYS)
        _known_keys(src, "geometry.", geo, GEOMETRY_KEYS)
        _known_keys(src, "bus.", bus, BUS_KEYS)
        for i, j in enumerate(data.get("joints", []) if isinstance(data.get("joints"), list) else []):
            if isinstance(j, dict):
                _known_keys(src, f"joints[{i}].", j, JOINT_KEYS)
        protocol = bus.get("protocol", 2.0)
        if isinstance(protocol, bool) or protocol != 2.0:
            raise ConfigError.field(src, "bus.protocol", protocol, "must be 2.0 (gonio speaks Dynamixel Protocol 2.0)")
    layout = data.get("layout", "arms")
    if not isinstance(layout, str) or layout not in LAYOUTS:
        raise ConfigError.field(src, "layout", layout, f"must be one of {', '.join(LAYOUTS)}")
    wanted = LAYOUTS[layout]
    names = [n for n, _ in wanted]
    joints_t = data.get("joints", [])
    if not isinstance(joints_t, list) or not all(isinstance(j, dict) for j in joints_t):
        raise ConfigError.field(src, "joints", str(joints_t)[:60], "must be an array of tables ([[joints]])")
    for i, j in enumerate(joints_t):
        if not isinstance(j.get("name"), str):
            raise ConfigError.field(src, f"joints[{i}].name", j.get("name"), "must be a joint name (a string)")
    by_name = {j["name"]: (i, j) for i, j in enumerate(joints_t)}
    if sorted(by_name) != sorted(names) or len(joints_t) != len(names):
        raise ConfigError.field(src, "joints.name", [j.get("name") for j in joints_t],
                                f"layout {layout!r} needs exactly the joints {', '.join(names)}")
    joints = []
    ids = set()
    for name, kind in wanted:
        i, jt = by_name[name]
        where = f"joints[{i}]"
        if jt.get("kind", kind) != kind:
            raise ConfigError.field(src, f"{where}.kind", jt["kind"], f"joint {name!r} of layout {layout!r} is "
                                    f"a {kind!r} joint")
        lo, hi = _num(src, where, jt, "min_deg", -360, 360), _num(src, where, jt, "max_deg", -360, 360)
        if lo >= hi:
            raise ConfigError.field(src, f"{where}.max_deg", hi, f"must be greater than min_deg = {lo}")
        sid = _int(src, where, jt, "servo_id", 0, 252)
        if sid in ids:
            raise ConfigError.field(src, f"{where}.servo_id", sid, "used by another joint")
        ids.add(sid)
        direction = jt.get("direction", 1)
        if isinstance(direction, bool) or direction not in (1, -1):
            raise ConfigError.field(src, f"{where}.direction", direction, "must be 1 or -1")
        model = jt.get("model", "XM430-W350")
        if not isinstance(model, str) or not model:
            raise ConfigError.field(src, f"{where}.model", model, "must be a servo model name (a string)")
        joints.append(Joint(name=name, servo_id=sid, model=model,
                            gear_ratio=_num(src, where, jt, "gear_ratio", 1e-3, 1e3),
                            zero_offset_deg=_num(src, where, jt, "zero_offset_deg", 0, 360),
                            direction=direction, lower=math.radians(lo), upper=math.radians(hi),
                            max_speed=math.radians(_num(src, where, jt, "max_speed_deg_s", 1e-3, 1e4)),
                            max_accel=math.radians(_num(src, where, jt, "max_accel_deg_s2", 1e-3, 1e6)),
                            kind=kind))
    rl = _num(src, "geometry", geo, "light_arm_radius_m", 1e-3, 100)
    rc = _num(src, "geometry", geo, "camera_arm_radius_m", 1e-3, 100)
    if rc >= rl:
        raise ConfigError.field(src, "geometry.camera_arm_radius_m", rc, f"must be less than light_arm_radius_m = {rl}")
    alpha = 0.0
    if layout == "turntable":
        alpha = math.radians(_num(src, "geometry", {"light_azimuth_deg": 0.0, **geo}, "light_azimuth_deg", -360, 360))
    elif "light_azimuth_deg" in geo:
        raise ConfigError.field(src, "geometry.light_azimuth_deg", geo["light_azimuth_deg"],
                                f"only for layout 'turntable' (the {layout!r} layout turns the light arm)")
    rig_name = data.get("name", Path(src).stem)
    if not isinstance(rig_name, str):
        raise ConfigError.field(src, "name", rig_name, "must be a string")
    baud = bus.get("baud", 1_000_000)
    from gonio.rig.control_table import BAUD_RATES

    if isinstance(baud, bool) or baud not in BAUD_RATES:
        raise ConfigError.field(src, "bus.baud", baud, f"must be one of {', '.join(map(str, BAUD_RATES))}")
    errors = covariance = None
    if "calibration" in data:  # written by `gonio calibrate rig` (gonio.rig.geocal.write_calibrated_rig)
        from gonio.rig.chain import ChainErrors

        cal = data["calibration"]
        if not isinstance(cal, dict):
            raise ConfigError.field(src, "calibration", str(cal)[:40], "must be a table of estimated assembly errors")
        errors = ChainErrors.from_dict({k: v for k, v in cal.items() if k in ("light", "camera", "turntable",
                                                                              "sample_height_mm")},
                                       source=f"{src}: calibration")
        if "covariance" in cal:
            from gonio.rig.geocov import GeometryCovariance

            covariance = GeometryCovariance.from_table(cal["covariance"], source=f"{src}: calibration.covariance")
    return Rig(name=rig_name, joints=tuple(joints), light_radius=rl, camera_radius=rc,
               camera_body_radius=_num(src, "geometry", geo, "camera_body_radius_m", 0, 10),
               light_beam_radius=_num(src, "geometry", geo, "light_beam_radius_m", 0, 10),
               min_separation=math.radians(_num(src, "geometry", geo, "min_arm_separation_deg", 0, 180)),
               baud=int(baud), source=src, layout=layout, light_azimuth=alpha, geometry_errors=errors,
               geometry_covariance=covariance)
