"""``gonio servo setup``: provision servos on a lab's first day (:mod:`gonio.rig.provision`) — a scan of every
standard baud rate; an ID and baud change of the one servo on the bus (``--set-id/--set-baud``, or the rig file's
for a joint: ``--rig RIG --joint NAME``); a factory reset. The same guards as ``gonio servo move``: a servo on a rig
is changed only with ``--controller-port`` (E-stop and interlock clear) or ``--unmounted``, and only when confirmed
(``--yes`` or the prompt)."""

from __future__ import annotations

from gonio.rig.controller import clear_to_move


def register_setup(ssub) -> None:
    """Add ``setup`` to ``gonio servo``'s subcommands."""
    su = ssub.add_parser("setup", help="provision servos: scan every baud rate; give the one servo on the bus an ID and "
                                       "baud rate (or the rig file's for a joint); factory reset",
                         description="Scan every standard baud rate for servos; with --set-id/--set-baud, --rig/--joint "
                                     "or --factory-reset, change the one servo on the bus (refused if more than one "
                                     "answers): torque off, EEPROM written, read back.")
    su.add_argument("--port", required=True, help="serial port, e.g. /dev/ttyUSB0")
    su.add_argument("--bauds", help="rates to scan, e.g. 57600,1000000 (default: every standard rate, "
                                    "9600 ... 4500000)")
    su.add_argument("--max-id", type=int, default=252, help="highest ID waited for in each broadcast ping (default 252)")
    su.add_argument("--latency-ms", type=float, default=16.0, help="USB latency timer used in reply timeouts")
    su.add_argument("--set-id", type=int, help="new ID of the servo")
    su.add_argument("--set-baud", type=int, help="new baud rate of the servo")
    su.add_argument("--rig", help="take the ID and baud rate from this rig file (with --joint): the joint's servo_id "
                                  "and the [bus] baud; the servo's model must be the joint's")
    su.add_argument("--joint", help="the rig joint the servo on the bus is for (with --rig)")
    su.add_argument("--factory-reset", choices=("all", "keep-id", "keep-id-baud"),
                    help="Factory Reset (0x06): all (ID 1, 57600 baud), keep-id, keep-id-baud")
    su.add_argument("--yes", action="store_true", help="do it without asking")
    su.add_argument("--controller-port", help="the rig controller: nothing is changed while the E-stop is pressed or "
                                              "the enclosure open (torque goes off: support the arm)")
    su.add_argument("--unmounted", action="store_true", help="a servo on the bench, not on a rig: no E-stop check")
    su.set_defaults(func=run_setup)


def _setup_target(args, servo):
    """``(new_id, new_baud)`` asked for by ``--set-id/--set-baud`` or ``--rig/--joint`` (the servo's model checked
    against the joint's)."""
    from gonio.errors import ConfigError
    from gonio.rig.kinematics import load_rig

    if args.rig is None:
        return (servo.id if args.set_id is None else args.set_id), (args.set_baud or servo.baud)
    rig = load_rig(args.rig)
    joint = next((j for j in rig.joints if j.name == args.joint), None)
    if joint is None:
        raise ConfigError.field("--joint", "joint", args.joint, f"not a joint of rig {rig.name!r} "
                                f"({', '.join(j.name for j in rig.joints)})")
    if servo.model != joint.model:
        raise ConfigError.field("--joint", "joint", args.joint, f"wants a {joint.model}; the servo on the bus is "
                                f"a {servo.model}")
    return joint.servo_id, rig.baud


