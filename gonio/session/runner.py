"""The session runner: executes a :class:`gonio.plan.Plan` against the rig's interfaces, one pose at a
time, appending each result to the session store. It never decides *what* to measure (docs/architecture.md §1).

Per session: check the devices (controller status: E-stop and interlock clear; the servos were scanned
and configured when the axes were opened, :func:`open_devices`), warm the light up (photodiode read on
the :class:`~gonio.rig.interfaces.Clock` until two readings one step apart differ by less than the
tolerance), then for each remaining pose in plan order:

1. solve the kinematics nearest the current joints (:meth:`gonio.rig.kinematics.Rig.solve`);
2. synchronized move (:meth:`Axes.move_to`), settle (``plan.capture.settle``, the controller's
   watchdog fed meanwhile), verify the *measured* joint angles against the target (re-issue the move a
   bounded number of times, then :class:`~gonio.errors.HardwareError`);
3. capture through the pipeline with the light position and camera-pose hint from the forward
   kinematics of the *measured* joints, photodiode normalization inside the pipeline. The board pose is
   searched once per camera position: while the camera stays where the last stored pose had it (same goal,
   same encoder readings, :meth:`SessionRunner._camera_key`) that pose's board pose is reused; one read back
   from an earlier run is first confirmed against this pose's metering frame. Exposure: with
   ``plan.capture.auto_exposure`` (the default) the pipeline chooses each pose's bracket from its
   metering frame (metered at the expected bracket's shortest exposure, so a pose's bracket depends on the
   pose only and a resumed session measures what an uninterrupted one does) on the exposure ladder, more
   frames where the SNR is below target; otherwise the plan's fixed bracket. Dark frames of every
   exposure the session may use are measured before the first pose and re-measured as one set on a
   schedule (``dark_max_age`` of lab time, before the pose so the light can warm up again); the white
   reference is in every frame;
4. append the samples with per-pose meta (measured joints, exposures and frames used, photodiode, lab
   time, timings).

Lab-time accounting: the runner spends exactly the costs of :mod:`gonio.plan.labtime` (its
:class:`~gonio.plan.labtime.SessionTiming` is built from :class:`RunnerSettings`); the ETA and the
estimate recorded with the run come from that model.

Faults: a hardware error during a pose is recovered from (servo alarm: reboot; controller reset or
watchdog trip: light back on and warmed up) and the pose retried, at most ``pose_retries`` times; then
the session ends cleanly with the error in the manifest's exit status. An *unsafe* controller status
(firmware_protocol/SPEC.md §4.6: E-stop, interlock, the light source over its temperature limit, a watchdog
trip after the light was switched on) is acted on before every move and after every capture
(:meth:`SessionRunner.check_devices`, :meth:`SessionRunner._stop_unsafe`): the light is commanded off, the pose
in flight is not kept, and the session stops with status ``safety stop: <cause>`` (exit code 7) and the
resume command; so does a servo's hardware alarm. A pose whose camera frames stay
bad (black, stale, all-saturated, wrong size: :mod:`gonio.pipeline.signal`) after the pipeline's retakes
and the pose retries is flagged, not stored (``RunResult.failed``), and the session goes on; it then ends
``incomplete`` (never ``completed``), and ``max_failed_in_a_row`` such poses stop it (a dead camera). A run most
of whose poses give nothing usable (every sample flagged NO_BOARD, saturated...; skipped; in a calibration, no
board pose or highlight) stops or ends ``unusable: ...`` naming the causes (:mod:`gonio.session.usability`).
A pose is appended only once,
whole, after it succeeded, so nothing measured is lost and nothing is duplicated. SIGINT (Ctrl-C)
finishes the pose in flight, marks the session ``interrupted`` and prints the command to resume.

Progress goes to stderr as one line with the ETA in *lab* time (the own small line instead of tqdm:
one line of logic, no extra dependency, and it has to show lab time, not tqdm's wall-clock rate).
"""

from __future__ import annotations

import math
import signal
import sys
import threading
import time
from dataclasses import dataclass, field
from typing import Callable, TextIO

import numpy as np

from gonio.errors import (ConfigError, EmergencyStop, GonioError, HardwareError, SafetyStop, ServoAlarm,
                          UnreachablePose)
from gonio.plan.labtime import SessionTiming, dark_exposures, session_lab_time
from gonio.rig.geocov import light_position_covariance
from gonio.rig.interfaces import Frame
from gonio.session.usability import Usability, sample_cause
from gonio.store.records import MAX_POSE

__all__ = ["RunnerSettings", "Devices", "RunResult", "SessionRunner", "PoseEvent", "open_devices", "format_lab_time",
           "SAFETY_STOP"]

#: The manifest's exit status of a session stopped for safety (``"safety stop: <cause>"``; exit code 7,
#: :class:`gonio.errors.SafetyStop`): an unsafe controller status or a servo alarm, a person must act
SAFETY_STOP = "safety stop"


@dataclass(frozen=True)
class PoseEvent:
    """One pose measured and stored (what :attr:`SessionRunner.on_pose` subscribers receive): its plan index,
    how many of the plan's poses are done, the samples appended (:class:`gonio.samples.SampleSet`), the pose's
    record meta (joints, exposures, photodiode, ...), the session's lab time so far and the cost model's
    estimate of the lab time left (s)."""

    index: int
    done: int
    total: int
    samples: object
    meta: dict
    lab_time: float
    eta: float


