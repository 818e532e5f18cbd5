"""``gonio fit SOURCE [--model NAME | --select] [--loss NAME] [--json OUT] [--mitsuba OUT.xml]``: fit analytic BRDF models to a
session directory or a MERL ``.binary`` and print a table."""

from __future__ import annotations

from functools import partial

from gonio.cli import many


def register(sub) -> None:
    p = sub.add_parser("fit", help="fit a BRDF model (or choose one) to a session or a MERL file",
                       description="Fit an analytic BRDF model to measured samples (a session directory or a "
                                   "MERL .binary file), or choose among candidates with --select.")
    p.add_argument("source", metavar="SOURCE", nargs="+",
                   help="session directory or data file (MERL .binary, gonio .npz/.csv, ...); several, a "
                        "directory of them or a glob fit each one (in parallel) and print a summary")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--model", default="microfacet", help="model to fit (see `gonio models`; sums such as "
                                                          "lambert+2ggx); default microfacet")
    g.add_argument("--select", action="store_true", help="fit the candidates and choose one")
    p.add_argument("--candidates", default=None, help=_candidates_help())
    p.add_argument("--criterion", default="auto", help="selection criterion: auto, bic, aic, cv, or what a rendering "
                                                       "shows: image (rendered-sphere error), delta-e (their CIELAB "
                                                       "colour difference)")
    p.add_argument("--equivalence", type=float, default=None, metavar="REL",
                   help="--select keeps the simplest candidate whose predictions are within REL (relative) of the "
                        "criterion's choice at every sample (default 0.01: 1 %%, about a gonioreflectometer's accuracy; "
                        "0: the criterion alone)")
    p.add_argument("--metal", action="store_true",
                   help="--select: the sample is a metal (a conductor), which the data alone cannot tell from a dark "
                        "dielectric: the choice is made among the candidates with a metal's Fresnel (normal-incidence "
                        "reflectance >= 0.5) while one remains, and the notes say how much better the best other "
                        "predicts; large tables also get abc-smooth-conductor and dupuy2015-conductor (a conductor's "
                        "complex-index Fresnel with the lobe's own scale) and dupuy2015-coated (the same conductor "
                        "under a thin dielectric coat: an oxidised or lacquered metal)")
    p.add_argument("--loss", default="auto", help="auto, cosine, chi2, log, cbrt (auto: chi2 with uncertainties)")
    p.add_argument("--image-weight", type=float, default=None, metavar="W",
                   help="dupuy2015 fits: weight of the squared relative image error (rendered spheres) beside "
                        "the loss's in what is minimized (default 10; 0: the loss alone, and --select on a large table "
                        "then scores held-out samples by the loss alone too)")
    p.add_argument("--fix", action="append", default=[], metavar="NAME=VALUE",
                   help="hold a parameter fixed (repeatable), e.g. distribution=beckmann or f0=0.9,0.6,0.5")
    p.add_argument("--max-theta", type=float, default=80.0, help="grazing cutoff for θi, θo in degrees (default 80)")
    p.add_argument("--all-angles", action="store_true", help="no grazing cutoff")
    p.add_argument("--seed", type=int, default=0, help="seed of the multi-start (default 0)")
    p.add_argument("--json", metavar="OUT", help="write the result as JSON (several sources: a directory "
                                                 "receiving SOURCE-NAME.json each)")
    p.add_argument("--force", action="store_true", help="overwrite existing output files")
    many.add_options(p)
    p.add_argument("--mitsuba", metavar="OUT.xml|OUT.json",
                   help="also write the fitted model as a Mitsuba 3 BSDF (XML element or load_dict JSON): exact for "
                        "lambert, microfacet/ggx/beckmann lobes with f0 = 1 (or within 1e-3 of it) and their sums; "
                        "with --approx the closest plugin, its error printed: Schlick f0 < 1 lobes as roughconductor "
                        "with the exact Fresnel equations or roughplastic (whichever is closer), other models "
                        "(abc, gtr, ...) as a lambert+ggx fitted to them")
    p.add_argument("--pbrt", metavar="OUT.pbrt", help="also write the fitted model as a pbrt-v4 material (diffuse, "
                   "conductor, mix); refused unless exact or --approx")
    p.add_argument("--gltf", metavar="OUT.gltf", help="also write the fitted model as a glTF 2.0 material on a sphere "
                   "(metallic-roughness + KHR_materials_specular/ior; Blender imports it); refused unless exact or --approx")
    p.add_argument("--approx", action="store_true", help="write the closest renderer material where it cannot "
                   "reproduce the model exactly, printing its error (default: refuse, naming the reason)")
    p.set_defaults(func=run)