def _check_setup(args):
    """Every value of ``gonio servo setup`` in range before a byte is sent; the rates to scan."""
    import math

    from gonio.errors import ConfigError
    from gonio.rig.dynamixel import MAX_ID
    from gonio.rig.provision import STANDARD_BAUDS

    bauds = STANDARD_BAUDS
    if args.bauds:
        try:
            bauds = tuple(int(b) for b in args.bauds.split(",") if b.strip())
        except ValueError:
            bauds = ()
        if not bauds or any(b not in STANDARD_BAUDS for b in bauds):
            raise ConfigError.field("--bauds", "bauds", args.bauds, f"rates among {', '.join(map(str, STANDARD_BAUDS))}")
    if not (math.isfinite(args.latency_ms) and 0 < args.latency_ms <= 1000):
        raise ConfigError.field("--latency-ms", "latency_ms", args.latency_ms, "must be in (0, 1000] ms")
    if not 0 <= args.max_id <= MAX_ID:
        raise ConfigError.field("--max-id", "max_id", args.max_id, f"servo IDs are 0..{MAX_ID}")
    if args.set_id is not None and not 0 <= args.set_id <= MAX_ID:
        raise ConfigError.field("--set-id", "set_id", args.set_id, f"servo IDs are 0..{MAX_ID} (253-255 are reserved)")
    if args.set_baud is not None and args.set_baud not in STANDARD_BAUDS:
        raise ConfigError.field("--set-baud", "set_baud", args.set_baud,
                                f"not a Dynamixel X rate; use one of {', '.join(map(str, STANDARD_BAUDS))}")
    if (args.rig is None) != (args.joint is None):
        raise ConfigError.field("--rig" if args.rig is None else "--joint", "setup", args.joint or args.rig,
                                "--rig and --joint go together (the joint whose servo_id the servo gets)")
    chosen = [o for o, v in (("--set-id/--set-baud", args.set_id is not None or args.set_baud is not None),
                             ("--rig/--joint", args.rig is not None), ("--factory-reset", args.factory_reset)) if v]
    if len(chosen) > 1:
        raise ConfigError(f"gonio servo setup: {' and '.join(chosen)}: one change at a time")
    if chosen and not args.unmounted and not args.controller_port:
        raise ConfigError("gonio servo setup: a servo on a rig is changed only with --controller-port (the E-stop is "
                          "checked first; torque goes off: support the arm); for a servo on the bench say --unmounted")
    return bauds, bool(chosen)


def _confirm(args, what: str) -> None:
    import sys

    from gonio.errors import ConfigError

    if args.yes:
        return
    if not sys.stdin.isatty():
        raise ConfigError(f"gonio servo setup: {what}: add --yes to confirm (no terminal to ask on)")
    if input(f"{what}\nproceed? [y/N] ").strip().lower() not in ("y", "yes"):
        raise ConfigError("gonio servo setup: not confirmed; nothing was changed")


def run_setup(args) -> int:
    """``gonio servo setup`` (module docstring; :mod:`gonio.rig.provision`)."""
    import os

    from gonio.errors import ConfigError
    from gonio.rig.controller import RigController
    from gonio.rig.provision import change_id_baud, factory_reset, only_servo, scan_bus

    bauds, change = _check_setup(args)
    if not os.path.exists(args.port):
        raise ConfigError.field("--port", "port", args.port, "no such serial device")
    ctl = RigController.open(args.controller_port) if change and not args.unmounted else None
    try:
        if ctl is not None:
            clear_to_move(ctl)
        scan = scan_bus(args.port, bauds, max_id=args.max_id, latency_timer_ms=args.latency_ms)
        print("\n".join(scan.lines()))
        if not change:
            if not scan.found:
                print(f"no servo answered at {', '.join(map(str, bauds))} baud")
                return 1
            return 0
        servo = only_servo(scan, args.port)
        if args.factory_reset:
            what = f"factory reset ({args.factory_reset}) of servo {servo}"
        else:
            new_id, new_baud = _setup_target(args, servo)
            if (new_id, new_baud) == (servo.id, servo.baud):
                print(f"servo {servo}: already ID {new_id} at {new_baud} baud; nothing to change")
                return 0
            what = f"servo {servo} -> ID {new_id} at {new_baud} baud (torque off, EEPROM written)"
        _confirm(args, what)
        if ctl is not None:
            clear_to_move(ctl)  # once more, right before the first byte that changes the servo
        if args.factory_reset:
            now = factory_reset(args.port, servo, args.factory_reset, latency_timer_ms=args.latency_ms)
        else:
            now = change_id_baud(args.port, servo, new_id, new_baud, latency_timer_ms=args.latency_ms)
        print(f"done: {what}; read back: {now}")
        return 0
    finally:
        if ctl is not None:
            ctl.close()
