"""``gonio measure`` and ``gonio resume``: run a measurement session (simulated or on a rig).

``gonio measure --sim`` builds the virtual rig (:mod:`sim.rig`: servo-bus and controller emulators on
pseudo-terminals, driven through the real dynamixel-sdk and pyserial, a rendering camera, a simulated
clock). This module is the *configuration boundary*: gonio never imports ``sim`` (docs/architecture.md §1); for
``--sim``/resuming a simulated session it finds the simulator through the ``gonio.plugins`` entry points
(:mod:`gonio.plugins`); everything below it (runner, drivers, pipeline) gets device paths, a camera and a
clock and cannot tell simulation from hardware.

The manifest records everything needed to rebuild the session (plan, rig, material, simulator
configuration and seed, or the hardware ports), so ``gonio resume DIR`` restarts the same simulated
rig and measures only the remaining poses.
"""

from __future__ import annotations

import sys
import time

#: Uniform in half/difference angles: the uniform plan on the Pareto front (lab time vs BRDF error) of
#: benchmarks/report/REPORT.md's plan table nearest its knee (the knee itself is an adaptive session).
DEFAULT_PLAN = "half_diff"
DEFAULT_SIM_RESOLUTION = "320x240"


#: Exit code of a session that ended with poses not measured (bad camera frames): not 0, not an error's.
INCOMPLETE_EXIT = 6


def default_plan_params(name: str = DEFAULT_PLAN) -> dict:
    """The parameters (radians) a plan gets when none are given: its generator's defaults, the one source
    shared with ``gonio plan`` (the default half/difference plan: 38 poses on the default rig, a few seconds
    of wall time on a 2-core machine, benchmarks/bench_session.py)."""
    from gonio.plan.generators import GENERATORS

    return {k: p.default for k, p in GENERATORS[name].params.items()}


def register(sub) -> None:
    from gonio.cli.plan import add_plan_options

    p = sub.add_parser("measure", help="run a measurement session (--sim: on the simulated rig)",
                       description="Measure a BRDF: move through a plan, capture, store every pose. "
                                   "With --sim the whole rig is simulated (emulators on pseudo-terminals, "
                                   "rendering camera, simulated clock).")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--sim", action="store_true", help="use the simulated rig")
    p.add_argument("--rig", metavar="RIG.toml", help="rig geometry (required on hardware; with --sim a rig file "
                   "or shipped rig name such as 'turntable', default 'default')")
    p.add_argument("--servo-port", help="servo bus serial port (hardware)")
    p.add_argument("--controller-port", help="rig controller serial port (hardware)")
    p.add_argument("--camera", help="camera index or path for OpenCV (hardware)")
    p.add_argument("--calibration", metavar="CAMERA.toml",
                   help="camera intrinsics and noise (hardware): width, height, focal_px, [dist], [noise]")
    p.add_argument("--material", metavar="FILE.toml", help="material of the simulated sample (model + [params]); "
                   "on hardware only its label is recorded")
    p.add_argument("--target", metavar="TARGET.toml", help="target layout (default: the standard board, flat "
                   "sample): sample/white rectangles, white_albedo, [charuco], [mount] tilt_x_deg, tilt_y_deg, "
                   "height (or matrix) of a tilted or raised sample; recorded in the manifest")
    add_plan_options(p, default_plan=DEFAULT_PLAN)
    p.add_argument("--seed", type=int, default=0, help="seed of the simulation and of the plan ordering")
    p.add_argument("--sim-resolution", default=DEFAULT_SIM_RESOLUTION, metavar="WxH",
                   help=f"simulated camera resolution (default {DEFAULT_SIM_RESOLUTION})")
    p.add_argument("--sim-frame-faults", default="", metavar="KIND=RATE,...",
                   help="simulated camera faults per frame: black, stale, saturated, wrong_size, nan, timeout "
                        "(e.g. black=0.05,stale=0.01; black=1 is a dead camera)")
    p.add_argument("--sim-controller", choices=("firmware", "python", "simavr"), default="firmware",
                   help="the simulated rig controller: firmware (default: the reference firmware's C code, host "
                        "build), python (the independent Python emulator) or simavr (the AVR binary in an "
                        "emulated ATmega328P; real emulated time)")
    p.add_argument("--sim-camera", choices=("direct", "gige"), default="direct",
                   help="gige: the simulated camera is served as a GigE Vision device on 127.0.0.1 and read "
                        "through gonio's Aravis backend, an 8-bit RGB8 sensor (needs gir1.2-aravis-0.8 and "
                        "gonio[genicam]); direct (default): called in-process")
    p.add_argument("--sim-as-built", metavar="SEED|ERRORS.toml", default="",
                   help="simulate an as-built rig: assembly errors (servo zeros, axis tilts and offsets, arm lengths, "
                        "sample height) drawn from SEED or read from a TOML file; the host still uses the declared "
                        "rig file (sim/as_built.py). Recorded in the manifest's sim.as_built")
    p.add_argument("--plan-file", metavar="PLAN.json", help="run the plan saved by 'gonio plan NAME --out PLAN.json' "
                   "(validated and solved again on this rig) instead of generating one; a session directory: "
                   "the plan it ran")
    p.add_argument("--accurate", action="store_true",
                   help="the conservative light and dark strategy: wait until the light is stable (about 4 min) "
                        "and re-measure the whole dark set (light off, warm-up again) every 15 min; default: "
                        "measure at once, drift corrected from the photodiode, dark frames modelled from the "
                        "first dark set and checked with one light-off frame (benchmarks/bench_labtime.py)")
    p.add_argument("--warmup-wait", type=float, default=None, metavar="S",
                   help="seconds to let the light stabilise before the first pose (default 0: the photodiode "
                        "corrects the drift)")
    p.add_argument("--darks", choices=("model", "measured"), default=None,
                   help="model (default): dark frames predicted per pixel from the first dark set and the sensor "
                        "temperature, checked on schedule; measured: the whole set re-measured on schedule")
    p.add_argument("--out", metavar="DIR", help="new session directory (default ./gonio-session-YYYYmmdd-HHMMSS)")
    p.add_argument("--quiet", action="store_true", help="no progress line")
    p.set_defaults(func=run_measure)

    r = sub.add_parser("resume", help="resume an interrupted session",
                       description="Measure the remaining poses of a session directory (simulated sessions "
                                   "restart the simulated rig with the same configuration and seed).")
    r.add_argument("dir", metavar="DIR", help="session directory")
    r.add_argument("--servo-port", help="override the recorded servo port (hardware)")
    r.add_argument("--controller-port", help="override the recorded controller port (hardware)")
    r.add_argument("--camera", help="override the recorded camera (hardware)")
    r.add_argument("--rig", metavar="RIG.toml", help="the rig file that bounds the joint limits (default: the one "
                   "the session recorded); a manifest edit can never widen the limits beyond it")
    r.add_argument("--quiet", action="store_true", help="no progress line")
    r.set_defaults(func=run_resume)