@dataclass(frozen=True)
class RunnerSettings:
    """Knobs of the runner (lab-time values in seconds, angles in degrees at this boundary)."""

    joint_tolerance_deg: float = 0.5  #: measured joint vs target, after settling
    move_retries: int = 2  #: re-issued moves when a joint is off target
    pose_retries: int = 3  #: recover-and-retry rounds per pose after a hardware error
    move_timeout: float = 60.0
    #: the lab-time cost model's values the runner spends (:mod:`gonio.plan.labtime`): warm-up step,
    #: dark frames per exposure, dark re-measurement age; the estimator uses the same object
    timing: SessionTiming = field(default_factory=SessionTiming)
    #: poses in a row whose frames stay bad before the session stops (a dead camera is not retried forever)
    max_failed_in_a_row: int = 3
    warmup_samples: int = 64  #: photodiode samples averaged per reading
    warmup_tolerance: float = 1e-3  #: relative change between readings that counts as stable
    warmup_max: float = 1800.0  #: give up (HardwareError) after this much warm-up
    light_level: float = 1.0


@dataclass
class Devices:
    """The opened hardware (real or simulated) a runner drives."""

    rig: object  #: gonio.rig.kinematics.Rig
    axes: object  #: gonio.rig.interfaces.Axes (DynamixelAxes)
    controller: object  #: gonio.rig.controller.RigController
    camera: object  #: gonio.rig.interfaces.Camera
    clock: object  #: gonio.rig.interfaces.Clock

    def close(self) -> None:
        """Switch the light off and release every device (each attempted, errors ignored)."""
        for dev in (self.controller, self.axes, self.camera):
            try:
                dev.close()
            except Exception:  # noqa: BLE001 - closing must release the rest whatever one device does
                pass


def open_devices(rig, servo_port: str, controller_port: str, camera, clock, *, latency_timer_ms: float = 50.0,
                 watchdog: float = 30.0, auto_recover: int = 0, scan_attempts: int = 4,
                 clear_alarms: bool = True, controller_timeout: float = 0.25) -> Devices:
    """Open the servo bus (scan: every joint's servo must answer; then configure) and the controller
    (handshake, watchdog period). ``watchdog`` must exceed the longest move plus settle, in lab seconds;
    ``controller_timeout`` is the controller's reply deadline (real seconds, before a retry).

    Servo alarms: a servo found with a hardware error when the session starts is rebooted
    (``clear_alarms``: a person started or resumed the session after the stop told them to remove the
    cause); an alarm during the session stops it (``auto_recover`` = 0: no reboot behind anyone's back)."""
    from gonio.rig.controller import RigController
    from gonio.rig.dynamixel import DynamixelAxes, DynamixelBus

    # the controller first: with the E-stop pressed or the enclosure open not one byte may go to a servo
    # (configuring them writes EEPROM, reboots an alarmed one and switches torque on)
    controller = RigController.open(controller_port, clock=clock, watchdog=watchdog, timeout=controller_timeout)
    try:
        what = controller.status().stop_reason
        if what:
            raise EmergencyStop(f"rig controller: {what}: release it and run the command again (nothing was sent "
                                "to the servos)", device="rig controller")
        bus = DynamixelBus(servo_port, rig.baud, latency_timer_ms=latency_timer_ms).open()
    except BaseException:
        controller.close()
        raise
    try:
        ids = [j.servo_id for j in rig.joints]
        faults: dict[int, str] = {}
        found = bus.scan(ids, attempts=scan_attempts, faults=faults)
        missing = [f"{j.name} (ID {j.servo_id}: {faults.get(j.servo_id, 'no answer')})"
                   for j in rig.joints if j.servo_id not in found]
        if missing:
            raise HardwareError(f"{servo_port}: servos not answering after {scan_attempts} pings each: "
                                f"{', '.join(missing)}", device=servo_port)
        axes = DynamixelAxes.from_rig(rig, bus, clock, auto_recover=auto_recover, clear_alarms=clear_alarms)
    except BaseException:
        bus.close()
        controller.close()
        raise
    return Devices(rig=rig, axes=axes, controller=controller, camera=camera, clock=clock)


def format_lab_time(seconds: float) -> str:
    """``h:mm:ss`` (or ``m:ss``) of a lab-time duration; ``unknown`` for one that is not a finite number (a
    duration read from a hand-edited file, an estimate that overflowed), never an exception."""
    try:
        seconds = float(seconds)
    except (TypeError, ValueError):
        return "unknown"
    if not math.isfinite(seconds):
        return "unknown"
    s = int(round(max(seconds, 0.0)))
    h, rem = divmod(s, 3600)
    m, s = divmod(rem, 60)
    return f"{h}:{m:02d}:{s:02d}" if h else f"{m}:{s:02d}"


def recovered_faults(devices) -> dict:
    """Hardware faults the devices recovered from in this run, as the manifest records them (``last_run``):
    ``servo_alarms_cleared`` (``{joint: Hardware Error Status}``, cleared by the start-up reboot) and
    ``controller_resets`` (re-handshakes after the rig controller reset); empty when there were none. A session
    whose rig needed them is not the same evidence as one whose rig did not."""
    out: dict = {}
    alarms = getattr(devices.axes, "cleared_alarms", None) or {}
    if alarms:
        out["servo_alarms_cleared"] = {str(k): int(v) for k, v in alarms.items()}
    resets = int(getattr(devices.controller, "resets_seen", 0) or 0)
    if resets:
        out["controller_resets"] = resets
    return out


