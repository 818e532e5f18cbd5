"""``gonio plan NAME --PARAM VALUE ... [--estimate] [--out PLAN.json]``: generate a measurement plan,
order it for lab time, report what was dropped and (with ``--estimate``) its lab time against a lower
bound and the raster, one-axis-at-a-time baseline. Angles in degrees here, radians in the plan file."""

from __future__ import annotations


def add_plan_options(p, *, default_plan: str | None = None) -> None:
    """Options shared by ``gonio plan`` and ``gonio measure``: every generator's parameters (degrees),
    capture settings and pose order. ``default_plan`` adds ``--plan NAME`` (measure); without it the
    generator is the positional NAME (plan)."""
    from gonio.plan.generators import GENERATORS

    if default_plan is not None:
        p.add_argument("--plan", default=default_plan, metavar="NAME",
                       help=f"plan generator (default {default_plan}): {', '.join(GENERATORS)}; its parameters as "
                            "options below, angles in degrees")
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
    c.add_argument("--exposures", default=None, metavar="S,S,...", help="exposure bracket, seconds")
    c.add_argument("--frames", type=int, default=None, help="frames averaged per exposure")
    c.add_argument("--gain", type=float, default=None, help="analogue gain")
    c.add_argument("--settle", type=float, default=None, help="settle time after each move, seconds")
    p.add_argument("--order", choices=["optimized", "raster"], default="optimized", help="pose order")


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

    gen = GENERATORS.get(name)
    if gen is None:
        raise ConfigError.field(where, "plan", name, f"unknown plan; known: {', '.join(GENERATORS)}")
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


def register(sub) -> None:
    from gonio.plan.generators import GENERATORS

    p = sub.add_parser("plan", help="generate a measurement plan and estimate its lab time",
                       description="Generate a plan (poses the rig can reach, ordered for lab time). "
                                   "Plans: " + "; ".join(f"{g.name}: {g.doc}" for g in GENERATORS.values()))
    p.add_argument("name", metavar="NAME", help=f"plan generator: {', '.join(GENERATORS)}")
    add_plan_options(p)
    p.add_argument("--rig", default=None, metavar="RIG.toml", help="rig description (default: the shipped rig)")
    p.add_argument("--seed", type=int, default=0, help="seed of the ordering heuristic")
    p.add_argument("--time-budget", type=float, default=None, metavar="S",
                   help="cap on the seconds spent ordering (default: none, so the order is reproducible)")
    p.add_argument("--estimate", action="store_true", help="print lab time, lower bound and raster baseline")
    p.add_argument("--out", metavar="PLAN.json", help="write the plan as JSON")
    p.set_defaults(func=run)


def run(args) -> int:
    import json
    import math
    import os
    from pathlib import Path

    from gonio.errors import ConfigError
    from gonio.plan import GENERATORS, estimate_plan
    from gonio.rig.kinematics import load_rig

    rig = load_rig(args.rig)
    plan = plan_from_args(args, args.name, rig, where="NAME", source="gonio plan", time_budget=args.time_budget)
    gen = GENERATORS[args.name]

    shown = ", ".join(f"{k} = {math.degrees(v):g} deg" if gen.params[k].kind == "angle" else f"{k} = {v:g}"
                      for k, v in plan.params.items() if k in gen.params)
    print(f"plan {plan.generator} ({shown}) on rig {rig.name!r}: {len(plan)} poses, {plan.order} order")
    if plan.n_dropped:
        why = ", ".join(f"{n} {r}" for r, n in sorted(plan.dropped_reasons().items()))
        print(f"dropped {plan.n_dropped} poses: {why}")
    cap = plan.capture
    print(f"capture: exposures {', '.join(f'{e:g}' for e in cap.exposures)} s x {cap.frames} frames, gain {cap.gain:g}, "
          f"settle {cap.settle:g} s -> {cap.pose_time():.3f} s per pose")
    if args.estimate:
        e = estimate_plan(plan, rig)

        def hms(t: float) -> str:
            return f"{t:10.1f} s  ({int(t // 3600)}:{int(t % 3600 // 60):02d}:{t % 60:04.1f})"

        print(f"lab time, this order:                     {hms(e.optimized)}")
        print(f"lower bound (N*pose time + MST of moves): {hms(e.lower_bound)}   this order / bound = {e.ratio_to_bound:.3f}")
        print(f"raster order, one axis at a time:         {hms(e.raster)}   this order / raster = {e.ratio_to_raster:.3f}")
        print(f"raster order, joints together:            {hms(e.raster_concurrent)}")
    if args.out:
        out = Path(args.out)
        data = json.dumps(plan.to_dict()) + "\n"
        try:
            tmp = out.with_name(f".{out.name}.tmp")
            tmp.write_text(data, encoding="utf-8")
            os.replace(tmp, out)
        except OSError as exc:
            raise ConfigError.field("--out", "file", str(out), f"cannot write: {exc.strerror}") from None
        print(f"wrote {out}")
    return 0