# -- building blocks ---------------------------------------------------------------------------
def _resolution(text: str) -> tuple[int, int]:
    from gonio.errors import ConfigError

    try:
        w, h = (int(x) for x in text.lower().split("x"))
    except ValueError:
        raise ConfigError.field("--sim-resolution", "resolution", text, "expected WIDTHxHEIGHT, e.g. 320x240") from None
    if not (64 <= w <= 4096 and 48 <= h <= 4096):
        raise ConfigError.field("--sim-resolution", "resolution", text, "width in [64, 4096], height in [48, 4096]")
    return w, h


def _material(path: str | None):
    from gonio.session.material import load_material

    if path is None:
        from importlib import resources

        res = resources.files("sim") / "materials" / "default.toml"
        with resources.as_file(res) as p:
            return load_material(p)
    return load_material(path)


def _make_plan(args, rig):
    from gonio.cli.plan import plan_from_args

    return plan_from_args(args, args.plan, rig, where="--plan", source="--plan")  # generator defaults


def _calibration_from_toml(path: str):
    """The camera description of a hardware session: intrinsics, [noise] and [camera] (linear, bit_depth,
    black_level, response, trigger), see :func:`gonio.rig.calibration.load_camera_calibration`."""
    from gonio.rig.calibration import load_camera_calibration

    return load_camera_calibration(path)


def _target(path):
    from gonio.pipeline.target import TargetLayout, load_target

    return load_target(path) if path else TargetLayout()


def _calibration_dict(calib) -> dict:
    return {"width": calib.width, "height": calib.height, "K": calib.K.tolist(), "dist": calib.dist.tolist(),
            "noise": dict(calib.noise.__dict__)}


def _calibration_from_dict(c, source: str):
    """The :class:`CameraCalibration` a manifest's ``calibration`` entry records (all of it: intrinsics,
    distortion, noise, radiometric scale), read by :meth:`gonio.rig.calibration.CameraDescription.from_dict`."""
    from gonio.errors import ConfigError, DataError
    from gonio.rig.calibration import CameraDescription

    if not isinstance(c, dict):
        raise DataError(f"{source}: calibration is not a valid camera calibration (got {type(c).__name__})")
    try:
        return CameraDescription.from_dict(c, source=source).calibration
    except (ConfigError, KeyError, TypeError, ValueError) as exc:
        raise DataError(f"{source}: calibration is not a valid camera calibration ({exc})") from None


def _rig_record(rig, source: str, text: str) -> dict:
    """The manifest's ``rig``: name, where it came from, and the full TOML text with its SHA-256, so
    that a resumed session (or anything rebuilding the rig) uses this rig even if the file changes."""
    import hashlib

    rec = {"name": rig.name, "source": source, "toml": text,
           "sha256": hashlib.sha256(text.encode("utf-8")).hexdigest()}
    if getattr(rig, "geometry_errors", None) is not None:  # a calibrated rig (gonio calibrate rig): its uncertainties
        import tomllib

        cal = tomllib.loads(text).get("calibration", {})
        rec["calibration"] = {k: cal[k] for k in ("uncertainty", "not_identified", "rms") if k in cal}
    return rec


def _warn(msg: str) -> None:
    print(f"gonio: warning: {msg}", file=sys.stderr)


