"""Run the instrument from Python: measure a plan on an opened rig, resume a session, watch it pose by pose.

The command line (``gonio measure``, ``gonio resume``, ``gonio calibrate``) is a thin shell over these functions::

    import gonio
    with gonio.open_rig(sim=True) as rig:                       # or the rig's files and ports
        result = gonio.measure(rig, "half_diff", "my-session",
                               on_pose=lambda ev: print(ev.index, ev.lab_time))
    if not result.ok:                                            # interrupted (Ctrl-C), a fault, bad frames
        result = gonio.resume("my-session")
    fit = gonio.fit(gonio.load("my-session"), "lambert+ggx")

A session is a directory (:mod:`gonio.store.directory`): created by :func:`measure` with a manifest saying what,
why and how (plan, rig, material, target, camera, simulator or hardware), appended one pose at a time, and ended
with its exit status. Ctrl-C and SIGTERM finish the pose in flight, switch the light off and record the session
as ``interrupted`` (the runner's signal handlers, when called from the main thread); :func:`resume` measures the
poses left. Calibration sessions (``gonio calibrate``) and adaptive sessions run through the same
:func:`run_session`.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, TextIO

from gonio.errors import ConfigError, DataError
from gonio.session.options import TimingOptions, check_exposures, check_session_dir, default_session_dir
from gonio.session.recording import check_plan_against_records, store_timing
from gonio.session.rigs import OpenRig, open_rig, open_rig_from_manifest
from gonio.session.runner import PoseEvent
from gonio.session.usability import STATUS_PREFIX as UNUSABLE_PREFIX, UNUSABLE_EXIT

__all__ = ["measure", "resume", "run_session", "SessionResult", "PoseEvent", "open_rig", "INCOMPLETE_EXIT",
           "make_session_plan"]

#: Exit code of a session that ended with poses not measured (bad camera frames): not 0, not an error's.
INCOMPLETE_EXIT = 6


@dataclass
class SessionResult:
    """How a session run ended (what :func:`measure` and :func:`resume` return).

    ``status`` is the store's exit status (``completed``, ``interrupted``, ``incomplete: ...``,
    ``error: ...``); ``run`` the runner's result of this run (:class:`gonio.session.runner.RunResult`, or the
    adaptive session's :class:`~gonio.session.adaptive.AdaptiveSessionResult`; None when nothing was left to
    measure); ``poses_done``/``poses_total``/``samples_total`` count the whole session."""

    directory: Path
    status: str
    run: object = None
    poses_done: int = 0
    poses_total: int = 0
    samples_total: int = 0
    simulated: bool = True
    kind: str = "plan"  #: ``plan``, ``adaptive`` or ``calibration``
    manifest: dict = field(default_factory=dict, repr=False)  #: the manifest at the end
    rig: object = field(default=None, repr=False)  #: the rig's kinematics (:class:`gonio.rig.kinematics.Rig`)
    recovered_faults: dict = field(default_factory=dict)  #: servo alarms cleared, controller resets
    nothing_to_resume: bool = False  #: :func:`resume` of a session whose poses were all measured

    @property
    def ok(self) -> bool:
        return self.status == "completed"

    @property
    def exit_code(self) -> int:
        """The command line's exit status for this outcome: 0, 130 (interrupted), 6 (incomplete: bad frames),
        8 (unusable: most poses gave nothing usable, :mod:`gonio.session.usability`), the fault's own code, or 3."""
        if self.ok:
            return 0
        if self.status == "interrupted":
            return 130
        if self.status.startswith("incomplete"):
            return INCOMPLETE_EXIT
        if self.status.startswith(UNUSABLE_PREFIX):
            return UNUSABLE_EXIT
        err = getattr(self.run, "error", None)
        return err.exit_code if err is not None else 3

    @property
    def lab_time(self) -> float:
        """Lab seconds of this run (simulated time on the simulated rig)."""
        return float(getattr(self.run, "lab_time", 0.0) or 0.0)

    def load(self):
        """The session's data as :func:`gonio.load` reads it (:class:`gonio.io.source.Measured`)."""
        from gonio.io.source import load_source

        return load_source(self.directory)


