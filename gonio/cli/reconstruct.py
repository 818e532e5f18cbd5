"""``gonio reconstruct SOURCE [--prior PRIOR.npz] -o OUT.npz|OUT.binary``: the whole BRDF table of a sparse
measurement (a session, CSV or NPZ) under a data-driven prior, with a per-cell σ (NPZ) and a one-line fit
quality report. The work is :mod:`gonio.prior.reconstruct`; this module only parses and prints."""

from __future__ import annotations

from gonio.cli.prior import add_prior_option, load_prior_arg


def register(sub) -> None:
    p = sub.add_parser("reconstruct", help="a whole BRDF table from a sparse measurement and a prior",
                       description="Condition a BRDF prior on the measured samples (each with its own σ) and "
                                   "write the posterior table: .npz (values and per-cell σ) or MERL .binary. "
                                   "A material outside the prior's span is said (docs/prior.md).")
    p.add_argument("source", metavar="SOURCE", help="session directory, CSV or NPZ export")
    add_prior_option(p)
    p.add_argument("-o", "--out", required=True, metavar="OUT", help="OUT.npz (with σ) or OUT.binary (MERL)")
    p.add_argument("--force", action="store_true", help="overwrite an existing --out file")
    p.set_defaults(func=run)


def run(args) -> int:
    from gonio.io.outputs import check_output
    from gonio.prior.reconstruct import reconstruct, write_reconstruction

    out = check_output(args.out, option="--out", force=args.force, suffixes=(".npz", ".binary"),
                       inputs=[args.source])
    prior, name = load_prior_arg(args.prior)
    post, measured, samples = reconstruct(args.source, prior)
    q = post.quality()
    write_reconstruction(out, post, source=str(args.source), prior_name=name, manifest=measured.manifest)
    print(f"{args.source}: {len(samples)} samples under prior {name} -> expected RMS error {post.expected_error():.3g} "
          "(log domain, ~relative)")
    print(q.line())
    print(f"wrote {out}")
    return 0
