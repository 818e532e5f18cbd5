"""The whole simulated rig: servo bus and rig controller on pseudo-terminals, a rendering camera, one clock.

:class:`SimRig` wires the emulators other modules provide, without changing them:

* one :class:`sim.clock.SimClock` shared by the host code and every emulator;
* :class:`sim.servo_bus.ServoBus` (one servo per joint of the rig TOML, IDs and models from it, provisioned
  to its ``[bus] baud``: they answer at that rate only) on a
  pty — the host drives it through the real ``dynamixel-sdk`` (:attr:`SimRig.servo_port`);
* :class:`sim.controller.ControllerEmulator` on another pty — the host drives it through pyserial and
  ``firmware_protocol`` (:attr:`SimRig.controller_port`);
* a :class:`sim.camera.SimCamera` whose scene follows the emulators' *actual* state at capture time:
  the camera pose and the light position come from the forward kinematics of the servos' load-side
  positions (:attr:`sim.servo_bus.SimServo.joint_ticks`, i.e. after backlash, not what the encoders
  report), and the light's output is the controller emulator's (warm-up drift, watchdog trips, resets:
  the photodiode sees the same output). :class:`RigCamera` does that per frame and implements
  :class:`gonio.rig.interfaces.Camera`.

Configuration boundary: ``gonio`` never imports ``sim``; only ``gonio/session/rigs.py`` finds this
module, lazily, for ``--sim``. The host code learns it is simulated only through the device paths and
the :class:`SimClock` it is given.

Every noise source is reproducible per pose (:func:`sim.seeding.pose_rng`): :meth:`SimRig.begin_pose`
reseeds the camera's noise, the photodiode's noise and the link faults from ``(seed, pose index,
source)``; the servo encoder noise restarts at every arrival from ``(seed, servo, goal)``; every dark
set (one light-off period) restarts the camera noise from ``(seed, "dark")``. So a pose measured in a
resumed session gives bit for bit the frames, readings and samples of an uninterrupted one, provided
the deterministic, path-dependent physics is off or equal: the backlash (which side of the play the
last move left the load on), the light's warm-up drift (lab time since switch-on) and the camera
sensor's self-heating (lab time since power-on: the dark level) —
``SimRigConfig(backlash_ticks=0, warmup_depth=0, sensor_heating_c=0)``, what the bit-identity tests use.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import numpy as np

from gonio.brdf import make
from gonio.brdf.base import BRDF
from gonio.pipeline.target import CameraCalibration, CameraPose, TargetLayout
from gonio.rig.control_table import load_control_table
from gonio.rig.interfaces import Frame
from gonio.rig.kinematics import Rig, load_rig
from sim import compiled
from sim.as_built import AsBuilt, observe, parse_as_built
from sim.camera import SensorModel, SimCamera, SimScene
from sim.clock import SimClock
from sim.controller import ControllerEmulator
from sim.faults import FrameFaults, LinkFaults
from sim.seeding import SETUP, pose_rng
from sim.servo_bus import HW_OVERLOAD, ServoBus

__all__ = ["AsBuilt", "observe", "parse_as_built", "SimRig", "SimRigConfig", "RigCamera", "RecordingServoBus", "DEFAULT_MATERIAL", "PARK_DEG"]

#: Material of the sample when none is given (a plastic-like GGX microfacet).
DEFAULT_MATERIAL = {"model": "microfacet",
                    "params": {"kd": [0.3, 0.12, 0.06], "ks": 0.8, "alpha": 0.25, "f0": 0.04, "distribution": "ggx"}}
#: Joint angles (degrees) the simulated rig is powered on at: arms apart, out of any collision zone.
#: Keyed by joint name, every layout's joints (gonio.rig.kinematics.LAYOUTS).
PARK_DEG = {"light_az": 0.0, "light_el": 30.0, "camera_az": 0.0, "camera_el": -20.0, "sample_az": 0.0}


@dataclass(frozen=True)
class SimRigConfig:
    """Everything that defines a simulated rig (JSON-able: the session manifest stores it so that
    ``gonio resume`` rebuilds the same rig).

    Camera: ``width`` × ``height`` pixels, focal length ``focal_px``. Servos: position noise and
    backlash in ticks. Light: warm-up depth and time constant (s), photodiode noise. Camera sensor:
    self-heating and dark non-uniformity (the dark level's drift).
    """

    seed: int = 0
    width: int = 320
    height: int = 240
    focal_px: float = 380.0
    bit_depth: int = 12
    light_intensity: float = 1.0
    servo_noise_ticks: float = 0.3
    backlash_ticks: float = 1.0
    warmup_depth: float = 0.05
    warmup_tau: float = 120.0
    pd_noise: float = 0.002
    #: Camera sensor: self-heating after power-on (K, first-order with ``sensor_thermal_tau`` s) and dark
    #: signal non-uniformity (relative rms of the per-pixel dark current): the dark level drifts with the
    #: sensor temperature during a session (sim.camera.SensorModel); 0 heating: a constant dark level
    sensor_heating_c: float = 8.0
    sensor_thermal_tau: float = 1200.0
    sensor_dsnu: float = 0.2
    #: frames carry the sensor temperature (``meta["sensor_temp_c"]``); False: a camera that does not report it
    sensor_reports_temperature: bool = True
    #: How the host reaches the camera: ``direct`` (in-process) or ``gige`` (sim.gige_camera over GigE Vision).
    camera_link: str = "direct"
    #: The GenICam pixel format of the ``gige`` link (sim.gige_camera.FILLABLE_FORMATS; empty: RGB8, as before
    #: it was recorded).
    pixel_format: str = ""
    #: Camera faults, :meth:`sim.faults.FrameFaults.from_spec` (``"black=0.05,stale=0.01"``; empty: none).
    frame_faults: str = ""
    #: The rig controller behind its pty: ``firmware`` (the reference firmware's C code, host build,
    #: :mod:`sim.firmware`), ``python`` (the independent Python implementation, :mod:`sim.controller`) or
    #: ``simavr`` (the AVR build in an emulated ATmega328P, :mod:`sim.simavr`; in lockstep with the clock).
    controller: str = "firmware"
    #: As-built geometry (:mod:`sim.as_built`): ``None`` the declared (perfect) rig, else
    #: :meth:`sim.as_built.AsBuilt.to_dict` (the assembly errors the simulator renders with).
    as_built: dict | None = None
    #: A glossy black tile (or mirror) in place of the sample, over the layout's sample rectangle
    #: (:class:`sim.mirror_tile.CalibrationTile`'s other fields: ``f0``, ``diffuse``, ``light_radius``):
    #: the geometric calibration's stage. ``None``: the sample.
    tile: dict | None = None
    #: The camera as built, which the host does not know (``gonio camera calibrate`` measures it): its principal
    #: point's offset from the image centre (px) and its lens distortion (OpenCV's k1, k2, p1, p2, k3). The frames
    #: are rendered through it; :meth:`calibration` (what the host is given) stays the ideal pinhole.
    principal_offset_px: tuple[float, float] | None = None
    distortion: tuple[float, ...] | None = None
    #: A sphere target as built: its true centre's offset (m) from the one the target file declares, which the
    #: host does not know (the silhouette refinement finds it, gonio.sphere.refine). ``None``: where declared.
    sphere_offset_m: tuple[float, float, float] | None = None

    def to_dict(self) -> dict:
        d = dict(self.__dict__)
        # a plain rig's manifest stays what it was before these existed
        for k in ("as_built", "tile", "principal_offset_px", "distortion", "sphere_offset_m"):
            if d[k] is None:
                del d[k]
        if not d["pixel_format"]:
            del d["pixel_format"]
        return d

    def true_calibration(self) -> CameraCalibration:
        """The calibration the frames are rendered with: :meth:`calibration` with the principal point offset and
        the distortion of the camera as built (the same when neither is set)."""
        c = self.calibration()
        if self.principal_offset_px is None and self.distortion is None:
            return c
        K = c.K.copy()
        if self.principal_offset_px is not None:
            K[0, 2] += float(self.principal_offset_px[0])
            K[1, 2] += float(self.principal_offset_px[1])
        dist = np.zeros(5)
        if self.distortion is not None:
            dist[:len(self.distortion)] = np.asarray(self.distortion, dtype=np.float64)[:5]
        return CameraCalibration(K=K, width=c.width, height=c.height, dist=dist, noise=c.noise)

    def calibration(self) -> CameraCalibration:
        """The simulated camera's exact calibration (ideal pinhole, no distortion, the sensor's noise
        model): what the host's pipeline is given, and what the session manifest records."""
        return CameraCalibration.pinhole(self.width, self.height, self.focal_px,
                                         noise=SensorModel(bit_depth=self.bit_depth).noise_model())

    def exposure_range(self) -> tuple[float, float]:
        """Shortest and longest exposure (s) the simulated camera takes (:class:`sim.camera.SensorModel`)."""
        sensor = SensorModel(bit_depth=self.bit_depth)
        return sensor.min_exposure, sensor.max_exposure

    @classmethod
    def at_resolution(cls, width: int, height: int, **kw) -> "SimRigConfig":
        """The default camera at another resolution: same field of view (focal length scaled with the width)."""
        return cls(width=int(width), height=int(height), focal_px=cls.focal_px * width / cls.width, **kw)

    @classmethod
    def from_dict(cls, d) -> "SimRigConfig":
        known = set(cls.__dataclass_fields__)
        return cls(**{k: v for k, v in dict(d).items() if k in known})


