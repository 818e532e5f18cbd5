"""``gonio calibrate rig|check``: geometric calibration of the rig (:mod:`gonio.rig.geocal`).

``gonio calibrate rig`` lays out the calibration poses (:func:`gonio.session.geocal_session.calibration_session_plan`:
ChArUco poses of the camera arm, mirror-highlight poses of the light arm, inside the declared joint limits
and collision zones), prints their number and lab-time estimate, then runs them as a session through the
session runner (same moves, safety checks, crash-safe store and progress line as a measurement; an
interrupted session continues with ``gonio resume DIR``): each pose's frames give the board pose and the
light's highlight in the tile on the stage. At the end it estimates the rig's assembly errors with their
uncertainties, prints them (parameters not identified are said so) and writes the calibrated rig file
(``--out``: the declared file plus a ``[calibration]`` table), which ``gonio measure --rig CALIBRATED.toml``
uses. On a rig: ``--rig RIG.toml --servo-port --controller-port --camera --calibration CAMERA.toml``; with
``--sim`` the simulated as-built rig (``--sim-as-built SEED|FILE``) renders the frames.
``gonio calibrate check`` re-measures a few poses the same way (a short session,
:func:`gonio.session.geocal_session.check_session_plan`, on the rig or the simulated as-built rig) and
reports how far the rig file's wi and wo are from what the camera sees (:mod:`gonio.rig.geocheck`), with a
one-line verdict against ``--threshold`` (exit status 1 when over it).
"""

from __future__ import annotations

import sys

#: ``gonio calibrate --help`` (plain text: the module docstring's Sphinx roles are for the API docs).
DESCRIPTION = (
    "gonio calibrate rig lays out the calibration poses (ChArUco poses of the camera arm, mirror-highlight poses "
    "of the light arm, inside the declared joint limits and collision zones), prints their number and lab-time "
    "estimate, then runs them as a session (same moves, safety checks, crash-safe store and progress line as a "
    "measurement; an interrupted session continues with gonio resume DIR): each pose's frames give the board "
    "pose and the light's highlight in the tile on the stage. At the end it estimates the rig's assembly errors "
    "with their uncertainties, prints them (parameters not identified are said so) and writes the calibrated "
    "rig file (--out: the declared file plus a [calibration] table), which gonio measure --rig CALIBRATED.toml "
    "uses. On a rig: --rig RIG.toml --servo-port --controller-port --camera --calibration CAMERA.toml; with "
    "--sim the simulated as-built rig (--sim-as-built SEED|FILE) renders the frames. gonio calibrate check "
    "re-measures a few poses the same way (a short session, on the rig or the simulated as-built rig) and "
    "reports how far the rig file's wi and wo are from what the camera sees, with a one-line verdict against "
    "--threshold (exit status 1 when over it).")

#: What a hardware calibration session needs besides --out (the option, what it is).
HARDWARE_OPTIONS = (("--rig", "rig", "the declared rig file"), ("--servo-port", "servo_port", "the servo bus port"),
                    ("--controller-port", "controller_port", "the rig controller port"),
                    ("--camera", "camera", "the camera"), ("--calibration", "calibration", "the camera's CAMERA.toml"))


#: What helps a calibration session that lost poses, by cause (said with the causes counted).
LOST_POSES_HELP = ("board not found: the whole ChArUco board lit and in focus at every camera pose, the camera "
                   "file this camera's; highlight near the tile's edge or off it: the tile centred and flush, "
                   "80 mm; saturated: dim the light (a mirror) or a darker tile")


