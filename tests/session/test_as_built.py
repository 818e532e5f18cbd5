"""The as-built simulated rig (sim/as_built.py, issue 15): the simulator renders with its own geometry,
the host sees only the declared rig file; a perfect rig changes nothing."""

from __future__ import annotations


import numpy as np
import pytest

from gonio.cli.main import main
from gonio.rig.chain import ChainErrors, angle_between_deg, chain_forward
from gonio.rig.kinematics import load_rig
from gonio.session.store import load_session
from sim.as_built import TOLERANCES, AsBuilt
from sim.rig import SimRig, SimRigConfig

SMALL = ["--quiet", "--plan", "in_plane", "--theta-i-step", "30", "--theta-o-step", "30", "--theta-max", "60",
         "--sim-resolution", "240x180", "--seed", "3"]


@pytest.mark.parametrize("name", ["default", "turntable"])
def test_zero_errors_are_the_declared_geometry_and_seeded_errors_are_not(name):
    rig = load_rig(name)
    j = np.random.default_rng(1).uniform(-1.2, 1.2, (64, 4))
    pl, pc, R = chain_forward(rig, ChainErrors(), j)
    pos, R0 = rig.camera_pose(j)
    np.testing.assert_allclose(pl, rig.light_position(j), atol=1e-15)
    np.testing.assert_allclose(pc, pos, atol=1e-15)
    np.testing.assert_allclose(R, R0, atol=1e-15)
    ab = AsBuilt.from_seed(rig, 5)
    err = angle_between_deg(ab.directions(j)[0], rig.directions(j)[0])
    assert 0.05 < np.median(err) < 6.0  # a few degrees: the servo zeros dominate
    for arm in ("light", "camera"):
        assert all(abs(v) <= TOLERANCES[k] for k, v in getattr(ab.errors, arm).items())
    assert AsBuilt.from_seed(rig, 5).errors.to_dict() == ab.errors.to_dict()  # reproducible from the seed
    assert AsBuilt.from_seed(rig, 6).errors.to_dict() != ab.errors.to_dict()


def test_the_simulator_places_camera_and_light_with_the_as_built_geometry():
    rig = load_rig("default")
    ab = AsBuilt.from_seed(rig, 2)
    with SimRig(rig, config=SimRigConfig(as_built=ab.to_dict(), servo_noise_ticks=0, backlash_ticks=0)) as sim:
        j = sim.actual_joints()
        sim.camera.capture(0.01)
        assert np.allclose(sim.sim_camera._light_pos, ab.light_position(j))
        assert not np.allclose(sim.sim_camera._light_pos, rig.light_position(j), atol=1e-3)
        assert np.allclose(sim.sim_camera._pose.centre, ab.camera_pose(j)[0])
    assert "as_built" not in SimRigConfig().to_dict()  # a perfect rig's manifest is unchanged


def test_measure_sim_with_a_perfect_as_built_file_gives_the_same_samples(tmp_path, tmp_path_factory):
    from tests.session.conftest import measured_shared

    zero = tmp_path / "zero.toml"
    zero.write_text("[light]\nd_az_deg = 0.0\n[camera]\nlateral_mm = 0\n")
    a_dir = measured_shared(tmp_path_factory, ["measure", "--sim", *SMALL])  # test_frame_faults' clean one too
    assert main(["measure", "--sim", *SMALL, "--sim-as-built", str(zero), "--out", str(tmp_path / "b")]) == 0
    assert main(["measure", "--sim", *SMALL, "--sim-as-built", "4", "--out", str(tmp_path / "c")]) == 0
    (_, a), (_, b), (mc, c) = (load_session(x) for x in (a_dir, tmp_path / "b", tmp_path / "c"))

    def rows(s):
        return np.concatenate([s.wi, s.wo, np.reshape(s.f, (len(s.wi), -1))], axis=1)

    assert len(a.wi) == len(b.wi) > 0 and np.array_equal(rows(a), rows(b))  # bit for bit
    assert mc["sim"]["as_built"]["source"] == "seed 4"
    assert len(c.wi) != len(a.wi) or not np.array_equal(rows(a), rows(c))  # the as-built rig is seen


def test_a_bad_as_built_file_is_one_line(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text("[light]\nd_az_dg = 1.0\n")
    code = main(["measure", "--sim", *SMALL, "--sim-as-built", str(bad), "--out", str(tmp_path / "x")])
    err = capsys.readouterr().err
    assert code not in (0, None) and "Traceback" not in err and "d_az_dg" in err and str(bad) in err
    assert not (tmp_path / "x").exists()
