"""Rig kinematics: round trips (property-based), nearest solution, refusals, poses, move times."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from gonio.errors import ConfigError, UnreachablePose
from gonio.geometry import dirs_from_angles
from gonio.rig.kinematics import REASONS, load_rig, trapezoid_progress, trapezoid_time

RIG = load_rig()
angle = st.floats(0.0, math.radians(84.9))
azim = st.floats(0.0, 2 * math.pi, exclude_max=True)
joints_st = st.tuples(st.floats(-2.9, 2.9), st.floats(-1.45, 1.45), st.floats(-2.9, 2.9), st.floats(-1.45, 1.45))


@given(angle, azim, angle, azim, joints_st)
def test_solve_then_forward_gives_the_same_directions(ti, pi_, to, po, current):
    try:
        j = RIG.solve(ti, pi_, to, po, current=np.array(current))
    except UnreachablePose as exc:
        assert exc.reason in ("collision", "shadow")  # every direction above 85 deg... is within limits
        return
    wi, wo = RIG.directions(RIG.as_array(j))
    wi0, wo0 = dirs_from_angles(ti, pi_, to, po)
    assert np.allclose(wi, wi0, atol=1e-9) and np.allclose(wo, wo0, atol=1e-9)
    arr = RIG.as_array(j)
    assert np.all(arr >= RIG.lower - 1e-9) and np.all(arr <= RIG.upper + 1e-9)


@given(joints_st)
def test_forward_then_solve_returns_the_same_joints_when_starting_there(joints):
    j = np.array(joints)
    ti, pi_, to, po = RIG.forward(j)
    sol, code = RIG.solve_many(ti, pi_, to, po, current=j)
    if code == 0:  # from the pose itself the nearest solution is the pose (no move needed)
        assert float(RIG.move_time(j, sol)) == pytest.approx(0.0, abs=1e-6)


@given(angle, azim, angle, azim, joints_st)
def test_chosen_solution_is_the_nearest_of_the_equivalent_ones(ti, pi_, to, po, current):
    cur = np.array(current)
    sol, code = RIG.solve_many(ti, pi_, to, po, current=cur)
    if code != 0:
        return
    # every other equivalent light solution within limits is no faster to reach
    best = trapezoid_time(sol[:2] - cur[:2], RIG.max_speed[:2], RIG.max_accel[:2]).max()
    for s in (1, -1):
        for k in range(-2, 3):
            az = pi_ + (0 if s > 0 else math.pi) + 2 * math.pi * k
            el = s * ti
            if RIG.lower[0] <= az <= RIG.upper[0] and ti > 1e-12:
                t = trapezoid_time(np.array([az, el]) - cur[:2], RIG.max_speed[:2], RIG.max_accel[:2]).max()
                assert best <= t + 1e-9


def test_vectorized_solve_matches_scalar_and_reports_reasons():
    rng = np.random.default_rng(4)
    n = 2000
    args = (rng.uniform(0, 1.6, n), rng.uniform(0, 6.3, n), rng.uniform(0, 1.6, n), rng.uniform(0, 6.3, n))
    joints, code = RIG.solve_many(*args)
    assert joints.shape == (n, 4) and code.shape == (n,)
    assert set(np.unique(code)) == {0, 1, 2, 3}  # all reasons occur over random poses
    for k in range(0, n, 97):
        a = [x[k] for x in args]
        if code[k] == 0:
            assert np.allclose(RIG.as_array(RIG.solve(*a)), joints[k])
        else:
            with pytest.raises(UnreachablePose) as exc:
                RIG.solve(*a)
            assert exc.value.reason == REASONS[code[k]]
            assert np.all(np.isnan(joints[k]))


def test_refusals_name_the_reason():
    with pytest.raises(UnreachablePose, match="joint limits") as exc:
        RIG.solve(math.radians(88), 0, math.radians(30), math.pi)
    assert exc.value.reason == "limits"
    with pytest.raises(UnreachablePose, match="closer than 6 deg") as exc:
        RIG.solve(math.radians(30), 0, math.radians(30), math.radians(3))  # retro-reflection
    assert exc.value.reason == "collision"
    # camera 8 deg from the light, nearer the sample: inside the beam cylinder (0.4 sin 8° < 0.065 m)
    with pytest.raises(UnreachablePose, match="shadow") as exc:
        RIG.solve(math.radians(40), 0, math.radians(32), 0)
    assert exc.value.reason == "shadow"
    # the same separation with the camera farther out along the arc is fine once it clears the beam
    RIG.solve(math.radians(40), 0, math.radians(20), 0)


def test_pole_keeps_the_current_azimuth():
    j = RIG.solve(0.0, 0.0, math.radians(45), 1.0, current=[1.2, 0.3, 0.0, 0.0])
    assert j["light_az"] == pytest.approx(1.2) and j["light_el"] == 0.0


def test_isotropic_reduction_keeps_an_arm_still_and_the_relative_azimuth():
    cur = RIG.as_array(RIG.solve(math.radians(30), 0.0, math.radians(50), math.pi))
    ti, pi_, to, po = math.radians(30), math.radians(120), math.radians(50), math.radians(120 + 150)
    plain, _ = RIG.solve_many(ti, pi_, to, po, cur)
    iso, code = RIG.solve_many(ti, pi_, to, po, cur, isotropic=True)
    assert code == 0
    assert float(RIG.move_time(cur, iso)) < float(RIG.move_time(cur, plain))
    fi = RIG.forward(iso)
    assert math.remainder(fi[3] - fi[1] - math.radians(150), 2 * math.pi) == pytest.approx(0, abs=1e-9)
    assert fi[0] == pytest.approx(ti) and fi[2] == pytest.approx(to)


def test_camera_pose_looks_at_the_sample_and_is_a_rotation():
    j = RIG.as_array(RIG.solve(math.radians(30), 0.3, math.radians(60), 2.0))
    pos, R = RIG.camera_pose(j)
    assert np.linalg.norm(pos) == pytest.approx(RIG.camera_radius)
    assert np.allclose(R @ R.T, np.eye(3)) and np.linalg.det(R) == pytest.approx(1.0)
    assert np.allclose(R @ (np.zeros(3) - pos), [0, 0, RIG.camera_radius])  # origin on the optical axis
    L = RIG.light_position(j)
    assert np.linalg.norm(L) == pytest.approx(RIG.light_radius)
    # vectorized
    many = np.tile(j, (5, 1))
    assert RIG.camera_pose(many)[1].shape == (5, 3, 3) and RIG.light_position(many).shape == (5, 3)


def test_trapezoid_profile_formulas_and_move_time():
    # triangular / trapezoidal / rectangular cases
    assert trapezoid_time(1.0, 2.0, 1.0) == pytest.approx(2.0)           # d < v²/a: 2√(d/a)
    assert trapezoid_time(10.0, 2.0, 1.0) == pytest.approx(10 / 2 + 2)  # d/v + v/a
    assert trapezoid_time(3.0, 2.0, np.inf) == pytest.approx(1.5)
    t = np.linspace(0, 7, 71)
    s, v = np.array([trapezoid_progress(x, 10.0, 2.0, 1.0) for x in t]).T
    assert s[0] == 0 and s[-1] == pytest.approx(10.0) and np.all(np.diff(s) >= -1e-12)
    assert np.max(v) == pytest.approx(2.0) and np.allclose(np.gradient(s, t)[5:-5], v[5:-5], atol=0.11)
    a = np.zeros(4)
    b = np.array([1.0, 0.1, -0.5, 0.0])
    expect = max(trapezoid_time(d, vm, am) for d, vm, am in zip(b - a, RIG.max_speed, RIG.max_accel))
    assert RIG.move_time(a, b) == pytest.approx(expect)
    assert RIG.move_time(np.zeros((3, 4)), np.tile(b, (3, 1))).shape == (3,)


@pytest.mark.parametrize("d, v, a", [(10.0, 2.0, 1.0), (1.0, 2.0, 1.0), (-10.0, 2.0, 1.0), (3.0, 2.0, np.inf),
                                     (-3.0, 2.0, np.inf), (250.0, 1e3, 5e4)])
def test_trapezoid_progress_is_the_profile_in_closed_form(d, v, a):
    """Against the profile's phases written out (ROBOTIS e-manual, Profile Velocity(112)): accelerate at a to
    the peak min(v, √(a·|d|)), cruise, decelerate; s(t) = ½at², then peak·(t − t_acc) + ½a·t_acc², then by symmetry."""
    total = float(trapezoid_time(d, v, a))
    dist, sign = abs(d), np.sign(d)
    peak = min(v, np.sqrt(a * dist))
    t_acc = 0.0 if np.isinf(a) else peak / a
    for t in np.linspace(-0.5, total + 0.5, 41):
        s, vel = trapezoid_progress(t, d, v, a)
        tc = min(max(t, 0.0), total)
        if tc <= t_acc:
            want_s, want_v = 0.5 * (0 if np.isinf(a) else a) * tc ** 2, (peak if np.isinf(a) else a * tc)
        elif tc <= total - t_acc:
            want_s, want_v = 0.5 * peak * t_acc + peak * (tc - t_acc), peak
        else:
            r = total - tc
            want_s, want_v = dist - 0.5 * a * r ** 2, a * r
        if t <= 0:
            want_v = want_v if np.isinf(a) else 0.0
        if t >= total:
            want_s, want_v = dist, 0.0
        assert s == pytest.approx(sign * want_s, rel=1e-9, abs=1e-9), t
        assert vel == pytest.approx(sign * want_v, rel=1e-9, abs=1e-9), t
    assert trapezoid_progress(0.3, 0.0, 2.0, 1.0) == (0.0, 0.0)  # no move
    assert trapezoid_progress(0.3, d, v, a, total) == trapezoid_progress(0.3, d, v, a)  # total given or computed


def test_rig_file_errors_name_file_and_field(tmp_path, monkeypatch):
    text = (__import__("importlib.resources").resources.files("gonio.rig") / "rigs" / "default.toml").read_text()
    bad = tmp_path / "bad.toml"
    bad.write_text(text.replace("min_deg = -85.0", "min_deg = 95.0", 1))
    with pytest.raises(ConfigError, match=r"bad.toml: joints\[1\].max_deg = 85.0"):
        load_rig(bad)
    bad.write_text(text.replace("servo_id = 2", "servo_id = 1"))
    with pytest.raises(ConfigError, match="servo_id = 1: used by another joint"):
        load_rig(bad)
    with pytest.raises(ConfigError, match=r"no such file, nor a shipped rig \(default, turntable\)"):
        load_rig("nope")
    named = tmp_path / "myrig"  # a rig file without .toml, given by its name in the working directory
    named.write_text(text)
    monkeypatch.chdir(tmp_path)
    assert load_rig("myrig").name == load_rig(tmp_path / "myrig").name


_BAD = [math.nan, math.inf, -math.inf]


@pytest.mark.parametrize("layout", ["default", "turntable"])
@pytest.mark.parametrize("position", range(4))
@pytest.mark.parametrize("bad", _BAD)
def test_the_guard_refuses_every_non_finite_angle_itself(layout, position, bad):
    """Whatever the caller checked: a non-finite angle in any position is refused by solve / solve_many
    (never a pole solution that skips the collision test), for both layouts."""
    rig = load_rig(None if layout == "default" else
                   str(__import__("importlib").resources.files("gonio.rig") / "rigs" / "turntable.toml"))
    good = [math.radians(30), 0.0, math.radians(30), math.pi]
    angles = list(good)
    angles[position] = bad
    with pytest.raises(UnreachablePose):
        rig.solve(*angles)
    joints, code = rig.solve_many(*[np.array([a, g]) for a, g in zip(angles, good)])
    assert code[0] != 0 and np.all(np.isnan(joints[0])) and code[1] == 0


@pytest.mark.parametrize("bad", _BAD)
def test_collision_check_never_clears_a_non_finite_direction(bad):
    ok_wi, ok_wo = dirs_from_angles(np.radians(30), 0.0, np.radians(40), np.pi)
    assert RIG.check_directions(ok_wi, ok_wo) == 0
    for which in range(2):
        for comp in range(3):
            wi, wo = np.array(ok_wi, float), np.array(ok_wo, float)
            (wi if which == 0 else wo)[comp] = bad
            assert REASONS[int(RIG.check_directions(wi, wo))] == "collision"
