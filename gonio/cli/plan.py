"""``gonio plan NAME --PARAM VALUE ... [--estimate] [--out PLAN.json]``: generate a measurement plan,
order it for lab time, report what was dropped and (with ``--estimate``) its lab time against a lower
bound and the raster, one-axis-at-a-time baseline. Angles in degrees here, radians in the plan file."""

from __future__ import annotations

#: Candidate poses of an adaptive plan when none are given (degrees).
ADAPTIVE_CANDIDATES = "isotropic"
ADAPTIVE_CANDIDATE_PARAMS = {"theta_step": 10.0, "phi_step": 30.0, "theta_max": 70.0}
ADAPTIVE_MODEL = "microfacet"
ADAPTIVE_TARGET = 0.02
#: Poses of a sparse plan when --n is not given (benchmarks sparse: the issue's twenty).
SPARSE_N = 20
_ADAPTIVE_OPTS = ("candidates", "model", "select", "target_error", "lab_budget", "batch", "coarse", "max_rounds")


def add_plan_options(p, *, default_plan: str | None = None) -> None:
    """Options shared by ``gonio plan`` and ``gonio measure``: every generator's parameters (degrees),
    capture settings and pose order. ``default_plan`` adds ``--plan NAME`` (measure); without it the
    generator is the positional NAME (plan)."""
    from gonio.plan.generators import GENERATORS

    if default_plan is not None:
        p.add_argument("--plan", default=default_plan, metavar="NAME",
                       help=f"plan generator (default {default_plan}): {', '.join(GENERATORS)}, adaptive or sparse; its "
                            "parameters as options below, angles in degrees")
    g = p.add_argument_group("plan parameters (each plan takes some; angles in degrees)")
    seen = set()
    for gen in GENERATORS.values():
        for name, spec in gen.params.items():
            if name in seen:
                continue
            seen.add(name)
            unit = " (deg)" if spec.kind == "angle" else ""
            g.add_argument(f"--{name.replace('_', '-')}", dest=f"plan_{name}", type=float, default=None,
                           metavar="V", help=f"{spec.doc}{unit}")
    c = p.add_argument_group("capture settings")
    c.add_argument("--exposures", default=None, metavar="S,S,...",
                   help="fixed exposure bracket, seconds")
    c.add_argument("--frames", type=int, default=None, help="frames averaged per exposure (fixes the bracket too)")
    c.add_argument("--gain", type=float, default=None, help="analogue gain")
    c.add_argument("--settle", type=float, default=None, help="settle time after each move, seconds")
    p.add_argument("--order", choices=["optimized", "raster"], default="optimized", help="pose order")
    a = p.add_argument_group("adaptive plan (plan adaptive: measure a coarse round, fit, add poses where the model is "
                             "least certain or fits worst; the plan parameters above describe the candidate poses)")
    a.add_argument("--candidates", default=None, metavar="NAME",
                   help=f"generator of the candidate poses (default {ADAPTIVE_CANDIDATES} "
                        + ", ".join(f"{k} {v:g}" for k, v in ADAPTIVE_CANDIDATE_PARAMS.items()) + ")")
    a.add_argument("--model", default=None, metavar="NAME", help=f"model fitted each round (default {ADAPTIVE_MODEL})")
    a.add_argument("--select", nargs="?", const="", default=None, metavar="M1,M2,...",
                   help="choose the model each round among these (gonio fit's default candidates if none given)")
    a.add_argument("--target-error", type=float, default=None, metavar="E",
                   help=f"stop when a round is predicted with relative RMS error <= E (default {ADAPTIVE_TARGET:g})")
    a.add_argument("--lab-budget", type=float, default=None, metavar="S",
                   help="stop when the poses' lab time (moves + settle + capture + a light check per round) would "
                        "exceed S seconds (default: none)")
    a.add_argument("--batch", type=int, default=None, metavar="N", help="poses added per round (default 16)")
    a.add_argument("--coarse", type=int, default=None, metavar="N", help="poses of the coarse first round (default 24)")
    a.add_argument("--max-rounds", type=int, default=None, metavar="N", help="rounds at most (default 20)")
    sp = p.add_argument_group("sparse plan (plan sparse: N poses chosen under a BRDF prior to minimise the expected "
                              "error of the reconstructed table; then gonio reconstruct)")
    sp.add_argument("--n", dest="sparse_n", type=int, default=None, metavar="N",
                    help=f"poses of a sparse plan (default {SPARSE_N})")
    from gonio.cli.prior import add_prior_option

    add_prior_option(sp)
    sp.add_argument("--adaptive", dest="sparse_adaptive", action="store_true", default=None,
                    help="gonio measure: choose each next pose while measuring, the one that most reduces the expected "
                         "error under the posterior of the samples so far; stops at --target-error (the expected "
                         "error, default: none) or --max-poses (--coarse N fixed-design poses first, default 4; "
                         "--batch per round, default 1)")
    sp.add_argument("--max-poses", dest="max_poses", type=int, default=None, metavar="N",
                    help="plan sparse --adaptive: poses at most (default 20)")


