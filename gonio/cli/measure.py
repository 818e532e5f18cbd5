"""``gonio measure`` and ``gonio resume``: run a measurement session (simulated or on a rig).

A thin shell over the session API (:mod:`gonio.session.api`): the options become typed option objects
(:mod:`gonio.session.options`), :func:`~gonio.session.rigs.open_rig` opens the simulated rig (emulators on
pseudo-terminals driven through the real dynamixel-sdk and pyserial, a rendering camera, a simulated clock) or the
rig's devices, :func:`~gonio.session.api.measure` and :func:`~gonio.session.api.resume` run the session, and this
module prints what they return.

The manifest records everything needed to rebuild the session (plan, rig, material, simulator configuration and
seed, or the hardware ports), so ``gonio resume DIR`` restarts the same simulated rig and measures only the
remaining poses.
"""

from __future__ import annotations

import sys

from gonio.session.api import INCOMPLETE_EXIT  # noqa: F401 - the exit code of an incomplete session, said here too
from gonio.session.options import DEFAULT_SIM_RESOLUTION  # noqa: F401 - the simulated camera's default resolution

#: Uniform in half/difference angles: the uniform plan on the Pareto front (lab time vs BRDF error) of
#: benchmarks/report/REPORT.md's plan table nearest its knee (the knee itself is an adaptive session).
DEFAULT_PLAN = "half_diff"


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
    p.add_argument("--material", metavar="FILE", help="material of the simulated sample: a TOML (model + [params]), "
                   "or a measured one (MERL .binary, RGL .bsdf, gonio NPZ) or a fit JSON, recorded with its "
                   "SHA-256; on hardware only its label is recorded")
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
                        "emulated ATmega328P, in lockstep with the simulated clock)")
    p.add_argument("--sim-camera", choices=("direct", "gige"), default="direct",
                   help="gige: the simulated camera is served as a GigE Vision device on 127.0.0.1 and read "
                        "through gonio's Aravis backend (needs gir1.2-aravis-0.8 and gonio[genicam]), in "
                        "--sim-pixel-format; direct (default): called in-process")
    p.add_argument("--sim-pixel-format", default="", metavar="FORMAT",
                   help="with --sim-camera gige: the GenICam pixel format (RGB12 by default, 12 bits like the default "
                        "camera; RGB8, Mono8, Mono12, Mono16, BayerRG8/12, ...: what the simulated GigE camera offers); "
                        "the simulated sensor takes its bit depth; recorded in the manifest's sim.pixel_format")
    p.add_argument("--keep-pixels", action="store_true",
                   help="a sphere target: keep each pose's per-pixel samples and footprints in OUT/pixels/*.npz "
                        "(for a footprint-aware fit of a lobe narrower than a pixel)")
    p.add_argument("--sim-sphere-offset", metavar="X,Y,Z", default=None,
                   help="a sphere target as built: its true centre this far (mm) from the declared one")
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


# -- measure -------------------------------------------------------------------------------------
def run_measure(args) -> int:
    from gonio.rig.kinematics import load_rig, read_rig_text
    from gonio.session.api import measure
    from gonio.session.options import (HardwareOptions, SimOptions, TimingOptions, check_session_dir,
                                       default_session_dir, load_material_file)
    from gonio.session.rigs import open_rig

    out = args.out or default_session_dir()
    hardware = HardwareOptions(servo_port=args.servo_port, controller_port=args.controller_port,
                               camera=args.camera, calibration=args.calibration)
    if not args.sim:
        missing = hardware.missing(args.rig)
        if missing:
            from gonio.errors import ConfigError

            raise ConfigError.field(None, missing[0], None, "required on hardware (or use --sim for the simulated rig)")
    rig_src = (args.rig or "default") if args.sim else args.rig
    rig_text, rig_where = read_rig_text(rig_src)
    rig = load_rig(text=rig_text, source=rig_where)
    material = load_material_file(args.material) if (args.sim or args.material) else None
    for note in (material.defaults_note(), getattr(material, "note", "")) if material is not None else ():
        if note:
            print(note)
    from gonio.cli.plan import measure_plan_from_args

    plan, adaptive = measure_plan_from_args(args, rig, default=DEFAULT_PLAN)
    check_session_dir(out)
    timing = TimingOptions(accurate=args.accurate, warmup_wait=args.warmup_wait, darks=args.darks).as_dict()
    sim = None
    if args.sim:
        sim = SimOptions(resolution=args.sim_resolution, frame_faults=args.sim_frame_faults,
                         controller=getattr(args, "sim_controller", "firmware"), camera=args.sim_camera,
                         as_built=getattr(args, "sim_as_built", ""), seed=args.seed,
                         pixel_format=getattr(args, "sim_pixel_format", ""),
                         sphere_offset_mm=getattr(args, "sim_sphere_offset", None))
    with open_rig(rig_src if args.sim else str(args.rig), sim=sim, hardware=None if args.sim else hardware,
                  material=material, target=args.target, hold=True) as opened:

        def started(store, plan):
            if not args.sim:
                _say_noise_defaults(store.manifest, args.calibration)
            _say_plan(plan, store, args.quiet, rig)

        result = measure(opened, plan, out, seed=args.seed, timing=timing, adaptive=adaptive, on_start=started,
                         progress=None if args.quiet else sys.stderr, keep_pixels=getattr(args, "keep_pixels", False))
    return print_outcome(result)


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
    from gonio.session.recording import store_timing
    from gonio.session.runner import format_lab_time

    timing = store_timing(store)
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
    if plan.generator == "sparse" and isinstance(plan.params.get("expected_error"), (int, float)):
        dropped = f" (prior {plan.params.get('prior')}; {plan.n_dropped} unreachable candidates never planned)"
        eta += (f"; expected reconstruction error {plan.params['expected_error']:.3g} (RMS, log domain; "
                "`gonio reconstruct` gives the table)")
    print(f"session {store.directory}: plan {plan.generator}, {len(plan)} poses{dropped}{eta}", file=sys.stderr)


