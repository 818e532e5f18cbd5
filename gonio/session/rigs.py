"""Open a rig in one call: its devices (servo bus, rig controller, camera, clock), the camera's calibration, the
target layout, and what the session will record about them — for the simulated rig, a real one, or a mix
(real ports with a camera object of your own, e.g. a simulated or a GenICam one).

:class:`OpenRig` is a context manager; leaving it switches the light off and releases the devices (and, unless
``hold=True``, the servos' torque), whatever happened inside::

    with open_rig(sim=SimOptions(resolution="160x120")) as rig:
        ...                                       # gonio.session.api.measure(rig, "half_diff", "out")

Configuration boundary (docs/architecture.md §1): ``gonio`` never imports ``sim``; the simulator is found through
the ``gonio.plugins`` entry points (:mod:`gonio.plugins`) here and only here. Everything below (runner, drivers,
pipeline) gets device paths, a camera and a clock and cannot tell simulation from hardware.
"""

from __future__ import annotations

import contextlib
import os
from dataclasses import dataclass, field

from gonio.errors import ConfigError, DataError, HardwareError
from gonio.session.options import HardwareOptions, SimOptions, check_servo_models, load_material_file
from gonio.session.recording import (calibration_record, checked_sim, manifest_calibration,
                                     manifest_layout, manifest_rig, record_detector, rig_record, target_layout)

__all__ = ["OpenRig", "open_rig", "open_rig_from_manifest", "open_hardware_rig", "open_sim_config",
           "open_hardware_devices"]


@dataclass
class OpenRig:
    """An opened rig: ``devices`` (:class:`gonio.session.runner.Devices`), the camera ``calibration``, the target
    ``layout``, ``record`` (the manifest entries describing the rig: mode, rig, material, target, calibration,
    detector, and ``sim`` or ``hardware``), ``before_pose`` and ``expect_poses`` (the simulator's per-pose and
    per-session hooks, None on a rig) and ``exposure_range`` (s) of the camera where known. Close it (or leave its
    ``with`` block) to switch the light off and release everything."""

    devices: object
    calibration: object
    layout: object
    record: dict
    before_pose: object = None
    expect_poses: object = None
    exposure_range: tuple[float, float] | None = None
    camera_label: str = "the camera"
    hold: bool = False  #: keep the servos' torque on when closing (arms do not drop); default: released
    _stack: contextlib.ExitStack = field(default_factory=contextlib.ExitStack, repr=False)

    @property
    def rig(self):
        """The rig's kinematics (:class:`gonio.rig.kinematics.Rig`)."""
        return self.devices.rig

    @property
    def mode(self) -> str:
        """``sim``, ``hardware`` or ``mixed`` (real ports, a camera object given by the caller)."""
        return self.record["mode"]

    def close(self) -> None:
        """Light off, torque released (unless ``hold``), every device closed; safe to call twice."""
        devices, self.devices = self.devices, _Closed(self.devices.rig) if self.devices is not None else None
        if devices is not None and not isinstance(devices, _Closed):
            axes = getattr(devices, "axes", None)
            if not self.hold and axes is not None and hasattr(axes, "torque_off_on_close"):
                axes.torque_off_on_close = True
            devices.close()
        self._stack.close()

    def __enter__(self) -> "OpenRig":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


@dataclass
class _Closed:
    """What an :class:`OpenRig`'s ``devices`` is after closing: the kinematics only."""

    rig: object


def _sim_plugin():
    from gonio.plugins import plugin

    return plugin("sim.rig")  # docs/architecture.md §1: gonio never imports sim; the simulator is found by configuration


def _load_rig(rig):
    """``(Rig, its TOML text, where it came from)`` of a rig file path, a shipped rig name, or a loaded Rig."""
    from gonio.rig.kinematics import Rig, load_rig, read_rig_text

    if isinstance(rig, Rig):
        text = getattr(rig, "toml_text", None)
        if text is None:
            raise ConfigError("open_rig: give the rig as a file or a shipped rig name (its text is recorded)")
        return rig, text, rig.source
    text, where = read_rig_text(rig)
    return load_rig(text=text, source=where), text, where


