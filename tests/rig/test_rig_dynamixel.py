"""DynamixelBus / DynamixelAxes (real dynamixel-sdk underneath) against the emulator on a real pty."""

from __future__ import annotations

import math
import threading
import time

import pytest

from gonio.errors import ChecksumError, ConfigError, HardwareError, HardwareTimeout, ServoAlarm
from gonio.rig.control_table import load_control_table
from gonio.rig.dynamixel import AxisConfig, DynamixelAxes, DynamixelBus
from gonio.rig.interfaces import Axes
from sim.servo_bus import HW_ENCODER, HW_OVERHEATING, HW_OVERLOAD

from .conftest import LATE_S

XM430 = load_control_table("XM430-W350")
TICK = 2 * math.pi / 4096


def test_axes_satisfy_the_protocol_and_configure_the_servos(axes, servo_bus, rig):
    assert isinstance(axes, Axes)
    assert axes.names == rig.names
    el = servo_bus.servo(2)  # light_el, gear ratio 2: limits ±85 deg joint -> ±170 deg horn
    assert el.peek("torque_enable") == 1 and el.peek("operating_mode") == 3
    assert el.peek("min_position_limit") == round(2048 - 170 / 360 * 4096)
    assert el.peek("max_position_limit") == round(2048 + 170 / 360 * 4096)
    # 45 deg/s joint * 2 = 90 deg/s horn = 15 rev/min -> floor(15 / 0.229) = 65 units (never faster)
    assert el.peek("profile_velocity") == 65
    assert all(abs(v) < 2 * TICK for v in axes.positions().values())


def test_move_returns_measured_angles_and_costs_lab_time_not_wall_time(axes, servo_bus, rig, clock):
    target = rig.solve(math.radians(40), math.radians(30), math.radians(60), math.radians(200))
    wall = time.perf_counter()
    measured = axes.move_to(target)
    wall = time.perf_counter() - wall
    expected = float(rig.move_time(rig.as_array(axes.positions()) * 0, rig.as_array(target)))
    assert clock.now() == pytest.approx(expected, rel=0.1, abs=0.1)  # the lab time of the profile
    assert wall < 2.0
    for name, value in measured.items():
        gear = rig.joints[rig.names.index(name)].gear_ratio
        assert abs(value - target[name]) <= 3 * TICK / gear + 1e-12
    # measured, not commanded: the returned angles are the servos' reported positions (quantized,
    # noisy), within the settle tolerance of the true horn angle, and not the exact targets
    truth = {n: servo_bus.servo(rig.joints[k].servo_id).horn for k, n in enumerate(rig.names)}
    assert all(abs(axes.to_ticks(n, measured[n]) - truth[n]) <= 3 for n in rig.names)
    assert measured != target


def test_alarm_raises_servo_alarm_then_recover_by_reboot(axes, servo_bus):
    servo_bus.servo(4).trip(HW_OVERLOAD)
    with pytest.raises(ServoAlarm, match="overload") as exc:
        axes.move_to({"camera_el": 0.4})
    assert exc.value.code == HW_OVERLOAD
    assert axes.recover() == {"camera_el": HW_OVERLOAD}
    assert servo_bus.servo(4).peek("torque_enable") == 1
    assert axes.move_to({"camera_el": 0.4})["camera_el"] == pytest.approx(0.4, abs=3 * TICK)


def test_alarm_during_a_move_is_seen_and_auto_recovered_when_allowed(rig, bus, servo_bus, clock):
    axes = DynamixelAxes.from_rig(rig, bus, clock, auto_recover=1)
    servo_bus.servo(1).trip(HW_OVERHEATING)
    got = axes.move_to({"light_az": 1.0})
    assert got["light_az"] == pytest.approx(1.0, abs=3 * TICK)
    servo_bus.servo(1).trip(HW_OVERLOAD)
    servo_bus.servo(3).trip(HW_OVERLOAD)  # both rebooted in the one recovery round allowed
    got = axes.move_to({"light_az": 0.0, "camera_az": 0.5})
    assert got["camera_az"] == pytest.approx(0.5, abs=3 * TICK)
    # a persistent fault (comes back after every reboot): bounded, then raised
    s = servo_bus.servo(1)
    reboot = s.reboot
    s.reboot = lambda: (reboot(), s.trip(HW_ENCODER))
    s.trip(HW_ENCODER)
    with pytest.raises(ServoAlarm, match="motor encoder"):
        axes.move_to({"light_az": 0.5})


def test_power_cycle_restores_ram_settings_and_the_move_completes(axes, servo_bus):
    axes.move_to({"light_el": 0.3})
    servo_bus.power_cycle()
    assert servo_bus.servo(2).peek("torque_enable") == 0
    got = axes.move_to({"light_el": -0.2})
    assert got["light_el"] == pytest.approx(-0.2, abs=3 * TICK)
    assert servo_bus.servo(2).peek("profile_velocity") == 65


def test_dropped_and_corrupted_replies_are_retried(axes, bus, servo_bus):
    servo_bus.faults.inject_next("drop")
    servo_bus.faults.inject_next("corrupt")
    servo_bus.faults.inject_next("garbage")
    servo_bus.faults.inject_next("truncate")
    before = dict(bus.stats)
    assert set(axes.positions()) == set(axes.names)
    assert bus.stats["retries"] - before["retries"] >= 1
    assert sum(servo_bus.faults.counts.values()) == 4  # every scheduled fault was met and survived
    # a sustained 5 % corruption rate: moves still complete. How many transactions a move takes depends on
    # timing (position polls), so move until two random corruptions were met, each move completing.
    servo_bus.faults.corrupt_rate = 0.05
    start = servo_bus.faults.counts["corrupt"]
    for k in range(40):
        axes.move_to({"camera_az": 0.2 * (k % 5 + 1)})
        if servo_bus.faults.counts["corrupt"] - start >= 2:
            break
    assert servo_bus.faults.counts["corrupt"] - start >= 2


