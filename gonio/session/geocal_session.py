"""The geometric calibration session (``gonio calibrate rig``): the calibration plan executed by the same
session runner as a measurement — the same moves, joint limits and collision zones, safety checks,
retries, crash-safe store (one record per pose, fsynced), progress line, ``gonio resume`` — with a
different capture per pose: :func:`gonio.session.geocal_observe.observe_pose` (the board pose and, on
the light arm's poses, the light's highlight in the tile) instead of the reflectance pipeline.

* :func:`calibration_session_plan`: :func:`gonio.rig.geocal.calibration_plan`'s joint angles as a
  :class:`gonio.plan.Plan` (the directions for the record, the joints to move to, which pose observes
  what in ``params["kinds"]``);
* :func:`calibration_lab_time`: its lab time under the runner's cost model (moves, settle, frames; no
  dark frames and no warm-up wait: the geometry does not depend on the light's output);
* :class:`CalibrationRunner`: the runner with that capture; each pose is approached from a set side
  (:data:`APPROACH_DEG`: alternately from below and from above, so the gears' backlash is balanced
  scatter around the zero offsets, not a bias that follows the move order); every pose's observations go into the record's metadata (JSON), so an interrupted
  session resumes where it stopped;
* :func:`observations_from_store`, :func:`finish_calibration`: the estimate from a session's records
  (:func:`gonio.rig.geocal.calibrate_geometry`) and the calibrated rig file.
"""

from __future__ import annotations

import math
import time

import numpy as np

from gonio.errors import HardwareError, UnreachablePose
from gonio.rig.geocal import CameraObservation, HighlightObservation
from gonio.session.runner import SessionRunner

__all__ = ["GENERATOR", "calibration_session_plan", "check_session_plan", "calibration_lab_time", "CalibrationRunner",
           "observations_from_store", "finish_calibration"]

#: The plan generator's name: a session whose plan has it is a calibration session.
GENERATOR = "geocal"
#: Every joint approaches its calibration pose from this far away (degrees), from below at even poses
#: and from above at odd ones (a balanced bidirectional approach, ISO 230-2 §3.1): the gears' backlash
#: then puts the load side ½ backlash below the encoder's reading at half of the poses and above it at
#: the other half, whatever the previous pose was, so the zero offsets are estimated at the middle of
#: the backlash (where a session approaching from either side scatters) and the backlash is scatter,
#: not a bias that follows the plan's move order.
APPROACH_DEG = 0.5


def calibration_session_plan(rig, *, quick: bool = False):
    """The calibration plan (:func:`gonio.rig.geocal.calibration_plan`) as a :class:`gonio.plan.Plan`."""
    from gonio.plan.plan import CaptureSettings, Plan
    from gonio.rig.geocal import calibration_plan
    from gonio.session.geocal_observe import BOARD_EXPOSURE, TILE

    jp = calibration_plan(rig, quick=quick)
    joints = np.concatenate([jp["camera"], jp["highlight"]])
    kinds = ["camera"] * len(jp["camera"]) + ["highlight"] * len(jp["highlight"])
    wi, wo = rig.directions(joints)
    ti, to = np.arccos(np.clip(wi[:, 2], -1, 1)), np.arccos(np.clip(wo[:, 2], -1, 1))
    pi_, po = np.arctan2(wi[:, 1], wi[:, 0]) % (2 * math.pi), np.arctan2(wo[:, 1], wo[:, 0]) % (2 * math.pi)
    # expected frames per pose: the board frame (metered: sometimes a retake) and ~3 short highlight frames
    # settle: 0.3 s after the move plus ~0.2 s for the unidirectional approach's last 0.5° (APPROACH_DEG)
    capture = CaptureSettings(exposures=(BOARD_EXPOSURE, 5e-5, 5e-5, 5e-5), frames=1, settle=0.5, auto_exposure=False)
    return Plan(np.stack([ti, pi_, to, po], -1), capture=capture, generator=GENERATOR,
                params={"kinds": kinds, "quick": bool(quick), "tile_m": list(TILE)}, joints=joints)


def check_session_plan(rig):
    """The poses ``gonio calibrate check`` re-measures: every other ChArUco pose of the quick calibration plan
    (two azimuths per elevation) and its highlight poses at the exact mirror direction at 30° and 50° of
    elevation (6 azimuths; higher, the board is seen too obliquely for a precise pose): 20 poses, about a
    minute of lab time."""
    from dataclasses import replace

    plan = calibration_session_plan(rig, quick=True)
    kinds, j = plan.params["kinds"], plan.joints
    cam = [i for i, k in enumerate(kinds) if k == "camera"][::2]
    light_el = np.round(np.degrees(j[:, rig.names.index("light_el")])) if "light_el" in rig.names else None
    hi = [i for i, k in enumerate(kinds) if k == "highlight" and abs(j[i, 1] + j[i, 3]) < 1e-9
          and (light_el is None or light_el[i] in (30.0, 50.0))]
    idx = cam + hi
    return replace(plan, poses=plan.poses[idx], joints=j[idx],
                   params={**plan.params, "kinds": [kinds[i] for i in idx], "check": True})