def register(sub) -> None:
    p = sub.add_parser("calibrate", help="geometric calibration of the rig (servo zeros, axes, arm lengths)",
                       description=DESCRIPTION)
    csub = p.add_subparsers(dest="calibrate_command", metavar="ACTION", required=True)

    def common(sp):
        sp.add_argument("--rig", metavar="RIG.toml", help="rig file (default with --sim: the shipped rig)")
        sp.add_argument("--sim", action="store_true", help="calibrate the simulated (as-built) rig")
        sp.add_argument("--sim-as-built", metavar="SEED|ERRORS.toml", default="0",
                        help="the simulated rig's assembly errors: a seed or a TOML file (default seed 0)")
        sp.add_argument("--seed", type=int, default=0, help="seed of the simulation's noise")
        sp.set_defaults(func=run)

    def hardware(sp):
        sp.add_argument("--servo-port", help="servo bus serial port (hardware)")
        sp.add_argument("--controller-port", help="rig controller serial port (hardware)")
        sp.add_argument("--camera", help="camera index, path or GigE id (hardware)")
        sp.add_argument("--calibration", metavar="CAMERA.toml", help="the camera's intrinsics and settings (hardware)")
        sp.add_argument("--quiet", action="store_true", help="no progress line")

    rig = csub.add_parser("rig", help="run a calibration session and write a calibrated rig file")
    common(rig)
    rig.add_argument("--out", metavar="CALIBRATED.toml", help="calibrated rig file to write (never overwritten)")
    rig.add_argument("--session", metavar="DIR", help="the calibration session's directory (default: OUT.session)")
    rig.add_argument("--estimate", action="store_true", help="only print the plan and its lab time")
    rig.add_argument("--quick", action="store_true", help="fewer poses (coarser azimuth steps)")
    hardware(rig)
    check = csub.add_parser("check", help="re-measure a few poses and report the angular error left (wi, wo)")
    common(check)
    check.add_argument("--session", metavar="DIR",
                       help="the check session's directory (default: ./calibrate-check-DATE-TIME)")
    check.add_argument("--threshold", metavar="DEG", default="0.25",
                       help="verdict threshold on the p95 of the wi and wo errors, degrees (default 0.25)")
    hardware(check)


def print_result(res, refused=()) -> None:
    """The estimate's table (value ± standard uncertainty, or why not identified) and the residuals."""
    for name, value, sigma, unit in res.table():
        if unit.startswith("not identified"):
            print(f"  {name:26s}      —          {unit}")
        else:
            print(f"  {name:26s} {value:+9.4f} ± {sigma:.4f} {unit}")
    print("  residual RMS: " + ", ".join(f"{k} {v:.3g}" for k, v in res.rms.items())
          + f"; {res.n_observations['camera']} board poses, {res.n_observations['highlight']} highlights; "
          f"least squares started from the {res.start} geometry")
    n = res.noise
    if n:
        def scale(k):  # a variance component at its bound (0) is said so
            return f"× {n[k]:.2f}" if n[k] >= 0.01 else "× 0 (the joints' scatter accounts for all of it)"

        print(f"  noise (estimated from the residuals): joints {n['joint_sigma_deg']:.3g}° rms; stated σ: board "
              f"frontal {scale('scale_board_frontal')}, board oblique {scale('scale_board_oblique')}, highlight "
              f"{scale('scale_highlight')}; χ²/n " + ", ".join(
                  f"{k[5:].replace('_', ' ')} {v:.2f}" for k, v in n.items() if k.startswith("chi2_")))
    if res.rejected:
        print(f"  {len(res.rejected)} frame(s) left out as outliers (whitened χ² improbable under their covariance), "
              f"e.g. {res.rejected[0]}")
    if refused:
        print(f"  {len(refused)} poses without a highlight or a board pose, e.g. pose {refused[0][0]}: {refused[0][1]}")


def print_calibration_outcome(result) -> int:
    """Print how a calibration session's run ended (:class:`gonio.session.api.SessionResult`); when every pose is
    done, estimate and write the calibrated rig file the manifest names (``geocal.out``), or report the check."""
    from gonio.session.runner import format_lab_time

    run = result.run
    resume_cmd = f"gonio resume {result.directory}"
    print(f"calibration session {result.directory}: {result.poses_done}/{result.poses_total} poses, lab time "
          f"{format_lab_time(run.lab_time)} in this run ({'simulated' if result.simulated else 'real'}; "
          f"estimated {format_lab_time(run.estimated_lab_time or 0.0)}), wall time {run.wall_time:.1f} s")
    if run.skipped:
        print(f"{len(run.skipped)} poses skipped: " + "; ".join(f"pose {k}: {r}" for k, r in run.skipped[:3]))
    from gonio.session.usability import STATUS_PREFIX, UNUSABLE_EXIT, run_warning

    if run_warning(run):  # a calibration that lost many poses still estimates, but says what it lost
        print(f"gonio: {run_warning(run)}; {LOST_POSES_HELP}", file=sys.stderr)
    if str(result.status).startswith(STATUS_PREFIX):
        print(f"gonio: calibration session {result.status}; no calibrated rig file written: {LOST_POSES_HELP}",
              file=sys.stderr)
        return UNUSABLE_EXIT
    if not result.ok:
        print(f"gonio: calibration session ended: {result.status}; resume with `{resume_cmd}`", file=sys.stderr)
        if result.status == "interrupted":
            return 130
        return run.error.exit_code if run.error is not None else 3
    g = result.manifest["geocal"]
    if "check" in g:
        return report_check(result.directory, result.rig, result.manifest)
    return _write_calibrated(result.directory, result.rig, result.manifest, g["out"])