def open_rig(rig="default", *, sim: SimOptions | bool | None = None, hardware: HardwareOptions | None = None,
             material=None, target=None, camera=None, calibration=None, clock=None, hold: bool = False,
             seed: int | None = None, detector: bool = True) -> OpenRig:
    """Open a rig from its files in one call.

    Parameters
    ----------
    rig : a rig TOML file or a shipped rig name (``default``, ``turntable``).
    sim : :class:`SimOptions` (or True for the defaults): the simulated rig — emulators on pseudo-terminals
        driven through the real dynamixel-sdk and pyserial, a rendering camera, a simulated clock.
    hardware : :class:`HardwareOptions`: a real rig's ports, camera and CAMERA.toml.
    material : the simulated sample's material file (a TOML, or a measured one: MERL, RGL .bsdf, gonio NPZ, fit JSON,
        :mod:`gonio.io.material_file`), or a loaded :class:`gonio.io.material_toml.Material`;
        on a rig only its label is recorded.
    target : TARGET.toml (default: the standard board, flat sample).
    camera, calibration, clock : a mixed rig: real ports (``hardware.servo_port``/``controller_port``) with a
        camera *object* (:class:`gonio.rig.interfaces.Camera`), its :class:`CameraCalibration` and the clock it
        runs on (default: the real clock).
    hold : keep the servos' torque on when the rig is closed (default: released, so the rig is safe to touch).
    seed : seeds the simulator (``sim.seed`` when not given).
    detector : record the detector's solid angle (``detector``; a calibration session has no sample to measure).

    >>> with open_rig(sim=SimOptions(resolution="160x120")) as r:   # doctest: +SKIP
    ...     r.mode, r.calibration.width
    ('sim', 160)
    """
    rig_obj, text, where = _load_rig(rig)
    if sim is not None and sim is not False:
        if hardware is not None or camera is not None:
            raise ConfigError("open_rig: give sim= or the hardware devices, not both")
        opts = SimOptions() if sim is True else sim
        if seed is not None and seed != opts.seed:
            from dataclasses import replace

            opts = replace(opts, seed=seed)
        mat = material if (material is None or not isinstance(material, (str, os.PathLike))) else load_material_file(str(material))
        return _open_sim(rig_obj, text, where, opts, mat if mat is not None else load_material_file(None), target, hold)
    hw = hardware or HardwareOptions()
    if camera is not None:
        record = _new_record("mixed", rig_obj, text, where, material, target)
        return _open_mixed(rig_obj, record, hw, camera, calibration, clock, hold)
    return open_hardware_rig(rig_obj, text, where, hw, material=material, target=target, hold=hold, detector=detector)


def open_hardware_rig(rig, text, where, hw: HardwareOptions, *, material=None, target=None, hold: bool = False,
                      detector: bool = True) -> OpenRig:
    """A real rig (its kinematics ``rig``, the rig file's ``text`` and where it came from) with the devices of
    ``hw``; ``material`` a material file, a Material, or the manifest's entry (a dict)."""
    record = _new_record("hardware", rig, text, where, material, target)
    return _open_hardware(rig, record, hw, hold, detector=detector)


def _new_record(mode, rig, text, where, material, target) -> dict:
    if isinstance(material, (str, os.PathLike)):
        material = load_material_file(str(material))
    if isinstance(material, dict):
        mat = dict(material)
    else:
        mat = material.to_dict() if material is not None else {"label": ""}
    return {"mode": mode, "rig": rig_record(rig, where, text), "material": mat,
            "target": target_layout(target).to_dict() if not hasattr(target, "to_dict") else target.to_dict()}


def _open_sim(rig, text, where, opts: SimOptions, material, target, hold) -> OpenRig:
    """The simulated rig of ``opts``: its configuration recorded (``sim``, ``calibration``, ``detector``) so a
    resume rebuilds the same rig."""
    simrig = _sim_plugin()
    record = _new_record("sim", rig, text, where, material, target)
    w, h = opts.size
    link = {} if opts.camera == "direct" else _gige_link(opts.pixel_format, simrig.SimRigConfig.bit_depth)
    if opts.frame_faults:
        try:
            simrig.FrameFaults.from_spec(opts.frame_faults)
        except ValueError as exc:
            raise ConfigError.field("--sim-frame-faults", "frame faults", opts.frame_faults, str(exc)) from None
        link["frame_faults"] = opts.frame_faults
    if opts.controller != "firmware":
        link["controller"] = opts.controller
    if opts.as_built:
        link["as_built"] = simrig.parse_as_built(rig, opts.as_built).to_dict()
    if opts.sphere_offset_mm is not None:
        link["sphere_offset_m"] = [x / 1000.0 for x in opts.sphere_offset_mm]
    config = simrig.SimRigConfig.at_resolution(w, h, seed=opts.seed, **link)
    return open_sim_config(rig, text, where, config, material, target, hold=hold)


def open_sim_config(rig, text, where, config, material, target, *, hold: bool = False,
                    detector: bool = True) -> OpenRig:
    """The simulated rig of a :class:`sim.rig.SimRigConfig` (its configuration recorded: ``sim``,
    ``calibration``, ``detector``, so a resume rebuilds the same rig)."""
    record = _new_record("sim", rig, text, where, material, target)
    record["sim"] = config.to_dict()
    record["calibration"] = calibration_record(config.calibration())
    if detector:
        record_detector(record, config.calibration(), rig, pinhole=True)
    check_servo_models(rig)  # the simulated servos need their control tables: say so before a session exists
    return _start_sim(record, rig, material_brdf=material.brdf(), config=config, hold=hold,
                      exposure_range=config.exposure_range())