def _manifest_rig(manifest, where: str, rig_file: str | None = None):
    """The session's rig, from the manifest's copy of its TOML (checked against its SHA-256); a manifest
    written before the copy existed falls back to the recorded source, with a warning line.

    The copy is bounded by the rig file (``rig_file``, i.e. ``gonio resume --rig``, else the file the
    session names): rig.sha256 is an integrity check, not authentication, so an edited manifest must never
    widen the limits that guard the arms. Limits and speeds are intersected (:meth:`Rig.within`); the
    angle-to-tick mapping of every joint (servo ID, model, gear ratio, zero offset, direction), which also
    sets the servos' own EEPROM position limits, must be the file's; without a readable rig file nothing
    can bound the copy, and the resume is refused in one line."""
    import hashlib

    from gonio.errors import ConfigError, DataError
    from gonio.rig.kinematics import load_rig

    rec = manifest.get("rig") or {}
    if not isinstance(rec, dict):
        raise DataError(f"{where}: rig = {str(rec)[:40]!r}: must be an object")
    text = rec.get("toml")
    if text is None:
        src = rig_file or rec.get("source") or rec.get("name") or "default"
        _warn(f"{where}: rig has no recorded description (older session): using the current {str(src)!r}, "
              f"which may differ from the one measured with")
        return load_rig(str(src))
    if hashlib.sha256(str(text).encode("utf-8")).hexdigest() != rec.get("sha256"):
        raise DataError(f"{where}: rig.toml does not match its rig.sha256 (the manifest was altered)")
    rig = load_rig(text=str(text), source=f"{where} rig", strict=False)  # what the session was started with
    src = rig_file or rec.get("source") or rec.get("name")
    try:
        declared = load_rig(src.removeprefix("rigs/").removesuffix(".toml") if str(src).startswith("rigs/") else src)
    except (ConfigError, DataError, OSError, TypeError, AttributeError) as exc:
        raise DataError(f"{where}: the rig file {str(src)[:80]!r} cannot be read ({str(exc)[:120]}); it bounds the "
                        "joint limits of a resumed session: gonio resume DIR --rig RIG.toml") from None
    theirs = {j.name: j for j in declared.joints}
    for j in rig.joints:
        o = theirs.get(j.name)
        if o is None:
            raise DataError(f"{where}: joint {j.name} is not in the rig file {str(src)!r}")
        for key in ("servo_id", "model", "gear_ratio", "zero_offset_deg", "direction"):
            if getattr(j, key) != getattr(o, key):
                raise DataError(f"{where}: joint {j.name}: {key} = {getattr(j, key)!r} in the session's rig but "
                                f"{getattr(o, key)!r} in the rig file {str(src)!r}: the rig changed since the session "
                                "started (or the manifest was edited); start a new session")
    return rig.within(declared)


def _manifest_calibration(manifest, where: str, fallback=None):
    """The calibration the session recorded; for an older simulated session without one, ``fallback``
    (the simulated camera's) with a warning line."""
    c = manifest.get("calibration")
    if c is None and fallback is not None:
        _warn(f"{where}: no recorded camera calibration (older session): using the simulated camera's")
        return fallback
    return _calibration_from_dict(c, where)


def open_hardware(args, rig, manifest: dict, *, before_open=None):
    """A real rig's devices from ``--servo-port``, ``--controller-port``, ``--camera`` and
    ``--calibration`` (CAMERA.toml), recorded in ``manifest`` (``hardware`` with the camera's own
    identity, ``calibration``); ``before_open(calibration)`` runs before any device is opened. The
    devices are opened before the session directory exists: a rig that does not start leaves nothing.
    Returns ``(calibration, devices)``."""
    from gonio.rig.clock import RealClock

    description = _calibration_from_toml(args.calibration)
    calibration = description.calibration
    manifest["hardware"] = {"servo_port": args.servo_port, "controller_port": args.controller_port,
                            "camera": args.camera}
    if description.noise_defaults:  # said when the session starts (_say_noise_defaults), recorded here
        manifest["hardware"]["noise_defaults"] = list(description.noise_defaults)
    manifest["calibration"] = description.to_dict()
    if before_open is not None:
        before_open(calibration)
    description.camera.check_session(args.calibration)
    devices = _open_hw_devices(rig, manifest["hardware"], description.camera, RealClock(),
                               size=(calibration.width, calibration.height))
    identity = getattr(devices.camera, "identity", None)
    if callable(identity):  # what the camera says it is (vendor, model, serial, ...)
        try:
            manifest["hardware"]["camera_identity"] = identity()
        except BaseException:
            devices.close()
            raise
    return calibration, devices


def _record_detector(manifest: dict, calibration, rig, *, pinhole: bool) -> None:
    """``detector`` (how it was computed) and ``detector_solid_angle_sr`` (None with the reason if
    unknown) in the manifest: :mod:`gonio.session.detector`."""
    from gonio.pipeline.target import TargetLayout
    from gonio.session.detector import aperture_from_calibration, detector_solid_angle

    diameter, how = (None, "") if pinhole else aperture_from_calibration(manifest["calibration"], "--calibration")
    det = detector_solid_angle(calibration, TargetLayout.from_dict(manifest["target"], source="--target"), rig,
                               aperture_diameter_m=diameter, pinhole=pinhole, aperture_source=how)
    manifest["detector"] = det
    manifest["detector_solid_angle_sr"] = det["solid_angle_sr"]


def _default_out() -> str:
    return time.strftime("gonio-session-%Y%m%d-%H%M%S")


def _check_out(out: str, option: str = "--out") -> None:
    """Refuse, before anything starts, a directory holding a session or one that cannot be created
    (one line naming ``option``, the option that chose the directory)."""
    import os
    from pathlib import Path

    from gonio.errors import ConfigError
    from gonio.session.store import MANIFEST, SAMPLES

    from gonio.io.outputs import session_root

    d = Path(out)
    if d.exists() and not d.is_dir():
        raise ConfigError.field(option, "session directory", out, "exists and is not a directory")
    root = session_root(Path(os.path.realpath(d.absolute())) / "manifest.json")  # d itself, or inside another
    if root is not None and root != Path(os.path.realpath(d.absolute())):
        raise ConfigError.field(option, "session directory", out, f"is inside the session directory {root}: a "
                                "session holds only what it measured (choose a directory elsewhere)")
    if any((d / n).exists() for n in (MANIFEST, SAMPLES)):
        raise ConfigError.field(option, "session directory", out,
                                f"holds another session; choose a new directory or `gonio resume {out}`")
    parent = d if d.exists() else next((p for p in d.absolute().parents if p.exists()), Path("/"))
    if not os.access(parent, os.W_OK | os.X_OK):
        raise ConfigError.field(option, "session directory", out, f"not writable ({parent} is read-only to you)")