@dataclass
class RunResult:
    """How a run ended and what it did."""

    #: "completed", "interrupted", "incomplete: ...", "unusable: ..." (:mod:`gonio.session.usability`), "error: ..."
    #: (the store's exit-status vocabulary)
    status: str
    measured: int = 0  #: poses appended in this run
    samples: int = 0  #: samples appended in this run
    skipped: list = field(default_factory=list)  #: (pose index, reason) of poses that could not be measured
    #: (pose index, reason) of poses whose frames had no usable signal after every retake (black, stale,
    #: all-saturated, wrong size): not stored; the session ends "incomplete" and resume measures them again
    failed: list = field(default_factory=list)
    lab_time: float = 0.0
    wall_time: float = 0.0
    timings: list = field(default_factory=list)  #: per-pose dicts of lab and wall seconds
    retries: int = 0
    error: GonioError | None = None
    estimated_lab_time: float | None = None  #: the cost model's estimate of this run, before it started
    exposure: dict = field(default_factory=dict)  #: mode and poses per bracket used
    recovered_faults: dict = field(default_factory=dict)  #: :func:`recovered_faults` of this run
    #: poses tried and the unusable ones by cause, over the session's runs up to this one
    #: (:class:`gonio.session.usability.Usability`)
    usability: dict = field(default_factory=dict)

    def summary(self) -> dict:
        """JSON-able summary for the manifest."""
        return {"status": self.status, "poses": self.measured, "samples": self.samples, "retries": self.retries,
                "lab_time_s": self.lab_time, "wall_time_s": self.wall_time,
                "estimated_lab_time_s": self.estimated_lab_time, "exposure": self.exposure,
                "skipped": [{"pose": k, "reason": r} for k, r in self.skipped],
                "failed": [{"pose": k, "reason": r} for k, r in self.failed],
                "recovered_faults": dict(self.recovered_faults), "usability": dict(self.usability)}

    @property
    def ok(self) -> bool:
        return self.status == "completed"


class _TimedCamera:
    """Camera proxy that adds up wall and lab time spent in ``capture`` (for the per-pose breakdown)."""

    def __init__(self, camera, clock):
        self._camera, self._clock = camera, clock
        self.wall = self.lab = 0.0
        self.frames = 0

    def capture(self, exposure: float, gain: float = 1.0, *, timeout: float = 10.0) -> Frame:
        w, t = time.perf_counter(), self._clock.now()
        try:
            return self._camera.capture(exposure, gain, timeout=timeout)
        finally:
            self.wall += time.perf_counter() - w
            self.lab += self._clock.now() - t
            self.frames += 1

    def close(self) -> None:
        self._camera.close()


