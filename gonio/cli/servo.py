"""``gonio servo scan|read|reboot|move|setup``: the lab-bench servo tools (what people otherwise do in Dynamixel
Wizard). ``setup`` provisions servos (:mod:`gonio.rig.provision`): a scan of every standard baud rate, an ID and
baud change of the one servo on the bus (from the rig file: ``--rig RIG --joint NAME``), a factory reset.

Raw angles: 0–360° ↔ 0–4095 ticks (Present/Goal Position, Position Control Mode).
"""

from __future__ import annotations

from gonio.rig.controller import clear_to_move

DEFAULT_BAUD = 57600  # the factory default of X-series servos (Baud Rate(8) = 1)


def register(sub) -> None:
    p = sub.add_parser("servo", help="scan, read, reboot and move Dynamixel servos on a bus",
                       description="Lab-bench tools for Dynamixel (Protocol 2.0) servos.")
    ssub = p.add_subparsers(dest="servo_command", metavar="ACTION", required=True)

    def common(sp):
        sp.add_argument("--port", required=True, help="serial port, e.g. /dev/ttyUSB0")
        sp.add_argument("--baud", type=int, default=DEFAULT_BAUD, help=f"baud rate (default {DEFAULT_BAUD})")
        sp.add_argument("--latency-ms", type=float, default=16.0, help="USB latency timer used in reply timeouts")
        sp.set_defaults(func=run)

    s = ssub.add_parser("scan", help="list the IDs and models that answer")
    common(s)
    s.add_argument("--ids", help="ping these IDs (e.g. 1-10 or 1,3,5) instead of one broadcast ping")
    r = ssub.add_parser("read", help="print the raw angle of every servo (or --ids)")
    common(r)
    r.add_argument("--ids", help="IDs to read (default: broadcast ping to find them)")
    rb = ssub.add_parser("reboot", help="reboot one servo: clears its hardware error (overload, overheating, ...); "
                                       "it does not move, and its torque stays off")
    common(rb)
    rb.add_argument("--id", type=int, required=True, help="servo ID")
    m = ssub.add_parser("move", help="move one servo to a raw angle and wait until it arrives")
    common(m)
    m.add_argument("--id", type=int, required=True, help="servo ID")
    m.add_argument("--deg", type=float, required=True, help="raw angle, 0-360 deg")
    m.add_argument("--timeout", type=float, default=30.0, help="seconds to wait for arrival")
    m.add_argument("--tolerance", type=int, default=3, help="arrived when within this many ticks")
    m.add_argument("--controller-port", help="the rig controller: nothing is sent to the servo while the E-stop is "
                                             "pressed or the enclosure open, and the move stops if either happens")
    m.add_argument("--rig", help="the rig file or name the servo is mounted on: the move must keep its joint within "
                                 "the rig's limits and the arms clear of each other (from where the other joints are)")
    m.add_argument("--unmounted", action="store_true",
                   help="a servo on the bench, not on a rig: no E-stop, limit or collision check (otherwise "
                        "--controller-port and --rig are required)")


    from gonio.cli.servo_setup import register_setup

    register_setup(ssub)


def _parse_ids(text: str | None):
    from gonio.errors import ConfigError

    if text is None:
        return None
    ids = []
    try:
        for part in text.split(","):
            if "-" in part:
                a, b = (int(v) for v in part.split("-", 1))
                if not (0 <= a <= 252 and 0 <= b <= 252):  # bounded before a range is expanded
                    raise ConfigError.field("--ids", "ids", text, "servo IDs are 0..252")
                ids.extend(range(a, b + 1))
            elif part.strip():
                ids.append(int(part))
    except ValueError:
        raise ConfigError.field("--ids", "ids", text, "expected IDs like 1-10 or 1,3,5 (servo IDs are 0..252)") from None
    if not ids or any(not 0 <= i <= 252 for i in ids) or len(ids) > 253:
        raise ConfigError.field("--ids", "ids", text, "servo IDs are 0..252 (a range low-high, low <= high)")
    return ids


def _check_numbers(args) -> None:
    """Every number of the command line in its range, before a byte is sent (one line each)."""
    import math

    from gonio.errors import ConfigError
    from gonio.rig.control_table import BAUD_RATES
    from gonio.rig.dynamixel import MAX_ID

    if args.baud not in BAUD_RATES:
        raise ConfigError.field("--baud", "baud", args.baud,
                                f"not a Dynamixel baud rate; use one of {', '.join(map(str, BAUD_RATES))}")
    if not (math.isfinite(args.latency_ms) and 0 < args.latency_ms <= 1000):
        raise ConfigError.field("--latency-ms", "latency_ms", args.latency_ms, "must be in (0, 1000] ms")
    if args.servo_command in ("move", "reboot") and not 0 <= args.id <= MAX_ID:
        raise ConfigError.field("--id", "id", args.id, f"servo IDs are 0..{MAX_ID} (253-255 are reserved/broadcast)")
    if args.servo_command != "move":
        return
    if not (math.isfinite(args.deg) and 0.0 <= args.deg <= 360.0):
        raise ConfigError.field("--deg", "deg", args.deg, "raw angle must be in [0, 360]")
    if not (math.isfinite(args.timeout) and 0 < args.timeout <= 3600):
        raise ConfigError.field("--timeout", "timeout", args.timeout, "must be in (0, 3600] seconds")
    if not 0 <= args.tolerance <= 4095:
        raise ConfigError.field("--tolerance", "tolerance", args.tolerance, "must be in 0..4095 ticks")
    if not args.unmounted and not (args.controller_port and args.rig):
        raise ConfigError.field(None, "servo move", f"--id {args.id}",
                                "a servo on a rig moves only with --controller-port (the E-stop is checked first) "
                                "and --rig (joint limits and collisions); for a servo on the bench say --unmounted")