def print_outcome(result) -> int:
    """Print how a session run ended (:class:`gonio.session.api.SessionResult`) and return its exit status; a
    calibration session's estimate or check (:mod:`gonio.cli.calibrate`) when all its poses are measured."""
    if result.kind == "calibration":
        from gonio.cli.calibrate import print_calibration_outcome

        return print_calibration_outcome(result)
    run = result.run
    from gonio.sphere.refine import centre_note

    note = centre_note(result.manifest.get("sphere_centre"))
    if note:
        print(note, file=sys.stderr)
    if result.kind == "adaptive":
        from gonio.session.adaptive import model_table, rounds_table

        print(f"adaptive: {len(run.rounds)} rounds, " + (f"stopped ({run.stop})" if run.stop else "not finished"))
        print("\n".join(rounds_table(run.rounds)))
        if run.model is not None:
            print("\n".join(model_table(run.model)))
    resets = result.recovered_faults.get("controller_resets", 0)
    if resets:  # recovered (re-handshake, light restored), but a board that browns out needs looking at
        print(f"gonio: the rig controller reset {resets} time{'s' if resets > 1 else ''} during this run (recovered: "
              "handshake and light restored); check its power supply and USB cable", file=sys.stderr)
    print(f"{run.measured} poses, {run.samples} samples measured in this run "
          f"({result.poses_done}/{result.poses_total} poses, {result.samples_total} samples in {result.directory})")
    from gonio.session.runner import format_lab_time

    print(f"lab time {format_lab_time(run.lab_time)} ({'simulated' if result.simulated else 'real'}), "
          f"wall time {run.wall_time:.1f} s")
    if run.skipped:
        print(f"{len(run.skipped)} poses skipped: " + "; ".join(f"pose {k}: {r}" for k, r in run.skipped[:3]))
    from gonio.session.usability import outcome_lines

    for line in outcome_lines(result):
        print(line, file=sys.stderr)
    code = result.exit_code
    if code in (0, 130) or result.status.startswith("unusable"):
        return code
    if code == INCOMPLETE_EXIT:
        failed = getattr(run, "failed", [])
        print(f"gonio: session incomplete: {len(failed)} poses not measured (bad camera frames), e.g. pose "
              f"{failed[0][0]}: {failed[0][1]}; `gonio status {result.directory}` lists them, "
              f"`gonio resume {result.directory}` measures them again", file=sys.stderr)
        return code
    print(f"gonio: session ended: {result.status}; resume with `gonio resume {result.directory}`", file=sys.stderr)
    return code


# -- resume --------------------------------------------------------------------------------------
def run_resume(args) -> int:
    from gonio.session.api import resume

    def started(store, remaining):
        if store.repaired is not None:
            q = store.repaired["quarantined"]
            where = ", ".join("line %s" % r["line"] for r in q[:5])
            print(f"repaired {store.directory}: {len(q)} damaged record(s) moved to quarantine.jsonl ({where}); "
                  "their poses are measured again", file=sys.stderr)
        ad, plan = store.manifest_entry("adaptive"), store.manifest_entry("plan")  # read only, not a copy (~1 MB)
        adapting = isinstance(ad, dict) and ad.get("stop") is None
        if not args.quiet:
            print(f"resuming {store.directory}: {len(remaining)} of {len(plan['poses'])} poses remaining"
                  + ("; then adapting from the stored samples" if adapting else ""), file=sys.stderr)

    result = resume(args.dir, rig_file=args.rig, servo_port=args.servo_port, controller_port=args.controller_port,
                    camera=args.camera, on_start=started, progress=None if args.quiet else sys.stderr)
    if result.nothing_to_resume:
        print(f"{args.dir}: all {result.poses_total} poses are measured; nothing to resume (not counted as a resume)")
        if not result.ok:  # every pose stored, most of them unusable (gonio.session.usability): it stays so
            print(f"gonio: the session ended {result.status}", file=sys.stderr)
            return result.exit_code
        if result.kind == "calibration":  # every pose measured: the calibration's estimate may still be missing
            from gonio.cli.calibrate import finish_from_directory

            return finish_from_directory(result.directory, result.manifest, rig_file=args.rig)
        return 0
    return print_outcome(result)