def load_source(path_text: str):
    """SampleSet of any source (:func:`gonio.api.as_samples`)."""
    from gonio.api import as_samples

    return as_samples(path_text)


def _candidates_help() -> str:
    """The --candidates help, from the lists :func:`gonio.fit.select.select` uses (not a copy of them)."""
    from gonio.fit.select import DEFAULT_CANDIDATES, LARGE_TABLE_CANDIDATES, SELECT_N, WIDEN_CANDIDATES

    return (f"comma-separated candidates for --select (default {','.join(DEFAULT_CANDIDATES)}; above "
            f"{2 * SELECT_N} samples, e.g. a MERL table, also {','.join(LARGE_TABLE_CANDIDATES)}; when none of them "
            f"fits the data and there are fewer, {','.join(WIDEN_CANDIDATES)} are added)")


def _options(args) -> dict:
    """What every source's fit needs, as plain data (sent to worker processes)."""
    from gonio.cli.models import parse_param
    from gonio.errors import ConfigError

    if not args.all_angles and not 0.0 < args.max_theta <= 90.0:
        raise ConfigError.field("--max-theta", "max_theta", args.max_theta, "must be in (0, 90] degrees")
    if args.select and args.fix:
        raise ConfigError.field("--fix", "fix", args.fix, "not supported with --select")
    fixed = dict(parse_param(t, "--fix") for t in args.fix) if args.fix else {}
    if fixed:  # checked before any source is read (names as `gonio fit` prints them, gonio.fit.layout.resolve_fixed)
        from gonio.fit.layout import model_class, resolve_fixed

        resolve_fixed(model_class(args.model), fixed)
    cands = tuple(c.strip() for c in args.candidates.split(",")) if args.candidates else None
    if args.image_weight is not None and (args.select or args.model != "dupuy2015"):
        raise ConfigError.field("--image-weight", "image_weight", args.image_weight,
                                "applies to --model dupuy2015 only (for --select use --criterion image)")
    if args.metal and not args.select:
        raise ConfigError.field("--metal", "metal", True, "applies to --select only")
    if args.equivalence is not None and not args.select:
        raise ConfigError.field("--equivalence", "equivalence", args.equivalence, "applies to --select only")
    return {"select": args.select, "model": args.model, "candidates": cands, "criterion": args.criterion,
            **({} if args.equivalence is None else {"equivalence": args.equivalence}),
            **({"metal": True} if args.metal else {}),
            "loss": args.loss, "fixed": fixed, "seed": args.seed,
            **({} if args.image_weight is None else {"image_weight": args.image_weight}),
            "max_theta_deg": None if args.all_angles else args.max_theta, "force": args.force}


def fit_one(source: str, opts: dict):
    """Fit (or select) for one source: ``(FitResult, Selection or None)``."""
    from gonio import api

    kw = {"loss": opts["loss"], "seed": opts["seed"], "max_theta_deg": opts["max_theta_deg"]}
    if opts["select"]:
        import sys

        if "equivalence" in opts:
            kw["equivalence"] = opts["equivalence"]
        if opts.get("metal"):
            kw["metal"] = True
        sel = api.select(source, opts["candidates"], criterion=opts["criterion"],
                         progress=opts.get("progress", False) and sys.stderr.isatty(), **kw)
        return sel.winner, sel
    if "image_weight" in opts:
        kw["image_weight"] = opts["image_weight"]
    return api.fit(source, opts["model"], fixed=opts["fixed"], **kw), None


def _json_name(source: str) -> str:
    """The file name of a source's fit result in a batch's ``--json`` directory."""
    from pathlib import Path

    return f"{Path(source).name}.json"


def fit_row(source: str, opts: dict) -> dict:
    """One summary row of a batch fit; writes its JSON (``opts["outputs"][source]``, checked and made unique
    within the batch before it ran: :func:`gonio.cli.many.output_targets`) when asked."""
    target = (opts.get("outputs") or {}).get(source)
    result, sel = fit_one(source, opts)
    if target is not None:
        (sel or result).to_json(target, force=opts["force"])
    status = {"status": sel.status} if sel is not None else ({"status": "misfit"} if not result.goodness.get("fits", True) else {})
    return {**status, **({"output": target} if target else {}), "model": result.model_name, "n_used": result.n_used, "rms_rel": result.rms_rel,
            "chi2_red": result.chi2_red, "seconds": round(result.seconds, 3),
            "params": "; ".join(f"{k}={v}" for k, v in result.params.items()),
            "at_bound": "; ".join(f"{k} ({', '.join(f'{c} {w}' for c, w in b.items())})"
                                  for k, b in result.at_bound.items()),
            "notes": " | ".join(result.notes)}