def _capture(args):
    from dataclasses import replace

    from gonio.errors import ConfigError, DataError
    from gonio.plan.plan import CaptureSettings

    cs = CaptureSettings()
    changes = {}
    if args.exposures is not None:
        try:
            changes["exposures"] = tuple(float(x) for x in args.exposures.split(","))
        except ValueError:
            raise ConfigError.field("--exposures", "exposures", args.exposures, "must be numbers, e.g. 0.01,0.04") from None
    for key in ("frames", "gain", "settle"):
        if getattr(args, key) is not None:
            changes[key] = getattr(args, key)
    if args.exposures is not None or args.frames is not None:
        changes["auto_exposure"] = False  # a bracket given on the command line is captured as given
    try:
        return replace(cs, **changes)
    except DataError as exc:
        raise ConfigError(f"capture settings: {str(exc).removeprefix('plan: ')}") from None


def plan_from_args(args, name: str, rig, *, where: str, source: str, defaults=None, time_budget=None):
    """Build the plan the options of :func:`add_plan_options` describe.

    ``defaults`` (degrees) apply when no plan parameter was given; ``where`` names the option that
    chose the generator and ``source`` the command, in error messages.
    """
    import math

    from gonio.errors import ConfigError
    from gonio.plan.generators import GENERATORS, make_plan

    if name == "adaptive":
        from gonio.plan.adaptive import AdaptivePlanner
        from gonio.plan.ordering import MotionModel

        candidates, settings, spec = adaptive_from_args(args, rig, source=source)
        planner = AdaptivePlanner(candidates, spec.callable(), motion=MotionModel.from_rig(rig), settings=settings)
        return planner.plan([planner.first_round()], extra={"fit": spec.to_dict()})
    sparse_given = [o for o in ("sparse_n", "prior", "sparse_adaptive", "max_poses") if getattr(args, o, None) is not None]
    if name == "sparse":
        return sparse_from_args(args, rig, source=source, time_budget=time_budget)
    if sparse_given:
        _refuse_options(args, sparse_given[:1], "only for plan sparse")
    gen = GENERATORS.get(name)
    if gen is None:
        raise ConfigError.field(where, "plan", name, f"unknown plan; known: {', '.join(GENERATORS)}, adaptive, sparse")
    given_adaptive = [o for o in _ADAPTIVE_OPTS if getattr(args, o, None) is not None]
    if given_adaptive and where != "--candidates":
        o = given_adaptive[0]
        raise ConfigError.field(f"--{o.replace('_', '-')}", "option", getattr(args, o), "only for plan adaptive")
    given = {k[5:]: v for k, v in vars(args).items() if k.startswith("plan_") and v is not None}
    for k in given:
        if k not in gen.params:
            raise ConfigError.field(f"--{k.replace('_', '-')}", "plan parameter", given[k],
                                    f"not a parameter of plan {name!r} (it takes "
                                    f"{', '.join('--' + n.replace('_', '-') for n in gen.params)})")
    if not given and defaults:
        given = dict(defaults)
    params = {k: (math.radians(v) if gen.params[k].kind == "angle" else v) for k, v in given.items()}
    return make_plan(name, rig=rig, capture=_capture(args), order=args.order, seed=args.seed,
                     time_budget=time_budget, source=source, **params)