def test_no_reply_at_all_gives_a_typed_timeout_after_bounded_retries(servo_bus):
    servo_bus.servo(3).unplug()
    with DynamixelBus(servo_bus.path, latency_timer_ms=40, late_reply_window_s=0.05, retries=3) as bus:
        t = time.perf_counter()
        with pytest.raises(HardwareTimeout, match="servo 3: read present_position: no answer after 4 attempts"):
            bus.read(3, XM430, "present_position")
        assert time.perf_counter() - t < 4 * (0.082 + 0.05) + 1.0  # bounded
        assert bus.stats["retries"] == 3
        servo_bus.servo(3).unplug(False)
        servo_bus.faults.corrupt_rate = 1.0
        with pytest.raises(ChecksumError):
            bus.read(3, XM430, "present_position")


def test_late_reply_is_not_taken_as_the_next_answer(bus, servo_bus):
    bus.write(2, XM430, "led", 1)
    servo_bus.faults.inject_next("delay")  # the read of LED (=1) comes back 0.2 s late
    assert bus.read(2, XM430, "led") == 1  # retried after the late reply was drained
    assert bus.read(2, XM430, "moving_threshold") == 10  # not the late LED reply (1)
    assert bus.read(2, XM430, "velocity_p_gain") == 100
    assert servo_bus.faults.counts["delay"] == 1


def test_late_reply_with_a_short_window_is_still_cleared_before_the_next_transaction(servo_bus):
    # A window shorter than the lateness: the late reply lands between transactions and the SDK's
    # clearPort before each request drops it.
    with DynamixelBus(servo_bus.path, latency_timer_ms=40, late_reply_window_s=0.0, retries=0) as b:
        servo_bus.faults.inject_next("delay")
        with pytest.raises(HardwareTimeout):
            b.read(2, XM430, "led")
        time.sleep(LATE_S + 0.1)
        assert b.read(2, XM430, "moving_threshold") == 10


def test_port_lock_serializes_threads(axes, bus):
    errors = []

    def worker():
        try:
            for _ in range(15):
                assert set(axes.positions()) == set(axes.names)
        except Exception as exc:  # noqa: BLE001 - reported below
            errors.append(exc)

    threads = [threading.Thread(target=worker) for _ in range(3)]
    for th in threads:
        th.start()
    for th in threads:
        th.join(timeout=20)
    assert not errors and bus.stats["retries"] == 0


def test_backlash_final_approach_from_one_side(rig, bus, servo_bus, clock):
    for s in servo_bus.servos.values():
        s.backlash_ticks = 20.0
        s.noise_ticks = 0.0
    axes = DynamixelAxes.from_rig(rig, bus, clock, approach=math.radians(2.0))
    load = lambda: servo_bus.servo(3).joint_ticks  # noqa: E731 - camera_az load side
    axes.move_to({"camera_az": 0.5})
    from_below = load()
    axes.move_to({"camera_az": 1.0})
    axes.move_to({"camera_az": 0.5})  # comes from above: overshoots, then approaches from below
    assert axes.last_move["stages"] == 2
    assert load() == pytest.approx(from_below, abs=0.5)
    plain = DynamixelAxes.from_rig(rig, bus, clock, configure=False)
    plain.move_to({"camera_az": 1.0})
    plain.move_to({"camera_az": 0.5})
    assert abs(load() - from_below) == pytest.approx(20.0, abs=0.5)  # the play shows without it


def test_timeout_and_bad_targets(axes, servo_bus):
    with pytest.raises(ConfigError, match="outside the joint limits"):
        axes.move_to({"light_el": math.radians(120)})
    with pytest.raises(ConfigError, match="unknown joint"):
        axes.move_to({"nope": 0.0})
    with pytest.raises(HardwareTimeout, match="did not settle"):
        axes.move_to({"light_az": 2.5}, timeout=0.5)


def test_wrong_model_and_missing_port(bus, servo_bus, clock):
    with pytest.raises(ConfigError, match="reports model number 1120"):
        DynamixelAxes(bus, [AxisConfig("a", 1, model="XM430-W350")], clock)
    with pytest.raises(HardwareError, match="cannot open serial port /dev/nonexistent"):
        DynamixelBus("/dev/nonexistent").open()
    with pytest.raises(ConfigError, match="baud = 12345"):
        DynamixelBus(servo_bus.path, 12345)


def test_scan_by_ping_and_bulk_read(bus):
    assert bus.scan([1, 2, 3, 4, 7]) == {1: 1120, 2: 1020, 3: 1120, 4: 1020}
    xm540 = load_control_table("XM540-W270")
    got = bus.bulk_read({1: (xm540, "model_number"), 2: (XM430, "present_position")})
    assert got == {1: 1120, 2: pytest.approx(2048, abs=2)}


def test_reboot_and_factory_reset_through_the_bus(bus, servo_bus):
    bus.write(2, XM430, "max_position_limit", 3000)
    bus.factory_reset(2, 0x02)
    assert bus.read(2, XM430, "max_position_limit") == 4095
    servo_bus.servo(2).trip()
    with pytest.raises(ServoAlarm):
        bus.read(2, XM430, "led")
    bus.reboot(2)
    assert bus.read(2, XM430, "hardware_error_status") == 0