def calibration_lab_time(plan, rig, start=None) -> float:
    """Lab seconds of ``plan`` under the runner's cost model without start-up darks and warm-up."""
    from gonio.plan import plan_move_times
    from gonio.plan.labtime import session_lab_time

    return session_lab_time(plan_move_times(plan, rig, start=start), plan.capture, startup=False).total


class CalibrationRunner(SessionRunner):
    """:class:`gonio.session.runner.SessionRunner` measuring calibration observations (module docstring)."""

    def __init__(self, plan, store, devices, calibration, layout, **kw):
        super().__init__(plan, store, devices, calibration, layout, **kw)
        self._calibration, self._layout = calibration, layout
        self._kinds = list(plan.params.get("kinds", ()))
        if len(self._kinds) != len(plan) or plan.joints is None:
            from gonio.errors import DataError

            raise DataError(f"calibration plan: {len(self._kinds)} pose kinds and joints "
                            f"{'missing' if plan.joints is None else 'given'} for {len(plan)} poses")
        from gonio.pipeline.target import Rect

        tile = plan.params.get("tile_m")
        self._tile = Rect(*tile) if tile is not None else layout.sample
        self._lit = False

    def unusable_cause(self, samples, meta) -> str | None:
        """A calibration pose is lost when it gave no board pose, or (a highlight pose) no highlight: its reason."""
        return str(meta.get("reason") or "") or None

    def _target(self, index: int, current) -> dict:
        """The plan's joints themselves (the calibration needs these configurations, not any equivalent one),
        refused like any pose outside the joint limits or in a collision zone."""
        rig = self.dev.rig
        j = np.asarray(self.plan.joints[index], dtype=np.float64)
        wi, wo = rig.directions(j)
        code = int(rig.check_directions(wi, wo))
        if not np.all((j >= rig.lower) & (j <= rig.upper)) or code != 0:
            why = "outside the joint limits" if code == 0 else "in a collision zone"
            raise UnreachablePose(f"{rig.name}: calibration pose {index} "
                                  f"({', '.join(f'{math.degrees(a):.1f}' for a in j)} deg) is {why}",
                                  reason="limits" if code == 0 else "collision")
        side = 1.0 if index % 2 == 0 else -1.0  # even poses from below, odd poses from above (module docstring)
        pre = j - side * np.radians(APPROACH_DEG)
        wi, wo = rig.directions(pre)
        if np.all((pre >= rig.lower) & (pre <= rig.upper)) and int(rig.check_directions(wi, wo)) == 0:
            self.dev.axes.move_to(rig.as_dict(pre), timeout=self.settings.move_timeout)
        return rig.as_dict(j)

    def warm_up(self) -> float:
        """Switch the light on and check that the photodiode sees it: no wait for a stable output (the
        geometry does not depend on it; each highlight frame's exposure is chosen on the spot)."""
        ctl, st = self.dev.controller, self.settings
        ctl.set_light(True, st.light_level)
        p, u = ctl.read_photodiode(st.warmup_samples)
        if p <= 4 * u:
            raise HardwareError(f"light: photodiode reads {p:g} ± {u:g} after switching on: the light is off or failed",
                                device="light")
        return 0.0

    def _refresh_darks(self) -> bool:
        """No dark frames (the board's and the highlight's detection subtract their own local background):
        the light is switched on once."""
        if not self._lit:
            self.warm_up()
            self._lit = True
        return False

    def _predict(self, todo) -> np.ndarray:
        from gonio.plan import plan_move_times
        from gonio.plan.labtime import session_lab_time

        if not todo:
            return np.zeros(0)
        try:
            start = self.dev.rig.as_array(self.dev.axes.positions())
            moves = plan_move_times(self.plan, self.dev.rig, start=start, indices=todo)
        except Exception:  # noqa: BLE001 - the ETA must never stop a session
            moves = np.zeros(len(todo))
        return session_lab_time(moves, self.plan.capture, self.timing, startup=False).ends

    def _measure(self, index: int) -> tuple:
        from gonio.samples import SampleSet
        from gonio.session.geocal_observe import observe_pose

        rig = self.dev.rig
        w0, l0 = time.perf_counter(), self.clock.now()
        target, measured = self._move(index)
        w1, l1 = time.perf_counter(), self.clock.now()
        self._refresh_darks()
        if self.before_pose is not None:
            self.before_pose(index)
        joints = rig.as_array(measured)
        kind = self._kinds[index]
        frames = self.camera.frames
        cam, hl, why = observe_pose(self.camera, self._calibration, self._layout, joints,
                                    highlight=kind == "highlight", tile=self._tile)
        self.check_devices()  # an E-stop during the capture: keep nothing of this pose
        w2, l2 = time.perf_counter(), self.clock.now()
        timing = {"move_lab": l1 - l0, "move_wall": w1 - w0, "capture_lab": l2 - l1, "capture_wall": w2 - w1,
                  "frames": self.camera.frames - frames}
        meta = {
            "kind": kind,
            "target_joints_rad": {k: float(v) for k, v in target.items()},
            "joints_rad": {k: float(v) for k, v in measured.items()},
            "board": None if cam is None else {"position_m": cam.position.tolist(), "R": cam.R.tolist(),
                                               "cov": None if cam.cov is None else cam.cov.tolist()},
            "highlight": None if hl is None else {"xy": hl.xy.tolist(), "cov": hl.cov.tolist(), "f0": hl.f0,
                                                  "source_radius_m": hl.source_radius_m},
            "reason": why,
            "exposures_s": [], "frames": [],
            "lab_time_s": float(self.clock.now()),
            "timing": timing,
        }
        return SampleSet.empty(), meta, timing