def make_session_plan(plan, rig, *, seed: int = 0):
    """A :class:`gonio.plan.Plan` from what a script gives: a Plan, a generator name (its default parameters,
    ``gonio plan`` lists them) or a saved plan file (``gonio plan NAME --out PLAN.json``, or a session directory:
    the plan it ran), solved on ``rig``."""
    from gonio.plan.plan import Plan

    if isinstance(plan, Plan):
        return plan
    if isinstance(plan, (str, Path)) and (str(plan).endswith(".json") or Path(plan).is_dir()):
        from gonio.io.plan_file import read_plan_file

        return read_plan_file(str(plan), rig)
    if isinstance(plan, str):
        from gonio.plan.generators import GENERATORS, make_plan

        if plan not in GENERATORS:
            raise ConfigError.field("--plan", "plan", plan, f"unknown plan; known: {', '.join(GENERATORS)}")
        return make_plan(plan, rig=rig, seed=seed, source="--plan")
    raise ConfigError(f"plan = {str(plan)[:60]!r}: expected a Plan, a plan name or a plan file")


def _command() -> list | None:
    return ["gonio", *sys.argv[1:]] if sys.argv and sys.argv[0].endswith(("gonio", "main.py")) else None


def measure(rig: OpenRig, plan, out: str | Path | None = None, *, seed: int | None = None,
            timing: TimingOptions | dict | None = None, adaptive: dict | None = None, geocal: dict | None = None,
            on_pose: Callable[[PoseEvent], None] | None = None, on_start: Callable[[object, object], None] | None = None,
            progress: TextIO | bool | None = True, out_option: str = "--out", keep_pixels: bool = False
            ) -> SessionResult:
    """Measure ``plan`` on the opened ``rig`` into the new session directory ``out``.

    Parameters
    ----------
    rig : :class:`OpenRig` from :func:`open_rig`.
    plan : a :class:`gonio.plan.Plan`, a generator name (``"half_diff"``, ``"in_plane"``, ...: its defaults) or a
        plan file / session directory whose plan is measured again.
    out : the new session directory (refused in one line if it holds a session; default
        ``./gonio-session-DATE-TIME``).
    seed : the plan ordering's seed, recorded (default: the simulator's seed, else 0).
    timing : :class:`TimingOptions` (the light and dark strategy).
    adaptive, geocal : an adaptive session's or a calibration session's manifest entry (the commands make them).
    on_pose : called with a :class:`PoseEvent` after each pose is stored.
    on_start : called with ``(store, plan)`` once the session directory exists, before the first move.
    progress : where the progress line and the runner's notes go: True (default) stderr, a stream, or None/False
        (silent).
    keep_pixels : a sphere target: keep each pose's per-pixel samples (with each pixel's footprint of normals) in
        ``out/pixels/pose-NNNNN.npz`` (:func:`gonio.sphere.pose.load_pixels`), recorded so a resume keeps them too.

    Returns a :class:`SessionResult`; the devices stay open (close the rig, or leave its ``with`` block).

    >>> with open_rig(sim=True) as rig:                                        # doctest: +SKIP
    ...     r = measure(rig, "in_plane", "s", progress=None)
    >>> r.ok, r.poses_done == r.poses_total                                    # doctest: +SKIP
    (True, True)
    """
    from gonio.store.directory import SessionStore

    out = str(out) if out is not None else default_session_dir()
    plan = make_session_plan(plan, rig.rig, seed=seed or 0)
    check_session_dir(out, option=out_option)
    if rig.exposure_range is not None:
        check_exposures(plan, rig.exposure_range, rig.camera_label)
    if seed is None:
        seed = int((rig.record.get("sim") or {}).get("seed", 0))
    manifest = {"mode": rig.mode if rig.mode != "mixed" else "hardware", "command": _command(), "seed": seed,
                "plan": plan, **{k: v for k, v in rig.record.items() if k != "mode"}}
    t = timing.as_dict() if isinstance(timing, TimingOptions) else dict(timing or {})
    if t:
        manifest["timing"] = t
    if adaptive is not None:
        manifest["adaptive"] = adaptive
    if geocal is not None:
        manifest["geocal"] = geocal
    if keep_pixels:
        manifest["keep_pixels"] = True
    manifest = _ordered(manifest)
    store = SessionStore.create(out, manifest)
    if on_start is not None:
        on_start(store, plan)
    return run_session(store, plan, rig, on_pose=on_pose, progress=progress)


#: The manifest's keys in the order a session has always written them (a reader sees what/why/how first).
_ORDER = ("mode", "command", "seed", "plan", "rig", "material", "target", "timing", "adaptive", "sim", "hardware",
          "calibration", "detector", "detector_solid_angle_sr", "geocal")