def controller_class(kind: str):
    """The emulator class of SimRigConfig.controller: ``firmware`` or ``python``."""
    if kind == "python":
        return ControllerEmulator
    if kind == "firmware":
        from sim import firmware

        try:
            firmware.library()  # built on first use: needs make and a C compiler
        except (OSError, RuntimeError) as exc:
            import warnings

            why = (str(exc).strip().splitlines() or [type(exc).__name__])[0][:160]
            warnings.warn(f"sim rig: the firmware's host build is not available ({why}); the simulated rig controller "
                          "is the Python emulator of the same protocol (apt-get install gcc make for the firmware)",
                          stacklevel=2)
            return ControllerEmulator
        return firmware.FirmwareController
    if kind == "simavr":
        from sim.simavr import SimavrController
        return SimavrController
    raise ValueError(f"sim rig: controller = {kind!r}: must be 'firmware', 'python' or 'simavr'")


class RecordingServoBus(ServoBus):
    """:class:`ServoBus` that records every Goal Position the host writes (for the safety tests).

    :attr:`goal_log` holds one entry per instruction packet that wrote a goal: a dict servo ID → goal
    in ticks (horn side, homing offset removed) of *every* servo, the ones not written keeping their
    last goal (or the power-on position). A synchronized move is one packet, so one entry is one
    commanded pose.
    """

    def __init__(self, servos, clock=None, **kw):
        super().__init__(servos, clock, **kw)
        self.goal_log: list[dict[int, float]] = []
        self._goals = {i: s.horn for i, s in self.servos.items()}
        self._written = False
        for s in self.servos.values():
            s.write = self._recorder(s, s.write)

    def _recorder(self, servo, write):
        field = servo.table["goal_position"]

        def recorded(address: int, data: bytes) -> int:
            if address <= field.address and field.address + field.size <= address + len(data):
                off = field.address - address
                raw = field.from_unsigned(int.from_bytes(data[off:off + field.size], "little"))
                self._goals[servo.dxl_id] = float(raw - servo.peek("homing_offset"))
                self._written = True
            return write(address, data)

        return recorded

    def on_bytes(self, data: bytes) -> None:
        with self.atomic():
            self._written = False
            super().on_bytes(data)
            if self._written:
                self.goal_log.append(dict(self._goals))


