"""``gonio fit SOURCE [--model NAME | --select] [--loss NAME] [--json OUT] [--mitsuba OUT.xml]``: fit analytic BRDF models to a
session directory or a MERL ``.binary`` and print a table."""

from __future__ import annotations


def register(sub) -> None:
    p = sub.add_parser("fit", help="fit a BRDF model (or choose one) to a session or a MERL file",
                       description="Fit an analytic BRDF model to measured samples (a session directory or a "
                                   "MERL .binary file), or choose among candidates with --select.")
    p.add_argument("source", metavar="SOURCE", help="session directory or MERL .binary file")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--model", default="microfacet", help="model to fit (see `gonio models`; sums such as "
                                                          "lambert+2ggx); default microfacet")
    g.add_argument("--select", action="store_true", help="fit the candidates and choose one")
    p.add_argument("--candidates", default=None, help="comma-separated candidates for --select "
                                                      "(default lambert,blinn-phong,microfacet,lambert+2ggx)")
    p.add_argument("--criterion", default="auto", help="selection criterion: auto, bic, aic, cv")
    p.add_argument("--loss", default="auto", help="auto, cosine, chi2, log, cbrt (auto: chi2 with uncertainties)")
    p.add_argument("--fix", action="append", default=[], metavar="NAME=VALUE",
                   help="hold a parameter fixed (repeatable), e.g. distribution=beckmann or f0=0.9,0.6,0.5")
    p.add_argument("--max-theta", type=float, default=80.0, help="grazing cutoff for θi, θo in degrees (default 80)")
    p.add_argument("--all-angles", action="store_true", help="no grazing cutoff")
    p.add_argument("--seed", type=int, default=0, help="seed of the multi-start (default 0)")
    p.add_argument("--json", metavar="OUT", help="write the result as JSON")
    p.add_argument("--mitsuba", metavar="OUT.xml|OUT.json",
                   help="also write the fitted model as a Mitsuba 3 BSDF (XML element or load_dict JSON) where "
                        "Mitsuba reproduces it exactly: lambert, microfacet/ggx/beckmann lobes with f0 = 1, their sums")
    p.set_defaults(func=run)


def load_source(path_text: str):
    """SampleSet of a session directory, an NPZ export or a MERL file (:func:`gonio.io.source.load_source`).

    Tables (MERL) become samples at the measured cell centres; a MERL file has no uncertainties, so
    sigma is dropped there (the ``auto`` loss is then cosine-weighted L2, not χ² on invented sigmas).
    """
    import numpy as np

    from gonio.io.source import load_source as load
    from gonio.samples import SampleSet

    src = load(path_text)
    if src.samples is not None:
        return src.samples
    s = src.table.to_samples()
    if src.table.sigma is None:
        s = SampleSet(s.wi, s.wo, s.f, np.full_like(s.f, np.nan), n_pixels=s.n_pixels)
    return s


def run(args) -> int:
    import json
    from pathlib import Path

    from gonio.cli.models import _parse_param
    from gonio.errors import ConfigError
    from gonio.fit import fit
    from gonio.fit.select import DEFAULT_CANDIDATES, select

    if not args.all_angles and not 0.0 < args.max_theta <= 90.0:
        raise ConfigError.field("--max-theta", "max_theta", args.max_theta, "must be in (0, 90] degrees")
    samples = load_source(args.source)
    fixed = dict(_parse_param(t) for t in args.fix)
    max_theta = None if args.all_angles else args.max_theta
    if args.select:
        cands = tuple(c.strip() for c in args.candidates.split(",")) if args.candidates else DEFAULT_CANDIDATES
        if fixed:
            raise ConfigError.field("--fix", "fix", args.fix, "not supported with --select")
        sel = select(samples, cands, criterion=args.criterion, loss=args.loss, seed=args.seed, max_theta_deg=max_theta)
        result, report = sel.winner, sel.to_dict()
        print("\n".join(sel.table_lines()))
        print()
    else:
        result = fit(samples, args.model, loss=args.loss, fixed=fixed, seed=args.seed, max_theta_deg=max_theta)
        report = {**result.to_dict(), "candidates": []}
    print("\n".join(result.summary_lines()))
    if args.mitsuba:
        from gonio.io.mitsuba import write_mitsuba

        write_mitsuba(result.model, args.mitsuba)
        print(f"wrote {args.mitsuba} (Mitsuba 3 BSDF)")
    if args.json:
        try:
            Path(args.json).write_text(json.dumps(report, indent=2, allow_nan=False) + "\n")
        except OSError as exc:
            raise ConfigError.field("--json", "json", args.json, f"cannot write ({exc.strerror or exc})") from None
    return 0