# -- running -------------------------------------------------------------------------------------
def _timing_args(args) -> dict:
    """The session's light and dark strategy from ``--accurate``/``--warmup-wait``/``--darks`` (a dict of
    :class:`gonio.plan.labtime.SessionTiming` fields for the manifest; validated here)."""
    from gonio.errors import ConfigError
    from gonio.plan.labtime import SessionTiming

    d = {"warmup": "stable", "darks": "measured"} if args.accurate else {}
    if args.warmup_wait is not None:
        if args.accurate:
            raise ConfigError.field("--warmup-wait", "warmup_wait", args.warmup_wait,
                                    "--accurate waits until the light is stable: give one of them")
        if not (0 <= args.warmup_wait <= 3600):
            raise ConfigError.field("--warmup-wait", "warmup_wait", args.warmup_wait, "must be seconds in [0, 3600]")
        d["warmup_min"] = float(args.warmup_wait)
    if args.darks is not None:
        d["darks"] = args.darks
    SessionTiming(**d)
    return d


def _manifest_timing(manifest):
    """The :class:`SessionTiming` a session recorded (``manifest["timing"]``; absent: the default)."""
    from gonio.errors import ConfigError
    from gonio.plan.labtime import SessionTiming

    d = manifest.get("timing") or {}
    known = {"warmup", "warmup_min", "darks"}
    if not isinstance(d, dict) or set(d) - known:
        raise ConfigError.field("manifest.json", "timing", d, f"must be an object with keys among {sorted(known)}")
    try:
        return SessionTiming(**d)
    except ConfigError as exc:
        raise ConfigError(f"manifest.json: {exc}") from None


def _run_session(store, plan, devices, calibration, layout, *, before_pose, quiet: bool, resume_cmd: str) -> int:
    from gonio.rig.dynamixel import describe_hardware_error
    from gonio.session.runner import RunnerSettings, SessionRunner, format_lab_time, recovered_faults

    for joint, bits in recovered_faults(devices).get("servo_alarms_cleared", {}).items():  # said even with --quiet
        print(f"gonio: servo {joint}: hardware error found at start ({describe_hardware_error(bits)}, Hardware Error "
              f"Status 0x{bits:02X}) cleared by a reboot; if its cause is not known, stop (Ctrl-C) and check the arm",
              file=sys.stderr)

    settings = RunnerSettings(timing=_manifest_timing(store.manifest))
    if "geocal" in store.manifest:  # a geometric calibration session (gonio calibrate rig)
        from gonio.cli.calibrate import run_calibration_session

        return run_calibration_session(store, plan, devices, calibration, layout, before_pose=before_pose,
                                       quiet=quiet, resume_cmd=resume_cmd)

    if "adaptive" in store.manifest:  # a loop around the runner: rounds planned from the stored samples
        from gonio.session.adaptive import AdaptiveSession, model_table, rounds_table

        result = AdaptiveSession(store, devices, calibration, layout, before_pose=before_pose, settings=settings,
                                 resume_command=resume_cmd, stream=None if quiet else sys.stderr).run()
        plan = store.manifest["plan"]["poses"]
        print(f"adaptive: {len(result.rounds)} rounds, "
              + (f"stopped ({result.stop})" if result.stop else "not finished"))
        print("\n".join(rounds_table(result.rounds)))
        if result.model is not None:
            print("\n".join(model_table(result.model)))
    else:
        runner = SessionRunner(plan, store, devices, calibration, layout, before_pose=before_pose, settings=settings,
                               resume_command=resume_cmd, stream=None if quiet else sys.stderr)
        result = runner.run()
    total = store.sample_count
    resets = recovered_faults(devices).get("controller_resets", 0)
    if resets:  # recovered (re-handshake, light restored), but a board that browns out needs looking at
        print(f"gonio: the rig controller reset {resets} time{'s' if resets > 1 else ''} during this run (recovered: "
              "handshake and light restored); check its power supply and USB cable", file=sys.stderr)
    print(f"{result.measured} poses, {result.samples} samples measured in this run "
          f"({len(store.done_poses())}/{len(plan)} poses, {total} samples in {store.directory})")
    print(f"lab time {format_lab_time(result.lab_time)} ({'simulated' if devices.clock.simulated else 'real'}), "
          f"wall time {result.wall_time:.1f} s")
    if result.skipped:
        print(f"{len(result.skipped)} poses skipped: " + "; ".join(f"pose {k}: {r}" for k, r in result.skipped[:3]))
    if result.ok:
        return 0
    if result.status == "interrupted":
        return 130
    if result.status.startswith("incomplete"):
        failed = getattr(result, "failed", [])
        print(f"gonio: session incomplete: {len(failed)} poses not measured (bad camera frames), e.g. pose "
              f"{failed[0][0]}: {failed[0][1]}; `gonio status {store.directory}` lists them, "
              f"`gonio resume {store.directory}` measures them again", file=sys.stderr)
        return INCOMPLETE_EXIT
    print(f"gonio: session ended: {result.status}; resume with `gonio resume {store.directory}`", file=sys.stderr)
    return result.error.exit_code if result.error is not None else 3