def run(args) -> int:
    paths = many.sources(args)
    if many.is_batch(args, paths):
        opts = _options(args)
        for option, value in (("--mitsuba", args.mitsuba), ("--pbrt", args.pbrt), ("--gltf", args.gltf)):
            if value:
                from gonio.errors import ConfigError

                raise ConfigError.field(option, option.lstrip("-"), value, "takes one source (fit each one alone)")
        summary = many.summary_path("fit", args, paths)  # all refused before anything is created
        json_dir = many.output_dir("--json", args.json, required=False)
        if json_dir is not None:
            opts["outputs"] = many.output_targets("--json", json_dir, paths, _json_name, args.force, summary)
        return many.run("fit", args, fit_row, paths, opts,
                        ["source", "status", "model", "n_used", "rms_rel", "chi2_red", "seconds", "params", "at_bound",
                         "error"] + (["output"] if json_dir is not None else []),
                        summary=summary)
    args.source = str(paths[0])
    return run_one(args)


def run_one(args) -> int:
    from gonio.io.outputs import check_output

    opts = _options(args)
    opts["progress"] = True  # one source: a progress bar on a terminal (tqdm)
    renderers = (("--pbrt", args.pbrt, ".pbrt"), ("--gltf", args.gltf, ".gltf"))
    for option, value, suffix in renderers:
        if value:
            check_output(value, option=option, force=args.force, suffixes=(suffix,), inputs=[args.source])
    for option, value in (("--json", args.json), ("--mitsuba", args.mitsuba)):
        if value:  # refused before minutes of fitting, not after
            check_output(value, option=option, force=args.force, inputs=[args.source])
    _refuse_shared_outputs((o, getattr(args, o.lstrip("-"))) for o, _ in _OUTPUTS)
    result, sel = fit_one(args.source, opts)
    if sel is not None:
        print("\n".join(sel.table_lines()))
        print()
    print("\n".join(result.summary_lines()))
    from gonio.cli.each_output import write_each

    # every output stands alone: one a renderer refuses is one line, the others are still written
    return write_each("fit", [(option, partial(write, args, result, sel)) for option, write in _OUTPUTS
                              if getattr(args, option.lstrip("-"))])


def _refuse_shared_outputs(named) -> None:
    """A one-line ConfigError before any work when two options name the same file: the second output would
    replace the first (with --force) or be refused on a file this very command wrote."""
    import os

    from gonio.errors import ConfigError

    seen: dict[str, str] = {}
    for option, value in named:
        if not value:
            continue
        key = os.path.realpath(os.path.expanduser(value))
        if key in seen:
            raise ConfigError.field(None, option, value, f"is also {seen[key]}'s output: name a file for each output")
        seen[key] = option


def _write_json(args, result, sel) -> str:
    (sel or result).to_json(args.json, force=args.force)
    return f"wrote {args.json}"


def _write_mitsuba(args, result, sel) -> str:
    from gonio.io.mitsuba import write_mitsuba
    from gonio.io.outputs import check_output

    ex = write_mitsuba(result.model, check_output(args.mitsuba, option="--mitsuba", force=args.force,
                                                  suffixes=(".xml", ".json")), approx=args.approx)
    return f"wrote {args.mitsuba} ({ex.describe()})"


def _write_pbrt(args, result, sel) -> str:
    from gonio.io.pbrt import write_pbrt

    return f"wrote {args.pbrt} ({write_pbrt(result.model, args.pbrt, approx=args.approx, option='--pbrt').describe()})"


def _write_gltf(args, result, sel) -> str:
    from gonio.io.gltf import write_gltf

    return f"wrote {args.gltf} ({write_gltf(result.model, args.gltf, approx=args.approx, option='--gltf').describe()})"


#: The outputs of one fit, in the order they are written: the result first (never lost to a renderer that
#: refuses the model), then each renderer's material.
_OUTPUTS = (("--json", _write_json), ("--mitsuba", _write_mitsuba), ("--pbrt", _write_pbrt), ("--gltf", _write_gltf))
