"""``gonio calibrate rig|check``: geometric calibration of the rig (:mod:`gonio.rig.geocal`).

``gonio calibrate rig`` lays out the calibration poses (:func:`gonio.rig.geocal.calibration_plan`:
ChArUco poses of the camera arm, mirror-highlight poses of the light arm, all inside the declared joint
limits and collision zones), prints their number and lab time, gathers the observations, estimates the
rig's assembly errors with their uncertainties, prints them (parameters not identified are said so)
and writes the calibrated rig file (``--out``: the declared file plus a ``[calibration]`` table), which
``gonio measure --rig CALIBRATED.toml`` uses. ``gonio calibrate check`` re-observes a few poses and
reports the angular error left with a (calibrated) rig file.

With ``--sim`` the observations come from the as-built simulated rig (``--sim-as-built SEED|FILE``,
:func:`sim.as_built.observe`: geometric observations with a ChArUco pose and highlight-centroid noise
model, no rendered frames), found through the ``gonio.plugins`` entry points (gonio never imports sim).
"""

from __future__ import annotations

import math


def register(sub) -> None:
    p = sub.add_parser("calibrate", help="geometric calibration of the rig (servo zeros, axes, arm lengths)",
                       description=__doc__.split("\n\n")[1])
    csub = p.add_subparsers(dest="calibrate_command", metavar="ACTION", required=True)

    def common(sp):
        sp.add_argument("--rig", metavar="RIG.toml", help="rig file (default: the shipped rig)")
        sp.add_argument("--sim", action="store_true", help="calibrate the simulated (as-built) rig")
        sp.add_argument("--sim-as-built", metavar="SEED|ERRORS.toml", default="0",
                        help="the simulated rig's assembly errors: a seed or a TOML file (default seed 0)")
        sp.add_argument("--seed", type=int, default=0, help="seed of the simulated observation noise")
        sp.add_argument("--quick", action="store_true", help="fewer poses (coarser azimuth steps)")
        sp.set_defaults(func=run)

    rig = csub.add_parser("rig", help="estimate the rig's geometry and write a calibrated rig file")
    common(rig)
    rig.add_argument("--out", metavar="CALIBRATED.toml", help="calibrated rig file to write")
    rig.add_argument("--estimate", action="store_true", help="only print the plan and its lab time")
    check = csub.add_parser("check", help="re-observe a few poses and report the angular error left")
    common(check)


def _observations(args, declared, plan):
    from gonio.errors import ConfigError

    if not args.sim:
        raise ConfigError("gonio calibrate: the hardware calibration session (ChArUco and mirror-highlight frames "
                          "through the session runner) is not available yet; use --sim, or see README "
                          "'Rig geometry' for the procedure")
    from gonio.plugins import plugin

    sim = plugin("sim.rig")
    as_built = sim.parse_as_built(declared, args.sim_as_built)
    return as_built, sim.observe(as_built, plan, args.seed)


def run(args) -> int:
    from gonio.errors import ConfigError
    from gonio.rig.geocal import calibrate_geometry, calibrated_rig_text, calibration_plan, plan_lab_time
    from gonio.rig.kinematics import load_rig, read_rig_text

    text, src = read_rig_text(args.rig or "default")
    rig = load_rig(text=text, source=src)
    if args.calibrate_command == "rig":
        if rig.geometry_errors is not None:
            raise ConfigError(f"{src}: already calibrated ([calibration] table): calibrate from the declared rig file")
        if rig.layout != "arms":
            raise ConfigError(f"{src}: layout {rig.layout!r}: the calibration plan supports the 'arms' layout only")
        plan = calibration_plan(rig, quick=args.quick)
        lab = plan_lab_time(rig, plan)
        print(f"calibration plan: {len(plan['camera'])} ChArUco poses (board on the stage) + "
              f"{len(plan['highlight'])} mirror-highlight poses (mirror or glossy black tile on the stage), "
              f"lab time {lab / 60:.1f} min")
        if args.estimate:
            return 0
        if not args.out:
            raise ConfigError("gonio calibrate rig: --out CALIBRATED.toml is required (or --estimate)")
        truth, (cams, highs) = _observations(args, rig, plan)
        res = calibrate_geometry(rig, cams, highs)
        for name, value, sigma, unit in res.table():
            if unit.startswith("not identified"):
                print(f"  {name:26s}      —          {unit}")
            else:
                print(f"  {name:26s} {value:+9.4f} ± {sigma:.4f} {unit}")
        print("  residual RMS: " + ", ".join(f"{k} {v:.3g}" for k, v in res.rms.items()))
        note = f"source rig: {src}; {len(cams)} ChArUco + {len(highs)} highlight observations"
        if args.sim:
            note += f"; simulated as-built rig ({truth.source})"
        from pathlib import Path

        Path(args.out).write_text(calibrated_rig_text(text, res, note=note), encoding="utf-8")
        print(f"wrote {args.out} (use it with: gonio measure --rig {args.out})")
        return 0
    # check: a quick plan's poses, the error of the rig file's geometry against what the camera sees
    import numpy as np

    from gonio.rig.chain import angle_between_deg
    from gonio.rig.geocal import _residual_blocks

    declared = load_rig(text=text.split("\n# ---- geometric calibration")[0], source=src) \
        if rig.geometry_errors is not None else rig
    plan = calibration_plan(declared, quick=True)
    truth, (cams, highs) = _observations(args, declared, plan)
    blocks = _residual_blocks(rig, rig.geometry_errors or type(truth.errors)(), cams, highs)
    cam_deg = np.linalg.norm(blocks["camera_deg"].reshape(-1, 3), axis=1)
    hi_deg = np.degrees(np.linalg.norm(blocks["highlight_mrad"].reshape(-1, 2), axis=1) * 1e-3)
    print(f"{len(cams)} ChArUco + {len(highs)} highlight poses re-observed with {src}:")
    print(f"  camera orientation vs ChArUco: median {np.median(cam_deg):.3f}°, max {cam_deg.max():.3f}°")
    print(f"  light reflection direction:    median {np.median(hi_deg):.3f}°, max {hi_deg.max():.3f}°")
    if args.sim:
        j = np.concatenate([plan["camera"], plan["highlight"]])
        twi, two = truth.directions(j)
        wi, wo = rig.directions(j)
        ei, eo = angle_between_deg(wi, twi), angle_between_deg(wo, two)
        print(f"  vs the simulated truth: wi median {np.median(ei):.3f}° (max {ei.max():.3f}°), "
              f"wo median {np.median(eo):.3f}° (max {eo.max():.3f}°)")
    return 0 if math.isfinite(float(np.median(hi_deg))) else 1