def _bounded(x, lo: float, hi: float) -> float:
    """A recorded number within [lo, hi] (ValueError otherwise: the record is refused in one line)."""
    v = float(x)
    if not lo <= v <= hi:
        raise ValueError(f"{v!r} outside [{lo:g}, {hi:g}]")
    return v


def observations_from_store(directory, rig):
    """``(cams, highs, refused)`` from the records of the calibration session in ``directory``: every board
    pose is a camera observation, every kept highlight a highlight observation; ``refused``: ``(pose, reason)``."""
    from gonio.errors import DataError
    from gonio.session.geocal_observe import EMITTER_RADIUS_M, TILE_F0
    from gonio.store.directory import _read_manifest, _samples_path, poses_beyond_plan, scan_samples
    from pathlib import Path

    d = Path(directory)
    manifest = _read_manifest(d)
    scan = scan_samples(_samples_path(d, manifest))
    cams, highs, refused = [], [], []
    beyond = set(poses_beyond_plan(manifest, scan.records))
    for pose in sorted(scan.records):
        if pose in beyond:
            refused.append((pose, "not a pose of this session's plan"))
            continue
        meta = scan.records[pose][1]
        try:
            j = rig.as_array({k: float(v) for k, v in meta["joints_rad"].items()})
            b, h = meta.get("board"), meta.get("highlight")
            if b is not None:
                cov = None if b.get("cov") is None else np.asarray(b["cov"], dtype=np.float64).reshape(6, 6)
                cams.append(CameraObservation(j, np.asarray(b["position_m"], np.float64).reshape(3),
                                              np.asarray(b["R"], np.float64).reshape(3, 3), cov))
                if h is not None:
                    # a record before the reflector and emitter were recorded: the calibration tile and light's
                    highs.append(HighlightObservation(j, np.asarray(h["xy"], np.float64).reshape(2), cams[-1].position,
                                                      cams[-1].R, np.asarray(h["cov"], np.float64).reshape(2, 2),
                                                      f0=_bounded(h.get("f0", TILE_F0), 0.0, 1.0),
                                                      source_radius_m=_bounded(h.get("source_radius_m", EMITTER_RADIUS_M),
                                                                               0.0, 0.1)))
            if meta.get("reason"):
                refused.append((pose, str(meta["reason"])))
        except (KeyError, TypeError, ValueError) as exc:
            raise DataError(f"{d}: pose {pose}: not a calibration record ({exc})") from None
    return cams, highs, refused


def finish_calibration(directory, rig, declared_text: str, out, *, note: str = ""):
    """Estimate the rig's geometry from the session in ``directory`` and write the calibrated rig file ``out``
    (never over an existing file). Returns ``(GeoCalResult, refused)``."""
    from pathlib import Path

    from gonio.errors import ConfigError
    from gonio.rig.geocal import calibrate_geometry, calibrated_rig_text

    cams, highs, refused = observations_from_store(directory, rig)
    res = calibrate_geometry(rig, cams, highs)
    note = (note + "\n" if note else "") + (f"session {directory}: {len(cams)} board poses, {len(highs)} highlights "
                                             f"({len(refused)} poses gave no highlight or no board)")
    text = calibrated_rig_text(declared_text, res, note=note)
    p = Path(out)
    try:
        with open(p, "x", encoding="utf-8") as f:  # nothing is overwritten
            f.write(text)
    except FileExistsError:
        raise ConfigError(f"{p}: exists: the calibrated rig file is never overwritten; choose another --out") from None
    return res, refused
