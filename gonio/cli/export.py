"""``gonio export DIR --format merl|csv|npz -o PATH``: write a session's samples as a MERL table, a
per-sample CSV, or a self-describing NPZ archive (samples + table + metadata)."""

from __future__ import annotations

from gonio.cli import many

FORMATS = ("merl", "csv", "npz", "mitsuba", "pbrt", "gltf")
#: Formats of a fitted model (the source is a ``gonio fit --json`` result), not of measurements.
RENDERERS = ("mitsuba", "pbrt", "gltf")
#: File name ending of each format, for batch outputs.
SUFFIX = {"merl": ".binary", "csv": ".csv", "npz": ".npz", "mitsuba": ".xml", "pbrt": ".pbrt", "gltf": ".gltf"}


def add_tabulation_options(p) -> None:
    """Options shared by ``gonio export`` and ``gonio tabulate``."""
    p.add_argument("--fill", "--fill-deg", dest="fill_deg", type=float, default=0.0, metavar="DEG",
                   help="fill empty cells by interpolation within DEG degrees of measured cells (default 0: "
                        "nothing is filled, every value in the table was measured; a filled table says so in "
                        "the printed summary, the NPZ metadata and the MERL export's sidecar OUT.json)")
    p.add_argument("--include-flagged", action="store_true",
                   help="also tabulate samples with quality flags (saturated, low signal, ...)")
    p.add_argument("--force-isotropic", action="store_true",
                   help="tabulate anisotropic data anyway, averaging over the half-vector azimuth")


def tabulation_kwargs(args) -> dict:
    from gonio.errors import ConfigError

    fill = 0.0 if args.fill_deg is None else args.fill_deg
    if not (fill >= 0 and fill < 180):
        raise ConfigError.field("--fill", "fill_deg", fill, "must be in [0, 180) degrees")
    return {"fill_deg": fill, "include_flagged": args.include_flagged, "force_isotropic": args.force_isotropic}


def register(sub) -> None:
    p = sub.add_parser("export", help="export a session as MERL, CSV or NPZ; a fit as Mitsuba, pbrt-v4 or glTF",
                       description="Export a session directory (or an NPZ export, or a MERL file) as a MERL "
                                   "binary table, a per-sample CSV (BRDF in 1/sr) or an NPZ archive with "
                                   "samples, table and metadata; or a fit result (gonio fit --json FIT.json) as a "
                                   "Mitsuba 3 BSDF, a pbrt-v4 material or a glTF 2.0 material.")
    p.add_argument("source", metavar="DIR", nargs="+",
                   help="session directory (or .npz export / MERL .binary); several, a directory of them or a "
                        "glob export each one (in parallel) into the directory -o names")
    p.add_argument("--format", required=True, choices=FORMATS, help="output format")
    p.add_argument("-o", "--output", required=True, metavar="PATH",
                   help="output file (several sources: a directory receiving SOURCE-NAME.EXT each)")
    p.add_argument("--force", action="store_true", help="overwrite an existing output file")
    p.add_argument("--approx", action="store_true", help="mitsuba/pbrt/gltf: write the renderer's closest material "
                   "where it cannot reproduce the model exactly, printing its error (default: refuse, naming why)")
    many.add_options(p)
    add_tabulation_options(p)
    p.set_defaults(func=run)


def check_merl_output(args):
    """The MERL output ``-o`` and its sidecar checked (:func:`gonio.io.outputs.check_output`), before any work."""
    from gonio.io.merl_sidecar import sidecar_path
    from gonio.io.outputs import check_output

    out = str(check_output(args.output, option="-o", force=args.force, inputs=[args.source],
                           suffixes=(".binary", ".merl")))
    check_output(sidecar_path(out), option="-o (its sidecar)", force=args.force, inputs=[args.source])
    return out


def write_merl_table(out: str, table, src, tab) -> str:
    """Write ``table`` as a MERL binary at ``out`` and, beside it, the sidecar that says which cells were
    measured and which filled (:mod:`gonio.io.merl_sidecar`), so no reader of gonio takes a filled cell
    for a measurement. Returns the sidecar's path."""
    from gonio.io.merl import write_merl
    from gonio.io.merl_sidecar import build_sidecar, sidecar_path, write_sidecar

    write_merl(out, table)
    return write_sidecar(sidecar_path(out), build_sidecar(table, source=str(src.path), tabulation=tab,
                                                          manifest=src.manifest, filled=src.filled))


def run(args) -> int:
    return many.run_each("export", args, run_one, output_name)