def _sim_session(store, plan, manifest, quiet: bool, rig_file: str | None = None) -> int:
    from gonio.session.material import material_from_dict
    from gonio.session.runner import open_devices
    from gonio.plugins import plugin

    simrig = plugin("sim.rig")  # docs/architecture.md §1: gonio never imports sim; the simulator is found by configuration
    SimRig, SimRigConfig = simrig.SimRig, simrig.SimRigConfig

    from gonio.errors import DataError

    where = f"{store.directory}/manifest.json"
    m = manifest.get("material")
    if not isinstance(m, dict):
        raise DataError(f"{where}: material = {str(m)[:40]!r}: must be an object (model, params, label)")
    material = material_from_dict({k: v for k, v in m.items() if k in ("model", "params", "label")},
                                  source="manifest material", complete=False)
    config = SimRigConfig.from_dict(_checked_sim(manifest.get("sim"), where))
    rig = _manifest_rig(manifest, where, rig_file)
    import contextlib

    with SimRig(rig, material.brdf(), config=config, layout=_layout(manifest)) as sim, contextlib.ExitStack() as stack:
        calibration = _manifest_calibration(manifest, where, fallback=sim.calibration)
        devices = None
        try:
            camera = sim.camera
            if getattr(config, "camera_link", "direct") == "gige":  # the sim camera behind a real GigE Vision link
                camera = _gige_sim_camera(sim, stack)
            devices = open_devices(sim.rig, sim.servo_port, sim.controller_port, camera, sim.clock)
            return _run_session(store, plan, devices, calibration, sim.layout, before_pose=sim.begin_pose,
                                quiet=quiet, resume_cmd=f"gonio resume {store.directory}")
        except BaseException as exc:
            if devices is None:  # could not even open the devices: record why, keep the session resumable
                store.finish(f"error: {exc}" if str(exc) else "interrupted")
            raise
        finally:
            if devices is not None:
                devices.close()


def _gige_sim_camera(sim, stack):
    """``sim.camera`` served as a GigE Vision camera on the loopback interface (:mod:`sim.gige_camera`)
    and opened through gonio's Aravis backend, as a GenICam camera on a rig would be."""
    from gonio.errors import HardwareError
    from gonio.plugins import plugin
    from gonio.rig.aravis import AravisCamera

    try:
        server = stack.enter_context(plugin("sim.gige_camera").GigECameraServer(
            sim.camera, temperature=sim.sensor.reports_temperature))
    except (ImportError, ValueError, OSError) as exc:
        raise HardwareError(f"--sim-camera gige: cannot serve the simulated camera over GigE Vision ({exc})") from None
    cal = sim.calibration
    camera = AravisCamera(server.device, sim.clock, pixel_format="RGB8", black_level=sim.sensor.black_level,
                          gain_unit="raw", width=cal.width, height=cal.height)
    stack.callback(camera.close)
    return camera


#: The simulated rig's settings a manifest may hold, with their ranges (a crafted manifest must not
#: make the simulator allocate a 100,000-pixel-wide frame or take a table for a number).
_SIM_RANGES = {"seed": (0, 2 ** 32 - 1, int), "width": (64, 4096, int), "height": (48, 4096, int),
               "focal_px": (1.0, 1e5, float), "bit_depth": (8, 16, int), "light_intensity": (1e-6, 1e6, float),
               "servo_noise_ticks": (0.0, 100.0, float), "backlash_ticks": (0.0, 100.0, float),
               "warmup_depth": (0.0, 1.0, float), "warmup_tau": (0.0, 1e5, float), "pd_noise": (0.0, 1.0, float)}


def _checked_sim(sim, where: str) -> dict:
    """The manifest's ``sim`` section, every field checked for type and range (DataError naming it)."""
    from gonio.errors import DataError

    if not isinstance(sim, dict):
        raise DataError(f"{where}: sim = {str(sim)[:40]}: expected the simulated rig's settings (an object)")
    out = {}
    for key, value in sim.items():
        if key == "frame_faults":
            from gonio.plugins import plugin

            try:
                plugin("sim.rig").FrameFaults.from_spec(value)
            except (ValueError, TypeError, AttributeError) as exc:
                raise DataError(f"{where}: sim.frame_faults = {str(value)[:40]!r}: {exc}") from None
            out[key] = value
            continue
        if key == "as_built":
            if value is not None:
                from gonio.rig.chain import ChainErrors

                errors = {k: v for k, v in value.items() if k != "source"} if isinstance(value, dict) else value
                ChainErrors.from_dict(errors, source=f"{where}: sim.as_built")  # ConfigError naming the field
            out[key] = value
            continue
        if key == "tile":  # the calibration tile (sim.mirror_tile.CalibrationTile's f0, diffuse, light_radius)
            ranges = {"f0": (0.0, 1.0), "diffuse": (0.0, 1.0), "light_radius": (1e-4, 0.1)}
            if value is not None:
                if not isinstance(value, dict):
                    raise DataError(f"{where}: sim.tile = {str(value)[:40]!r}: expected an object")
                for k, v in value.items():
                    lo, hi = ranges.get(k, (None, None))
                    ok = lo is not None and isinstance(v, (int, float)) and not isinstance(v, bool) and lo <= v <= hi
                    if not ok:
                        raise DataError(f"{where}: sim.tile.{k} = {str(v)[:40]}: expected one of "
                                        f"{', '.join(ranges)} with a number in its range")
            out[key] = value
            continue
        if key == "controller":
            if value not in ("firmware", "python", "simavr"):
                raise DataError(f"{where}: sim.controller = {str(value)[:40]!r}: expected 'firmware', 'python' or 'simavr'")
            out[key] = value
            continue
        if key == "camera_link":
            if value not in ("direct", "gige"):
                raise DataError(f"{where}: sim.camera_link = {str(value)[:40]!r}: expected 'direct' or 'gige'")
            out[key] = value
            continue
        if key not in _SIM_RANGES:
            continue  # a newer gonio's setting: ignored, as SimRigConfig.from_dict does
        lo, hi, kind = _SIM_RANGES[key]
        ok = isinstance(value, (int, float)) and not isinstance(value, bool) and lo <= value <= hi
        if not ok or (kind is int and not isinstance(value, int)):
            raise DataError(f"{where}: sim.{key} = {str(value)[:40]}: expected {'an integer' if kind is int else 'a number'} "
                            f"in [{lo:g}, {hi:g}]")
        out[key] = value
    return out


