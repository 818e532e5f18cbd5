"""How many round trips the servo driver spends, and that saving them keeps every value (issue 17).

Over a real pty with the emulated bus: the safety check's alarm read brings the positions along, a
position read at the same Clock time reuses them, a move whose goals are known writes at once (no read
before it), and the SDK's CRC and unstuffing shortcuts give the SDK's results.
"""

from __future__ import annotations

import math

import dynamixel_sdk as sdk
import numpy as np

from gonio.rig.control_table import load_control_table
from sim import dxl_packet as P

XM430 = load_control_table("XM430-W350")


def test_a_reply_with_stuffed_bytes_is_read_not_taken_as_corrupted(bus, servo_bus):
    """Goal Velocity's bytes FF FF FD 00 sit inside the state block: the status packet carries them stuffed
    (FF FF FD FD), and the unstuffed reply has exactly the requested size."""
    ids = sorted(servo_bus.servos)
    value = int.from_bytes(b"\xff\xff\xfd\x00", "little")
    for i in ids:
        servo_bus.servo(i).poke("goal_velocity", value)
        servo_bus.servo(i).poke("goal_position", 1000 + i)
    got = bus.sync_read(XM430, "torque_enable", "present_position", ids)
    assert {i: (got[i]["goal_velocity"], got[i]["goal_position"]) for i in ids} == {i: (value, 1000 + i) for i in ids}
    assert bus.stats["retries"] == 0
    assert bus.read(ids[0], XM430, "goal_velocity") == value


def test_the_crc_and_unstuffing_shortcuts_give_the_sdks_results():
    from gonio.rig.dynamixel import _CheckedPacketHandler

    mine, theirs = _CheckedPacketHandler(), sdk.Protocol2PacketHandler()
    rng = np.random.default_rng(0)
    for n in range(0, 80, 7):
        data = list(rng.integers(0, 256, n))
        assert mine.updateCRC(0, data, n) == theirs.updateCRC(0, data, n)
    for params in (b"\x00\x01\x02\x03", b"\xff\xff\xfd\x05", bytes(10) + b"\xff\xff\xfd" + bytes(5)):
        packet = list(P.status(1, 0, params))
        a, b = mine.removeStuffing(list(packet)), theirs.removeStuffing(list(packet))
        length = b[sdk.PKT_LENGTH_L] | (b[sdk.PKT_LENGTH_H] << 8)
        assert a == b[:sdk.PKT_LENGTH_H + 1 + length]  # the SDK's bytes, without the leftover tail
        assert bytes(a[sdk.PKT_PARAMETER0 + 1:-2]) == params


def test_the_alarm_read_brings_the_positions_of_that_instant(axes, servo_bus, clock):
    before = servo_bus.packets
    assert axes.alarms() == {}
    first = axes.positions()
    assert servo_bus.packets - before == 1  # one sync read for both, at the same Clock time
    assert axes.positions() == first and servo_bus.packets - before == 1
    clock.sleep(0.1)
    axes.positions()  # time moved on: the servos are read again
    assert servo_bus.packets - before == 2


def test_a_move_writes_its_goals_without_reading_first_and_reads_after_it(axes, servo_bus, clock):
    axes.move_to({"light_el": 0.2})  # the first move reads the positions: goals are not known yet
    target = {"light_el": 0.3}
    before = servo_bus.packets
    measured = axes.move_to(target)
    assert math.isclose(measured["light_el"], 0.3, abs_tol=0.01)
    # one sync write, then the polls: the one at once (the write has no reply: the round trip after it shows
    # that the goal was taken), the ones every max_blind_s and the one at the predicted end
    polls = servo_bus.packets - before - 1
    assert 2 <= polls <= 2 + math.ceil(axes.last_move["lab_time"] / axes.max_blind_s)
    after = servo_bus.packets
    assert axes.positions() == measured and servo_bus.packets == after  # settled at this instant: known
    clock.sleep(0.5)
    assert axes.positions() == measured and servo_bus.packets == after + 1  # at rest: same reading, read again


def test_an_alarm_after_the_check_is_still_seen_by_the_move(axes, servo_bus):
    from gonio.errors import ServoAlarm
    import pytest

    assert axes.alarms() == {}
    axes.positions()
    servo_bus.servo(2).trip()  # between the safety check and the move, at the same Clock time
    with pytest.raises(ServoAlarm, match="overload"):
        axes.move_to({"light_el": 0.25})
