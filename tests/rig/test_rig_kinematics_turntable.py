"""Turntable layout kinematics: round trips (property-based), the lab -> sample frame rotation, the
nearest of the equivalent solutions, the isotropic reduction, refusals and rig-file errors."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from gonio.errors import ConfigError, UnreachablePose
from gonio.geometry import dirs_from_angles
from gonio.rig.kinematics import JOINT_NAMES, LAYOUTS, REASONS, load_rig

TT = load_rig("turntable")
ARMS = load_rig()
angle = st.floats(0.0, math.radians(84.9))
azim = st.floats(0.0, 2 * math.pi, exclude_max=True)
joints_st = st.tuples(st.floats(-3.0, 3.0), st.floats(-1.45, 1.45), st.floats(-2.9, 2.9), st.floats(-1.45, 1.45))


def rz(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def arc(az, el):
    return rz(az) @ np.array([math.sin(el), 0.0, math.cos(el)])


def equivalents(q):
    """Joint vectors giving the same directions as ``q``, generated from the forward side: turn the
    turntable half a turn with the light past the pole (and the camera stage along); flip the camera past
    its pole; whole turns of the turntable (camera along) and of the camera stage."""
    s, lel, caz, cel = q
    for a, b, k, m in itertools.product((0, 1), (0, 1), range(-2, 3), range(-3, 4)):
        yield np.array([s + a * math.pi + 2 * math.pi * k, -lel if a else lel,
                        caz + a * math.pi + b * math.pi + 2 * math.pi * (k + m), -cel if b else cel])


def test_layout_joint_names_and_kinds():
    assert TT.layout == "turntable" and TT.names == ("sample_az", "light_el", "camera_az", "camera_el")
    assert [j.kind for j in TT.joints] == ["turntable", "elevation", "azimuth", "elevation"]
    assert ARMS.layout == "arms" and ARMS.names == JOINT_NAMES == tuple(n for n, _ in LAYOUTS["arms"])


@given(joints_st)
def test_sample_frame_is_the_lab_frame_turned_by_the_turntable(joints):
    """Built independently in the lab frame: light R_z(α)(sin el, 0, cos el), camera R_z(caz)(...);
    in the sample frame both are turned by −sample_az."""
    s, lel, caz, cel = joints
    wi, wo = TT.directions(np.array(joints))
    back = rz(-s)
    assert np.allclose(wi, back @ arc(TT.light_azimuth, lel), atol=1e-12)
    assert np.allclose(wo, back @ arc(caz, cel), atol=1e-12)
    pos, R = TT.camera_pose(np.array(joints))
    assert np.allclose(pos, TT.camera_radius * wo) and np.allclose(R[2], -wo)
    assert np.allclose(R @ R.T, np.eye(3), atol=1e-12) and np.linalg.det(R) == pytest.approx(1.0)
    assert np.allclose(TT.light_position(np.array(joints)), TT.light_radius * wi)


@given(angle, azim, angle, azim, joints_st)
def test_solve_then_forward_gives_the_same_directions(ti, pi_, to, po, current):
    try:
        j = TT.as_array(TT.solve(ti, pi_, to, po, current=np.array(current)))
    except UnreachablePose as exc:
        assert exc.reason in ("collision", "shadow")  # every direction up to 85 deg is within limits
        return
    wi, wo = TT.directions(j)
    wi0, wo0 = dirs_from_angles(ti, pi_, to, po)
    assert np.allclose(wi, wi0, atol=1e-9) and np.allclose(wo, wo0, atol=1e-9)
    assert np.all(j >= TT.lower - 1e-9) and np.all(j <= TT.upper + 1e-9)
    if ti > 1e-6 and to > 1e-6:  # away from the poles the angles come back too
        got = np.array(TT.forward(j))
        dphi = np.angle(np.exp(1j * (got[[1, 3]] - np.array([pi_, po]))))
        assert np.allclose(got[[0, 2]], [ti, to], atol=1e-9) and np.allclose(dphi, 0.0, atol=1e-9)


@given(joints_st)
def test_forward_then_solve_from_there_does_not_move(joints):
    j = np.clip(np.array(joints), TT.lower, TT.upper)
    sol, code = TT.solve_many(*TT.forward(j), current=j)
    if code == 0:
        assert float(TT.move_time(j, sol)) == pytest.approx(0.0, abs=1e-6)


@given(angle, azim, angle, azim, joints_st)
def test_chosen_solution_is_the_nearest_of_the_equivalent_ones(ti, pi_, to, po, current):
    cur = np.array(current)
    sol, code = TT.solve_many(ti, pi_, to, po, current=cur)
    if code != 0 or ti < 1e-6 or to < 1e-6:
        return
    best = float(TT.move_time(cur, sol))
    wi0, wo0 = TT.directions(sol)
    for q in equivalents(sol):
        wi, wo = TT.directions(q)
        assert np.allclose(wi, wi0, atol=1e-9) and np.allclose(wo, wo0, atol=1e-9)  # really equivalent
        if np.all(q >= TT.lower - 1e-12) and np.all(q <= TT.upper + 1e-12):
            assert best <= float(TT.move_time(cur, q)) + 1e-9


def test_nearest_solution_uses_the_light_past_the_pole_when_the_turntable_is_far():
    # φi = 180°: the turntable at -180° is outside its ±175° limits; the light past the pole (el < 0,
    # +180°) reaches it with the turntable at 0.
    j = TT.solve(math.radians(30), math.pi, math.radians(40), 0.0, current=np.zeros(4))
    assert j["sample_az"] == pytest.approx(0.0, abs=1e-12) and j["light_el"] == pytest.approx(-math.radians(30))
    # from a turntable near 170°, a small positive light el wins (turntable 180° - φi = 180° - 10° ≈ 170°)
    j = TT.solve(math.radians(30), math.radians(-170) % (2 * math.pi), math.radians(40), 0.0,
                 current=np.array([math.radians(168), 0.5, 0.0, -0.5]))
    assert j["sample_az"] == pytest.approx(math.radians(170)) and j["light_el"] > 0


def test_vectorized_solve_matches_one_by_one_and_refuses_like_the_arms_rig():
    rng = np.random.default_rng(3)
    n = 400
    ti, to = rng.uniform(0, math.radians(88), (2, n))
    pi_, po = rng.uniform(0, 2 * math.pi, (2, n))
    joints, code = TT.solve_many(ti, pi_, to, po)
    assert joints.shape == (n, 4) and code.shape == (n,)
    # collision and shadow depend on the directions only; limits on θ ≤ 85° (same elevation limits)
    _, code_arms = ARMS.solve_many(ti, pi_, to, po)
    np.testing.assert_array_equal(code, code_arms)
    assert {REASONS[c] for c in code} >= {"ok", "limits", "collision"}
    assert np.isnan(joints[code != 0]).all() and np.isfinite(joints[code == 0]).all()
    for i in range(0, n, 37):
        if code[i] == 0:
            np.testing.assert_allclose(TT.as_array(TT.solve(ti[i], pi_[i], to[i], po[i])), joints[i], atol=1e-12)


@pytest.mark.parametrize("pose_deg, reason", [((86, 0, 30, 180), "limits"), ((40, 10, 40, 12), "collision"),
                                              ((60, 0, 52, 0), "shadow")])
def test_refusals_name_the_reason(pose_deg, reason):
    with pytest.raises(UnreachablePose) as exc:
        TT.solve(*np.radians(pose_deg))
    assert exc.value.reason == reason and "turntable" in str(exc.value)


@given(angle, azim, angle, azim, joints_st)
def test_isotropic_reduction_keeps_the_isotropic_angles_and_is_never_slower(ti, pi_, to, po, current):
    cur = np.clip(np.array(current), TT.lower, TT.upper)
    j, code = TT.solve_many(ti, pi_, to, po, current=cur)
    ji, ci = TT.solve_many(ti, pi_, to, po, current=cur, isotropic=True)
    if code == 0:
        assert ci == 0 and float(TT.move_time(cur, ji)) <= float(TT.move_time(cur, j)) + 1e-9
    if ci == 0:
        wi, wo = TT.directions(ji)
        wi0, wo0 = dirs_from_angles(ti, pi_, to, po)
        assert np.allclose([wi[2], wo[2]], [wi0[2], wo0[2]], atol=1e-9)  # θi, θo
        assert float(wi @ wo) == pytest.approx(float(wi0 @ wo0), abs=1e-9)  # with θi, θo: |φo − φi|


@pytest.mark.parametrize("turn_deg", [40.0, 123.0, -75.0])
def test_isotropic_reduction_does_not_move_for_a_pose_turned_about_the_normal(turn_deg):
    ti, pi_, to, po = math.radians(30), 1.0, math.radians(50), 3.0
    cur = TT.as_array(TT.solve(ti, pi_, to, po))
    d = math.radians(turn_deg)
    j = TT.as_array(TT.solve(ti, pi_ + d, to, po + d, current=cur, isotropic=True))
    assert float(TT.move_time(cur, j)) == pytest.approx(0.0, abs=1e-9)
    moved = TT.as_array(TT.solve(ti, pi_ + d, to, po + d, current=cur))  # anisotropic: the turntable turns
    assert abs(moved[0] - cur[0]) > 0.1 and float(TT.move_time(cur, moved)) > 1.0


def test_isotropic_reduction_prefers_the_turntable_still_when_it_is_slow(tmp_path):
    (tmp_path / "slow.toml").write_text(_rig_text(**{"max_speed_deg_s = 30.0": "max_speed_deg_s = 2.0"}))
    slow = load_rig(tmp_path / "slow.toml")
    cur = slow.as_array(slow.solve(math.radians(30), 1.0, math.radians(50), 3.0))
    for pose in [(20, 0, 40, 200), (45, 123, 30, 250), (60, 300, 20, 90)]:
        j = slow.solve(*np.radians(pose), current=cur, isotropic=True)
        assert j["sample_az"] == pytest.approx(cur[0], abs=1e-12)


def test_a_turned_light_arc_round_trips(tmp_path):
    p = tmp_path / "tt.toml"
    p.write_text(_rig_text(**{"light_azimuth_deg = 0.0": "light_azimuth_deg = 90.0"}))
    rig = load_rig(p)
    assert rig.light_azimuth == pytest.approx(math.pi / 2)
    j = rig.as_array(rig.solve(math.radians(30), 0.3, math.radians(40), 2.0))
    wi, wo = rig.directions(j)
    assert np.allclose(wi, rz(-j[0]) @ arc(math.pi / 2, j[1])) and np.allclose(rig.forward(j)[1], 0.3)


def _rig_text(**subs):
    from importlib import resources

    src = (resources.files("gonio.rig") / "rigs" / "turntable.toml").read_text()
    for old, new in subs.items():
        assert old in src
        src = src.replace(old, new)
    return src


@pytest.mark.parametrize("old, new, field", [
    ('layout = "turntable"', 'layout = "tripod"', "layout"),
    ('layout = "turntable"', 'layout = "arms"', "joints.name"),
    ('name = "sample_az"', 'name = "light_az"', "joints.name"),
    ('kind = "turntable"', 'kind = "azimuth"', "joints[0].kind"),
    ("light_azimuth_deg = 0.0", "light_azimuth_deg = 400.0", "geometry.light_azimuth_deg"),
])
def test_bad_rig_files_name_the_field(tmp_path, old, new, field):
    p = tmp_path / "bad.toml"
    p.write_text(_rig_text(**{old: new}))
    with pytest.raises(ConfigError) as exc:
        load_rig(p)
    assert str(p) in str(exc.value) and field in str(exc.value)


def test_light_azimuth_is_refused_on_the_arms_layout(tmp_path):
    from importlib import resources

    src = (resources.files("gonio.rig") / "rigs" / "default.toml").read_text()
    p = tmp_path / "arms.toml"
    p.write_text(src.replace("[geometry]\n", "[geometry]\nlight_azimuth_deg = 10.0\n"))
    with pytest.raises(ConfigError, match="light_azimuth_deg"):
        load_rig(p)