def _write_calibrated(directory, rig, manifest, out) -> int:
    """Estimate the geometry from the session's records, write the calibrated rig file ``out``, print both."""
    from gonio.session.geocal_session import finish_calibration

    res, refused = finish_calibration(directory, rig, manifest["rig"]["toml"], out,
                                      note=manifest["geocal"].get("note", ""))
    print_result(res, refused)
    from gonio.rig.geocov import goal_line, with_calibration

    reached, line = goal_line(with_calibration(rig, res))
    print(f"  {line}")
    print(f"wrote {out} (use it with: gonio measure --rig {out})")
    return 0


def report_check(directory, rig, manifest) -> int:
    """``gonio calibrate check``'s report from its session's records (:mod:`gonio.rig.geocheck`): the error of
    the rig file's wi and wo against what the camera saw, and the verdict; 0 when within the threshold, else 1.
    On the simulated rig also the error against the simulated truth (the manifest's ``sim.as_built``)."""
    from dataclasses import replace

    import numpy as np

    from gonio.errors import DataError
    from gonio.rig.chain import ChainErrors, angle_between_deg, true_directions
    from gonio.rig.geocheck import check_geometry
    from gonio.session.geocal_session import observations_from_store

    where = f"{directory}/manifest.json"
    threshold = _threshold(manifest["geocal"]["check"].get("threshold_deg"), f"{where}: geocal.check.threshold_deg",
                           error=DataError)
    cams, highs, refused = observations_from_store(directory, rig)
    sim = manifest.get("sim")
    truth = None
    if isinstance(sim, dict) and isinstance(sim.get("as_built"), dict):
        truth = ChainErrors.from_dict({k: v for k, v in sim["as_built"].items() if k != "source"}, source=where)
    chk = check_geometry(rig, cams, highs, threshold_deg=threshold, truth=truth)
    name = manifest["rig"].get("source") or rig.name
    print(f"{len(cams)} board poses and {len(highs)} highlights re-measured with {name}"
          + (f" ({len(refused)} poses without one, e.g. pose {refused[0][0]}: {refused[0][1]})" if refused else "") + ":")
    lines = chk.lines(str(name))
    print("\n".join(lines[:-1]))
    if truth is not None and cams:
        j = np.stack([c.joints for c in cams])
        twi, two = true_directions(replace(rig, geometry_errors=None), truth, j)
        wi, wo = rig.directions(j)
        ei, eo = angle_between_deg(wi, twi), angle_between_deg(wo, two)
        print(f"  vs the simulated truth at the board poses: wi median {np.median(ei):.3f}° (max {ei.max():.3f}°), "
              f"wo median {np.median(eo):.3f}° (max {eo.max():.3f}°)")
    print(lines[-1])
    return 0 if chk.ok else 1


def _threshold(value, where, error=None) -> float:
    """A verdict threshold in degrees: a number in (0, 90]; else one line naming ``where``."""
    from gonio.errors import ConfigError

    try:
        t = float(value)
    except (TypeError, ValueError):
        t = float("nan")
    if isinstance(value, bool) or not (0.0 < t <= 90.0):
        raise (error or ConfigError)(f"{where} = {str(value)[:40]!r}: expected degrees in (0, 90]")
    return t


def finish_from_directory(d, manifest, *, rig_file=None) -> int:
    """The estimate of a calibration session whose poses are all measured (``gonio resume`` of a session
    stopped before its estimate was written): writes the calibrated rig file unless it exists."""
    from pathlib import Path

    from gonio.session.recording import manifest_rig
    from gonio.store.directory import MANIFEST

    if "check" in manifest["geocal"]:
        return report_check(d, manifest_rig(manifest, str(Path(d) / MANIFEST), rig_file), manifest)
    out = Path(manifest["geocal"]["out"])
    if out.exists():
        print(f"{d}: the calibrated rig file {out} is written; nothing to do")
        return 0
    return _write_calibrated(d, manifest_rig(manifest, str(Path(d) / MANIFEST), rig_file), manifest, out)


