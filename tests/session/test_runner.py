"""The session runner on the simulated rig (real dynamixel-sdk and pyserial on ptys, SimCamera, SimClock)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gonio.errors import ConfigError
from gonio.session.material import load_material
from gonio.session.store import load_session
from sim.rig import SimRig, SimRigConfig
from tests.session.conftest import POSES_DEG, assert_one_record_per_pose, joint_tolerance_rad


# -- material files -------------------------------------------------------------------------------
@pytest.mark.parametrize("text, names", [
    ('model = "nope"', ["model", "nope"]),
    ('model = "microfacet"\n[params]\nkd = [1, 2]\nks = 0.5\nalpha = 0.2\nf0 = 0.04\ndistribution = "ggx"',
     ["microfacet.kd", "[1, 2]"]),
    ('model = "lambert"\n[params]\nalbedo = true', ["lambert.albedo", "True", "not a string or a boolean"]),
    ('model = "lambert"\n[params]\nalbedo = "0.5"', ["lambert.albedo", "'0.5'", "must be a number"]),
    ('model = "lambert"\n[params]\nalbedo = [0.5, false, 0.5]', ["lambert.albedo", "must be a number"]),
    ('model = "lambert"\n[params]\nalbedo = -1', ["lambert.albedo", "-1"]),
    ('model = "lambert"\ncolour = 1', ["colour"]),
    ('label = "x"', ["model", "missing"]),
    ('model = "lambert"\nparams = 3', ["params", "3"]),
    ("model = ", ["not valid TOML"]),
])
def test_bad_material_files_name_file_field_and_value(tmp_path, text, names):
    p = tmp_path / "m.toml"
    p.write_text(text)
    with pytest.raises(ConfigError) as err:
        load_material(p)
    msg = str(err.value)
    assert "\n" not in msg and str(p) in msg
    for n in names:
        assert n in msg


def test_default_material_file_loads_and_builds():
    from importlib import resources

    with resources.as_file(resources.files("sim") / "materials" / "default.toml") as p:
        m = load_material(p)
    assert m.model == "microfacet" and m.label
    f = m.brdf().eval([0, 0, 1], [0, 0, 1])
    assert f.shape == (3,) and np.all(f > 0)


# -- the simulated rig ----------------------------------------------------------------------------
def test_simrig_camera_follows_the_servo_emulators_actual_state():
    from gonio.rig.dynamixel import DynamixelAxes, DynamixelBus

    with SimRig(config=SimRigConfig(width=160, height=120, focal_px=190.0, backlash_ticks=8.0)) as sim:
        bus = DynamixelBus(sim.servo_port, latency_timer_ms=50).open()
        axes = DynamixelAxes.from_rig(sim.rig, bus, sim.clock)
        try:
            target = sim.rig.solve(*np.radians([40, 0, 30, 180]))
            measured = axes.move_to(target)
            actual = sim.actual_joints()
            # encoder reading vs load side differ by at most the play (backlash/2 ticks) + noise
            tick = 2 * math.pi / 4096
            for i, name in enumerate(sim.rig.names):
                gear = sim.rig.joints[i].gear_ratio
                assert abs(actual[i] - measured[name]) <= (4.0 + 2.0) * tick / gear
            sim.camera.capture(0.001)
            position, _ = sim.rig.camera_pose(actual)
            assert np.allclose(sim.sim_camera._pose.centre, position, atol=1e-9)
            # the goal packet was recorded as one commanded pose
            assert np.allclose(sim.commanded_joints()[-1], sim.rig.as_array(target), atol=2 * tick)
        finally:
            axes.close()


def test_begin_pose_makes_camera_noise_depend_only_on_seed_and_pose():
    with SimRig(config=SimRigConfig(seed=5, width=96, height=72, focal_px=114.0)) as sim:
        sim.controller  # light off: dark frames, noise only
        sim.begin_pose(3)
        a = sim.camera.capture(0.01).pixels
        sim.camera.capture(0.01)
        sim.begin_pose(3)
        b = sim.camera.capture(0.01).pixels
        sim.begin_pose(4)
        c = sim.camera.capture(0.01).pixels
    assert np.array_equal(a, b) and not np.array_equal(a, c)


# -- the runner -----------------------------------------------------------------------------------
def test_session_measures_every_pose_with_meta_and_accurate_values(tmp_path, session_factory):
    s = session_factory(tmp_path / "s")
    result = s.run()
    assert result.status == "completed" and result.measured == len(POSES_DEG)
    manifest, samples = load_session(tmp_path / "s")
    assert manifest["exit_status"] == "completed" and manifest["pose_count"] == len(POSES_DEG)
    scan = assert_one_record_per_pose(tmp_path / "s", len(POSES_DEG))
    for k, (_, meta) in scan.records.items():
        for name, angle in meta["joints_rad"].items():
            assert abs(angle - meta["target_joints_rad"][name]) <= joint_tolerance_rad()
        # automatic exposure (the default): each pose's bracket is drawn from the ladder whose darks were measured
        assert meta["auto_exposure"] is True and meta["exposures_s"] == sorted(meta["exposures_s"])
        assert 1 <= len(meta["exposures_s"]) and set(meta["exposures_s"]) <= set(manifest["last_run"]["exposure"]["dark_exposures_s"])
        assert 0.9 < meta["photodiode"]["mean"] < 1.05
        assert meta["lab_time_s"] > 0
        # every bracket frame's reading is timestamped (protocol 2.1): on the lab clock before the pose's
        # record, on the controller's clock in increasing order, the window as long as the samples take
        pd = meta["photodiode"]
        assert len(pd["time_s"]) == len(pd["uptime_s"]) == len(pd["span_s"]) == sum(meta["frames"])
        assert all(0 < t <= meta["lab_time_s"] for t in pd["time_s"])
        assert pd["time_s"] == sorted(pd["time_s"]) and pd["uptime_s"] == sorted(pd["uptime_s"])
        assert all(s_ >= 0 for s_ in pd["span_s"])
    good = samples.good()
    assert len(good) > 0.8 * len(samples)
    truth = s.sim.material.eval(good.wi, good.wo)
    z = np.abs(good.f - truth) / np.maximum(good.sigma, 1e-12)
    assert np.median(np.abs(good.f / truth - 1)) < 0.01
    assert np.median(z) < 3.0
    # the dark set was measured before the first pose, in lab time, not wall time; no warm-up wait (the default
    # strategy: the photodiode above saw the light still short of warm, 0.95 at switch-on, and corrected it)
    assert s.runner.pipeline.darks.captures > 0 and s.runner.pipeline.darks.model is not None
    dark_set = 4 * sum(t + 0.05 for t in manifest["last_run"]["exposure"]["dark_exposures_s"])
    poses_lab = sum(t["move_lab"] + t["dark_lab"] + t["capture_lab"] for t in result.timings)
    assert result.lab_time >= poses_lab + dark_set
    assert result.lab_time < poses_lab + dark_set + 1.0


def test_interrupt_finishes_pose_in_flight_and_resume_adds_only_the_rest(tmp_path, session_factory, capsys):
    from gonio.session.store import SessionStore

    d = tmp_path / "s"
    first = session_factory(d, hooks={3: lambda sess: sess.runner.request_stop()})
    first.runner.stream = __import__("sys").stderr
    r1 = first.run()
    assert r1.status == "interrupted" and r1.measured == 4  # pose 3 was in flight: finished and stored
    assert f"gonio resume {d}" in capsys.readouterr().err
    assert load_session(d)[0]["exit_status"] == "interrupted"
    second = session_factory(d, store=SessionStore.open(d))
    r2 = second.run()
    assert r2.status == "completed" and r2.measured == len(POSES_DEG) - 4
    assert_one_record_per_pose(d, len(POSES_DEG))


def test_estop_ends_the_session_cleanly_before_anything_moves(tmp_path, session_factory):
    s = session_factory(tmp_path / "s")
    s.sim.controller.set_estop(True)
    result = s.run()
    assert result.status.startswith("safety stop:") and "E-stop" in result.status
    manifest, samples = load_session(tmp_path / "s")
    assert manifest["exit_status"] == result.status and len(samples) == 0
    assert len(s.sim.servo_bus.goal_log) == 0


def test_servo_that_cannot_reach_its_target_ends_the_session_with_the_joint_named(tmp_path, session_factory):
    def block(sess):  # an overload that comes back after every reboot: retries are bounded
        sess.sim.trip("camera_el")
        orig = sess.devices.axes.recover

        def recover_and_trip():
            out = orig()
            sess.sim.trip("camera_el")
            return out
        sess.devices.axes.recover = recover_and_trip

    s = session_factory(tmp_path / "s", hooks={2: block})
    result = s.run()
    assert result.status.startswith("safety stop:")
    manifest, samples = load_session(tmp_path / "s")
    assert manifest["exit_status"].startswith("safety stop:")
    assert sorted(set(samples.pose.tolist())) == [0, 1, 2]  # nothing measured was lost (pose 2 finished first)


def test_an_unexpected_error_is_recorded_as_error_and_keeps_what_was_measured(tmp_path, session_factory):
    def crash(sess):  # a bug (or a full disk) between poses: not a HardwareError
        raise RuntimeError("simulated bug")

    s = session_factory(tmp_path / "s", hooks={3: crash})
    with pytest.raises(RuntimeError, match="simulated bug"):
        s.run()
    manifest, samples = load_session(tmp_path / "s")
    assert manifest["exit_status"] == "error: RuntimeError: simulated bug"  # never "completed"
    assert sorted(set(samples.pose.tolist())) == [0, 1, 2]  # nothing measured before the error is lost