def sparse_from_args(args, rig, *, source, time_budget=None):
    """The sparse plan (:func:`gonio.prior.design.sparse_plan`) the options describe: ``--n`` poses under
    ``--prior`` (default: the shipped prior), with the capture settings and order of any plan."""
    from gonio.cli.prior import load_prior_arg
    from gonio.errors import ConfigError
    from gonio.prior.design import sparse_plan

    given = [k for k, v in vars(args).items() if k.startswith("plan_") and k != "plan_file" and v is not None]
    if given:
        k = given[0][5:]
        raise ConfigError.field(f"--{k.replace('_', '-')}", "plan parameter", getattr(args, given[0]),
                                "not a parameter of plan 'sparse' (it takes --n and --prior)")
    if getattr(args, "sparse_adaptive", None):
        raise ConfigError.field("--adaptive", "option", True, "the poses are chosen while measuring: "
                                "gonio measure --plan sparse --adaptive")
    _refuse_options(args, ("sparse_adaptive", "max_poses", *_ADAPTIVE_OPTS), "only for plan sparse --adaptive "
                    "(or plan adaptive)")
    n = SPARSE_N if getattr(args, "sparse_n", None) is None else args.sparse_n
    if not 1 <= n <= 1000:
        raise ConfigError.field("--n", "n", n, "must be in [1, 1000]")
    prior, name = load_prior_arg(getattr(args, "prior", None))
    return sparse_plan(n, prior, rig=rig, capture=_capture(args), order=args.order, seed=args.seed,
                       time_budget=time_budget, prior_name=name, source=source)


def _refuse_options(args, names, why: str) -> None:
    """A one-line ConfigError naming the first of the options ``names`` (dests) that was given."""
    from gonio.errors import ConfigError

    for o in names:
        if getattr(args, o, None) is not None:
            flag = {"sparse_n": "--n", "sparse_adaptive": "--adaptive"}.get(o, f"--{o.replace('_', '-')}")
            raise ConfigError.field(flag, "option", getattr(args, o), why)


def sparse_adaptive_from_args(args, rig, *, source: str = "--plan sparse --adaptive") -> dict:
    """The ``plan`` and ``adaptive`` manifest entries of ``gonio measure --plan sparse --adaptive``
    (:func:`gonio.prior.adaptive.new_sparse_adaptive_manifest`): ``--prior``, ``--target-error``, ``--max-poses``,
    ``--coarse``, ``--batch``, ``--lab-budget`` and the capture settings."""
    import math

    from gonio.errors import ConfigError
    from gonio.prior.adaptive import SparseAdaptiveSettings, new_sparse_adaptive_manifest
    from gonio.session.runner import RunnerSettings

    given = [k for k, v in vars(args).items() if k.startswith("plan_") and k != "plan_file" and v is not None]
    if given:
        k = given[0][5:]
        raise ConfigError.field(f"--{k.replace('_', '-')}", "plan parameter", getattr(args, given[0]),
                                "not a parameter of plan 'sparse' (it takes --n and --prior)")
    _refuse_options(args, ("sparse_n",), "plan sparse --adaptive takes --max-poses (the poses are chosen while "
                    "measuring)")
    _refuse_options(args, ("candidates", "model", "select", "max_rounds"), "not an option of plan sparse --adaptive")
    for opt, lo in (("batch", 1), ("coarse", 1), ("max_poses", 1)):
        v = getattr(args, opt, None)
        if v is not None and not lo <= v <= 1000:
            raise ConfigError.field(f"--{opt.replace('_', '-')}", opt, v, f"must be in [{lo}, 1000]")
    for opt in ("target_error", "lab_budget"):
        v = getattr(args, opt, None)
        if v is not None and (not math.isfinite(v) or v < 0 or (opt == "lab_budget" and v == 0)):
            raise ConfigError.field(f"--{opt.replace('_', '-')}", opt, v,
                                    "must be positive seconds" if opt == "lab_budget" else "must be >= 0")
    settings = SparseAdaptiveSettings(
        n_initial=4 if args.coarse is None else args.coarse, batch=1 if args.batch is None else args.batch,
        target_error=0.0 if args.target_error is None else args.target_error,
        max_poses=20 if getattr(args, "max_poses", None) is None else args.max_poses,
        lab_budget=math.inf if args.lab_budget is None else args.lab_budget, seed=args.seed,
        round_overhead=RunnerSettings().timing.warmup_step)
    return new_sparse_adaptive_manifest(rig, prior_arg=getattr(args, "prior", None), settings=settings,
                                        capture=_capture(args))