def _layout(manifest):
    """The session's target layout (sessions recorded before ``target`` existed: the default one)."""
    from gonio.pipeline.target import TargetLayout

    return TargetLayout.from_dict(manifest.get("target", {}), source="manifest target")


def _open_hw_devices(rig, hw: dict, settings, clock, size: tuple[int, int] | None = None):
    """Check and open a rig's devices before anything is written: the serial ports exist, the camera opens,
    every servo answers, the controller handshakes. On any failure nothing stays open and the error (one
    line) names the device."""
    import os

    from gonio.errors import HardwareError
    from gonio.rig.camera import open_camera
    from gonio.session.runner import open_devices

    for key, option in (("servo_port", "--servo-port"), ("controller_port", "--controller-port")):
        port = str(hw[key])
        if "://" not in port and not os.path.exists(port):  # pyserial URLs (socket://, rfc2217://) are not paths
            raise HardwareError(f"{option} {port}: no such device", device=port)
    width, height = size or (None, None)
    camera = open_camera(hw["camera"], settings, clock, width=width, height=height)
    try:
        devices = open_devices(rig, hw["servo_port"], hw["controller_port"], camera, clock)
    except BaseException:
        camera.close()
        raise
    if settings.trigger == "controller":  # the rig controller fires each exposure
        camera.trigger = devices.controller.trigger_camera
    return devices


def _camera_settings(calibration: dict, where: str):
    from gonio.rig.calibration import CameraSettings

    settings = CameraSettings.from_dict((calibration or {}).get("camera", {}), source=where)
    settings.check_session(where)
    return settings


def _hw_session(store, plan, manifest, rig, calibration, quiet: bool, devices=None) -> int:
    """Run a hardware session; ``devices`` already opened (a new session opens them before creating its
    directory), otherwise opened here (resume), recording a failure to open in the manifest."""
    from gonio.rig.clock import RealClock

    try:
        if devices is None:
            where = f"{store.directory} manifest calibration"
            devices = _open_hw_devices(rig, manifest["hardware"], _camera_settings(manifest.get("calibration"), where),
                                       RealClock(), size=(calibration.width, calibration.height))
        return _run_session(store, plan, devices, calibration, _layout(manifest), before_pose=None, quiet=quiet,
                            resume_cmd=f"gonio resume {store.directory}")
    except BaseException as exc:
        if devices is None:
            store.finish(f"error: {exc}")
        raise
    finally:
        if devices is not None:
            devices.close()


