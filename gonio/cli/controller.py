"""``gonio controller status|light|photodiode|trigger``: the lab-bench tools for the rig controller.

What a technician checks before a session: the controller answers with a compatible protocol
(firmware_protocol/SPEC.md), the E-stop and interlock are released, the light switches and dims,
the reference photodiode follows the light, and the camera trigger fires. ``python -m sim.controller``
serves the emulator on a pty to try them without hardware.
"""

from __future__ import annotations

DEFAULT_BAUD = 115200


def register(sub) -> None:
    p = sub.add_parser("controller", help="check the rig controller: status, light, photodiode, trigger",
                       description="Lab-bench tools for the rig controller (firmware_protocol/SPEC.md).")
    csub = p.add_subparsers(dest="controller_command", metavar="ACTION", required=True)

    def common(sp):
        sp.add_argument("--port", required=True, help="serial port or pyserial URL, e.g. /dev/ttyACM0")
        sp.add_argument("--baud", type=int, default=DEFAULT_BAUD, help=f"baud rate (default {DEFAULT_BAUD})")
        sp.set_defaults(func=run)

    common(csub.add_parser("status", help="protocol version, capabilities, E-stop, interlock, light, temperature"))
    light = csub.add_parser("light", help="switch the light on at a level for a while, reading the photodiode",
                            description="Switch the light on at --level, keep it on for --seconds (feeding the "
                                        "controller's watchdog) while printing photodiode readings, then switch "
                                        "it off. The light is never left on when the command ends.")
    common(light)
    light.add_argument("--level", type=float, default=1.0, help="relative output level in [0, 1] (default 1)")
    light.add_argument("--seconds", type=float, default=5.0, help="how long to keep it on (default 5)")
    light.add_argument("--every", type=float, default=1.0, help="seconds between photodiode readings (default 1)")
    pd = csub.add_parser("photodiode", help="read the reference photodiode (light as it is)")
    common(pd)
    pd.add_argument("--samples", type=int, default=16, help="readings averaged by the controller, 1..255")
    trig = csub.add_parser("trigger", help="fire the camera trigger once")
    common(trig)
    trig.add_argument("--exposure", type=float, required=True, help="pulse length in seconds")


def _caps(bits: int) -> str:
    from gonio.rig.controller import CAPABILITY_NAMES

    return ", ".join(name for bit, name in sorted(CAPABILITY_NAMES.items()) if bits & bit) or "-"


def _print_status(st) -> None:
    from firmware_protocol import codec as fp

    print(f"E-stop      {'PRESSED' if st.estop else 'released'}")
    print(f"interlock   {'OPEN' if st.interlock_open else 'closed'}")
    print(f"light       {'on' if st.light_on else 'off'} (level {st.light_level:.3f})")
    print(f"temperature {st.temperature_c:.2f} °C" + ("  OVERTEMP (above the controller's limit)"
                                                      if st.flags & fp.FLAG_OVERTEMP else ""))
    if st.flags & fp.FLAG_WATCHDOG_TRIPPED:  # SPEC.md §4.2: cleared by the next successful switch-on
        print("watchdog    TRIPPED (it switched the light off: the host stopped talking while the light was on)")
    print(f"uptime      {st.uptime_s:.1f} s")
    if st.reset_cause is not None:  # protocol 2.2 (SPEC.md §4.5)
        print(f"last reset  {st.reset_cause}" + ("  (the controller's main loop hung and its hardware watchdog reset "
                                                 "it, switching the light off)" if st.reset_cause == "hardware watchdog"
                                                 else ""))


def run(args) -> int:
    import math
    import os

    from gonio.errors import ConfigError, ControllerError, EmergencyStop, SafetyStop
    from gonio.rig.controller import RigController

    if not 50 <= args.baud <= 4_000_000:  # the UART rates of USB-serial bridges; 0 (B0) hangs a real port up
        raise ConfigError.field("--baud", "baud", args.baud, f"must be a serial baud rate in 50..4000000 "
                                f"(the controller's default is {DEFAULT_BAUD})")
    if "://" not in args.port and not os.path.exists(args.port):
        raise ConfigError.field("--port", "port", args.port, "no such serial device")
    if args.controller_command == "light":
        if not 0.0 <= args.level <= 1.0:
            raise ConfigError.field("--level", "level", args.level, "must be in [0, 1]")
        if not (math.isfinite(args.seconds) and 0.0 <= args.seconds <= 3600.0):
            raise ConfigError.field("--seconds", "seconds", args.seconds, "must be in [0, 3600]")
        if not (math.isfinite(args.every) and args.every > 0.0):
            raise ConfigError.field("--every", "every", args.every, "must be a finite number of seconds > 0")
    with RigController.open(args.port, baudrate=args.baud) as ctl:  # close() switches the light off
        info = ctl.info
        if args.controller_command == "status":
            print(f"{args.port}: protocol {info.major}.{info.minor}, firmware 0x{info.firmware:08X}, "
                  f"watchdog {info.watchdog_s:g} s")
            print(f"capabilities {_caps(info.capabilities)}")
            _print_status(ctl.status())
            return 0
        if args.controller_command == "photodiode":
            pd = ctl.read_photodiode(args.samples)
            when = "" if pd.uptime is None else f", at controller uptime {pd.uptime:.3f} s over {pd.span * 1e3:.2f} ms"
            print(f"photodiode {pd.mean:.6f} ± {pd.sem:.6f} (relative units, {args.samples} readings{when})")
            return 0
        if args.controller_command == "trigger":
            ctl.trigger_camera(args.exposure)
            print(f"trigger pulse of {args.exposure:g} s started")
            return 0
        # light
        st = ctl.status()
        if st.estop or st.interlock_open:
            raise EmergencyStop(f"{args.port}: light refused: "
                                f"{'E-stop pressed' if st.estop else 'interlock open'}", device=args.port)
        dark, _ = ctl.read_photodiode(16)
        ctl.set_light(True, args.level)
        print(f"{'t/s':>6} {'photodiode':>12} {'±':>10}   (dark {dark:.6f})")
        t0 = ctl.clock.now()
        for _ in range(int(args.seconds / args.every) + 1):  # bounded
            mean, sem = ctl.read_photodiode(16)
            print(f"{ctl.clock.now() - t0:>6.1f} {mean:>12.6f} {sem:>10.6f}", flush=True)
            st = ctl.status()  # the E-stop or the interlock cut the light in hardware: say so, do not go on
            if st.estop or st.interlock_open:
                raise EmergencyStop(f"{args.port}: light off after {ctl.clock.now() - t0:.1f} s: "
                                    f"{'E-stop pressed' if st.estop else 'interlock opened'}", device=args.port)
            what = st.unsafe_reason(True)  # over temperature, watchdog (SPEC.md §4.6)
            if what:
                raise SafetyStop(f"{args.port}: light off after {ctl.clock.now() - t0:.1f} s: {what}", device=args.port)
            if not st.light_on:
                raise ControllerError(f"{args.port}: light off after {ctl.clock.now() - t0:.1f} s: the controller "
                                      f"switched it off (status flags 0x{st.flags:02X})", device=args.port)
            left = args.seconds - (ctl.clock.now() - t0)
            if left <= 0:
                break
            ctl.wait(min(args.every, left))
        ctl.set_light(False, 0.0)
        print("light off")
    return 0
