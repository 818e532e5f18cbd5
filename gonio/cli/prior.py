"""``gonio prior build SOURCES... -o PRIOR.npz`` and ``gonio prior info [PRIOR]``: learn a BRDF prior from
tables gonio reads (MERL ``.binary``, RGL ``.bsdf``, gonio NPZ with a table), and describe one.
The work is :mod:`gonio.prior` (docs/prior.md); this module only parses and prints."""

from __future__ import annotations


def add_prior_option(p) -> None:
    """``--prior PRIOR.npz`` (default: the shipped prior), shared by plan, measure and reconstruct."""
    p.add_argument("--prior", default=None, metavar="PRIOR.npz",
                   help="BRDF prior (gonio prior build; default: the shipped prior of 63 real materials)")


def load_prior_arg(value):
    """``(prior, name)`` of a ``--prior`` value (None: the shipped prior)."""
    from gonio.prior import default_prior, load_prior

    if value is None:
        return default_prior(), "default"
    return load_prior(value), str(value)


def register(sub) -> None:
    p = sub.add_parser("prior", help="build or describe a BRDF prior learned from measured tables",
                       description="A prior is the principal components of measured materials in a log-relative "
                                   "domain (Nielsen et al. 2015), with leave-one-out calibrated variances; "
                                   "gonio plan sparse and gonio reconstruct use it (docs/prior.md).")
    s = p.add_subparsers(dest="prior_command", metavar="ACTION")
    b = s.add_parser("build", help="build a prior from tables gonio reads")
    b.add_argument("sources", nargs="+", metavar="SOURCE", help="MERL .binary, RGL .bsdf or gonio .npz tables")
    b.add_argument("-o", "--out", required=True, metavar="PRIOR.npz", help="the prior file to write")
    b.add_argument("--components", type=int, default=None, metavar="K",
                   help="principal components kept (default: all, at most 96)")
    b.add_argument("--name", default=None, help="a name stored in the prior (default: the output's file name)")
    b.add_argument("--force", action="store_true", help="overwrite an existing --out file")
    b.set_defaults(func=run_build)
    i = s.add_parser("info", help="describe a prior")
    i.add_argument("prior", nargs="?", default=None, metavar="PRIOR.npz", help="default: the shipped prior")
    i.set_defaults(func=run_info)
    p.set_defaults(func=lambda args: (p.print_help(), 2)[1])


def run_build(args) -> int:
    from pathlib import Path

    from gonio.errors import ConfigError
    from gonio.io.outputs import check_output
    from gonio.prior import build_from_sources, save_prior

    out = check_output(args.out, option="--out", force=args.force, suffixes=(".npz",), inputs=args.sources)
    if len(args.sources) < 2:
        raise ConfigError.field("SOURCES", "sources", len(args.sources), "a prior needs at least 2 materials")
    if args.components is not None and args.components < 1:
        raise ConfigError.field("--components", "components", args.components, "must be >= 1")
    prior = build_from_sources(args.sources, n_components=args.components,
                               metadata={"name": args.name or Path(args.out).stem})
    save_prior(prior, out)
    print(prior.describe())
    print(f"wrote {out} ({out.stat().st_size / 1e6:.2f} MB) in {prior.metadata['build_seconds']:.1f} s")
    return 0


def run_info(args) -> int:
    prior, _ = load_prior_arg(args.prior)
    print(prior.describe())
    return 0