def run_measure(args) -> int:
    from gonio.errors import ConfigError
    from gonio.rig.kinematics import load_rig, read_rig_text
    from gonio.session.store import SessionStore

    out = args.out or _default_out()
    if args.sim:
        rig_src = args.rig or "default"
    else:
        missing = [o for o, v in (("--rig", args.rig), ("--servo-port", args.servo_port),
                                  ("--controller-port", args.controller_port), ("--camera", args.camera),
                                  ("--calibration", args.calibration)) if not v]
        if missing:
            raise ConfigError.field(None, missing[0], None,
                                    "required on hardware (or use --sim for the simulated rig)")
        rig_src = args.rig
    rig_text, rig_where = read_rig_text(rig_src)
    rig = load_rig(text=rig_text, source=rig_where)
    material = _material(args.material) if (args.sim or args.material) else None
    if material is not None and material.defaulted:
        print(material.defaults_note())
    adaptive = None
    if getattr(args, "plan_file", None):
        given = [k for k, v in vars(args).items() if k.startswith("plan_") and k != "plan_file" and v is not None]
        if args.plan != DEFAULT_PLAN or given:
            raise ConfigError.field("--plan-file", "plan_file", args.plan_file,
                                    "runs a saved plan: give it without --plan or plan parameters")
        from gonio.io.plan_file import read_plan_file

        plan = read_plan_file(args.plan_file, rig)
        print(f"plan {args.plan_file}: {plan.generator}, {len(plan)} poses")
    elif args.plan == "adaptive":
        from gonio.cli.plan import adaptive_from_args
        from gonio.session.adaptive import new_adaptive_manifest

        adaptive = new_adaptive_manifest(*adaptive_from_args(args, rig, source="--plan adaptive"), rig)
        plan = adaptive["plan"]
    else:
        plan = _make_plan(args, rig)
    _check_out(out)
    manifest = {
        "mode": "sim" if args.sim else "hardware",
        "command": ["gonio", *sys.argv[1:]] if sys.argv and sys.argv[0].endswith(("gonio", "main.py")) else None,
        "seed": args.seed,
        "plan": plan,
        "rig": _rig_record(rig, rig_src if args.sim else str(args.rig), rig_text),
        "material": material.to_dict() if material is not None else {"label": ""},
        "target": _target(args.target).to_dict(),
    }
    timing = _timing_args(args)
    if timing:
        manifest["timing"] = timing
    if adaptive is not None:
        manifest["adaptive"] = adaptive["adaptive"]
    if args.sim:
        from gonio.plugins import plugin

        SimRigConfig = plugin("sim.rig").SimRigConfig

        w, h = _resolution(args.sim_resolution)
        link = {} if args.sim_camera == "direct" else {"camera_link": "gige", "bit_depth": 8}
        if args.sim_frame_faults:
            try:
                plugin("sim.rig").FrameFaults.from_spec(args.sim_frame_faults)
            except ValueError as exc:
                raise ConfigError.field("--sim-frame-faults", "frame faults", args.sim_frame_faults, str(exc)) from None
            link["frame_faults"] = args.sim_frame_faults
        if getattr(args, "sim_controller", "firmware") != "firmware":
            link["controller"] = args.sim_controller
        if getattr(args, "sim_as_built", ""):
            link["as_built"] = plugin("sim.rig").parse_as_built(rig, args.sim_as_built).to_dict()
        config = SimRigConfig.at_resolution(w, h, seed=args.seed, **link)
        manifest["sim"] = config.to_dict()
        manifest["calibration"] = _calibration_dict(config.calibration())
        _record_detector(manifest, config.calibration(), rig, pinhole=True)
        _check_servo_models(rig)  # the simulated servos need their control tables: say so before a session exists
        _check_exposures(plan, config.exposure_range(), "the simulated camera")
        store = SessionStore.create(out, manifest)
        _say_plan(plan, store, args.quiet, rig)
        return _sim_session(store, plan, store.manifest, args.quiet)
    calibration, devices = open_hardware(args, rig, manifest,
                                         before_open=lambda c: _record_detector(manifest, c, rig, pinhole=False))
    try:
        store = SessionStore.create(out, manifest)
    except BaseException:
        devices.close()
        raise
    _say_noise_defaults(store.manifest, args.calibration)
    _say_plan(plan, store, args.quiet, rig)
    return _hw_session(store, plan, store.manifest, rig, calibration, args.quiet, devices=devices)


def _say_noise_defaults(manifest, source) -> None:
    """One warning line when the camera file left out noise-model fields every sample's σ rests on (even with
    --quiet: the uncertainties are not this camera's)."""
    missing = (manifest.get("hardware") or {}).get("noise_defaults") or []
    if missing:
        from gonio.pipeline.target import NoiseModel

        given = ", ".join(f"{k} = {getattr(NoiseModel(), k):g}" for k in missing)
        print(f"gonio: warning: {source}: [noise] does not give {' or '.join(missing)}: the samples' uncertainties "
              f"use gonio's defaults ({given}), not this camera's; measure them (EMVA 1288's photon-transfer "
              "curve) and write them under [noise]", file=sys.stderr)


def _say_plan(plan, store, quiet: bool, rig) -> None:
    if quiet:
        return
    from gonio.plan import estimate_plan
    from gonio.session.runner import format_lab_time

    timing = _manifest_timing(store.manifest)
    est = estimate_plan(plan, rig, timing)
    dropped = f", {plan.n_dropped} dropped ({plan.dropped_summary()})" if plan.n_dropped else ""
    eta = (f", estimated lab time {format_lab_time(est.optimized)} incl. {format_lab_time(est.startup)} of darks and "
           f"warm-up (lower bound {format_lab_time(est.lower_bound)})"
           + ("; automatic exposure: estimated with the expected bracket" if est.auto_exposure else "")
           + f"; {timing.describe()}")
    if plan.generator == "adaptive":
        p = plan.params
        budget = f"at most the lab budget {format_lab_time(p['lab_budget'])}" if p["lab_budget"] else "no lab budget"
        dropped = f" of {p['candidates']} candidates" + (f" ({plan.n_dropped} unreachable)" if plan.n_dropped else "")
        eta = (f" in the coarse round, estimated {format_lab_time(est.optimized)}; later rounds are chosen while "
               f"measuring: total lab time not known ahead ({budget}), target error {p['target_error']:g}")
    print(f"session {store.directory}: plan {plan.generator}, {len(plan)} poses{dropped}{eta}", file=sys.stderr)


def _nothing_to_resume(d, manifest, plan, scan) -> bool:
    """If every pose of the session in ``d`` (its ``manifest``, ``plan`` and samples ``scan``) is stored (and an
    adaptive session has stopped adapting), say so and return True without counting a resume (a session not
    marked completed is marked so)."""
    from gonio.session.store import SessionStore

    adapting = isinstance(manifest.get("adaptive"), dict) and manifest["adaptive"].get("stop") is None
    if adapting or scan.torn is not None or scan.damaged or any(k not in scan.records for k in range(len(plan))):
        return False
    if manifest.get("exit_status") != "completed":
        SessionStore.open(d, resume=False).finish("completed")
    print(f"{d}: all {len(plan)} poses are measured; nothing to resume (not counted as a resume)")
    return True