def adaptive_from_args(args, rig, *, source: str):
    """``(candidates, AdaptiveSettings, FitSpec)`` of an adaptive plan from the options of
    :func:`add_plan_options`: the candidates are the ``--candidates`` generator's poses (its parameters
    as given, or :data:`ADAPTIVE_CANDIDATE_PARAMS` for the default generator), in raster order."""
    import math

    from gonio.errors import ConfigError
    from gonio.plan.adaptive import AdaptiveSettings
    from gonio.session.adaptive import FitSpec
    from gonio.session.runner import RunnerSettings

    _refuse_options(args, ("sparse_n", "prior", "sparse_adaptive", "max_poses"), "only for plan sparse")
    name = args.candidates or ADAPTIVE_CANDIDATES
    if name == "adaptive":
        raise ConfigError.field("--candidates", "plan", name, "the candidates must come from a generator")
    ns = _copy_args(args, order="raster")
    defaults = ADAPTIVE_CANDIDATE_PARAMS if name == ADAPTIVE_CANDIDATES else None
    candidates = plan_from_args(ns, name, rig, where="--candidates", source=source, defaults=defaults)
    for opt, lo in (("batch", 1), ("coarse", 1), ("max_rounds", 1)):
        v = getattr(args, opt)
        if v is not None and v < lo:
            raise ConfigError.field(f"--{opt.replace('_', '-')}", opt, v, f"must be >= {lo}")
    for opt in ("target_error", "lab_budget"):
        v = getattr(args, opt)
        if v is not None and (not math.isfinite(v) or v < 0 or (opt == "lab_budget" and v == 0)):
            raise ConfigError.field(f"--{opt.replace('_', '-')}", opt, v,
                                    "must be positive seconds" if opt == "lab_budget" else "must be >= 0")
    settings = AdaptiveSettings(
        n_initial=24 if args.coarse is None else args.coarse, batch=16 if args.batch is None else args.batch,
        target_error=ADAPTIVE_TARGET if args.target_error is None else args.target_error,
        lab_budget=math.inf if args.lab_budget is None else args.lab_budget,
        max_rounds=20 if args.max_rounds is None else args.max_rounds, seed=args.seed,
        round_overhead=RunnerSettings().timing.warmup_step)
    if args.select is not None and args.model is not None:
        raise ConfigError.field("--select", "option", args.select, "give --model or --select, not both")
    select = None if args.select is None else tuple(m.strip() for m in args.select.split(",") if m.strip())
    if select == ():
        from gonio.fit.select import DEFAULT_CANDIDATES

        select = tuple(DEFAULT_CANDIDATES)
    return candidates, settings, FitSpec(model=args.model or ADAPTIVE_MODEL, select=select)


def _copy_args(args, **changes):
    import argparse

    return argparse.Namespace(**{**vars(args), **changes})


def register(sub) -> None:
    from gonio.plan.generators import GENERATORS

    p = sub.add_parser("plan", help="generate a measurement plan and estimate its lab time",
                       description="Generate a plan (poses the rig can reach, ordered for lab time). "
                                   "Plans: " + "; ".join(f"{g.name}: {g.doc}" for g in GENERATORS.values()))
    p.add_argument("name", metavar="NAME", help=f"plan generator: {', '.join(GENERATORS)}, adaptive (a coarse "
                   "first round; later rounds are chosen while measuring), or sparse (--n poses chosen under a "
                   "BRDF prior; gonio reconstruct then gives the whole table)")
    add_plan_options(p)
    p.add_argument("--rig", default=None, metavar="RIG.toml", help="rig description (default: the shipped rig)")
    p.add_argument("--seed", type=int, default=0, help="seed of the ordering heuristic")
    p.add_argument("--time-budget", type=float, default=None, metavar="S",
                   help="cap on the seconds spent ordering (default: none, so the order is reproducible)")
    p.add_argument("--estimate", action="store_true", help="print lab time, lower bound and raster baseline")
    p.add_argument("--accurate", action="store_true", help="estimate with gonio measure --accurate's light and dark "
                   "strategy (wait for a stable light, re-measure the dark set) instead of the default")
    p.add_argument("--out", metavar="PLAN.json", help="write the plan as JSON")
    p.add_argument("--force", action="store_true", help="overwrite an existing --out file")
    s = p.add_argument_group("plan sphere: the MERL cells it fills, before anything moves")
    s.add_argument("--target", metavar="TARGET.toml", help="the target file declaring the [sphere] (default: a "
                   "20 mm ball on the board's centre)")
    s.add_argument("--sim-resolution", metavar="WxH", default=None,
                   help="the camera: the simulated one at this resolution (default 320x240)")
    s.add_argument("--calibration", metavar="CAMERA.toml", help="the camera: a rig's camera file")
    s.add_argument("--fill", type=float, default=None, metavar="F",
                   help="choose the light positions greedily for the cells they fill per lab second until this "
                        "fraction of the reachable cells is filled (e.g. 0.9); candidates every --theta-i-step and "
                        "--phi-i-step (default 1 and 3 deg: ~10,000 light positions, about a minute to plan)")
    s.add_argument("--fill-budget", type=float, default=None, metavar="S",
                   help="with --fill: stop at this much lab time (seconds, default 1200)")
    p.set_defaults(func=run)


