"""``gonio report DIR|FILE… -o REPORT.html``: a material on one page (:mod:`gonio.report`); ``gonio view``
(:mod:`gonio.cli.view`) shares its options."""

from __future__ import annotations


def _common(p) -> None:
    p.add_argument("source", metavar="DIR|FILE", nargs="+", help="sessions or data files (several: one comparison)")
    p.add_argument("--model", action="append", default=[], metavar="FIT.json",
                   help="fitted model(s) to show (gonio fit --json; repeatable); default: fit --fit MODELS now")
    p.add_argument("--fit", default=None, metavar="MODELS",
                   help="comma-separated models fitted on the fly when no --model is given (default microfacet)")
    p.add_argument("--max-theta", type=float, default=80.0, help="grazing cutoff of the on-the-fly fits (deg)")


def register(sub) -> None:
    r = sub.add_parser("report", help="one self-contained HTML page: coverage, slices, fits, lit spheres",
                       description="Write a self-contained HTML report (no network needed to open it).")
    _common(r)
    r.add_argument("-o", "--output", required=True, metavar="REPORT.html")
    r.add_argument("--force", action="store_true", help="overwrite an existing output file")
    r.set_defaults(func=run_report)
    from gonio.cli import view

    view.register(sub, _common)


def run_report(args) -> int:
    from pathlib import Path

    from gonio.errors import ConfigError
    from gonio.io.outputs import check_output
    from gonio.report import build_report

    out = check_output(args.output, option="-o", force=args.force, suffixes=(".html", ".htm"),
                       inputs=[*args.source, *(args.model or [])])
    from gonio.cli.view import entries

    page = build_report(entries(args), title="gonio report: " + ", ".join(Path(s).name for s in args.source))
    from gonio.io.outputs import write_text_atomically

    try:
        write_text_atomically(out, page)
    except OSError as exc:
        raise ConfigError.field(None, "-o", str(out), f"cannot write ({exc.strerror or exc})") from None
    print(f"wrote {out} ({len(page) / 1e6:.1f} MB, self-contained)")
    return 0