def _new_session(args, rig, text, src, plan, check: dict | None = None) -> int:
    from pathlib import Path

    from gonio.errors import ConfigError
    from gonio.session.api import measure
    from gonio.session.geocal_observe import calibration_layout
    from gonio.session.options import HardwareOptions, check_session_dir, default_material
    from gonio.session.rigs import open_hardware_rig, open_sim_config

    if check is None:
        from gonio.io.outputs import check_output

        out = Path(args.out).resolve()
        if out.exists():
            raise ConfigError(f"--out {args.out}: exists: the calibrated rig file is never overwritten")
        check_output(args.out, option="--out", suffixes=(".toml",))  # not into a session, its directory exists
        session = args.session or f"{args.out}.session"
        geocal = {"out": str(out), "note": f"source rig: {src}"}
    else:
        import time

        session = args.session or time.strftime("calibrate-check-%Y%m%d-%H%M%S")
        geocal = {"check": check, "note": f"rig file checked: {src}"}
    check_session_dir(session, option="--session")
    if args.sim:
        from gonio.plugins import plugin

        simrig = plugin("sim.rig")
        as_built = simrig.parse_as_built(rig, args.sim_as_built)
        config = simrig.SimRigConfig(seed=args.seed, as_built=as_built.to_dict(), tile={})
        geocal["note"] += f"; simulated as-built rig ({as_built.source})"
        # the simulator renders the default material off the tile (nothing): recorded as what it renders
        opened = open_sim_config(rig, text, src, config, default_material(), calibration_layout(), hold=True,
                                 detector=False)
    else:
        hw = HardwareOptions(servo_port=args.servo_port, controller_port=args.controller_port, camera=args.camera,
                             calibration=args.calibration)
        opened = open_hardware_rig(rig, text, src, hw, material={"label": "calibration tile"},
                                   target=calibration_layout(), hold=True, detector=False)
    with opened:
        result = measure(opened, plan, session, seed=args.seed, geocal=geocal, out_option="--session",
                         progress=None if args.quiet else sys.stderr)
    return print_calibration_outcome(result)


def _hardware_needs(args, action: str) -> None:
    """Refuse, in one line naming every missing option, a hardware run without its devices."""
    from gonio.errors import ConfigError

    if args.sim:
        return
    missing = [f"{o} ({what})" for o, key, what in HARDWARE_OPTIONS if not getattr(args, key)]
    if missing:
        raise ConfigError(f"gonio calibrate {action} on a rig needs {', '.join(missing)} (or --sim for the "
                          "simulated rig)")


def run(args) -> int:
    from gonio.errors import ConfigError
    from gonio.rig.kinematics import load_rig, read_rig_text

    if not args.sim and not args.rig and not getattr(args, "estimate", False):
        raise ConfigError("gonio calibrate: --rig RIG.toml (the declared rig file) is required on a rig "
                          "(or --sim for the simulated rig)")
    text, src = read_rig_text(args.rig or "default")
    rig = load_rig(text=text, source=src)
    if rig.layout != "arms":
        raise ConfigError(f"{src}: layout {rig.layout!r}: the calibration plan supports the 'arms' layout only")
    if args.calibrate_command == "rig":
        from gonio.session.geocal_session import calibration_lab_time, calibration_session_plan
        from gonio.session.runner import format_lab_time

        if not args.estimate:
            _hardware_needs(args, "rig")
        if rig.geometry_errors is not None:
            raise ConfigError(f"{src}: already calibrated ([calibration] table): calibrate from the declared rig file")
        plan = calibration_session_plan(rig, quick=args.quick)
        kinds = plan.params["kinds"]
        lab = calibration_lab_time(plan, rig)
        print(f"calibration plan: {kinds.count('camera')} ChArUco poses + {kinds.count('highlight')} highlight poses "
              f"(ChArUco board with an 80 mm glossy black tile or front-surface mirror on the sample area), "
              f"estimated lab time {format_lab_time(lab)}")
        if args.estimate:
            return 0
        if not args.out:
            raise ConfigError("gonio calibrate rig: --out CALIBRATED.toml is required (or --estimate)")
        return _new_session(args, rig, text, src, plan)
    # check: a few poses re-measured on the rig (or the simulated as-built rig) through the same session path
    from gonio.session.geocal_session import calibration_lab_time, check_session_plan
    from gonio.session.runner import format_lab_time

    threshold = _threshold(args.threshold, "--threshold")
    _hardware_needs(args, "check")
    plan = check_session_plan(rig)
    kinds = plan.params["kinds"]
    print(f"check plan: {kinds.count('camera')} ChArUco poses + {kinds.count('highlight')} highlight poses (the "
          f"calibration tile on the stage), estimated lab time {format_lab_time(calibration_lab_time(plan, rig))}")
    return _new_session(args, rig, text, src, plan, check={"threshold_deg": threshold})