def _check_exposures(plan, limits, camera: str) -> None:
    """A fixed bracket's exposures lie in the camera's range ``limits`` (s), else one line naming the value —
    checked before the session directory is made (an exposure typed in milliseconds, ``--exposures 4,16,64``,
    left a session that failed at its first pose on every resume). Automatic exposure stays in range itself."""
    from gonio.errors import ConfigError

    cap = plan.capture
    if cap.auto_exposure:
        return
    lo, hi = limits
    for t in cap.exposures:
        if not lo <= t <= hi:
            raise ConfigError.field("--exposures", "capture.exposures", t,
                                    f"must be in [{lo:g}, {hi:g}] s for {camera} (exposures are in seconds)")


def _check_servo_models(rig) -> None:
    """Every joint's servo model has a control table (:func:`gonio.rig.control_table.load_control_table`), else
    one line naming the rig file and the joint — checked before the session directory is made (it was made, then
    left marked running with nothing in it, when the simulated bus refused the model)."""
    from gonio.errors import ConfigError
    from gonio.rig.control_table import load_control_table

    for j in rig.joints:
        try:
            load_control_table(j.model)
        except ConfigError as exc:
            raise ConfigError(f"{rig.source}: joint {j.name}: {exc}") from None


def _check_plan_against_records(d, manifest, plan, scan) -> None:
    """Refuse a plan that no longer describes the stored poses: every record names the plan pose it measured
    (``pose``) and the angles it was measured at (``meta.pose_rad``, [θi, φi, θo, φo] rad, written from the
    plan); a manifest whose plan was edited, reordered or replaced since would make a resume measure the poses
    still missing at other angles than planned, and skip planned angles that no record holds, yet end
    "completed". Records without ``pose_rad`` (older sessions) are not checked; nor is an adaptive session.
    Read-only: run before the store marks the session as resumed."""
    import numpy as np

    from gonio.errors import DataError
    from gonio.session.store import MANIFEST, SAMPLES

    if "adaptive" in manifest:  # an adaptive session's plan is rebuilt from its rounds as it grows
        return
    for pose in sorted(scan.records):
        got = scan.records[pose][1].get("pose_rad")
        if got is None:
            continue
        if pose >= len(plan):
            raise DataError(f"{d / MANIFEST}: plan has {len(plan)} poses, but {d / SAMPLES} holds a record of pose "
                            f"{pose}: the manifest's plan is not the one this session measured")
        try:
            stored = np.asarray(got, dtype=np.float64).reshape(4)
        except (TypeError, ValueError):
            continue  # not angles: the record's own reader refuses it where it matters
        if not np.allclose(stored, plan.poses[pose], rtol=0.0, atol=1e-9):
            raise DataError(f"{d / MANIFEST}: plan.poses[{pose}] = {np.round(plan.poses[pose], 6).tolist()} rad, but "
                            f"pose {pose} was measured at {np.round(stored, 6).tolist()}: the manifest's plan is not "
                            "the one this session measured (edited or replaced); nothing is resumed")


def run_resume(args) -> int:
    from pathlib import Path

    from gonio.errors import ConfigError, DataError
    from gonio.plan.plan import Plan
    from gonio.session.store import MANIFEST, SessionStore, _read_manifest, _samples_path, scan_samples

    d = Path(args.dir)
    if not (d / MANIFEST).is_file():
        raise ConfigError.field(None, "session directory", args.dir, "is not a gonio session (no manifest.json)")
    # read once for both checks below (read-only: the store reads the file again under its lock)
    manifest = _read_manifest(d)
    plan = Plan.from_dict(manifest.get("plan"), source=str(d / MANIFEST))
    scan = scan_samples(_samples_path(d, manifest))
    if _nothing_to_resume(d, manifest, plan, scan):
        if "geocal" in manifest:  # every pose measured: the calibration's estimate may still be missing
            from gonio.cli.calibrate import finish_from_directory

            return finish_from_directory(d, _read_manifest(d), rig_file=args.rig)  # as marked completed just now
        return 0
    _check_plan_against_records(d, manifest, plan, scan)  # before the store marks the session as resumed
    store = SessionStore.open(d)
    if store.repaired is not None:
        q = store.repaired["quarantined"]
        where = ", ".join("line %s" % r["line"] for r in q[:5])
        print(f"repaired {d}: {len(q)} damaged record(s) moved to quarantine.jsonl ({where}); their poses are "
              "measured again", file=sys.stderr)
    manifest = store.manifest
    try:
        remaining = store.remaining(plan)  # the plan read above: opening the store does not change it
        adapting = isinstance(manifest.get("adaptive"), dict) and manifest["adaptive"].get("stop") is None
        if not args.quiet:
            print(f"resuming {d}: {len(remaining)} of {len(plan)} poses remaining"
                  + ("; then adapting from the stored samples" if adapting else ""), file=sys.stderr)
        mode = manifest.get("mode")
        if mode == "sim":
            return _sim_session(store, plan, manifest, args.quiet, rig_file=args.rig)
        if mode != "hardware":
            raise DataError(f"{d / MANIFEST}: mode = {mode!r}: expected 'sim' or 'hardware'")
        hw = dict(manifest["hardware"])
        for key in ("servo_port", "controller_port", "camera"):
            if getattr(args, key):
                hw[key] = getattr(args, key)
        manifest["hardware"] = hw
        where = str(d / MANIFEST)
        rig = _manifest_rig(manifest, where, args.rig)
        calib = _manifest_calibration(manifest, where)
        return _hw_session(store, plan, manifest, rig, calib, args.quiet)
    except BaseException:
        store.close()
        raise