class _Progress:
    """One status line on stderr: poses done, lab time, ETA in lab time."""

    def __init__(self, stream: TextIO | None, total: int):
        self.stream, self.total = stream, max(total, 1)
        self.tty = bool(stream is not None and getattr(stream, "isatty", lambda: False)())
        self.every = 1 if self.tty else max(1, total // 10)

    def update(self, done: int, lab: float, eta: float, note: str = "") -> None:
        if self.stream is None or (not self.tty and done % self.every and done != self.total):
            return
        line = (f"[{done:>{len(str(self.total))}}/{self.total}] {100 * done / self.total:3.0f}%  "
                f"lab {format_lab_time(lab)}  ETA {format_lab_time(eta)} lab{('  ' + note) if note else ''}")
        self.stream.write(("\r" + line + "\033[K") if self.tty else line + "\n")
        self.stream.flush()

    def close(self) -> None:
        if self.stream is not None and self.tty:
            self.stream.write("\n")
            self.stream.flush()


def _reading_times(times) -> dict:
    """The photodiode readings' timestamps for a pose's meta (docs/formats.md): per bracket frame, in
    capture order, the host clock's time (``time_s``, lab seconds), the controller's uptime (``uptime_s``,
    protocol ≥ 2.1, else null) and the sampling span (``span_s``); omitted where nothing is known."""
    out = {}
    for i, key in enumerate(("time_s", "uptime_s", "span_s")):
        vals = [None if t[i] is None else float(t[i]) for t in times]
        if any(v is not None for v in vals):
            out[key] = vals
    return out


class SessionRunner:
    """Run ``plan`` into ``store`` on ``devices``; see the module docstring.

    Parameters
    ----------
    plan : gonio.plan.Plan
    store : gonio.store.directory.SessionStore (``append``, ``done_poses``, ``remaining``, ``finish``)
    devices : Devices
    calibration, layout : what the pipeline needs (gonio.pipeline.target)
    settings : RunnerSettings
    before_pose : callable(pose index), optional
        Called right before a pose is captured (logging; the simulator reseeds its camera noise here).
    resume_command : str
        Printed when the session is interrupted or ends on a fault.
    stream : where progress and messages go (stderr; None = silent)
    """

    def __init__(self, plan, store, devices: Devices, calibration, layout, *, settings: RunnerSettings | None = None,
                 before_pose: Callable[[int], None] | None = None, resume_command: str = "",
                 stream: TextIO | None = sys.stderr, pipeline_settings=None):
        from gonio.pipeline.acquire import Pipeline, PipelineSettings
        from gonio.pipeline.exposure import CapturePlan

        self.plan, self.store, self.dev = plan, store, devices
        self.settings = st = settings or RunnerSettings()
        self.before_pose = before_pose
        self.resume_command = resume_command
        self.stream = stream
        self.clock = devices.clock
        self.camera = _TimedCamera(devices.camera, self.clock)
        from dataclasses import replace

        cap = plan.capture
        self.timing = st.timing
        #: every exposure the session may capture (the bracket, or the auto-exposure ladder): its dark set
        self.dark_exposures = dark_exposures(cap, self.timing)
        # the runner schedules the dark set (one light-off for all of it); the cache never refreshes alone
        ps = pipeline_settings or PipelineSettings(light_level=st.light_level, gain=cap.gain)
        ps = replace(ps, dark_max_age=math.inf, dark_frames=st.timing.dark_frames)
        if cap.auto_exposure:
            ps = replace(ps, exposure=replace(ps.exposure, ladder=self.dark_exposures),
                         initial_exposure=cap.exposures[0])
        self.pipeline = Pipeline(self.camera, calibration, layout, light=devices.controller, clock=self.clock,
                                 settings=ps)
        #: the fixed bracket, or None: chosen per pose (automatic exposure)
        self.bracket = None if cap.auto_exposure else CapturePlan(tuple(cap.exposures),
                                                                  (cap.frames,) * len(cap.exposures), cap.gain)
        self._darks_at: float | None = None
        #: lab seconds the session spent before this run (earlier runs, earlier adaptive rounds): the progress
        #: line shows the session's lab time, not this run's
        self.lab_offset = 0.0
        self._stop = threading.Event()
        self._interrupts = 0
        #: the board pose of the last stored pose and where its camera was (:meth:`_board_entry`), and whether it
        #: must be confirmed (it comes from an earlier run): reused while the camera stays put (:meth:`_measure`)
        self._board_prev: tuple[bytes, object, bool, int | None] | None = None
        #: called with a :class:`PoseEvent` after each pose is stored (a notebook's live plot, a progress bar);
        #: returning False stops the session after that pose (as Ctrl-C does: ``interrupted``, resumable); an
        #: exception it raises is said in one line and does not stop the session
        self.on_pose: Callable[[PoseEvent], None] | None = None
        self._light_used = False  #: this run switched the light on (a watchdog trip is then unsafe)
        #: a sphere: the stored poses' silhouette centres by pose index (:meth:`_stored_sphere_centres`); else None
        self._sphere_history: dict | None = None
        #: a sphere: where each pose's per-pixel samples are kept (``--keep-pixels``, gonio.sphere.pose); None: not
        self.keep_pixels_dir = None

    # -- messages -------------------------------------------------------------------------------
    def _say(self, msg: str) -> None:
        if self.stream is not None:
            self.stream.write(msg + "\n")
            self.stream.flush()

    # -- device checks and warm-up --------------------------------------------------------------
    def check_devices(self) -> None:
        """No unsafe controller status (firmware_protocol/SPEC.md §4.6): E-stop and interlock clear
        (:class:`EmergencyStop` otherwise), the light source under its temperature limit, and — once this run
        switched the light on — no watchdog trip (:class:`SafetyStop`). A trip left by an earlier host session
        is history: the next switch-on clears it."""
        st = self.dev.controller.status()
        what = st.stop_reason
        if what:
            raise EmergencyStop(f"rig controller: {what}: release it, then resume", device="rig controller")
        what = st.unsafe_reason(self._light_used)
        if what:
            raise SafetyStop(f"rig controller: {what}, then resume", device="rig controller")

    def _stop_unsafe(self, exc: SafetyStop, result: "RunResult") -> None:
        """Act on an unsafe status or a safety stop (SPEC.md §4.6): the light commanded off (the controller has
        cut it; the host's record becomes "off" so nothing switches it back on), and the run's status
        ``safety stop: <cause>`` naming the actual cause; the caller keeps nothing of the pose in flight."""
        exc = self._precise(exc)
        try:
            self.dev.controller.set_light(False, 0.0)
        except Exception:  # noqa: BLE001 - the stop stands whatever the controller does; closing retries it
            pass
        result.status, result.error = f"{SAFETY_STOP}: {exc}", exc

    def safety_check(self) -> None:
        """Before every move: the controller's E-stop and interlock (first: after an E-stop not one byte
        goes to a servo), then every servo's Hardware Error Status (over-temperature, overload, input
        voltage, electrical shock, encoder). Either stops the session (:class:`SafetyStop`, no retry)."""
        from gonio.rig.dynamixel import describe_hardware_error

        self.check_devices()
        alarms_of = getattr(self.dev.axes, "alarms", None)
        alarms = alarms_of() if callable(alarms_of) else {}
        if alarms:
            name, bits = next(iter(alarms.items()))
            raise SafetyStop(f"servo of joint {name}: {describe_hardware_error(bits)} (Hardware Error Status "
                             f"0x{bits:02X}): remove the cause (load, heat, supply), then resume", device=name)

    def _precise(self, exc: SafetyStop) -> SafetyStop:
        """A command the controller refused (E-stop *or* interlock) restated with the actual cause."""
        if not isinstance(exc, EmergencyStop):
            return exc
        try:
            self.check_devices()
        except SafetyStop as precise:
            return precise
        except HardwareError:
            pass
        return exc

    def warm_up(self) -> float:
        """Switch the light on and wait (lab time, watchdog fed) as the timing's ``warmup`` says.

        ``"corrected"``: one photodiode reading must see the light (above 4 standard uncertainties of a
        reading), then ``warmup_min`` seconds; the drift that follows is corrected frame by frame from the
        photodiode (:mod:`gonio.pipeline.hdr`). ``"stable"``: until ``|p_k − p_{k−1}| ≤ tol · p_k`` for two
        readings ``warmup_step`` apart, both above 4 standard uncertainties. Returns the lab seconds spent."""
        st, ctl = self.settings, self.dev.controller
        t0 = self.clock.now()
        ctl.set_light(True, st.light_level)
        self._light_used = True  # from now on a watchdog trip is this run's: unsafe (SPEC.md §4.6)
        if st.timing.warmup == "corrected":
            p, u = ctl.read_photodiode(st.warmup_samples)
            if p <= 4 * u:
                raise HardwareError(f"light: photodiode reads {p:g} ± {u:g} after switching on: the light is off "
                                    "or failed", device="light")
            if st.timing.warmup_min > 0:
                ctl.wait(st.timing.warmup_min)
            return self.clock.now() - t0
        prev = None
        for _ in range(int(math.ceil(st.warmup_max / st.timing.warmup_step)) + 1):  # bounded
            p, u = ctl.read_photodiode(st.warmup_samples)
            if p <= 4 * u:
                raise HardwareError(f"light: photodiode reads {p:g} ± {u:g} after switching on: the light is off "
                                    "or failed", device="light")
            if prev is not None and abs(p - prev) <= max(st.warmup_tolerance * p, 2 * u):
                return self.clock.now() - t0
            prev = p
            if self.clock.now() - t0 >= st.warmup_max:
                break
            ctl.wait(st.timing.warmup_step)
        raise HardwareError(f"light: not stable after {st.warmup_max:g} s of warm-up (photodiode {prev:g})",
                            device="light")

    # -- one pose -------------------------------------------------------------------------------
    def _move(self, index: int) -> tuple[dict, dict]:
        """Solve nearest the current joints, move, settle, verify; returns (target, measured)."""
        axes, ctl, st = self.dev.axes, self.dev.controller, self.settings
        self.safety_check()
        current = axes.positions()
        target = self._target(index, current)
        tol = math.radians(st.joint_tolerance_deg)
        for attempt in range(st.move_retries + 1):
            if attempt:
                self.safety_check()
            # no HEARTBEAT here: safety_check's STATUS request just fed the watchdog (every accepted frame
            # feeds it, firmware_protocol/SPEC.md "Watchdog"), which open_devices sets longer than a move
            axes.move_to(target, timeout=st.move_timeout)
            ctl.wait(self.plan.capture.settle)  # settle with the watchdog fed
            measured = axes.positions()
            off = {n: measured[n] - target[n] for n in target if abs(measured[n] - target[n]) > tol}
            if not off:
                return target, measured
        worst = max(off, key=lambda n: abs(off[n]))
        raise HardwareError(f"joint {worst}: at {math.degrees(measured[worst]):.2f} deg after "
                            f"{st.move_retries + 1} moves, target {math.degrees(target[worst]):.2f} deg "
                            f"(tolerance {st.joint_tolerance_deg:g} deg)", device=worst)

    def _target(self, index: int, current) -> dict:
        """Joint angles (by name) of pose ``index``: the kinematics' solution nearest ``current``
        (:class:`~gonio.errors.UnreachablePose` if none)."""
        return self.dev.rig.solve(*self.plan.poses[index], current=current)

    def _refresh_darks(self) -> bool:
        """Measure the whole dark set (every exposure the session may use) if it was never measured, or
        when older than ``dark_max_age``: again (``darks="measured"``) or, with ``darks="model"``, fit the
        per-pixel dark model to the first set and afterwards check it with ``dark_check_frames`` light-off
        frames at the set's longest exposure. Then warm the light up again (switching it off restarts it)."""
        now, tm = self.clock.now(), self.settings.timing
        if self._darks_at is not None and now - self._darks_at <= tm.dark_max_age:
            return False
        self._darks_at = now
        darks, gain = self.pipeline.darks, self.plan.capture.gain
        if tm.darks == "model" and darks.model is not None:
            darks.check(max(self.dark_exposures), gain, tm.dark_check_frames)  # one short light-off period
        else:
            darks.refresh(self.dark_exposures, gain)  # one light-off period
            if tm.darks == "model":
                darks.fit_model(gain)
        self.warm_up()  # switching the light off and on restarts its warm-up
        return True

    @staticmethod
    def _camera_key(planned_pose, measured_pose) -> bytes:
        """Where the camera is relative to the sample, as bytes: the planned and the measured camera pose
        (``(position, R)`` of :meth:`Rig.camera_pose`, sample frame: the camera arm's joints and a turntable's). Two
        poses with the same key have the camera's servos at the same goal and the same encoder readings: the
        camera has not moved."""
        return b"".join(np.ascontiguousarray(p, dtype=np.float64).tobytes() for p in (*planned_pose, *measured_pose))

    def _board_entry(self, meta, confirm: bool) -> tuple[bytes, object, bool, int | None] | None:
        """What a stored pose's ``meta`` lets the next pose reuse: ``(camera key, board pose, confirm, origin)``, the
        board pose rebuilt from its record (``board_pose``, docs/formats.md) — the very bits a resumed run reads back
        from the file; None without a usable one (no board, an older session, not this rig's joints, not numbers).
        ``confirm``: it comes from an earlier run (the rig may have been stopped, moved or touched since).
        ``origin``: the pose whose metering frame the board pose was found in (``board_from``; None if the record
        does not say: a session written before that field)."""
        from gonio.pipeline.markers import BoardPose

        if not isinstance(meta, dict) or not isinstance(meta.get("board_pose"), dict):
            return None
        rig = self.dev.rig
        try:
            planned = rig.as_array({k: float(v) for k, v in meta["target_joints_rad"].items()})
            measured = rig.as_array({k: float(v) for k, v in meta["joints_rad"].items()})
        except (KeyError, TypeError, ValueError, AttributeError, ConfigError):
            return None
        board = BoardPose.from_record(meta["board_pose"])
        origin = meta.get("board_from")
        origin = origin if isinstance(origin, int) and not isinstance(origin, bool) and 0 <= origin <= MAX_POSE else None
        return None if board is None else (self._camera_key(rig.camera_pose(planned), rig.camera_pose(measured)),
                                           board, confirm, origin)

    def _stored_sphere_centres(self) -> dict | None:
        """A sphere session: the stored poses' silhouette centres (``sphere_centre`` of their metas) by pose index,
        read back from the file — what a resumed run continues from; None for a flat sample."""
        if getattr(self.pipeline.layout, "sphere", None) is None:
            return None
        from gonio.store.directory import _samples_path, scan_samples

        path = _samples_path(self.store.directory, self.store.manifest)
        if not path.exists():
            return {}
        return {int(k): {"sphere_centre": m["sphere_centre"]} for k, (_, m) in scan_samples(path).records.items()
                if isinstance(m, dict) and isinstance(m.get("sphere_centre"), dict)}

    def _dark_meta(self) -> dict:
        """The dark model's state for the pose's meta (modelled darks only): scale k of the dark current
        and the sensor temperature it was predicted at."""
        dc = self.pipeline.darks
        if dc.model is None:
            return {}
        k, u = dc.model.scale(dc.temperature)
        return {"dark_model": {"k": k, "u_k": u, "sensor_temp_c": dc.temperature,
                               "doubling_c": dc.model.doubling_c, "checks": len(dc.model.checks)}}

    def _measure(self, index: int) -> tuple:
        from gonio.pipeline.target import CameraPose

        rig = self.dev.rig
        w0, l0 = time.perf_counter(), self.clock.now()
        target, measured = self._move(index)
        w1, l1 = time.perf_counter(), self.clock.now()
        darks = self._refresh_darks()
        w2, l2 = time.perf_counter(), self.clock.now()
        if self.before_pose is not None:
            self.before_pose(index)
        joints, planned = rig.as_array(measured), rig.as_array(target)
        position, R = rig.camera_pose(joints)
        planned_pose = rig.camera_pose(planned)
        # the camera has not moved since the last stored pose (same goal, same encoder readings): its board pose
        # stands, the board is not searched again (confirmed once when it comes from an earlier run)
        key = self._camera_key(planned_pose, (position, R))
        prev = self._board_prev if self._board_prev is not None and self._board_prev[0] == key else None
        cam_w, cam_l, frames = self.camera.wall, self.camera.lab, self.camera.frames
        if self._sphere_history is not None:  # the centre found by the poses stored so far (gonio.sphere.pose)
            self.pipeline.sphere_history = [self._sphere_history[k] for k in sorted(self._sphere_history)]
        lcov = light_position_covariance(rig, joints)  # the geometric calibration's, at this pose (or None)
        # meter every pose at the expected bracket's shortest exposure, not at the previous pose's: a pose's
        # bracket then depends on the pose only, so a resumed session measures what an uninterrupted one does
        res = self.pipeline.measure(rig.light_position(joints), pose_index=index,
                                    camera_pose_hint=CameraPose(R, -R @ position), plan=self.bracket,
                                    meter_exposure=self.plan.capture.exposures[0],
                                    nominal=(planned_pose[0], rig.light_position(planned)),
                                    board=None if prev is None else prev[1],
                                    confirm_board=prev is not None and prev[2],
                                    light_cov=lcov)
        self.check_devices()  # an E-stop during the capture: the frames are not of a lit sample, keep nothing
        w3, l3 = time.perf_counter(), self.clock.now()
        capture_wall = self.camera.wall - cam_w
        timing = {"move_lab": l1 - l0, "move_wall": w1 - w0, "dark_lab": l2 - l1, "dark_wall": w2 - w1,
                  "capture_lab": l3 - l2, "capture_wall": capture_wall, "pipeline_wall": (w3 - w2) - capture_wall,
                  "frames": self.camera.frames - frames, "camera_lab": self.camera.lab - cam_l}
        pd = np.asarray(res.light, dtype=np.float64)
        meta = {
            "pose_rad": [float(a) for a in self.plan.poses[index]],
            "target_joints_rad": {k: float(v) for k, v in target.items()},
            "joints_rad": {k: float(v) for k, v in measured.items()},
            "exposures_s": [float(t) for t in res.plan.exposures],
            "frames": [int(n) for n in res.plan.frames],
            "auto_exposure": self.bracket is None,
            "gain": float(res.plan.gain),
            "photodiode": {"mean": float(pd.mean()) if pd.size else None,
                           "min": float(pd.min()) if pd.size else None, "max": float(pd.max()) if pd.size else None,
                           **_reading_times(res.light_times)},
            "board_found": res.board is not None,
            "board_pose": None if res.board is None else res.board.to_record(),
            "board_source": res.board_source,
            # the pose whose metering frame gave the board pose: samples of poses with the same board_from share
            # its pose error (their camera-pose uncertainty is one draw, not independent ones)
            "board_from": (None if res.board is None else
                           prev[3] if res.board_source in ("reused", "confirmed") else int(index)),
            # covariance (m²) of the light's position from the rig file's calibration (gonio.rig.geocov): part of
            # every sample's sigma_pose
            "light_cov_m2": None if lcov is None else np.asarray(lcov).tolist(),
            "darks_refreshed": darks,
            **self._dark_meta(),
            "lab_time_s": float(self.clock.now()),
            "run_lab_time_s": float(self.clock.now() - self._lab0),  # lab time of this run so far
            "timing": timing,
        }
        if res.sphere_counts is not None:  # a sphere's pose: its pixels used and rejected (gonio.sphere.pixels)
            counts = dict(res.sphere_counts)
            centre = counts.pop("centre", None)
            meta["sphere_centre_used"] = counts.pop("centre_used", None)  # the centre its samples used, and σ
            meta["sphere_pixels"] = counts
            if centre is not None:  # the centre this pose's silhouette says (gonio.sphere.refine)
                meta["sphere_centre"] = centre
            if self.keep_pixels_dir is not None and res.sphere_frame is not None:
                from gonio.sphere.pose import save_pixels

                save_pixels(self.keep_pixels_dir, index, res.sphere_frame)
        return res.samples, meta, timing

    def _recover(self, exc: HardwareError) -> None:
        """Best effort before retrying a pose: clear servo alarms, light back on and warm."""
        ctl = self.dev.controller
        if isinstance(exc, ServoAlarm) or "torque is off" in str(exc):
            self.dev.axes.recover()
        self.check_devices()  # an unsafe status is never recovered from behind a person's back (SafetyStop)
        status = ctl.status()  # re-handshakes if the controller reset (NOT_READY)
        if not status.light_on:
            self.warm_up()

    # -- the session ----------------------------------------------------------------------------
    def _on_sigint(self, signum, frame) -> None:
        self._interrupts += 1
        if self._interrupts > 1:
            raise KeyboardInterrupt  # second Ctrl-C: stop now (the store holds every finished pose)
        self._stop.set()
        what = "terminated" if signum == signal.SIGTERM else "interrupt"
        self._say(f"\n{what}: finishing the pose in flight (Ctrl-C again to stop at once)")

    def request_stop(self) -> None:
        """Stop after the pose in flight (what SIGINT does)."""
        self._stop.set()

    def run(self) -> RunResult:
        """Measure every remaining pose; always ends with ``store.finish(status)``."""
        wall0, lab0 = time.perf_counter(), self.clock.now()
        self._lab0 = lab0
        remaining = [int(k) for k in self.store.remaining(self.plan)]
        done = set(int(k) for k in self.store.done_poses())
        result = RunResult(status="completed")
        # poses that gave nothing usable, by cause (gonio.session.usability), counted over the session's runs: a
        # resume goes on from the last run's counts (a session is judged whole, not one short resume at a time)
        entry = getattr(self.store, "manifest_entry", None)  # the stored field itself: read here, never changed
        last = entry("last_run") if entry is not None else (getattr(self.store, "manifest", None) or {}).get("last_run")
        usable = Usability.from_dict(last.get("usability") if isinstance(last, dict) else None)
        total = len(self.plan)
        progress = _Progress(self.stream, total)
        todo = [k for k in remaining if k not in done]
        ends = self._predict(todo)
        result.estimated_lab_time = float(ends[-1]) if len(ends) else 0.0
        brackets: dict[str, int] = {}
        if self._board_prev is None:
            self._board_prev = self._board_entry(getattr(self.store, "last_meta", None), confirm=True)
        self._sphere_history = self._stored_sphere_centres()
        old_handler = old_term = None
        if threading.current_thread() is threading.main_thread():
            old_handler = signal.signal(signal.SIGINT, self._on_sigint)
            # SIGTERM (kill, timeout, a service manager) stops the same clean way: the pose in flight
            # finished, the light switched off, the run recorded as interrupted with its resume command
            old_term = signal.signal(signal.SIGTERM, self._on_sigint)
        try:
            try:
                self.check_devices()
                t_warm = self.clock.now()
                if self._refresh_darks():  # darks first (light off), then one warm-up; still fresh: nothing to say
                    light = ("stable after" if self.timing.warmup == "stable" else
                             "on (drift corrected from the photodiode) after")
                    self._say(f"darks measured ({len(self.dark_exposures)} exposures"
                              f"{', modelled' if self.timing.darks == 'model' else ''}), light {light} "
                              f"{format_lab_time(self.clock.now() - t_warm)} lab")
                n_todo = failed_run = 0
                for k in remaining:
                    if self._stop.is_set():
                        result.status = "interrupted"
                        break
                    if k in done:
                        continue
                    samples, meta, timing = self._pose_with_retries(k, result)
                    if samples is None:
                        self._board_prev = None  # the camera may have moved: search the board again
                        lost = [r for j, r in result.skipped[-1:] + result.failed[-1:] if j == k]
                        usable.add(lost[0] if lost else "not measured")
                        stop = usable.should_stop()
                        if stop:
                            result.status = stop
                            break
                        failed_run = failed_run + 1 if result.failed and result.failed[-1][0] == k else 0
                        if failed_run >= self.settings.max_failed_in_a_row:
                            raise HardwareError(f"camera: {failed_run} poses in a row without a usable frame "
                                                f"({result.failed[-1][1]}): check the camera and the light",
                                                device="camera")
                        continue
                    failed_run = 0
                    self.store.append(k, samples, meta)
                    usable.add(self.unusable_cause(samples, meta))
                    self._board_prev = self._board_entry(meta, confirm=False)  # what the next pose may reuse
                    if self._sphere_history is not None and isinstance(meta.get("sphere_centre"), dict):
                        self._sphere_history[k] = {"sphere_centre": meta["sphere_centre"]}
                    done.add(k)
                    result.measured += 1
                    result.samples += len(samples)
                    result.timings.append(timing)
                    key = ",".join(f"{t:g}x{f}" for t, f in zip(meta["exposures_s"], meta["frames"]))
                    brackets[key] = brackets.get(key, 0) + 1
                    n_todo += 1
                    # ETA: the cost model's remaining time from this pose on (gonio.plan.labtime)
                    eta = float(ends[-1] - ends[min(n_todo, len(ends)) - 1]) if len(ends) else 0.0
                    progress.update(len(done), self.lab_offset + self.clock.now() - lab0, eta)
                    self._notify(PoseEvent(k, len(done), total, samples, meta,
                                           self.lab_offset + self.clock.now() - lab0, eta))
                    stop = usable.should_stop()
                    if stop:  # a session that cannot succeed stops instead of measuring on
                        result.status = stop
                        break
                else:
                    if self._stop.is_set():
                        result.status = "interrupted"
                    elif usable.final_status():  # never "completed" when most poses gave nothing usable
                        result.status = usable.final_status()
                    elif result.failed:  # never "completed" with poses whose frames were bad
                        result.status = (f"incomplete: {len(result.failed)} poses not measured (bad camera frames: "
                                         f"{result.failed[0][1]})")
            except SafetyStop as exc:
                self._stop_unsafe(exc, result)
            except HardwareError as exc:
                result.status, result.error = f"error: {exc}", exc
            except KeyboardInterrupt:
                result.status = "interrupted"
            except BaseException as exc:  # a bug or a store error: never record such a session as completed
                result.status, result.error = f"error: {type(exc).__name__}: {exc}", exc
                raise
        finally:
            progress.close()
            if old_handler is not None:
                signal.signal(signal.SIGINT, old_handler)
            if old_term is not None:
                signal.signal(signal.SIGTERM, old_term)
            result.lab_time = self.clock.now() - lab0
            result.wall_time = time.perf_counter() - wall0
            result.recovered_faults = recovered_faults(self.dev)
            result.usability = usable.to_dict()
            result.exposure = {"mode": "fixed" if self.bracket is not None else "auto",
                               "dark_exposures_s": list(self.dark_exposures), "poses_per_bracket": brackets}
            self.store.finish(result.status, last_run=result.summary())
        if result.status != "completed" and self.resume_command:
            self._say(f"session {result.status.split(':')[0]}: {result.measured} poses measured in this run; "
                      f"resume with:\n  {self.resume_command}")
        return result

    def _notify(self, event: PoseEvent) -> None:
        if self.on_pose is None:
            return
        try:
            if self.on_pose(event) is False:
                self.request_stop()
        except Exception as exc:  # noqa: BLE001 - a subscriber's bug must not stop a measurement
            print(f"gonio: warning: pose {event.index}: the on_pose callback failed ({type(exc).__name__}: "
                  f"{str(exc)[:120]}); the pose is stored", file=self.stream or sys.stderr, flush=True)

    def unusable_cause(self, samples, meta) -> str | None:
        """Why a stored pose gave nothing usable (``None``: it did): no sample without a flag
        (:func:`gonio.session.usability.sample_cause`)."""
        return sample_cause(samples)

    def _predict(self, todo) -> np.ndarray:
        """Cost-model lab time at the end of each pose of ``todo`` from the start of this run (start-up
        darks and warm-up included), moves from the current joints; zeros if the model cannot say."""
        from gonio.plan import plan_move_times

        if not todo:
            return np.zeros(0)
        try:
            cur = self.dev.axes.positions()
            start = self.dev.rig.as_array(cur)
            moves = plan_move_times(self.plan, self.dev.rig, start=start, indices=todo)
        except Exception:  # noqa: BLE001 - the ETA must never stop a session
            moves = np.zeros(len(todo))
        return session_lab_time(moves, self.plan.capture, self.timing).ends

    def _pose_with_retries(self, k: int, result: RunResult):
        """``(samples, meta, timing)`` of pose ``k`` or ``(None, None, None)`` if it cannot be measured."""
        from gonio.pipeline.acquire import BoardNotFound
        from gonio.pipeline.hdr import BadFrame

        last: HardwareError | None = None
        for attempt in range(self.settings.pose_retries + 1):
            try:
                if attempt:
                    result.retries += 1
                    self._board_prev = None  # a recovery may have moved the servos: search the board again
                    self._recover(last)
                samples, meta, timing = self._measure(k)
                meta["attempts"] = attempt + 1
                return samples, meta, timing
            except (SafetyStop, ServoAlarm):  # a person must look at it: no retry, no reboot
                raise
            except (UnreachablePose, BoardNotFound, ConfigError) as exc:
                result.skipped.append((k, str(exc)))
                self._say(f"pose {k}: skipped: {exc}")
                return None, None, None
            except HardwareError as exc:
                last = exc
                self._say(f"pose {k}: {exc} (attempt {attempt + 1} of {self.settings.pose_retries + 1})")
        if isinstance(last, BadFrame):  # retaken and retried: flag the pose, store nothing, go on
            result.failed.append((k, str(last)))
            self._say(f"pose {k}: not measured: {last}")
            return None, None, None
        raise last  # type: ignore[misc]