def _start_sim(record, rig, *, material_brdf, config, hold, exposure_range=None, calibration=None) -> OpenRig:
    """Start :class:`sim.rig.SimRig` for ``record`` and open its devices through the host's own drivers."""

    simrig = _sim_plugin()
    layout = manifest_layout(record)
    stack = contextlib.ExitStack()
    try:
        sim = stack.enter_context(simrig.SimRig(rig, material_brdf, config=config, layout=layout))
        camera = sim.camera
        if getattr(config, "camera_link", "direct") == "gige":  # the sim camera behind a real GigE Vision link
            camera = _gige_sim_camera(sim, stack)
        # through the host's own drivers, with the reply deadlines the emulators ask for (sim.pty.PtyServer.reply_timeout)
        devices = sim.open_devices(camera)
    except BaseException:
        stack.close()
        raise
    return OpenRig(devices=devices, calibration=calibration if calibration is not None else sim.calibration,
                   layout=sim.layout, record=record, before_pose=sim.begin_pose, expect_poses=sim.expect_poses,
                   exposure_range=exposure_range,
                   camera_label="the simulated camera", hold=hold, _stack=stack)


#: The simulated GigE camera's default pixel format (12-bit colour, like the default simulated camera) and the
#: one it falls back to where this Aravis's fake device cannot offer it.
GIGE_DEFAULT_FORMAT, GIGE_FALLBACK_FORMAT = "RGB12", "RGB8"


def _gige_link(pixel_format: str, default_bits: int) -> dict:
    """The simulated rig's settings for ``--sim-camera gige`` in ``pixel_format``: validated against the formats
    the simulated GigE camera offers (one line naming them), the sensor's bit depth set to the format's (so the
    host reads what the sensor makes), a warning when that is not the default camera's ``default_bits``."""
    import warnings

    from gonio.plugins import plugin
    from gonio.rig.aravis import PIXEL_FORMATS, aravis_available

    if not aravis_available():
        raise HardwareError("--sim-camera gige needs Aravis: apt-get install gir1.2-aravis-0.8 and "
                            "pip install 'gonio[genicam]' (PyGObject)")
    offered = [f for f in plugin("sim.gige_camera").served_formats() if f in PIXEL_FORMATS]
    fmt = pixel_format
    if not fmt:
        fmt = GIGE_DEFAULT_FORMAT if GIGE_DEFAULT_FORMAT in offered else GIGE_FALLBACK_FORMAT
    if fmt not in offered:
        raise ConfigError.field("--sim-pixel-format", "pixel_format", fmt,
                                f"the simulated GigE camera offers {', '.join(offered)}")
    bits = PIXEL_FORMATS[fmt][0]
    if bits != default_bits:
        why = ("this Aravis's fake camera offers no 12-bit colour format" if not pixel_format
               else f"{fmt} has {bits} bits")
        warnings.warn(f"--sim-camera gige: {why}: the simulated camera is a {bits}-bit {fmt} sensor, not the default "
                      f"camera's {default_bits} bits", stacklevel=2)
    return {"camera_link": "gige", "pixel_format": fmt, "bit_depth": bits}


def _gige_sim_camera(sim, stack):
    """``sim.camera`` served as a GigE Vision camera on the loopback interface (:mod:`sim.gige_camera`)
    and opened through gonio's Aravis backend, as a GenICam camera on a rig would be."""
    from gonio.plugins import plugin
    from gonio.rig.aravis import AravisCamera

    try:
        server = stack.enter_context(plugin("sim.gige_camera").GigECameraServer(
            sim.camera, temperature=sim.sensor.reports_temperature))
    except (ImportError, ValueError, OSError) as exc:
        raise HardwareError(f"--sim-camera gige: cannot serve the simulated camera over GigE Vision ({exc})") from None
    cal = sim.calibration
    fmt = getattr(sim.config, "pixel_format", "") or GIGE_FALLBACK_FORMAT  # sessions before pixel_format: RGB8
    camera = AravisCamera(server.device, sim.clock, pixel_format=fmt, black_level=sim.sensor.black_level,
                          gain_unit="raw", width=cal.width, height=cal.height)
    stack.callback(camera.close)
    return camera