def _stream(progress):
    """The stream of ``progress``: True → the current ``sys.stderr`` (looked up at call time), None/False → None."""
    if progress is True:
        return sys.stderr
    return progress or None


def _ordered(m: dict) -> dict:
    return {**{k: m[k] for k in _ORDER if k in m}, **{k: v for k, v in m.items() if k not in _ORDER}}


def run_session(store, plan, rig: OpenRig, *, on_pose=None, progress: TextIO | bool | None = True) -> SessionResult:
    """Run (or continue) the session in ``store`` on ``rig``: a calibration session (``geocal`` in its manifest)
    through :class:`gonio.session.geocal_session.CalibrationRunner`, an adaptive one through
    :class:`gonio.session.adaptive.AdaptiveSession`, any other through
    :class:`gonio.session.runner.SessionRunner`."""
    from gonio.rig.dynamixel import describe_hardware_error
    from gonio.session.runner import RunnerSettings, SessionRunner, recovered_faults

    devices = rig.devices
    for joint, bits in recovered_faults(devices).get("servo_alarms_cleared", {}).items():  # said even when quiet
        print(f"gonio: servo {joint}: hardware error found at start ({describe_hardware_error(bits)}, Hardware Error "
              f"Status 0x{bits:02X}) cleared by a reboot; if its cause is not known, stop (Ctrl-C) and check the arm",
              file=sys.stderr)
    resume_cmd = f"gonio resume {store.directory}"
    # the fields read, not a copy of the manifest (up to ~1 MB: an adaptive session's candidates)
    has = store.has_manifest_entry
    kind = "calibration" if has("geocal") else "adaptive" if has("adaptive") else "plan"
    common = dict(before_pose=rig.before_pose, resume_command=resume_cmd, stream=_stream(progress))
    if kind == "calibration":
        from gonio.session.geocal_session import CalibrationRunner

        runner = CalibrationRunner(plan, store, devices, rig.calibration, rig.layout, **common)
    elif kind == "adaptive":  # a loop around the runner: rounds planned from the stored samples
        from gonio.session.adaptive import AdaptiveSession

        runner = AdaptiveSession(store, devices, rig.calibration, rig.layout,
                                 settings=RunnerSettings(timing=store_timing(store)), **common)
        runner.runner.on_pose = on_pose
    else:
        runner = SessionRunner(plan, store, devices, rig.calibration, rig.layout,
                               settings=RunnerSettings(timing=store_timing(store)), **common)
    if kind != "adaptive":
        runner.on_pose = on_pose
        expect = getattr(rig, "expect_poses", None)  # the simulator prepares for the session's size
        if expect is not None:
            expect(len(plan))
    if store.manifest_entry("keep_pixels") is True and kind == "plan":
        runner.keep_pixels_dir = Path(store.directory) / "pixels"
    result = runner.run()
    _record_sphere_centre(store, rig)
    manifest = store.manifest  # as the run left it
    total = manifest["plan"] if kind == "adaptive" else plan
    n_total = len(total["poses"]) if isinstance(total, dict) else len(total)
    return SessionResult(directory=store.directory, status=result.status, run=result,
                         poses_done=len(store.done_poses()), poses_total=n_total, samples_total=store.sample_count,
                         simulated=bool(devices.clock.simulated), kind=kind, manifest=manifest, rig=devices.rig,
                         recovered_faults=recovered_faults(devices))


def _record_sphere_centre(store, rig: OpenRig) -> None:
    """A sphere session: the centre its poses' silhouettes say (:func:`gonio.sphere.refine.session_centre`) and
    the one the last pose's samples used (``used_m``, ``used_sigma_m``: with the declared centre as a prior,
    :func:`gonio.sphere.refine.centre_in_use`), recorded in the manifest (``sphere_centre``) after every run."""
    sph = getattr(rig.layout, "sphere", None)
    if sph is None:
        return
    from gonio.store.directory import scan_samples, _samples_path
    from gonio.sphere.refine import centre_in_use, session_centre

    scan = scan_samples(_samples_path(store.directory, store.manifest))
    found = session_centre((scan.records[k][1] for k in sorted(scan.records)), sph)
    if found is not None:
        used, sigma = centre_in_use(found, sph)
        store.update_manifest(sphere_centre={**found, "used_m": list(used.centre), "used_sigma_m": sigma.tolist()})