def run(args) -> int:
    import math

    from gonio.plan import GENERATORS, estimate_plan
    from gonio.rig.kinematics import load_rig

    if args.out:  # refused before the plan is computed and ordered (10^5 poses take seconds), not after
        from gonio.io.outputs import check_output

        check_output(args.out, option="--out", force=getattr(args, "force", False), suffixes=(".json",))
    rig = load_rig(args.rig)
    # source=None: the CLI's own prefix ("gonio plan: error: ") already names the command
    plan = plan_from_args(args, args.name, rig, where="NAME", source=None, time_budget=args.time_budget)
    if args.name == "adaptive":
        return _print_adaptive(args, plan, rig)
    for o in ("target", "sim_resolution", "calibration", "fill", "fill_budget"):
        if getattr(args, o, None) is not None and args.name != "sphere":
            from gonio.errors import ConfigError

            raise ConfigError.field(f"--{o.replace('_', '-')}", "option", getattr(args, o), "only for plan sphere")
    if args.name == "sphere" and (getattr(args, "fill", None) is not None or getattr(args, "fill_budget", None)):
        plan = _greedy_sphere(args, plan, rig)
    if args.name == "sparse":
        p = plan.params
        print(f"plan sparse (n = {p['n']}, prior {p['prior']}) on rig {rig.name!r}: {len(plan)} poses chosen among "
              f"the reachable candidates, {plan.order} order")
        print(f"expected reconstruction error: {p['expected_error']:.3g} RMS in the log domain (~relative error of f; "
              f"the prior alone: {p['expected_error_prior']:.3g}; cube-root error about a third of it)")
    else:
        gen = GENERATORS[args.name]
        shown = ", ".join(f"{k} = {math.degrees(v):g} deg" if gen.params[k].kind == "angle" else f"{k} = {v:g}"
                          for k, v in plan.params.items() if k in gen.params)
        print(f"plan {plan.generator} ({shown}) on rig {rig.name!r}: {len(plan)} poses, {plan.order} order")
    if plan.n_dropped and args.name == "sparse":
        print(f"candidates the rig cannot reach (never planned): {plan.n_dropped}: {plan.dropped_summary()}")
    elif plan.n_dropped:
        why = plan.dropped_summary()
        print(f"dropped {plan.n_dropped} poses: {why}")
    cap = plan.capture
    bracket = f"exposures {', '.join(f'{e:g}' for e in cap.exposures)} s x {cap.frames} frame{'s' * (cap.frames != 1)}"
    print(f"capture: {'automatic exposure per pose (expected ' + bracket + ')' if cap.auto_exposure else bracket}, "
          f"gain {cap.gain:g}, settle {cap.settle:g} s, readout {cap.readout:g} s/frame -> "
          f"{cap.pose_time():.3f} s per pose + moves")
    if args.estimate:
        from gonio.plan.labtime import SessionTiming

        timing = SessionTiming.accurate() if args.accurate else SessionTiming()
        e = estimate_plan(plan, rig, timing)

        def hms(t: float) -> str:
            return f"{t:10.1f} s  ({int(t // 3600)}:{int(t % 3600 // 60):02d}:{t % 60:04.1f})"

        a = e.account
        print(f"lab time, this order:                     {hms(e.optimized)}")
        print(f"  start-up (darks + warm-up) {a['startup']:.1f} s, moves {a['moves']:.1f} s, settle {a['settle']:.1f} s, "
              f"capture {a['capture']:.1f} s, {a['refreshes']} dark {'re-measurements' if timing.darks == 'measured' else 'checks'} "
              f"{a['refresh_time']:.1f} s")
        print(f"  ({timing.describe()})")
        if e.auto_exposure:
            print("  (automatic exposure: capture estimated with the expected bracket; each pose's is chosen "
                  "while measuring)")
        print(f"lower bound (MST moves, minimum costs):   {hms(e.lower_bound)}   this order / bound = {e.ratio_to_bound:.3f}")
        print(f"raster order, one axis at a time:         {hms(e.raster)}   this order / raster = {e.ratio_to_raster:.3f}")
        print(f"raster order, joints together:            {hms(e.raster_concurrent)}")
    if args.name == "sphere":
        _print_sphere_coverage(args, plan, rig)
    _write(args, plan)
    return 0


