"""Model selection: fit candidates from simple to complex and keep the one the data require.

Criteria
--------
``bic`` / ``aic``
    Schwarz (1978) / Akaike (1974) information criteria from each fit's likelihood
    (:attr:`gonio.fit.result.FitResult.bic`); lowest wins. With known uncertainties (χ² loss) the
    likelihood is exact; otherwise Gaussian with unknown variance.
``cv``
    Seeded k-fold cross-validation: mean held-out squared residual of the loss. The winner is the
    simplest candidate within one standard error of the best (the one-standard-error rule, Hastie,
    Tibshirani & Friedman, *The Elements of Statistical Learning*, 2nd ed., §7.10).
``auto``
    ``bic`` when every sample has an uncertainty (χ² loss), else ``cv``.

Honesty guards
--------------
*Error inflation.* With χ² and stated uncertainties that are too small (or small systematic errors the
models cannot represent), every candidate has χ²_red ≫ 1 and an information criterion on raw χ² rewards
any extra parameter that absorbs a little of the misfit. When the most complex candidate still has
χ²_red > :data:`INFLATE_ABOVE`, every χ² is divided by that χ²_red before AIC/BIC are compared — the
standard rescaling of the σ by the Birge ratio √χ²_red of the most complete model (e.g. Burnham &
Anderson, *Model Selection and Multimodel Inference*, 2nd ed., 2002, §2.5 "overdispersion", c-hat
estimated from the global model). The table says so in every row (``chi2_scale``).

*Redundant terms.* A sum of lobes whose terms the data cannot tell apart — the correlation between
parameters of two different terms is above :data:`REDUNDANT_RHO` (e.g. two GGX lobes of equal width
sharing the specular reflectance in an undetermined ratio) — is over-parameterized whatever its score:
it is rejected with that reason unless no other candidate remains.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from gonio.errors import ConfigError, GonioError
from gonio.fit.data import DEFAULT_MAX_THETA_DEG, prepare
from gonio.fit.fit import fit, resolve_loss
from gonio.fit.result import FitResult, _clean

#: Default candidates, simple to complex: diffuse; diffuse + Blinn-Phong; diffuse + one GGX lobe;
#: diffuse + two GGX lobes.
DEFAULT_CANDIDATES = ("lambert", "blinn-phong", "microfacet", "lambert+2ggx")
CRITERIA = ("auto", "bic", "aic", "cv")
#: χ²_red of the most complex candidate above which χ² is rescaled before AIC/BIC (see module docstring).
INFLATE_ABOVE = 1.5
#: |correlation| between parameters of two terms of a sum above which the terms are redundant.
REDUNDANT_RHO = 0.99


@dataclass
class Selection:
    """Result of :func:`select`: the winning fit and a row per candidate saying why it won or lost."""

    winner: FitResult
    criterion: str
    candidates: list[dict[str, Any]] = field(default_factory=list)
    fits: dict[str, FitResult] = field(default_factory=dict)
    #: How the scores were adjusted (χ² rescaling), empty if they were not.
    adjustment: str = ""

    def to_dict(self) -> dict[str, Any]:
        out = self.winner.to_dict()
        out["criterion"] = self.criterion
        out["adjustment"] = self.adjustment
        out["candidates"] = _clean(self.candidates)
        return out

    # The winner's fields, so a Selection reads like the FitResult it chose.
    model = property(lambda self: self.winner.model, doc="The chosen model, evaluable (``.eval(wi, wo)``).")
    model_name = property(lambda self: self.winner.model_name)
    params = property(lambda self: self.winner.params)
    uncertainty = property(lambda self: self.winner.uncertainty)
    errors = property(lambda self: self.winner.errors)

    def to_json(self, path=None, *, force: bool = False) -> str:
        """The JSON report of ``gonio fit --select --json`` (winner, criterion, one row per candidate)."""
        import json

        from gonio.fit.result import _write_new

        text = json.dumps(self.to_dict(), indent=2, allow_nan=False) + "\n"
        if path is not None:
            _write_new(path, text, force)
        return text

    def to_mitsuba(self, path=None):
        """The chosen model as a Mitsuba 3 BSDF (see :meth:`FitResult.to_mitsuba`)."""
        return self.winner.to_mitsuba(path)

    def table_lines(self) -> list[str]:
        """One row per candidate: parameters, score, error, status and why it won or lost."""
        lines = [f"{'model':<16} {'k':>3} {self.criterion:>12} {'rms_rel':>9} {'chi2_red':>9}  status    reason"]
        for r in self.candidates:
            if r["status"] == "failed":
                lines.append(f"{r['model']:<16} {'':>3} {'':>12} {'':>9} {'':>9}  failed    {r['reason']}")
            else:
                c2 = "-" if r.get("chi2_red") is None else f"{r['chi2_red']:.4g}"
                lines.append(f"{r['model']:<16} {r['n_params']:>3} {r['score']:>12.6g} {r['rms_rel']:>9.4f} {c2:>9}  "
                             f"{r['status']:<9} {r['reason']}")
        return lines

    def __repr__(self) -> str:
        return "\n".join([f"Selection by {self.criterion}" + (f" ({self.adjustment})" if self.adjustment else ""),
                          *("  " + line for line in self.table_lines()), *self.winner.summary_lines()])


def _cv_score(d, model, loss, k, seed, fit_kw) -> tuple[float, float]:
    """Mean held-out ½·mean(r²) over k folds and its standard error."""
    rng = np.random.default_rng(seed)
    folds = np.array_split(rng.permutation(len(d)), k)
    scores = []
    for j in range(k):
        test = folds[j]
        train = np.concatenate([folds[i] for i in range(k) if i != j])
        r = fit(d.subset(train), model, loss=loss.name, seed=seed, **fit_kw)
        m = r.build().eval(d.wi[test], d.wo[test])
        sigma = None if d.sigma is None else d.sigma[test]
        res = loss.residual(m, d.y[test], d.cos_i[test], sigma)
        scores.append(float(np.mean(res * res)))
    scores = np.array(scores)
    return float(scores.mean()), float(scores.std(ddof=1) / np.sqrt(k)) if k > 1 else 0.0


def select(data, candidates: Sequence[str] = DEFAULT_CANDIDATES, *, criterion: str = "auto", loss: str = "auto",
           folds: int = 5, seed: int = 0, max_theta_deg: float | None = DEFAULT_MAX_THETA_DEG,
           **fit_kw) -> Selection:
    """Fit every candidate model and choose one (criteria in the module docstring).

    Candidates that cannot be fitted (e.g. too few samples for their parameters) are listed with
    status ``failed`` and the reason; if none can be fitted the first error is raised.
    """
    if criterion not in CRITERIA:
        raise ConfigError.field("--criterion", "criterion", criterion, f"must be one of {', '.join(CRITERIA)}")
    d = prepare(data, max_theta_deg=max_theta_deg)
    lossobj = resolve_loss(loss, d)
    if criterion == "auto":
        criterion = "bic" if lossobj.name == "chi2" else "cv"
    rows, fits, first_error = [], {}, None
    for name in candidates:
        try:
            r = fit(d, name, loss=lossobj.name, seed=seed, **fit_kw)
        except GonioError as exc:
            first_error = first_error or exc
            rows.append({"model": name, "status": "failed", "reason": str(exc)})
            continue
        row = {"model": name, "n_params": r.n_params, "loss": r.loss, "cost": r.cost, "rms_rel": r.rms_rel,
               "chi2_red": r.chi2_red, "aic": r.aic, "bic": r.bic, "identifiable": r.identifiable}
        if criterion == "cv":
            if len(d) < 2 * folds:
                raise ConfigError.field("--folds", "folds", folds, f"{len(d)} samples are too few for {folds}-fold CV")
            row["cv"], row["cv_se"] = _cv_score(d, name, lossobj, folds, seed, fit_kw)
        row["score"] = row[criterion]
        rows.append(row)
        fits[name] = r
    adjustment = ""
    ok = [r for r in rows if "score" in r]
    if criterion in ("aic", "bic") and lossobj.name == "chi2" and ok:
        top = max(ok, key=lambda r: r["n_params"])
        scale = top["chi2_red"] if top["chi2_red"] and top["chi2_red"] > INFLATE_ABOVE else 1.0
        if scale > 1.0:
            adjustment = (f"chi2 divided by {scale:.4g} = chi2_red of {top['model']} (the most complex candidate): "
                          f"the stated uncertainties are too small or the data have systematic errors")
        for r in ok:
            f = fits[r["model"]]
            neg2 = 2.0 * f.cost / scale
            k, m = f.n_params, f.n_residuals
            r["chi2_scale"] = scale
            r["aic"], r["bic"] = neg2 + 2.0 * k, neg2 + k * np.log(m)
            r["score"] = r[criterion]
    for r in ok:
        red = fits[r["model"]].redundancy
        r["redundancy"] = None if red is None else red[0]
        if red is not None and red[0] > REDUNDANT_RHO:
            r["redundant"] = f"terms not separable: corr({red[1]}, {red[2]}) = {red[0]:.4f} > {REDUNDANT_RHO}"
    if not ok:
        raise first_error
    eligible = [r for r in ok if "redundant" not in r] or ok
    best = min(eligible, key=lambda r: r["score"])
    if criterion == "cv":
        limit = best["score"] + best["cv_se"]
        within = [r for r in eligible if r["score"] <= limit]
        win = min(within, key=lambda r: (r["n_params"], r["score"]))
        for r in ok:
            if r is win:
                r["reason"] = (f"simplest model whose held-out error {r['score']:.4g} is within one standard "
                               f"error of the best ({best['score']:.4g} + {best['cv_se']:.2g})")
            elif r not in eligible:
                r["reason"] = r["redundant"]
            elif r["score"] <= limit:
                r["reason"] = f"held-out error within one SE of the best but {r['n_params']} parameters > {win['n_params']}"
            else:
                r["reason"] = f"held-out error {r['score']:.4g} > {limit:.4g} (best + one SE)"
    else:
        win = best
        for r in ok:
            if r is win:
                nxt = sorted(x["score"] for x in eligible if x is not win)
                gap = f"; next best is {nxt[0] - r['score']:.4g} higher" if nxt else ""
                lower = [x for x in ok if x not in eligible and x["score"] < r["score"]]
                among = " among the separable candidates" if lower else ""
                r["reason"] = f"lowest {criterion.upper()}{among} ({r['score']:.6g}){gap}"
            elif r not in eligible:
                r["reason"] = f"{r['redundant']} ({criterion.upper()} {r['score'] - win['score']:+.4g})"
            else:
                r["reason"] = f"{criterion.upper()} {r['score'] - win['score']:+.4g} over {win['model']}"
        if adjustment:
            for r in ok:
                r["reason"] += f"; {adjustment}" if r is win else ""
    for r in rows:
        if "score" in r:
            r["status"] = "chosen" if r is win else "rejected"
    return Selection(fits[win["model"]], criterion, rows, fits, adjustment)