def _open_hardware(rig, record: dict, hw: HardwareOptions, hold: bool, *, detector: bool = True) -> OpenRig:
    """A real rig's devices from ``hw``, recorded in ``record`` (``hardware`` with the camera's own identity,
    ``calibration``, ``detector``). The devices are opened before any session directory exists: a rig that
    does not start leaves nothing."""
    from gonio.rig.calibration import load_camera_calibration
    from gonio.rig.clock import RealClock

    missing = hw.missing()
    if missing:
        raise ConfigError.field(None, missing[0], None, "required on hardware (or use --sim for the simulated rig)")
    description = load_camera_calibration(hw.calibration)
    calibration = description.calibration
    record["hardware"] = {"servo_port": hw.servo_port, "controller_port": hw.controller_port, "camera": hw.camera}
    if description.noise_defaults:  # said when the session starts (noise_defaults_note), recorded here
        record["hardware"]["noise_defaults"] = list(description.noise_defaults)
    record["calibration"] = description.to_dict()
    if detector:
        record_detector(record, calibration, rig, pinhole=False)
    description.camera.check_session(hw.calibration)
    devices = open_hardware_devices(rig, record["hardware"], description.camera, RealClock(),
                                    size=(calibration.width, calibration.height))
    identity = getattr(devices.camera, "identity", None)
    if callable(identity):  # what the camera says it is (vendor, model, serial, ...)
        try:
            record["hardware"]["camera_identity"] = identity()
        except BaseException:
            devices.close()
            raise
    return OpenRig(devices=devices, calibration=calibration, layout=manifest_layout(record), record=record,
                   camera_label=f"camera {hw.camera}", hold=hold)


def _open_mixed(rig, record: dict, hw: HardwareOptions, camera, calibration, clock, hold: bool) -> OpenRig:
    """Real ports with a camera object of the caller's (a simulated camera, a GenICam camera opened by hand)."""
    from gonio.rig.clock import RealClock
    from gonio.session.runner import open_devices

    if calibration is None:
        raise ConfigError("open_rig: a camera object needs its calibration= (a CameraCalibration)")
    missing = [o for o, v in (("servo_port", hw.servo_port), ("controller_port", hw.controller_port)) if not v]
    if missing:
        raise ConfigError(f"open_rig: a camera object needs the rig's ports: hardware.{missing[0]} is not given")
    record["hardware"] = {"servo_port": hw.servo_port, "controller_port": hw.controller_port,
                          "camera": f"<{type(camera).__name__}>"}
    record["calibration"] = calibration_record(calibration)
    record_detector(record, calibration, rig, pinhole=True)
    devices = open_devices(rig, hw.servo_port, hw.controller_port, camera, clock or RealClock())
    return OpenRig(devices=devices, calibration=calibration, layout=manifest_layout(record), record=record,
                   camera_label=f"camera {type(camera).__name__}", hold=hold)


def open_hardware_devices(rig, hw: dict, settings, clock, size: tuple[int, int] | None = None):
    """Check and open a rig's devices before anything is written: the serial ports exist, the camera opens,
    every servo answers, the controller handshakes. On any failure nothing stays open and the error (one
    line) names the device."""
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


def open_rig_from_manifest(manifest: dict, directory, *, rig_file: str | None = None, hold: bool = True) -> OpenRig:
    """The rig a session directory recorded, opened again for a resume: the simulated rig rebuilt from its
    configuration and seed, or the hardware ports (``manifest["hardware"]``, overrides already applied) and
    the camera file it recorded. Every field is checked (one line naming it)."""
    from gonio.rig.clock import RealClock
    from gonio.io.material_file import material_from_record

    where = f"{directory}/manifest.json"
    mode = manifest.get("mode")
    if mode == "sim":
        m = manifest.get("material")
        if not isinstance(m, dict):
            raise DataError(f"{where}: material = {str(m)[:40]!r}: must be an object (model, params, label)")
        material = material_from_record({k: v for k, v in m.items() if k in ("model", "params", "label", "file", "kind",
                                                                        "sha256")},
                                        source="manifest material", complete=False)
        config = _sim_plugin().SimRigConfig.from_dict(checked_sim(manifest.get("sim"), where))
        rig = manifest_rig(manifest, where, rig_file)
        opened = _start_sim(manifest, rig, material_brdf=material.brdf(), config=config, hold=hold)
        try:
            opened.calibration = manifest_calibration(manifest, where, fallback=opened.calibration)
        except BaseException:
            opened.close()
            raise
        return opened
    if mode != "hardware":
        raise DataError(f"{where}: mode = {mode!r}: expected 'sim' or 'hardware'")
    rig = manifest_rig(manifest, where, rig_file)
    calib = manifest_calibration(manifest, where)
    devices = open_hardware_devices(rig, manifest["hardware"], _camera_settings(manifest.get("calibration"), where),
                                    RealClock(), size=(calib.width, calib.height))
    return OpenRig(devices=devices, calibration=calib, layout=manifest_layout(manifest), record=manifest, hold=hold)