def _open_guard(args):
    """The rig controller (E-stop and interlock clear, else :class:`EmergencyStop`: nothing is sent to the servo)
    and the rig of a mounted servo's move; ``(None, None)`` with ``--unmounted``."""
    from gonio.rig.controller import RigController
    from gonio.rig.kinematics import load_rig

    if args.unmounted:
        return None, None
    rig = load_rig(args.rig)
    ctl = RigController.open(args.controller_port)
    try:
        clear_to_move(ctl)
    except BaseException:
        ctl.close()
        raise
    return ctl, rig


def _check_move(bus, rig, servo_id: int, table, goal: int) -> None:
    """A mounted servo's move to raw ``goal`` keeps its joint within the rig's limits and the arms clear of each
    other (:meth:`gonio.rig.kinematics.Rig.check_directions`' collision test; a shadow is allowed) at every point
    of the way, the other joints where they are now (read from their servos). ConfigError naming the joint
    otherwise."""
    import numpy as np

    from gonio.errors import ConfigError
    from gonio.rig.control_table import table_for_model_number
    from gonio.rig.dynamixel import AxisConfig
    from gonio.rig.kinematics import REASONS

    names = [j.name for j in rig.joints]
    mine = next((k for k, j in enumerate(rig.joints) if j.servo_id == servo_id), None)
    if mine is None:
        raise ConfigError.field("--id", "id", servo_id, f"is not a servo of rig {rig.name!r} "
                                f"(its servos: {', '.join(f'{j.name} {j.servo_id}' for j in rig.joints)})")
    axis = AxisConfig.from_joint(rig.joints[mine])
    now = np.empty(len(names))
    for k, j in enumerate(rig.joints):
        t = table if k == mine else (table_for_model_number(bus.ping(j.servo_id)) or table)
        now[k] = AxisConfig.from_joint(j).angle_of(bus.read(j.servo_id, t, "present_position", alarm_ok=True),
                                                   t.ticks_per_rev)
    target = axis.angle_of(goal, table.ticks_per_rev)
    where = f"joint {names[mine]} would go to {np.degrees(target):.2f} deg"
    if not axis.lower - 1e-9 <= target <= axis.upper + 1e-9:
        raise ConfigError.field(None, "--deg", round(goal * 360.0 / table.ticks_per_rev, 2),
                                f"{where}, outside the rig's limits [{np.degrees(axis.lower):g}, "
                                f"{np.degrees(axis.upper):g}] deg")
    path = np.repeat(now[None, :], 65, axis=0)
    path[:, mine] = np.linspace(now[mine], target, 65)
    hit = np.flatnonzero(rig.check_directions(*rig.directions(path)) == REASONS.index("collision"))
    if hit.size:  # a shadow (the camera in the light's beam) spoils a measurement, not the rig: allowed here
        raise ConfigError.field(None, "--deg", round(goal * 360.0 / table.ticks_per_rev, 2),
                                f"{where}: the arms would collide at {np.degrees(path[hit[0], mine]):.1f} deg "
                                f"(closer than {np.degrees(rig.min_separation):g} deg, the other joints where they "
                                "are); move the other arm first")


def _reboot(bus, servo_id: int, port: str) -> int:
    """Reboot ``servo_id`` (Protocol 2.0 REBOOT), wait until it answers again and say what its Hardware Error
    Status was and is: the reboot clears the alarm, not its cause."""
    from gonio.errors import HardwareTimeout
    from gonio.rig.clock import RealClock
    from gonio.rig.control_table import load_control_table, table_for_model_number
    from gonio.rig.dynamixel import describe_hardware_error

    table = table_for_model_number(bus.ping(servo_id)) or load_control_table("XM430-W350")
    before = bus.read(servo_id, table, "hardware_error_status", alarm_ok=True)
    bus.reboot(servo_id)
    clock = RealClock()
    deadline = clock.now() + 3.0  # a Dynamixel answers again within ~1 s of a reboot
    while True:
        try:
            bus.ping(servo_id)
            break
        except HardwareTimeout:
            if clock.now() > deadline:
                raise
            clock.sleep(0.1)
    after = bus.read(servo_id, table, "hardware_error_status", alarm_ok=True)
    was = f"hardware error 0x{before:02X} ({describe_hardware_error(before)})" if before else "no hardware error"
    now = (f"still 0x{after:02X} ({describe_hardware_error(after)}): its cause is still there" if after else
           "now clear")
    print(f"servo {servo_id}: rebooted ({port}); it had {was}, {now}; torque off"
          + ("; remove the cause (load, heat, supply) before moving it" if before else ""))
    return 0 if not after else 3


