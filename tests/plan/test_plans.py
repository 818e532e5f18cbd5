"""Plan generation, reachability filtering and the JSON round trip."""

import json
import math

import numpy as np
import pytest

from gonio.errors import ConfigError, DataError
from gonio.geometry import dirs_from_angles, half_diff_from_dirs
from gonio.plan import GENERATORS, CaptureSettings, Plan, estimate_plan, make_plan
from gonio.plan.generators import grid_poses, half_diff_poses, in_plane_poses, isotropic_poses
from gonio.rig.kinematics import load_rig

RAD = math.radians


def test_grid_counts_and_pole_once():
    p = grid_poses(RAD(30), RAD(90), RAD(60))
    # per hemisphere: pole + 2 rings x 4 azimuths = 9 directions -> 81 pairs
    assert p.shape == (81, 4)
    assert len(np.unique(np.round(p, 12), axis=0)) == 81


def test_isotropic_and_in_plane_shapes():
    p = isotropic_poses(RAD(30), RAD(90), RAD(60))
    assert np.all(p[:, 1] == 0) and np.all((p[:, 3] >= 0) & (p[:, 3] <= math.pi))
    assert p.shape == (3 * (1 + 2 * 3), 4)
    q = in_plane_poses(RAD(30), RAD(30), RAD(60))
    assert q.shape == (3 * 5, 4) and set(np.round(q[:, 3], 12)) <= {0.0, round(math.pi, 12)}


def test_half_diff_angles_are_what_was_asked():
    p = half_diff_poses(4, RAD(30), RAD(90), RAD(89))
    th, _, td, _ = half_diff_from_dirs(*dirs_from_angles(*p.T))
    assert set(np.round(np.degrees(td), 6)) <= {0.0, 30.0, 60.0}
    np.testing.assert_allclose(np.unique(np.round(th, 9)), np.round((np.arange(4) / 4) ** 2 * math.pi / 2, 9))


@pytest.mark.parametrize("name", sorted(GENERATORS))
def test_make_plan_reachable_and_accounted(name):
    small = {"grid": dict(theta_step=RAD(30), phi_step=RAD(90)), "isotropic": dict(theta_step=RAD(20), phi_step=RAD(45)),
             "in_plane": dict(theta_o_step=RAD(10)), "half_diff": dict(n_theta_h=6, theta_d_step=RAD(20)),
             "sphere": dict(theta_i_step=RAD(20), phi_i_step=RAD(90))}[name]
    rig = load_rig()
    plan = make_plan(name, rig=rig, **small)
    raw = GENERATORS[name].fn(**{k: small.get(k, s.default) for k, s in GENERATORS[name].params.items()})
    assert len(plan) + plan.n_dropped == len(raw)
    joints, code = rig.solve_many(*plan.poses.T)
    assert np.all(code == 0)
    ti, pi_, to, po = rig.forward(plan.joints)
    np.testing.assert_allclose(ti, plan.poses[:, 0], atol=1e-9)
    np.testing.assert_allclose(to, plan.poses[:, 2], atol=1e-9)
    for d in plan.dropped:
        assert d["reason"] in {"horizon", "duplicate", "limits", "collision", "shadow"}
    e = estimate_plan(plan, rig)
    assert e.lower_bound <= e.optimized + 1e-9 and e.optimized <= e.raster_concurrent + 1e-9 <= e.raster + 2e-9


def test_unreachable_poses_are_dropped_with_reason():
    plan = make_plan("in_plane", theta_i_step=RAD(10), theta_o_step=RAD(10))
    reasons = plan.dropped_reasons()
    assert reasons.get("collision", 0) >= 1  # the camera at the light's direction (retro-reflection)
    for d in plan.dropped:
        if d["reason"] == "collision":
            ti, _, to, _ = d["pose"]
            assert abs(ti - to) < RAD(7)


def test_plan_json_round_trip_exact():
    plan = make_plan("half_diff", n_theta_h=5, capture=CaptureSettings(exposures=(0.001, 0.1 / 3), frames=3))
    text = json.dumps(plan.to_dict())
    back = Plan.from_dict(json.loads(text))
    assert back.poses.tobytes() == plan.poses.tobytes()
    assert back.joints.tobytes() == plan.joints.tobytes()
    assert back.capture == plan.capture and back.params == plan.params and back.dropped == plan.dropped
    assert back.generator == "half_diff" and back.order == "optimized"


def test_bad_parameters_name_field_and_value():
    with pytest.raises(ConfigError, match="grid.theta_step"):
        make_plan("grid", theta_step=-1.0)
    with pytest.raises(ConfigError, match="unknown plan"):
        make_plan("spiral")
    with pytest.raises(ConfigError, match="grid.bogus"):
        make_plan("grid", bogus=1)
    with pytest.raises(ConfigError, match="half_diff.n_theta_h"):
        make_plan("half_diff", n_theta_h=2.5)


def test_from_dict_rejects_bad_data():
    good = Plan(np.zeros((2, 4))).to_dict()
    with pytest.raises(DataError, match="m.json: format"):
        Plan.from_dict({**good, "format": 9}, source="m.json")
    with pytest.raises(DataError, match="m.json.*shape"):
        Plan.from_dict({**good, "poses": [[1, 2, 3]], "n_poses": 1}, source="m.json")
    with pytest.raises(DataError, match="capture.frames"):
        Plan.from_dict({**good, "capture": {"frames": 0}}, source="m.json")
    with pytest.raises(DataError, match="n_poses"):
        Plan.from_dict({**good, "n_poses": 3}, source="m.json")