#: The simulated camera's focal length at 320 px wide (sim.rig.SimRigConfig.focal_px; gonio does not import sim).
SIM_FOCAL_PX = 380.0


#: The greedy sphere plan's candidate light steps (zenith, azimuth; degrees) unless given: on the default rig and
#: camera (320x240) the 20-minute plan fills 44 % of the reachable cells from 1° x 3° candidates, 39 % from
#: 2.5° x 10° (benchmarks sphere; the greedy picks the best ~1,300 of ~10,000 light positions)
GREEDY_STEPS_DEG = {"theta_i_step": 1.0, "phi_i_step": 3.0}


def _greedy_sphere(args, plan, rig):
    """``--fill``: the sphere plan chosen for cells per lab second (:func:`gonio.session.sphere_plan.greedy_sphere_plan`),
    its candidates the given sphere plan's parameters (denser defaults)."""
    import math

    from gonio.errors import ConfigError
    from gonio.session.sphere_plan import greedy_sphere_plan

    fill = 0.9 if args.fill is None else args.fill
    if not (0.0 < fill <= 1.0):
        raise ConfigError.field("--fill", "option", fill, "must be a fraction in (0, 1]")
    budget = 1200.0 if args.fill_budget is None else args.fill_budget
    if not (math.isfinite(budget) and budget > 0):
        raise ConfigError.field("--fill-budget", "option", budget, "must be positive seconds")
    sphere, calib, layout = _sphere_camera(args)
    p = plan.params
    steps = {k: (p[k] if getattr(args, f"plan_{k}", None) is not None else math.radians(d))
             for k, d in GREEDY_STEPS_DEG.items()}
    greedy, info = greedy_sphere_plan(rig, calib, sphere, theta_o=p["theta_o"], theta_max=p["theta_max"],
                                      coverage=fill, budget=budget, capture=plan.capture, seed=args.seed,
                                      layout=layout, **steps)
    print(f"greedy: {info['poses']} of {info['candidates']} candidate light positions fill {info['filled']} cells, "
          f"{100 * info['filled'] / max(info['reachable'], 1):.1f} % of the {info['reachable']} the rig can reach "
          f"(all the candidates: {info['candidates_reach']}), in {info['lab_s'] / 60:.1f} lab min (estimated)")
    return greedy


def _sphere_camera(args):
    """The declared sphere and the camera of ``gonio plan sphere`` (--target, --sim-resolution, --calibration)."""
    from gonio.pipeline.target import TargetLayout, load_target
    from gonio.session.options import DEFAULT_SIM_RESOLUTION, parse_resolution
    from gonio.sphere import Sphere

    layout = load_target(args.target) if args.target else TargetLayout(sphere=Sphere((0.0, 0.0, 0.02), 0.02))
    if layout.sphere is None:
        from gonio.errors import ConfigError

        raise ConfigError.field("--target", "sphere", args.target, "declares no [sphere] (radius, centre)")
    if args.calibration:
        from gonio.rig.calibration import load_camera_calibration

        calib = load_camera_calibration(args.calibration).calibration
    else:
        from gonio.pipeline.target import CameraCalibration

        w, h = parse_resolution(args.sim_resolution or DEFAULT_SIM_RESOLUTION)
        calib = CameraCalibration.pinhole(w, h, SIM_FOCAL_PX * w / 320)  # the simulated camera's field of view
    return layout.sphere, calib, layout


