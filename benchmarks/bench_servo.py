"""Servo bus: transactions per second through dynamixel-sdk to the emulator on a pty, and a full
move-and-settle cycle of the rig (wall time and simulated lab time).

Baseline row: one ping (the smallest round trip). The move cycle's baseline is the kinematic lower
bound (the slowest joint's trapezoidal profile time) from :meth:`gonio.rig.kinematics.Rig.move_time`.
"""

from __future__ import annotations

import math
import time

import numpy as np

from benchmarks.common import Table, time_call


def run(quick: bool = False) -> list[Table]:
    from gonio.rig.control_table import load_control_table
    from gonio.rig.dynamixel import DynamixelAxes, DynamixelBus
    from gonio.rig.kinematics import load_rig
    from sim.clock import SimClock
    from sim.servo_bus import ServoBus

    rig = load_rig()
    clock = SimClock()
    table = load_control_table("XM430-W350")
    min_time = 0.1 if quick else 0.3
    tables = []
    with ServoBus({j.servo_id: j.model for j in rig.joints}, clock, seed=0) as sim_bus:
        with DynamixelBus(sim_bus.path, latency_timer_ms=40.0) as bus:
            ids = [j.servo_id for j in rig.joints]
            ops = [
                ("ping (1 servo)", lambda: bus.ping(2)),
                ("read 4 B (present position)", lambda: bus.read(2, table, "present_position")),
                ("write 1 B (LED)", lambda: bus.write(2, table, "led", 1)),
                ("sync read 14 B x 4 servos", lambda: bus.sync_read(table, "moving", "present_position", ids)),
                # a sync write has no reply: timed alone it only measures how fast the host can queue
                # bytes (the emulator falls behind); pair it with a read, as a control cycle does.
                ("sync write goal x 4 + sync read x 4 (a control cycle)",
                 lambda: (bus.sync_write(table, "goal_position", {i: 2048 for i in ids}),
                          bus.sync_read(table, "moving", "present_position", ids))),
                ("positions() (sync read, 4 joints)", None),
            ]
            axes = DynamixelAxes.from_rig(rig, bus, clock)
            ops[-1] = (ops[-1][0], axes.positions)
            t = Table("Servo bus transactions (dynamixel-sdk → pty → emulator)",
                      ["operation", "µs/transaction", "transactions/s", "× ping time"], baseline=0, default=3,
                      why_default="the settle loop polls with sync reads (one transaction for all servos)")
            base = None
            for name, fn in ops:
                s = time_call(fn, min_time=min_time, repeat=3)
                base = base or s
                t.add(name, s * 1e6, 1.0 / s, s / base)
            t.notes.append("pty round trips are not paced by the baud rate; on a real 1 Mbps bus add ~10 µs/byte")
            tables.append(t)

            rng = np.random.default_rng(0)
            n = 5 if quick else 20
            poses = []
            while len(poses) < n:
                a = rng.uniform([0.1, 0, 0.1, 0], [1.3, 2 * math.pi, 1.3, 2 * math.pi])
                j, code = rig.solve_many(*a)
                if code == 0:
                    poses.append(rig.as_dict(j))
            mv = Table("Full move-and-settle cycle (4 joints, random reachable poses)",
                       ["quantity", "per move", "ratio to baseline"], baseline=0, default=1,
                       why_default="what a session pays per pose")
            cur = rig.as_array(axes.positions())
            lower_bound = 0.0
            lab0, wall0, tx0 = clock.now(), time.perf_counter(), bus.stats["transactions"]
            for p in poses:
                lower_bound += float(rig.move_time(cur, rig.as_array(p)))
                cur = rig.as_array(axes.move_to(p))
            lab, wall = clock.now() - lab0, time.perf_counter() - wall0
            tx = bus.stats["transactions"] - tx0
            mv.add("kinematic lower bound (slowest joint's profile), lab s", lower_bound / n, 1.0)
            mv.add("simulated lab time to settle, s", lab / n, lab / lower_bound)
            mv.add("wall time, s", wall / n, wall / lower_bound)
            mv.add("bus transactions", tx / n, float("nan"))
            mv.notes.append(f"{n} moves; SimClock shared by driver and emulator, so lab time costs no wall time")
            tables.append(mv)
            axes.close()
    return tables