def resume(directory, *, rig: OpenRig | None = None, rig_file: str | None = None, servo_port: str | None = None,
           controller_port: str | None = None, camera: str | None = None,
           on_pose: Callable[[PoseEvent], None] | None = None, on_start: Callable[[object, object], None] | None = None,
           progress: TextIO | bool | None = True) -> SessionResult:
    """Measure the poses a session directory still lacks: the simulated rig rebuilt from its configuration and
    seed, or the recorded hardware (``servo_port``/``controller_port``/``camera`` override the recorded ones;
    ``rig_file`` bounds the joint limits, default the rig file the session recorded). ``rig``: an
    :class:`OpenRig` the caller holds open (a mixed rig whose camera object cannot be opened from a file); it must
    be the rig the session recorded (same rig file text), and stays open.

    Refused in one line, before anything is written, when the directory is not a session or its manifest's plan
    no longer describes its records. A session whose poses are all stored returns at once
    (``nothing_to_resume``; not counted as a resume). ``on_start(store, remaining)`` runs once the store is
    open, before the rig is.

    >>> resume("my-session").ok                                                # doctest: +SKIP
    True
    """
    from gonio.plan.plan import Plan
    from gonio.store.directory import (MANIFEST, SessionStore, _read_manifest, _samples_path, read_manifest_bytes,
                                       scan_samples)

    d = Path(directory)
    if not (d / MANIFEST).is_file():
        raise ConfigError.field(None, "session directory", str(directory), "is not a gonio session (no manifest.json)")
    # read once for both checks below (read-only: the store reads the file again under its lock, and parses it
    # again only if it changed)
    known = read_manifest_bytes(d)
    manifest = known[1]
    plan = Plan.from_dict(manifest.get("plan"), source=str(d / MANIFEST))
    scan = scan_samples(_samples_path(d, manifest))
    if _all_measured(manifest, plan, scan):
        status = manifest.get("exit_status")
        if str(status).startswith(UNUSABLE_PREFIX):  # every pose stored, most of them unusable: it stays so
            return SessionResult(directory=d, status=status, poses_done=len(plan), poses_total=len(plan),
                                 kind="calibration" if "geocal" in manifest else "plan", manifest=manifest,
                                 nothing_to_resume=True, simulated=manifest.get("mode") == "sim")
        if status != "completed":
            SessionStore.open(d, resume=False).finish("completed")
        return SessionResult(directory=d, status="completed", poses_done=len(plan), poses_total=len(plan),
                             kind="calibration" if "geocal" in manifest else "plan", manifest=_read_manifest(d),
                             nothing_to_resume=True, simulated=manifest.get("mode") == "sim")
    check_plan_against_records(d, manifest, plan, scan)  # before the store marks the session as resumed
    store = SessionStore.open(d, known=known)  # takes the manifest over: not used here after
    opened = None
    try:
        manifest = store.manifest
        if on_start is not None:
            on_start(store, store.remaining(plan))
        if rig is not None:
            if (rig.record.get("rig") or {}).get("sha256") != (manifest.get("rig") or {}).get("sha256"):
                raise ConfigError(f"{d}: resume(rig=...): the rig given is not the rig this session was measured "
                                  "with (its rig file differs)")
            return run_session(store, plan, rig, on_pose=on_pose, progress=progress)
        if manifest.get("mode") == "hardware":
            hw = dict(manifest.get("hardware") or {})
            for key, value in (("servo_port", servo_port), ("controller_port", controller_port), ("camera", camera)):
                if value:
                    hw[key] = value
            manifest["hardware"] = hw
        elif manifest.get("mode") != "sim":
            raise DataError(f"{d / MANIFEST}: mode = {manifest.get('mode')!r}: expected 'sim' or 'hardware'")
        try:
            opened = open_rig_from_manifest(manifest, store.directory, rig_file=rig_file)
        except BaseException as exc:  # could not even open the devices: record why, keep the session resumable
            store.finish(f"error: {exc}" if str(exc) else "interrupted")
            raise
        return run_session(store, plan, opened, on_pose=on_pose, progress=progress)
    except BaseException:
        store.close()
        raise
    finally:
        if opened is not None:
            opened.close()


def _all_measured(manifest, plan, scan) -> bool:
    """Every pose of the session is stored (and an adaptive session has stopped adapting)."""
    adapting = isinstance(manifest.get("adaptive"), dict) and manifest["adaptive"].get("stop") is None
    return not (adapting or scan.torn is not None or scan.damaged
                or any(k not in scan.records for k in range(len(plan))))
