"""What a session records about itself, and how it is read back: the manifest's ``rig`` (the rig file's text
with its SHA-256, bounded on resume by the rig file), ``calibration`` (the camera's intrinsics, distortion and
noise), ``target``, ``timing``, ``detector`` and the simulator's settings (``sim``), each checked field by field
when a session directory is read again (a manifest is a file from outside: docs/formats.md).

These are the session layer's building blocks shared by :mod:`gonio.session.api` (measure, resume, calibrate)
and the commands; every error is one line naming the manifest field.
"""

from __future__ import annotations

import sys

__all__ = ["rig_record", "manifest_rig", "calibration_record", "calibration_from_record", "manifest_calibration",
           "manifest_layout", "target_layout", "record_detector", "manifest_timing", "checked_sim", "SIM_RANGES",
           "check_plan_against_records", "warn"]


def warn(msg: str) -> None:
    """One warning line on stderr (``gonio: warning: ...``): what a session does that its user must know."""
    print(f"gonio: warning: {msg}", file=sys.stderr)


def target_layout(path):
    """The target layout of ``--target TARGET.toml`` (None: the standard board, flat sample)."""
    from gonio.pipeline.target import TargetLayout, load_target

    return load_target(path) if path else TargetLayout()


def calibration_record(calib) -> dict:
    return {"width": calib.width, "height": calib.height, "K": calib.K.tolist(), "dist": calib.dist.tolist(),
            "noise": dict(calib.noise.__dict__)}


def calibration_from_record(c, source: str):
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


def rig_record(rig, source: str, text: str) -> dict:
    """The manifest's ``rig``: name, where it came from, and the full TOML text with its SHA-256, so
    that a resumed session (or anything rebuilding the rig) uses this rig even if the file changes."""
    import hashlib

    rec = {"name": rig.name, "source": source, "toml": text,
           "sha256": hashlib.sha256(text.encode("utf-8")).hexdigest()}
    if getattr(rig, "geometry_errors", None) is not None:  # a calibrated rig (gonio calibrate rig): its uncertainties
        import tomllib

        cal = tomllib.loads(text).get("calibration", {})
        rec["calibration"] = {k: cal[k] for k in ("uncertainty", "not_identified", "rms", "covariance") if k in cal}
    return rec


def manifest_rig(manifest, where: str, rig_file: str | None = None):
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
        warn(f"{where}: rig has no recorded description (older session): using the current {str(src)!r}, "
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


def manifest_calibration(manifest, where: str, fallback=None):
    """The calibration the session recorded; for an older simulated session without one, ``fallback``
    (the simulated camera's) with a warning line."""
    c = manifest.get("calibration")
    if c is None and fallback is not None:
        warn(f"{where}: no recorded camera calibration (older session): using the simulated camera's")
        return fallback
    return calibration_from_record(c, where)


def record_detector(manifest: dict, calibration, rig, *, pinhole: bool) -> None:
    """``detector`` (how it was computed) and ``detector_solid_angle_sr`` (None with the reason if
    unknown) in the manifest: :mod:`gonio.session.detector`."""
    from gonio.pipeline.target import TargetLayout
    from gonio.session.detector import aperture_from_calibration, detector_solid_angle

    diameter, how = (None, "") if pinhole else aperture_from_calibration(manifest["calibration"], "--calibration")
    det = detector_solid_angle(calibration, TargetLayout.from_dict(manifest["target"], source="--target"), rig,
                               aperture_diameter_m=diameter, pinhole=pinhole, aperture_source=how)
    manifest["detector"] = det
    manifest["detector_solid_angle_sr"] = det["solid_angle_sr"]


def manifest_timing(manifest):
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


def store_timing(store):
    """:func:`manifest_timing` of an open store's manifest, from its ``timing`` field alone (the manifest is not
    copied: an adaptive session's is up to ~1 MB)."""
    return manifest_timing({"timing": store.manifest_entry("timing")})


#: The simulated rig's settings a manifest may hold, with their ranges (a crafted manifest must not
#: make the simulator allocate a 100,000-pixel-wide frame or take a table for a number).
SIM_RANGES = {"seed": (0, 2 ** 32 - 1, int), "width": (64, 4096, int), "height": (48, 4096, int),
               "focal_px": (1.0, 1e5, float), "bit_depth": (8, 16, int), "light_intensity": (1e-6, 1e6, float),
               "servo_noise_ticks": (0.0, 100.0, float), "backlash_ticks": (0.0, 100.0, float),
               "warmup_depth": (0.0, 1.0, float), "warmup_tau": (0.0, 1e5, float), "pd_noise": (0.0, 1.0, float)}


#: The simulated rig's list-valued settings: allowed lengths and the bound on each value (px, OpenCV distortion
#: coefficients, metres) — dropped by a resume before, so a resumed session rendered another camera or sphere.
_SIM_VECTORS = {"principal_offset_px": ((2,), 1000.0), "distortion": ((4, 5, 8), 10.0),
                "sphere_offset_m": ((3,), 0.05)}


def checked_sim(sim, where: str) -> dict:
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
        if key == "pixel_format":
            from gonio.rig.aravis import PIXEL_FORMATS

            if value not in PIXEL_FORMATS:
                raise DataError(f"{where}: sim.pixel_format = {str(value)[:40]!r}: expected a GenICam pixel format "
                                f"({', '.join(PIXEL_FORMATS)})")
            out[key] = value
            continue
        if key in _SIM_VECTORS:  # the camera and the sphere as built: short lists of bounded numbers
            n, bound = _SIM_VECTORS[key]
            ok = value is None or (isinstance(value, list) and len(value) in n and all(
                isinstance(v, (int, float)) and not isinstance(v, bool) and abs(v) <= bound for v in value))
            if not ok:
                raise DataError(f"{where}: sim.{key} = {str(value)[:60]}: expected None or {'/'.join(map(str, n))} "
                                f"numbers within ±{bound:g}")
            out[key] = value
            continue
        if key not in SIM_RANGES:
            continue  # a newer gonio's setting: ignored, as SimRigConfig.from_dict does
        lo, hi, kind = SIM_RANGES[key]
        ok = isinstance(value, (int, float)) and not isinstance(value, bool) and lo <= value <= hi
        if not ok or (kind is int and not isinstance(value, int)):
            raise DataError(f"{where}: sim.{key} = {str(value)[:40]}: expected {'an integer' if kind is int else 'a number'} "
                            f"in [{lo:g}, {hi:g}]")
        out[key] = value
    return out


def manifest_layout(manifest):
    """The session's target layout (sessions recorded before ``target`` existed: the default one)."""
    from gonio.pipeline.target import TargetLayout

    return TargetLayout.from_dict(manifest.get("target", {}), source="manifest target")


def check_plan_against_records(d, manifest, plan, scan) -> None:
    """Refuse a plan that no longer describes the stored poses: every record names the plan pose it measured
    (``pose``) and the angles it was measured at (``meta.pose_rad``, [θi, φi, θo, φo] rad, written from the
    plan); a manifest whose plan was edited, reordered or replaced since would make a resume measure the poses
    still missing at other angles than planned, and skip planned angles that no record holds, yet end
    "completed". Records without ``pose_rad`` (older sessions) are not checked; nor is an adaptive session.
    Read-only: run before the store marks the session as resumed."""
    import numpy as np

    from gonio.errors import DataError
    from gonio.store.directory import MANIFEST, SAMPLES

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
