"""``gonio repair DIR``: keep every good sample of a damaged session: damaged records (flipped bits,
stray newlines, crafted fields) are moved to ``DIR/quarantine.jsonl`` and a torn last line is cut; the
poses they held are measured again by ``gonio resume DIR`` (which also repairs, and says so)."""

from __future__ import annotations


def register(sub) -> None:
    p = sub.add_parser("repair", help="move a session's damaged records to quarantine.jsonl",
                       description="Check every record of a session; move damaged ones to quarantine.jsonl (kept, "
                                   "not deleted) so status, export, fit and resume use every good sample.")
    p.add_argument("dir", metavar="DIR", help="session directory")
    p.set_defaults(func=run)


def run(args) -> int:
    from pathlib import Path

    from gonio.store.directory import QUARANTINE, SessionStore

    repaired = SessionStore.repair(Path(args.dir))
    if repaired is None:
        print(f"{args.dir}: every record is intact; nothing to repair")
        return 0
    lines = ", ".join(f"line {q['line']} ({q['reason']})" for q in repaired["quarantined"][:5])
    n = len(repaired["quarantined"])
    print(f"{args.dir}: {n} damaged record(s) moved to {QUARANTINE}: {lines}{' ...' if n > 5 else ''}; "
          f"`gonio resume {args.dir}` measures their poses again")
    return 0
