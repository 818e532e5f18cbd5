"""``gonio tabulate DIR [-o TABLE.binary]``: tabulate a session on the MERL grid and report coverage."""

from __future__ import annotations


def register(sub) -> None:
    from gonio.cli.export import add_tabulation_options

    p = sub.add_parser("tabulate", help="tabulate a session on the MERL half/difference grid",
                       description="Tabulate a session's samples on the 90x90x180 MERL grid: report samples "
                                   "used, cells measured/filled/missing and the isotropy check; with -o, "
                                   "write the MERL binary.")
    p.add_argument("source", metavar="DIR", help="session directory (or .npz export)")
    p.add_argument("-o", "--output", metavar="TABLE.binary", help="also write the table as a MERL binary")
    p.add_argument("--force", action="store_true", help="overwrite an existing -o file")
    add_tabulation_options(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from gonio.cli.export import check_merl_output, tabulation_kwargs, write_merl_table
    from gonio.errors import ConfigError
    from gonio.io.source import load_source
    from gonio.tabulate import tabulate

    kwargs = tabulation_kwargs(args)
    out = check_merl_output(args) if args.output else None  # refused before any work, not after
    src = load_source(args.source)
    if src.samples is None:
        raise ConfigError.field(None, "DIR", str(src.path), "is a MERL table, not a set of samples to tabulate")
    tab = tabulate(src.samples, source=str(src.path), **kwargs)
    print(tab.summary())
    if out:
        side = write_merl_table(out, tab.table, src, tab)
        print(f"wrote {out}")
        print(f"wrote {side} (what the table holds: source, measured and filled cells)")
    return 0
