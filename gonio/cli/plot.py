"""``gonio plot DIR --kind polar|inplane|coverage|residual -o FILE.png``: plot a session (or an NPZ
export, or a MERL binary), optionally with a fitted model (``--model FIT.json`` from ``gonio fit --json``)."""

from __future__ import annotations

from gonio.cli import many

KINDS = ("polar", "inplane", "coverage", "residual")


def register(sub) -> None:
    p = sub.add_parser("plot", help="plot a session or a MERL table as PNG",
                       description="Polar slice at fixed incidence, in-plane curve with error bars and a fitted "
                                   "model, coverage of the sampled directions, or residuals after a fit. "
                                   "Needs matplotlib (pip install 'gonio[plots]').")
    p.add_argument("source", metavar="DIR", nargs="+",
                   help="session directory, .npz export, or MERL .binary; several, a directory of them or a glob "
                        "plot each one (in parallel) into the directory -o names")
    p.add_argument("--kind", required=True, choices=KINDS, help="what to plot")
    p.add_argument("-o", "--output", required=True, metavar="FILE.png",
                   help="output image (several sources: a directory receiving SOURCE-NAME-KIND.png each)")
    p.add_argument("--theta-i", type=float, default=None, metavar="DEG",
                   help="incidence angle of polar/inplane plots (default: the most measured one; 45 for tables)")
    p.add_argument("--tol", type=float, default=2.5, metavar="DEG",
                   help="angular tolerance selecting the incidence and the plane (default 2.5)")
    p.add_argument("--model", metavar="FIT.json", help="fitted model to overlay (JSON of `gonio fit --json`)")
    p.add_argument("--linear", action="store_true", help="linear instead of log BRDF axis (inplane)")
    p.add_argument("--force", action="store_true", help="overwrite an existing output file")
    many.add_options(p)
    p.set_defaults(func=run)


def load_model(path):
    """The model of a ``gonio fit --json`` report (:meth:`gonio.fit.result.FitResult.from_dict`); every fault is
    one :class:`ConfigError` line naming the file."""
    import json

    from gonio.errors import ConfigError, DataError
    from gonio.fit.result import FitResult

    try:
        with open(path, encoding="utf-8") as fh:
            report = json.load(fh)
    except OSError as exc:
        raise ConfigError.field("--model", "model", path, f"cannot read ({exc.strerror or exc})") from None
    except UnicodeDecodeError:  # not text: say what it is (a MERL table, an NPZ, ...)
        from gonio.io.sniff import describe

        raise ConfigError(f"{path}: not a fit result (gonio fit --json FIT.json): it looks like {describe(path)}") from None
    except ValueError as exc:
        raise ConfigError(f"{path}: not valid JSON ({exc})") from None
    try:
        return FitResult.from_dict(report, str(path)).model
    except DataError as exc:
        raise ConfigError(str(exc)) from None


def run(args) -> int:
    return many.run_each("plot", args, run_one, output_name)


def output_name(source: str, opts: dict) -> str:
    """The file name of ``source``'s output in a batch's output directory."""
    from pathlib import Path

    return f"{Path(source).name}-{opts['kind']}.png"


def run_one(args) -> int:
    from gonio import plots
    from gonio.errors import ConfigError
    from gonio.io.source import load_source

    if not 0.0 < args.tol <= 45.0:
        raise ConfigError.field("--tol", "tol", args.tol, "must be in (0, 45] degrees")
    if args.theta_i is not None and not 0.0 <= args.theta_i < 90.0:
        raise ConfigError.field("--theta-i", "theta_i", args.theta_i, "must be in [0, 90) degrees")
    if args.model and args.kind in ("polar", "coverage"):
        import sys

        print(f"gonio plot: note: --model {args.model} is not drawn by --kind {args.kind} (--kind inplane "
              "overlays it, --kind residual shows its residuals)", file=sys.stderr)
    from gonio.io.outputs import check_output

    check_output(args.output, option="-o", force=args.force, suffixes=(".png", ".pdf", ".svg"),
                 inputs=[args.source, *([args.model] if args.model else [])])
    plots.figure(1, 1)  # fail early, with the install hint, when matplotlib is missing
    model = load_model(args.model) if args.model else None
    src = load_source(args.source)
    title = src.path.name
    samples, table = src.samples, src.table
    if samples is None and table is None:  # an evaluable material (RGL .bsdf): its samples on a grid
        samples = src.to_samples()
    if table is None and len(samples) == 0:
        from gonio.errors import DataError

        raise DataError(f"{src.path}: no samples to plot (an empty export or a session stopped before its first pose)")
    if args.kind == "polar":
        fig = plots.polar_slice(samples=samples, table=table if samples is None else None,
                                theta_i_deg=args.theta_i, tol_deg=args.tol, title=title)
    elif args.kind == "inplane":
        fig = plots.inplane(samples=samples, table=table, model=model, theta_i_deg=args.theta_i,
                            tol_deg=args.tol, log=not args.linear, title=title)
    elif args.kind == "coverage":
        fig = plots.coverage(samples=samples, table=table if samples is None else None, title=title)
    else:
        if model is None:
            raise ConfigError.field("--model", "model", None, "--kind residual needs --model FIT.json")
        if samples is None:
            raise ConfigError.field(None, "DIR", str(src.path), "--kind residual needs samples, not a MERL table")
        fig = plots.residual(samples=samples, model=model, title=title)
    plots.save(fig, args.output)
    print(f"wrote {args.output}")
    return 0