class RigCamera:
    """The rig's camera as the host sees it (:class:`gonio.rig.interfaces.Camera`).

    Before each frame it places the :class:`SimCamera` and the light where the servo emulator's
    load-side joint positions put them (forward kinematics of the actual state, so backlash and
    position noise show up as on a rig), then captures; the light output is read from the controller
    emulator by the SimCamera itself (``light_output``).
    """

    def __init__(self, simrig: "SimRig"):
        self._rig = simrig
        self._dark = False
        self._placed = None  # (joints, geometry, camera pose, light position) of the last frame

    def capture(self, exposure: float, gain: float = 1.0, *, timeout: float = 10.0) -> Frame:
        r = self._rig
        dark = r.controller.light_output() == 0.0
        if dark and not self._dark:  # a new light-off period (a dark set): the same noise every time
            r.sim_camera.reseed(pose_rng(r.config.seed, SETUP, "dark"))
        self._dark = dark
        joints = r.actual_joints()
        placed = self._placed
        if placed is None or placed[1] is not r.geometry or not np.array_equal(placed[0], joints):
            # the forward kinematics of the joints (a pure function of them: the frames of a pose, where the arms
            # stand still, reuse it)
            position, R = r.geometry.camera_pose(joints)  # the true (as-built) geometry, not the declared one
            placed = self._placed = (joints, r.geometry, CameraPose(R, -R @ position), r.geometry.light_position(joints))
        r.sim_camera.set_pose(placed[2])
        r.sim_camera.set_light(placed[3])
        return r.frame_faults.apply(lambda: r.sim_camera.capture(exposure, gain, timeout=timeout))

    def close(self) -> None:
        self._rig.sim_camera.close()


