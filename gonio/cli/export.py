"""``gonio export DIR --format merl|csv|npz -o PATH``: write a session's samples as a MERL table, a
per-sample CSV, or a self-describing NPZ archive (samples + table + metadata)."""

from __future__ import annotations

FORMATS = ("merl", "csv", "npz")


def add_tabulation_options(p) -> None:
    """Options shared by ``gonio export`` and ``gonio tabulate``."""
    p.add_argument("--fill-deg", type=float, default=None, metavar="DEG",
                   help="fill empty cells by interpolation within DEG degrees of measured cells "
                        "(default 2; 0 = no filling)")
    p.add_argument("--include-flagged", action="store_true",
                   help="also tabulate samples with quality flags (saturated, low signal, ...)")
    p.add_argument("--force-isotropic", action="store_true",
                   help="tabulate anisotropic data anyway, averaging over the half-vector azimuth")


def tabulation_kwargs(args) -> dict:
    from gonio.errors import ConfigError
    from gonio.tabulate import DEFAULT_FILL_DEG

    fill = DEFAULT_FILL_DEG if args.fill_deg is None else args.fill_deg
    if not (fill >= 0 and fill < 180):
        raise ConfigError.field("--fill-deg", "fill_deg", fill, "must be in [0, 180) degrees")
    return {"fill_deg": fill, "include_flagged": args.include_flagged, "force_isotropic": args.force_isotropic}


def register(sub) -> None:
    p = sub.add_parser("export", help="export a session as MERL, CSV or NPZ",
                       description="Export a session directory (or an NPZ export, or a MERL file) as a MERL "
                                   "binary table, a per-sample CSV (BRDF in 1/sr) or an NPZ archive with "
                                   "samples, table and metadata.")
    p.add_argument("source", metavar="DIR", help="session directory (or .npz export / MERL .binary)")
    p.add_argument("--format", required=True, choices=FORMATS, help="output format")
    p.add_argument("-o", "--output", required=True, metavar="PATH", help="output file")
    add_tabulation_options(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from gonio.errors import ConfigError, DataError
    from gonio.io.csv import write_csv
    from gonio.io.merl import write_merl
    from gonio.io.npz import build_metadata, write_npz
    from gonio.io.source import load_source
    from gonio.samples import SampleSet
    from gonio.tabulate import tabulate

    kwargs = tabulation_kwargs(args)
    src = load_source(args.source)
    out = args.output
    if src.samples is None and args.format == "csv":
        raise ConfigError.field("--format", "format", "csv",
                                f"{src.path} is a MERL table without samples; use --format merl or npz")
    table, extra, tab = src.table, {}, None
    if src.samples is not None and (args.format == "merl" or src.table is None):
        try:
            tab = tabulate(src.samples, source=str(src.path), **kwargs)
            table = tab.table
            extra["tabulation"] = {"fill_deg": tab.fill_deg, "n_measured": tab.n_measured,
                                   "n_filled": tab.n_filled, "isotropy": tab.isotropy.describe()}
        except DataError as exc:
            if args.format == "merl":
                raise
            extra["table_omitted"] = str(exc)  # e.g. anisotropic: the NPZ keeps the 4-D samples only
    if args.format == "merl":
        write_merl(out, table)
    elif args.format == "csv":
        write_csv(out, src.samples)
    else:
        samples = src.samples if src.samples is not None else SampleSet.empty()
        write_npz(out, samples, build_metadata(src.manifest, source=str(src.path), **extra), table)
    n = len(src.samples) if src.samples is not None else 0
    print(f"wrote {out} ({args.format}, {n} samples)")
    if tab is not None:
        print(tab.summary())
    if "table_omitted" in extra:
        print(f"note: no table in the archive: {extra['table_omitted']}")
    return 0
