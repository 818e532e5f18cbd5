"""``gonio models``: list the analytic BRDF models, their parameters, and sample values."""

from __future__ import annotations


def register(sub) -> None:
    p = sub.add_parser("models", help="list BRDF models and their parameters",
                       description="List the BRDF models of gonio.brdf with their parameters; "
                                   "with --eval, print f(wi, wo) of one model along the incidence plane.")
    p.add_argument("--eval", metavar="MODEL", help="evaluate MODEL with its default/given parameters")
    p.add_argument("--param", action="append", default=[], metavar="NAME=VALUE",
                   help="parameter for --eval (repeatable); RGB as R,G,B")
    p.add_argument("--theta-i", type=float, default=30.0, help="incidence angle for --eval, degrees")
    p.set_defaults(func=run)


def parse_param(text: str, option: str = "--param"):
    from gonio.errors import ConfigError

    name, sep, value = text.partition("=")
    if not sep or not name.strip():
        raise ConfigError.field(option, option.lstrip("-"), text, "expected NAME=VALUE")
    parts = value.split(",")
    try:
        nums = [float(x) for x in parts]
    except ValueError:
        return name, value  # a choice such as distribution=ggx
    return name, nums[0] if len(nums) == 1 else nums


def run(args) -> int:
    import numpy as np

    from gonio.brdf import MODELS, make
    from gonio.geometry import from_spherical

    if not args.eval:
        for name, cls in MODELS.items():
            print(name)
            for pname, spec in cls.PARAMS.items():
                default = ("required" if spec.default is None
                           else f"default {_fmt(spec.default)}" if spec.kind == "table" else f"default {spec.default}")
                print(f"    {pname:<14} {spec.kind:<7} {default:<22} {spec.doc}")
        from gonio.brdf.lobes import TERMS

        print(f"\nSums of lobes: any name like 'lambert+2ggx' (a digit repeats a term); terms: {', '.join(TERMS)}.")
        print("Lafortune: lobe2.*, lobe3.* ... add lobes (or lobes=N).")
        return 0
    params = dict(parse_param(p) for p in args.param)
    model = make(args.eval, source="--param", **params)
    wi = from_spherical(np.radians(args.theta_i), 0.0)
    theta_o = np.radians(np.arange(-85, 86, 5.0))
    wo = from_spherical(np.abs(theta_o), np.where(theta_o < 0, 0.0, np.pi))
    f = model.eval(wi, wo)
    print(f"{model!r}; theta_i = {args.theta_i:g} deg, phi_i = 0; wo in the incidence plane")
    print(f"{'theta_o_deg':>11} {'f_r':>12} {'f_g':>12} {'f_b':>12}   (1/sr)")
    for t, row in zip(np.degrees(theta_o), f):
        print(f"{t:11.1f} {row[0]:12.6g} {row[1]:12.6g} {row[2]:12.6g}")
    return 0


def _fmt(value) -> str:
    """A table default as its size and range (:func:`gonio.fit.result._fmt`)."""
    from gonio.fit.result import _fmt as fmt

    return fmt(value)