def output_name(source: str, opts: dict) -> str:
    """The file name of ``source``'s output in a batch's output directory."""
    from pathlib import Path

    return Path(source).name.removesuffix(Path(source).suffix) + SUFFIX[opts["format"]]


def export_model(args) -> int:
    """``--format mitsuba|pbrt|gltf`` of a fit result (``gonio fit --json FIT.json``)."""
    from gonio.cli.plot import load_model
    from gonio.io.outputs import check_output

    suffixes = {"mitsuba": (".xml", ".json"), "pbrt": (".pbrt",), "gltf": (".gltf",)}[args.format]
    out = check_output(args.output, option="-o", force=args.force, suffixes=suffixes, inputs=[args.source])
    from pathlib import Path

    from gonio.errors import ConfigError
    from gonio.io.sniff import sniff

    src = Path(args.source)
    looks = sniff(src)[1] if src.is_file() else ("a directory" if src.is_dir() else "nothing (no such file)")
    if looks != "a JSON document":
        raise ConfigError(f"{src}: --format {args.format} exports a fit result (gonio fit --json FIT.json), "
                          f"and this is {looks}")
    model = load_model(args.source)
    if args.format == "mitsuba":
        from gonio.io.mitsuba import write_mitsuba

        ex = write_mitsuba(model, out, approx=args.approx, option="-o")
    elif args.format == "pbrt":
        from gonio.io.pbrt import write_pbrt

        ex = write_pbrt(model, out, approx=args.approx, option="-o")
    else:
        from gonio.io.gltf import write_gltf

        ex = write_gltf(model, out, approx=args.approx, option="-o")
    print(f"wrote {out} ({ex.describe()})")
    return 0


def run_one(args) -> int:
    from gonio.errors import ConfigError, DataError

    if args.format in RENDERERS:
        return export_model(args)
    from gonio.io.csv import write_csv
    from gonio.io.npz import build_metadata, write_npz
    from gonio.io.outputs import check_output
    from gonio.io.source import load_source
    from gonio.samples import SampleSet
    from gonio.tabulate import tabulate

    kwargs = tabulation_kwargs(args)
    if args.format == "merl":  # refused before any work, the sidecar too
        out = check_merl_output(args)
    else:
        out = str(check_output(args.output, option="-o", force=args.force, inputs=[args.source],
                               suffixes=(f".{args.format}",)))
    src = load_source(args.source)
    if src.samples is None and args.format == "csv":
        raise ConfigError.field("--format", "format", "csv",
                                f"{src.path} is a MERL table without samples; use --format merl or npz")
    table, extra, tab = src.table, {}, None
    # CSV holds the samples as they are: nothing is tabulated for it
    if src.samples is not None and args.format != "csv" and (args.format == "merl" or src.table is None):
        try:
            tab = tabulate(src.samples, source=str(src.path), **kwargs)
            table = tab.table
            extra["tabulation"] = {"fill_deg": tab.fill_deg, "n_measured": tab.n_measured,
                                   "n_filled": tab.n_filled, "filled": tab.n_filled > 0,
                                   "isotropy": tab.isotropy.describe()}
        except DataError as exc:
            if args.format == "merl":
                raise
            extra["table_omitted"] = str(exc)  # e.g. anisotropic: the NPZ keeps the 4-D samples only
    if args.format == "merl":
        side = write_merl_table(out, table, src, tab)
    elif args.format == "csv":
        write_csv(out, src.samples)
    else:
        samples = src.samples if src.samples is not None else SampleSet.empty()
        write_npz(out, samples, build_metadata(src.manifest, source=str(src.path), **extra), table,
                  filled=src.filled if table is src.table else None)
    if src.samples is not None:
        what = f"{len(src.samples)} samples"
    else:  # a table source: its cells are what was written
        import numpy as np

        what = f"a table of {int(np.count_nonzero(np.isfinite(table.values).all(axis=-1)))} cells with values"
    print(f"wrote {out} ({args.format}, {what})")
    if args.format == "merl":
        print(f"wrote {side} (what the table holds: source, measured and filled cells)")
    if tab is not None:
        print(tab.summary())
        if tab.n_filled:
            print(f"FILLED: {tab.n_filled} of the table's cells were not measured but interpolated within "
                  f"{tab.fill_deg:g} deg (--fill); listed in the sidecar, which gonio reads (it does not fit "
                  "them); other readers of the binary cannot tell them from measurements")
    if "table_omitted" in extra:
        print(f"note: no table in the archive: {extra['table_omitted']}")
    return 0