class SimRig:
    """A complete simulated gonioreflectometer; see the module docstring.

    Parameters
    ----------
    rig : Rig, path or shipped rig name (default ``"default"``)
    material : BRDF, ``{"model": ..., "params": {...}}`` (default :data:`DEFAULT_MATERIAL`), or a material file
        (TOML, MERL ``.binary``, RGL ``.bsdf``, gonio NPZ, fit JSON: :func:`gonio.io.material_file.open_material`)
        or a manifest's record of one
    config : SimRigConfig
    layout : TargetLayout (board, sample and white patches)
    servo_faults, controller_faults : LinkFaults on the two links (none by default)

    Attributes
    ----------
    clock : SimClock shared by everything
    servo_bus, controller : the emulators (fault-injection handles: ``servo_bus.faults``,
        :meth:`trip`, :meth:`power_cycle_servos`, ``controller.faults``, :meth:`reset_controller`,
        ``controller.set_estop``)
    camera : :class:`RigCamera` to give the host; ``sim_camera`` is the renderer behind it
    calibration, layout, sensor : what the host's pipeline should be configured with
    """

    def __init__(self, rig: Rig | str | None = None, material: BRDF | dict | None = None, *,
                 config: SimRigConfig | None = None, layout: TargetLayout | None = None,
                 servo_faults: LinkFaults | None = None, controller_faults: LinkFaults | None = None,
                 camera_faults: FrameFaults | None = None):
        self.config = cfg = config or SimRigConfig()
        #: faults of the camera's frames (black, stale, saturated, wrong size, NaN, timeout): ``camera_faults``,
        #: else the config's ``frame_faults`` spec
        self.frame_faults = camera_faults or FrameFaults.from_spec(cfg.frame_faults, seed=cfg.seed)
        self.rig = rig if isinstance(rig, Rig) else load_rig(rig)
        #: the geometry the simulator renders with: the declared rig, or its as-built version (sim/as_built.py)
        self.geometry = self.rig if cfg.as_built is None else AsBuilt.from_dict(self.rig, cfg.as_built)
        if isinstance(material, (str, os.PathLike)) or (isinstance(material, dict) and "file" in material):
            from gonio.io.material_file import material_from_record, open_material

            material = (material_from_record(material, "sim material") if isinstance(material, dict)
                        else open_material(material)).brdf()
        elif material is None or isinstance(material, dict):
            m = material or DEFAULT_MATERIAL
            material = make(m["model"], source="sim material", **m.get("params", {}))
        self.material = material
        self.clock = SimClock()
        self._tables = {j.name: load_control_table(j.model) for j in self.rig.joints}
        park = {j.servo_id: self._ticks(j, math.radians(PARK_DEG[j.name])) for j in self.rig.joints}
        self.servo_bus = RecordingServoBus({j.servo_id: j.model for j in self.rig.joints}, self.clock, seed=cfg.seed,
                                           noise_ticks=cfg.servo_noise_ticks, backlash_ticks=cfg.backlash_ticks,
                                           faults=servo_faults, positions=park, baud=self.rig.baud)
        self.controller = controller_class(cfg.controller)(
                                             self.clock, faults=controller_faults, seed=cfg.seed + 1,
                                             warmup_depth=cfg.warmup_depth, warmup_tau=cfg.warmup_tau,
                                             pd_noise=cfg.pd_noise)
        self.sensor = SensorModel(bit_depth=cfg.bit_depth, heating_c=cfg.sensor_heating_c,
                                  thermal_tau=cfg.sensor_thermal_tau, dsnu=cfg.sensor_dsnu,
                                  reports_temperature=cfg.sensor_reports_temperature)
        self.layout = layout or TargetLayout()
        self.calibration = cfg.calibration()
        tile = None
        if cfg.tile is not None:
            from sim.mirror_tile import CalibrationTile

            tile = CalibrationTile(rect=self.layout.sample, **cfg.tile)
        scene = SimScene(self.layout, self.material, light_intensity=cfg.light_intensity, tile=tile,
                         sphere=self._true_sphere(cfg))
        self.sim_camera = SimCamera(cfg.true_calibration(), self.sensor, scene, seed=cfg.seed, clock=self.clock,
                                    light_output=self.controller.light_output)
        self.camera = RigCamera(self)
        self._started = False

    # -- device paths ---------------------------------------------------------------------------
    def _true_sphere(self, cfg):
        """The layout's sphere (or cylinder) where it really is (``cfg.sphere_offset_m`` from the declared centre)."""
        sph = self.layout.curved
        if sph is None or cfg.sphere_offset_m is None:
            return sph
        from dataclasses import replace

        return replace(sph, centre=tuple(np.asarray(sph.centre) + np.asarray(cfg.sphere_offset_m, dtype=float)))

    @property
    def servo_port(self) -> str:
        """The servo bus's pty (open it with the real dynamixel-sdk)."""
        return self.servo_bus.path

    @property
    def controller_port(self) -> str:
        """The rig controller's pty (open it with pyserial)."""
        return self.controller.path

    def open_devices(self, camera=None, **options):
        """Open this rig's devices through the host's own drivers (:func:`gonio.session.runner.open_devices`:
        the real dynamixel-sdk on the servo bus's pty, the controller client on the controller's), ``camera``
        (default :attr:`camera`), with the reply deadlines the emulators ask for (:attr:`sim.pty.PtyServer.reply_timeout`:
        generous on links without faults, so the machine's load cannot change a seeded session). ``options``
        go to ``open_devices`` and win over those deadlines."""
        from gonio.session.runner import open_devices

        deadlines = {}
        if getattr(self.controller, "reply_timeout", None) is not None:
            deadlines["controller_timeout"] = float(self.controller.reply_timeout)
        if getattr(self.servo_bus, "reply_timeout", None) is not None:  # the SDK's packet timeout is 2 x latency timer + transfer
            deadlines["latency_timer_ms"] = 1000.0 * self.servo_bus.reply_timeout / 2.0
        return open_devices(self.rig, self.servo_port, self.controller_port, self.camera if camera is None else camera,
                            self.clock, **{**deadlines, **options})

    # -- lifecycle ------------------------------------------------------------------------------
    def start(self) -> "SimRig":
        if not self._started:
            self.servo_bus.start()
            self.controller.start()
            self._started = True
        return self

    def stop(self) -> None:
        """Stop both emulators and close their ptys (idempotent)."""
        if self._started:
            self._started = False
            self.servo_bus.stop()
            self.controller.stop()

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()

    # -- state ----------------------------------------------------------------------------------
    def _ticks(self, joint, angle: float) -> float:
        """Joint angle (rad) → servo ticks, the rig TOML's formula
        ``ticks = zero_offset/360·N + direction · gear_ratio · θ · N/2π`` (N ticks per revolution)."""
        n = self._tables[joint.name].ticks_per_rev
        return joint.zero_offset_deg / 360.0 * n + joint.direction * joint.gear_ratio * angle * n / (2.0 * math.pi)

    def _angle(self, joint, ticks: float) -> float:
        """Inverse of :meth:`_ticks`."""
        n = self._tables[joint.name].ticks_per_rev
        return (ticks - joint.zero_offset_deg / 360.0 * n) * 2.0 * math.pi / n / (joint.direction * joint.gear_ratio)

    def actual_joints(self) -> np.ndarray:
        """Joint angles (rad, :attr:`gonio.rig.kinematics.Rig.names` order) of the arms *now*: the
        load side of each servo after backlash, advanced to the current simulated time."""
        out = []
        with self.servo_bus.atomic():  # the bus thread updates the servos under this lock
            for j in self.rig.joints:
                s = self.servo_bus.servo(j.servo_id)
                s.read(0, 0)  # brings the motion up to clock.now() (same as a host read would)
                out.append(self._angle(j, s.joint_ticks))
        return np.array(out)

    def commanded_joints(self) -> np.ndarray:
        """Every pose the host commanded, as joint angles (rad), shape (M, 4), one row per goal packet."""
        rows = [[self._angle(j, g[j.servo_id]) for j in self.rig.joints] for g in self.servo_bus.goal_log]
        return np.array(rows, dtype=np.float64).reshape(-1, len(self.rig.joints))

    # -- per-session and per-pose hooks, and faults -----------------------------------------------
    def expect_poses(self, poses: int) -> None:
        """A session of ``poses`` poses is about to start: the camera's frames take numba's compiled paths from the
        first if NumPy's would cost more (:func:`sim.compiled.expect`; the same frames either way)."""
        c = self.sim_camera.calibration
        compiled.expect(c.width * c.height * 3, poses)

    def begin_pose(self, index: int) -> None:
        """Reseed the camera noise, the photodiode noise and the link faults from ``(seed, index)``
        (:func:`sim.seeding.pose_rng`) so a pose's frames and readings do not depend on what was simulated
        before it (bit-identical across interrupted and resumed sessions)."""
        seed, index = int(self.config.seed), int(index)
        self.camera._dark = self.controller.light_output() == 0.0  # the pose's frames keep the pose's noise
        self.sim_camera.reseed(pose_rng(seed, index, "camera"))
        self.controller.reseed(pose_rng(seed, index, "photodiode"))
        for stream, faults in (("servo_faults", self.servo_bus.faults), ("controller_faults", self.controller.faults)):
            if faults is not None:
                faults.reseed(pose_rng(seed, index, stream))
        if index != getattr(self, "_faults_pose", None):  # a retried pose draws new frame faults, not the same again
            self._faults_pose = index
            self.frame_faults.reseed(pose_rng(seed, index, "frame_faults"))

    def trip(self, joint: str, bits: int = HW_OVERLOAD) -> None:
        """Raise a hardware error (default overload) on the servo of ``joint``."""
        sid = {j.name: j.servo_id for j in self.rig.joints}[joint]
        with self.servo_bus.atomic():
            self.servo_bus.servo(sid).trip(bits)

    def power_cycle_servos(self) -> None:
        """Switch the servo bus's power off and on (RAM settings lost, torque off)."""
        self.servo_bus.power_cycle()

    def reset_controller(self) -> None:
        """Brown-out of the rig controller at its next request (light off, handshake forgotten)."""
        self.controller.inject_reset()