def _model_name(number: int) -> str:
    from gonio.rig.control_table import table_for_model_number

    t = table_for_model_number(number)
    return t.model if t else f"model {number}"


def run(args) -> int:
    import os

    from gonio.errors import ConfigError

    _check_numbers(args)  # every value first: a wrong one is named even when the port is wrong too
    ids = _parse_ids(getattr(args, "ids", None))
    if not os.path.exists(args.port):
        raise ConfigError.field("--port", "port", args.port, "no such serial device")
    ctl, rig = _open_guard(args) if args.servo_command == "move" else (None, None)
    try:
        return _run_bus(args, ids, ctl, rig)
    finally:
        if ctl is not None:
            ctl.close()


def _run_bus(args, ids, ctl, rig) -> int:
    from gonio.errors import ConfigError, HardwareTimeout
    from gonio.rig.clock import RealClock
    from gonio.rig.control_table import load_control_table, table_for_model_number
    from gonio.rig.dynamixel import DynamixelBus

    with DynamixelBus(args.port, args.baud, latency_timer_ms=args.latency_ms) as bus:
        if args.servo_command in ("scan", "read"):
            found = bus.scan(ids, attempts=3)  # a lost ping is not a missing servo
            if not found:
                raise HardwareTimeout(f"{args.port}: no servo answered at {args.baud} baud"
                                      + (f" (IDs {getattr(args, 'ids')})" if ids else "")
                                      + "; a servo answers only at the rate it was set to: try --baud with the rig "
                                      "file's [bus] baud (the shipped rigs: 1000000)", device=args.port)
            if args.servo_command == "scan":
                print(f"{'id':>3}  {'model':<12} model_number")
                for i, model in found.items():
                    print(f"{i:>3}  {_model_name(model):<12} {model}")
                return 0
            print(f"{'id':>3}  {'model':<12} {'ticks':>6} {'deg':>8}  torque  error")
            for i, model in found.items():
                table = table_for_model_number(model) or load_control_table("XM430-W350")
                ticks = bus.read(i, table, "present_position", alarm_ok=True)
                torque = bus.read(i, table, "torque_enable", alarm_ok=True)
                err = bus.read(i, table, "hardware_error_status", alarm_ok=True)
                print(f"{i:>3}  {_model_name(model):<12} {ticks:>6} {ticks * 360.0 / table.ticks_per_rev:>8.2f}  "
                      f"{'on' if torque else 'off':<6}  {'0x%02X' % err if err else '-'}")
            return 0
        if args.servo_command == "reboot":
            return _reboot(bus, args.id, args.port)
        # move
        model = bus.ping(args.id)
        table = table_for_model_number(model)
        if table is None:
            raise ConfigError.field("--id", "id", args.id, f"servo reports model number {model}, which has no control table")
        goal = min(int(round(args.deg / 360.0 * table.ticks_per_rev)), table.position_max)
        if rig is not None:
            _check_move(bus, rig, args.id, table, goal)
            clear_to_move(ctl)  # once more, right before the first byte that makes the servo move
        if bus.read(args.id, table, "hardware_error_status", alarm_ok=True):
            bus.raise_alarm(args.id)
        if not bus.read(args.id, table, "torque_enable"):
            if bus.read(args.id, table, "operating_mode") != 3:
                bus.write(args.id, table, "operating_mode", 3)
            bus.write(args.id, table, "torque_enable", 1)
        bus.write(args.id, table, "goal_position", goal)
        clock = RealClock()
        deadline = clock.now() + args.timeout
        while True:
            state = bus.sync_read(table, "moving", "present_position", [args.id])[args.id]
            if bus.read(args.id, table, "hardware_error_status", alarm_ok=True):
                bus.raise_alarm(args.id)
            if not state["moving"] and abs(state["present_position"] - goal) <= args.tolerance:
                break
            if ctl is not None:
                clear_to_move(ctl)  # the E-stop pressed mid-move (it cuts the servos' power): not one more byte to them
            if clock.now() > deadline:
                raise HardwareTimeout(f"{args.port}: servo {args.id} did not arrive within {args.timeout:g} s "
                                      f"(at {state['present_position']} ticks, goal {goal})", device=args.port)
            clock.sleep(0.02)
        ticks = state["present_position"]
        print(f"servo {args.id}: at {ticks} ticks = {ticks * 360.0 / table.ticks_per_rev:.2f} deg (goal {goal})")
    return 0