def _print_sphere_coverage(args, plan, rig) -> None:
    """The sphere plan's coverage of the MERL table (:func:`gonio.session.sphere_coverage.plan_coverage`)."""
    from gonio.session.sphere_coverage import plan_coverage

    sphere, calib, _ = _sphere_camera(args)
    print("\n".join(plan_coverage(plan, rig, calib, sphere).lines()))


def _print_adaptive(args, plan, rig) -> int:
    """``gonio plan adaptive``: the candidates, the coarse first round (estimated like any plan), and what
    cannot be known before measuring."""
    import math

    from gonio.plan import GENERATORS, estimate_plan

    p = plan.params
    spec = GENERATORS[p["candidates"]].params
    shown = ", ".join(f"{k} = {math.degrees(v):g} deg" if spec[k].kind == "angle" else f"{k} = {v:g}"
                      for k, v in p["candidate_params"].items() if k in spec)
    print(f"plan adaptive on rig {rig.name!r}: candidates {p['candidates']} ({shown}); fit "
          f"{'select among ' + ', '.join(p['fit']['select']) if p['fit']['select'] else p['fit']['model']}")
    print(f"coarse first round: {len(plan)} poses (farthest-point spread), then {p['batch']} poses a round, "
          f"at most {p['max_rounds']} rounds; stop when a round is predicted within {p['target_error']:g} "
          f"(relative RMS)" + (f" or at the lab budget of {p['lab_budget']:g} s" if p["lab_budget"] else ""))
    if plan.n_dropped:
        why = plan.dropped_summary()
        print(f"candidates dropped: {plan.n_dropped} poses: {why}")
    e = estimate_plan(plan, rig)
    print(f"lab time of the coarse round: {e.optimized:.1f} s (lower bound {e.lower_bound:.1f} s)")
    budget = (f"it is at most the lab budget, {p['lab_budget']:g} s (poses + {p['round_overhead']:g} s of light "
              "check per round; the session's start-up, dark frames and warm-up come on top)"
              if p["lab_budget"] else "no --lab-budget is set, so it is bounded only by the round limit "
              f"({p['n_initial']} + {p['max_rounds'] - 1} x {p['batch']} poses at most)")
    print("total lab time: cannot be estimated ahead of time — the later rounds are chosen from the "
          f"measurements; {budget}")
    _write(args, plan)
    return 0


def _write(args, plan) -> None:
    import json

    from gonio.errors import ConfigError

    if args.out:
        from gonio.io.outputs import check_output, write_text_atomically

        out = check_output(args.out, option="--out", force=getattr(args, "force", False), suffixes=(".json",))
        data = json.dumps(plan.to_dict()) + "\n"
        try:
            write_text_atomically(out, data)
        except OSError as exc:
            raise ConfigError.field("--out", "file", str(out), f"cannot write: {exc.strerror}") from None
        print(f"wrote {out}")


def measure_plan_from_args(args, rig, *, default: str):
    """``gonio measure``'s plan: ``--plan-file`` / ``--plan sparse --adaptive`` / ``--plan adaptive`` /
    ``--plan NAME`` (``default``: the command's default plan name), and for an adaptive one its manifest entry:
    ``(plan, adaptive or None)``."""
    from gonio.errors import ConfigError

    if getattr(args, "plan_file", None):
        given = [k for k, v in vars(args).items() if k.startswith("plan_") and k != "plan_file" and v is not None]
        if args.plan != default or given:
            raise ConfigError.field("--plan-file", "plan_file", args.plan_file,
                                    "runs a saved plan: give it without --plan or plan parameters")
        from gonio.io.plan_file import read_plan_file

        plan = read_plan_file(args.plan_file, rig)
        print(f"plan {args.plan_file}: {plan.generator}, {len(plan)} poses")
        return plan, None
    if args.plan == "sparse" and getattr(args, "sparse_adaptive", None):
        adaptive = sparse_adaptive_from_args(args, rig)
        return adaptive["plan"], adaptive["adaptive"]
    if args.plan == "adaptive":
        from gonio.session.adaptive import new_adaptive_manifest

        adaptive = new_adaptive_manifest(*adaptive_from_args(args, rig, source="--plan adaptive"), rig)
        return adaptive["plan"], adaptive["adaptive"]
    return plan_from_args(args, args.plan, rig, where="--plan", source="--plan"), None  # generator defaults
