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
    Tibshirani & Friedman, *The Elements of Statistical Learning*, 2nd ed., §7.10), an energy-conserving one
    before one that is not. Physical plausibility is a tie-break among candidates the data cannot tell apart,
    never a reason to accept a worse prediction — except what the user declares: a sample declared a metal
    (``metal=True``, ``--metal``) is chosen among the candidates with a metal's Fresnel factor (normal-incidence
    reflectance ≥ :data:`METAL_F0_MIN`: the conductor models of :data:`METAL_CANDIDATES` by construction) whenever one
    remains, as a bound constrains a parameter; how much better the best unconstrained candidate predicts is said.
``auto``
    ``bic`` when every sample has an uncertainty (χ² loss), else ``cv``.
``image`` / ``delta-e`` (on request)
    What a rendering shows: the relative RMS difference of spheres rendered with each candidate and with the
    measurement itself under point lights at 0/30/60° (:func:`gonio.fit.metrics.image_error`), or their mean
    CIELAB ΔE*ab (:func:`gonio.fit.metrics.delta_e`), on the samples the candidates were not fitted to when
    the table is large; lowest wins. No penalty for parameters: the practical-equivalence rule below still
    prefers the simpler of two candidates that predict the same.

Large tables (more than 2 × :data:`SELECT_N` samples, e.g. a MERL table's 9·10⁵): every candidate is fitted
once on a seeded random subset of :data:`SELECT_N` samples — plus the samples the image error's rendered spheres
show (:func:`gonio.fit.metrics.sphere_sample_index`; a random subset misses most of a razor-thin highlight) —
and ``cv`` scores it on a disjoint subset of the same size (without those) (hold-out validation, Hastie et al. §7.2; the one-standard-error rule uses the per-sample scatter
of the held-out score), so a selection costs a few subset fits instead of (k + 1) full ones; the error
measures of the winner are computed on all samples. The held-out score is the held-out value of the kind of objective the
data-driven fits minimize (:class:`HeldOut`): the loss normalized by the zero model's plus :data:`SELECT_IMAGE_WEIGHT`
(0 with ``--image-weight 0``) times the rendered spheres' squared relative error as the held-out samples approximate it — what a rendering of the scene shows is part of how well a candidate predicts
(issue 29: on the loss alone a fit made in both terms was judged by one of them). ``python -m benchmarks realdata`` measures the time
and the resulting fits against published ones on real materials.

Physical sense: a candidate whose parameters are not identified (infinite uncertainty, or the width of a
term of a sum on a bound) is not chosen while another remains; every candidate's directional albedo is
checked (:mod:`gonio.fit.energy`) and a winner above 1 says so; parameters at or near a bound are listed
in the winner's reason.

Honesty guards
--------------
*Error inflation.* With χ² and stated uncertainties that are too small (or small systematic errors the
models cannot represent), every candidate has χ²_red ≫ 1 and an information criterion on raw χ² rewards
any extra parameter that absorbs a little of the misfit. When even the best-fitting candidate (the lowest
χ²_red) has χ²_red > :data:`INFLATE_ABOVE`, every χ² is divided by that χ²_red before AIC/BIC are compared —
the standard rescaling of the σ by the Birge ratio √χ²_red of the most complete model (e.g. Burnham &
Anderson, *Model Selection and Multimodel Inference*, 2nd ed., 2002, §2.5 "overdispersion", c-hat
estimated from the global model, which must itself fit). For nested candidates that is the most complex one;
candidates that are not nested (an anisotropic Ward beside isotropic lobes) have no global model, and the one
that fits best is the closest to it: a candidate that cannot represent the data must not make the stated
uncertainties look too small. The table says so in every row (``chi2_scale``).

*Redundant terms.* A sum of lobes whose terms the data cannot tell apart — the correlation between
parameters of two different terms is above :data:`REDUNDANT_RHO` (e.g. two GGX lobes of equal width
sharing the specular reflectance in an undetermined ratio) — is over-parameterized whatever its score:
it is rejected with that reason unless no other candidate remains.

*Practical equivalence.* With many samples a criterion detects differences far below what the instrument
can vouch for: a second lobe of 0.1 % of the signal that absorbs a 0.1 % systematic error (angular
averaging over a tile, a grazing-angle bias) lowers χ² by tens over a thousand samples, so BIC keeps
it although no prediction changes by more than the measurement's accuracy. After the criterion has
chosen, the simplest candidate whose predictions are within ``equivalence`` (relative, default
:data:`EQUIVALENCE`) of the chosen one's at *every* fitted sample and channel replaces it — the two are
practically equivalent on the measured domain, and the simpler is kept (the region of practical
equivalence, Kruschke, *Advances in Methods and Practices in Psychological Science* 1 (2), 2018,
"Rejecting or accepting parameter values in Bayesian estimation"; here applied to predictions, not
parameters). Every row records its largest relative difference from the criterion's choice
(``max_rel_diff``); ``equivalence=0`` turns the rule off.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from gonio.brdf.fresnel import METAL_F0_MIN  # a metal's F(0) is at least this; the conductor candidates' bound
from gonio.errors import ConfigError, DataError, GonioError
from gonio.fit.data import DEFAULT_MAX_THETA_DEG, prepare
from gonio.fit.fit import fit, resolve_loss
from gonio.fit.gof import goodness_of_fit
from gonio.fit.result import FitResult, _clean

#: Default candidates, simple to complex: diffuse; diffuse + Blinn-Phong; diffuse + one GGX lobe;
#: diffuse + two GGX lobes.
DEFAULT_CANDIDATES = ("lambert", "blinn-phong", "microfacet", "lambert+2ggx")
CRITERIA = ("auto", "bic", "aic", "cv", "image", "delta-e")
#: Criteria judged on rendered spheres (:mod:`gonio.fit.metrics`), on request: what a rendering of the scene shows.
IMAGE_CRITERIA = {"image": "image_error", "delta-e": "delta_e"}
#: χ²_red of the best-fitting candidate above which χ² is rescaled before AIC/BIC (see module docstring).
INFLATE_ABOVE = 1.5
#: |correlation| between parameters of two terms of a sum above which the terms are redundant.
REDUNDANT_RHO = 0.99
#: Largest relative difference between two candidates' predictions at every fitted sample below which the simpler
#: one is kept (see "Practical equivalence" in the module docstring): 1 %, the relative accuracy a careful
#: gonioreflectometer reaches at best (a white standard's certified reflectance alone is known to about ±1 %).
EQUIVALENCE = 0.01


@dataclass
class Selection:
    """Result of :func:`select`: the winning fit and a row per candidate saying why it won or lost."""

    winner: FitResult
    criterion: str
    candidates: list[dict[str, Any]] = field(default_factory=list)
    fits: dict[str, FitResult] = field(default_factory=dict)
    #: How the scores were adjusted (χ² rescaling), empty if they were not.
    adjustment: str = ""
    #: How the selection ran (anisotropic candidates added, subset fits), also the winner's first notes.
    notes: list[str] = field(default_factory=list)
    #: Empty when the winner fits the data (:mod:`gonio.fit.gof`); else how far the best candidate misses.
    misfit: str = ""

    @property
    def status(self) -> str:
        """``ok`` when the chosen model fits the data to within their noise, ``misfit`` when no candidate does."""
        return "misfit" if self.misfit else "ok"

    def to_dict(self) -> dict[str, Any]:
        out = self.winner.to_dict()
        out["criterion"] = self.criterion
        out["status"] = self.status
        out["misfit"] = self.misfit
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
        if self.misfit:
            lines.append(f"NO CANDIDATE FITS: {self.misfit.split(': ', 1)[1]}")
        return lines

    def __repr__(self) -> str:
        return "\n".join([f"Selection by {self.criterion}" + (f" ({self.adjustment})" if self.adjustment else ""),
                          *("  " + line for line in self.table_lines()), *self.winner.summary_lines()])


def free_cores() -> int:
    """Cores this process may use that are not busy: the CPUs it is allowed to run on (``taskset``) minus
    the 1-minute load average of the machine (at least 1)."""
    import os

    try:
        allowed = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        allowed = os.cpu_count() or 1
    try:
        busy = os.getloadavg()[0]
    except OSError:
        busy = 0.0
    return max(1, min(allowed, int(allowed - busy + 0.5)))


#: What one candidate's fit or scoring may raise that makes it a ``failed`` row of the selection, not the end of it:
#: a gonio error (too few samples for its parameters, a table it cannot build) or a singular linear algebra step.
CANDIDATE_ERRORS = (GonioError, np.linalg.LinAlgError)


def _one_line(exc: BaseException) -> str:
    """An exception as the one line of a candidate's row (gonio errors as they say it, others with their type)."""
    text = " ".join(str(exc).split())
    return text if isinstance(exc, GonioError) else f"{type(exc).__name__}: {text}"


def _cv_score(d, model, loss, k, seed, fit_kw, bar=None, start=None) -> tuple[float, float]:
    """Mean held-out ½·mean(r²) over k folds and its standard error; each fold's fit is warm-started from
    ``start`` (the full-data fit: a local refinement instead of a global search) and shares the geometry
    computed on all samples (:meth:`gonio.fit.data.FitData.subset`). The folds run in threads when
    :func:`free_cores` says cores are free (NumPy releases the GIL in its array operations), else in turn. A fold
    whose fit fails (:data:`CANDIDATE_ERRORS`) or predicts non-finite values raises a one-line DataError naming
    the fold: the candidate then fails as it would on all samples."""
    rng = np.random.default_rng(seed)
    folds = np.array_split(rng.permutation(len(d)), k)
    for name in ("cos_i", "cos_o", "cos_h", "cos_d"):
        getattr(d, name)  # computed once, sliced by every fold

    def one(j: int) -> float:
        test = folds[j]
        train = np.concatenate([folds[i] for i in range(k) if i != j])
        sub = d.subset(train)
        object.__setattr__(sub, "geometry", None)  # a fold's score needs no σ: not the calibration's propagation
        try:
            r = fit(sub, model, loss=loss.name, seed=seed, start=start,
                    **{k: v for k, v in fit_kw.items() if k != "geometry"})
            m = r.build().eval(d.wi[test], d.wo[test])
        except CANDIDATE_ERRORS as exc:
            raise DataError(f"its fit on cross-validation fold {j + 1} of {k} failed: {_one_line(exc)}") from exc
        sigma = None if d.sigma is None else d.sigma[test]
        res = loss.residual(m, d.y[test], d.cos_i[test], sigma)
        score = float(np.mean(res * res))
        if not np.isfinite(score):
            raise DataError(f"its fit on cross-validation fold {j + 1} of {k} predicts non-finite values "
                            f"for the held-out samples")
        if bar is not None:
            bar.update(1)
        return score

    workers = min(k, free_cores())
    if workers > 1:
        from concurrent.futures import ThreadPoolExecutor

        with ThreadPoolExecutor(max_workers=workers) as pool:
            scores = list(pool.map(one, range(k)))
    else:
        scores = [one(j) for j in range(k)]
    scores = np.array(scores)
    return float(scores.mean()), float(scores.std(ddof=1) / np.sqrt(k)) if k > 1 else 0.0


#: Default candidates added for large tables (above 2 × :data:`SELECT_N` samples, e.g. a MERL table): Burley's
#: GTR lobe, whose tail exponent fits the long tails of measured metals, and Löw et al. 2012's smooth-surface
#: ABC model, whose lobe is a function of the projected deviation ‖wi⊥ + wo⊥‖ = 2 cos θd sin θh from the
#: mirror direction (Rayleigh–Rice scattering), so it widens in θh towards grazing θd as the narrow peaks of
#: polished metals and the lobes of paints do, where a microfacet lobe keeps its width in θh
#: (``python -m benchmarks realdata``); and the data-driven microfacet model of Dupuy et al. 2015 (tabulated D and
#: Fresnel, :mod:`gonio.fit.dupuy`), which fits where analytic lobes fail and a full table determines its tables.
#: Its conductor variant (``dupuy2015-conductor``: ks times the exact Fresnel factor of a complex index η + ik per
#: channel) is added for a sample declared a metal (``metal=True``, :data:`METAL_CANDIDATES`): the data alone cannot
#: tell a metal whose table reflects little (the MERL metals' specular albedo is 0.05–0.3) from a dark dielectric.
LARGE_TABLE_CANDIDATES = ("gtr", "abc-smooth", "dupuy2015")
#: Added on a large table when the sample is declared a metal (``metal=True``): a conductor's complex-index Fresnel with
#: F(0) ≥ :data:`METAL_F0_MIN` (Gulbrandsen 2014's parameters, :func:`gonio.brdf.fresnel.gulbrandsen_index`) and the
#: lobe's own scale, on Löw et al.'s smooth-surface lobe (chrome) and on the tabulated D (brass, nickel), and the
#: tabulated D's conductor under a thin dielectric coat (``dupuy2015-coated``, :mod:`gonio.brdf.coated`: an oxidised or
#: lacquered metal, whose Fresnel factor rises towards grazing as a dielectric's — alum-bronze).
METAL_CANDIDATES = ("abc-smooth-conductor", "dupuy2015-conductor", "dupuy2015-coated")
#: Width parameters of the terms of a sum: one on a bound means the term has no shape the data determine.
_WIDTHS = ("alpha", "roughness", "exponent", "alpha_x", "alpha_y", "sigma")
#: Candidates added when no candidate fits the data (:mod:`gonio.fit.gof`): a rough diffuse surface (Oren &
#: Nayar 1994, alone and under a GGX lobe), an anisotropic lobe (Ward 1992) and the data-driven microfacet model
#: (Dupuy et al. 2015).
WIDEN_CANDIDATES = ("oren-nayar", "oren-nayar+ggx", "ward", "dupuy2015")
#: Candidates added when the data are anisotropic (:func:`gonio.tabulate.check_isotropy`) and none of
#: the requested ones is.
ANISOTROPIC_CANDIDATES = ("ward",)
#: Above this many samples, selection fits every candidate on a seeded random subset of this size and
#: scores it on a disjoint subset of the same size (hold-out validation instead of k folds); only the
#: winner is refitted on all samples up to :data:`REFIT_MAX`. (Whether a full-data selection would choose
#: differently is not measured yet; ``python -m benchmarks realdata`` measures the chosen fits' errors on
#: the whole tables.)
SELECT_N = 20_000
#: On a large table each candidate's global shape search runs on a seeded random :data:`SEARCH_N` of its
#: :data:`SELECT_N`-sample subset and only a local refinement on the whole subset (coarse to fine; ``fit``'s
#: ``search_n``): the search's hundreds of evaluations cost a quarter, the refinement lands where the whole
#: subset's optimum is. ``python -m benchmarks select`` times it; the held-out scores and the choices of the four
#: real MERL tables it times and the synthetic one are those of a search on the whole subset (checked when it was
#: introduced: held-out errors within 0.5 %).
SEARCH_N = 6_000
#: Weight of the image term in a large table's held-out score (:class:`HeldOut`; the data-driven fits minimize the loss
#: plus :data:`gonio.fit.dupuy.IMAGE_WEIGHT` = 10 times it). Chosen on ``python -m benchmarks realdata``'s 12 MERL
#: materials: at 1 the white basketball stays with lambert+2ggx (image error 1.45x the published fit's); at 10 the image
#: term's sampling noise (a few held-out samples near a highlight carry most of it: its standard error reaches 40 % of
#: the score on alum-bronze) widens the one-standard-error window until alum-bronze and brass go to a candidate up to
#: twice as far from their tables in all three errors. Checked on 6 RGL-EPFL materials it was not chosen on (the
#: benchmark's selection table).
SELECT_IMAGE_WEIGHT = 4.0
#: Up to this many samples the winner is refitted on all of them (warm-started from its subset fit); above
#: it the subset fit is the result, said in its notes (a full MERL table has 9·10⁵ samples: refitting would
#: cost more than the whole selection); its error measures are computed on all samples.
REFIT_MAX = 200_000


def lobe_f0s(params: dict) -> list[float]:
    """Normal-incidence Fresnel reflectance of every specular term of fitted ``params`` (mean over channels):
    ``f0`` (or Ashikhmin–Shirley's ``rs``) as fitted (Schlick), a tabulated Fresnel factor's first row (``dupuy2015``), ((η − 1)/(η + 1))² for a
    real index η, ((n − 1)² + k²)/((n + 1)² + k²) for a complex one n + ik (Born & Wolf, *Principles of Optics*,
    §14.2). Empty for a model without a Fresnel factor."""
    out = []
    for k, v in params.items():
        base = k.rsplit(".", 1)[-1]
        if base in ("f0", "rs"):  # Schlick's f0 (Ashikhmin & Shirley's R_s is theirs)
            out.append(float(np.mean(v)))
        elif base == "fresnel":
            out.append(float(np.mean(np.asarray(v, dtype=float)[0])))
        elif base == "eta" and not any(x.rsplit(".", 1)[-1] == "k" for x in params):
            out.append(float(np.mean(((np.asarray(v) - 1) / (np.asarray(v) + 1)) ** 2)))
        elif base == "k":
            n = np.asarray(params[k.rsplit(".", 1)[0] + ".eta" if "." in k else "eta"], dtype=float)
            kk = np.asarray(v, dtype=float)
            out.append(float(np.mean(((n - 1) ** 2 + kk ** 2) / ((n + 1) ** 2 + kk ** 2))))
    return out


def _not_a_metal(params: dict) -> str:
    """Why fitted ``params`` are not a metal's (a specular term's normal-incidence reflectance below
    :data:`METAL_F0_MIN`, a free Fresnel table — ``dupuy2015``'s F(θd) takes any shape and holds the lobe's scale
    too, its conductor form is ``dupuy2015-conductor`` —, or no specular term at all), or ``""``."""
    bases = {k.rsplit(".", 1)[-1] for k in params}
    if not bases & {"ks", "A", "fresnel", "rs", "rho"}:
        return "not a metal: no specular term (the sample was declared a metal)"
    if "fresnel" in bases:
        return ("not a metal's Fresnel: a free Fresnel table (any shape; dupuy2015-conductor is its metal form) (the "
                "sample was declared a metal)")
    f0s = lobe_f0s(params)
    if f0s and min(f0s) < METAL_F0_MIN:
        return (f"not a metal's Fresnel: normal-incidence reflectance {min(f0s):.3g} < {METAL_F0_MIN:g} (the sample "
                f"was declared a metal)")
    return ""


def one_se_choice(rows: list[dict]) -> tuple[dict, float, list[dict]]:
    """The one-standard-error rule (Hastie, Tibshirani & Friedman, *The Elements of Statistical Learning*, 2nd ed.,
    §7.10) on scored rows (``score``: held-out error, ``cv_se``: its standard error, ``n_params``): among the rows
    within one standard error of the lowest score, a physical one (no ``unphysical`` key: energy conserving, a
    declared metal's Fresnel) before one that is not, then the fewest parameters, then the lowest score. Physical
    sense only breaks ties the held-out error cannot: a row beyond the limit is never chosen, however physical.
    ``(chosen row, limit, rows within it)``."""
    best = min(rows, key=lambda r: r["score"])
    limit = best["score"] + best["cv_se"]
    within = [r for r in rows if r["score"] <= limit]
    return min(within, key=lambda r: ("unphysical" in r, r["n_params"], r["score"])), limit, within


def large_table_split(d_all, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """``(fit, held-out)`` sample indices of a large table's selection: a seeded random :data:`SELECT_N` plus the
    samples the image error's rendered spheres show (:func:`gonio.fit.metrics.sphere_sample_index`: a random subset
    misses most of a razor-thin highlight, issue 29) to fit on, and the next :data:`SELECT_N` of the same
    permutation without those to score on."""
    from gonio.fit.metrics import sphere_sample_index

    perm = np.random.default_rng(seed).permutation(len(d_all))
    shown = sphere_sample_index(d_all)
    return np.union1d(perm[:SELECT_N], shown), np.setdiff1d(perm[SELECT_N:2 * SELECT_N], shown)


def check_candidates(candidates: Sequence[str]) -> tuple[str, ...]:
    """The candidate names, each known (a registered model or a valid sum); one-line ConfigError naming
    the first unknown one."""
    from gonio.fit.layout import model_class

    names = tuple(c.strip() for c in candidates)
    if not names or any(not c for c in names):
        raise ConfigError.field("--candidates", "candidates", ",".join(names), "give one or more model names")
    for name in names:
        try:
            model_class(name)
        except ConfigError:
            from gonio.brdf import MODELS

            raise ConfigError.field("--candidates", "candidates", name,
                                    f"unknown model; known: {', '.join(sorted(MODELS))} (or sums such as "
                                    f"lambert+2ggx)") from None
    return names


def _anisotropy(data):
    """:class:`gonio.tabulate.IsotropyCheck` of the samples, or None where it cannot be run."""
    from gonio.samples import SampleSet
    from gonio.tabulate import check_isotropy

    if not isinstance(data, SampleSet):
        return None
    try:
        return check_isotropy(data)
    except GonioError:
        return None


def _progress(total: int, enabled: bool, desc: str):
    """A tqdm progress bar on stderr (a core dependency), or a silent stand-in."""
    if enabled:
        try:
            from tqdm import tqdm

            return tqdm(total=total, desc=desc, unit="fit", leave=False)
        except ImportError:
            pass

    class _Quiet:
        def update(self, n=1):
            pass

        def set_postfix_str(self, s):
            pass

        def close(self):
            pass

    return _Quiet()


def _variant(r: FitResult) -> dict:
    """The ``chroma`` a refit of ``r`` takes (the variant ``r`` is: lobes of one chromaticity or their own), so
    a warm-started refit does not search the other variant again."""
    from gonio.fit.layout import linked_lobes, model_class

    if not linked_lobes(model_class(r.model_name)):
        return {}
    return {"chroma": "shared" if r.links else "free"}


class HeldOut:
    """The held-out score of a large table's selection (module docstring, "Large tables"): per held-out sample, the
    loss's mean square normalized by the zero model's plus ``image`` times the image term — cos²θi of the sphere
    pixels the sample is nearest to (:func:`gonio.fit.metrics.sphere_cover`) times its squared difference, normalized
    by the same sum of the data — so its mean over the samples is the held-out value of the objective the data-driven
    fits minimize (:func:`gonio.fit.dupuy._with_image`) and its scatter gives the standard error the
    one-standard-error rule uses. ``image = 0`` (``--image-weight 0``), or samples no sphere pixel shows: the loss
    alone."""

    def __init__(self, d, loss, image: float):
        from gonio.fit.metrics import sphere_cover

        self.d, self.loss = d, loss
        r0 = loss.residual(np.zeros_like(d.y), d.y, d.cos_i, d.sigma)
        self.l0 = max(float(np.mean(r0 * r0)), 1e-300)
        cover = sphere_cover(d) if image > 0 else np.zeros(len(d))
        self.image = float(image) if cover.any() else 0.0
        self.cover = len(d) * cover / max(float(np.sum(cover[:, None] * np.asarray(d.y) ** 2)), 1e-300)

    def __call__(self, r: FitResult) -> tuple[float, float, float]:
        """``(score, its standard error, the image term's share of the score)`` of fit ``r``."""
        d = self.d
        m = r.build().eval(d.wi, d.wo)
        res = self.loss.residual(m, d.y, d.cos_i, d.sigma)
        img = self.image * self.cover * np.sum((m - d.y) ** 2, axis=1)
        per = np.mean(res * res, axis=1) / self.l0 + img
        mean = float(per.mean())
        return mean, float(per.std(ddof=1) / np.sqrt(per.size)), float(img.mean()) / max(mean, 1e-300)


def _practically_equivalent(win: dict, eligible: list, ok: list, fits: dict, d, equivalence: float,
                            criterion: str) -> dict:
    """The simplest eligible candidate whose predictions at every sample of ``d`` and channel are within
    ``equivalence`` (relative) of the criterion's choice ``win`` (module docstring, "Practical
    equivalence"), or ``win``; records ``max_rel_diff`` in every scored row and rewrites the reasons of
    the two rows when the choice changes."""
    f_win = np.asarray(fits[win["model"]].model.eval(d.wi, d.wo), dtype=np.float64)
    scale = np.maximum(np.abs(f_win), np.finfo(np.float64).tiny)
    for r in ok:
        with np.errstate(invalid="ignore", over="ignore"):
            diff = np.abs(np.asarray(fits[r["model"]].model.eval(d.wi, d.wo), dtype=np.float64) - f_win) / scale
        r["max_rel_diff"] = float(np.max(diff)) if diff.size and np.isfinite(diff).all() else float("inf")
    if equivalence <= 0.0:
        return win
    simpler = [r for r in eligible if r["n_params"] < win["n_params"] and r["max_rel_diff"] <= equivalence]
    if not simpler:
        return win
    new = min(simpler, key=lambda r: (r["n_params"], r["score"]))
    name = criterion.upper()
    new["reason"] = (f"simplest model practically equivalent to {win['model']} (the {name} choice): every prediction "
                     f"within {100 * equivalence:.3g} % of it, max {100 * new['max_rel_diff']:.2g} % ({name} "
                     f"{new['score'] - win['score']:+.4g})")
    win["reason"] = (f"{name} choice, but {new['model']} predicts every sample within {100 * equivalence:.3g} % of "
                     f"it (max {100 * new['max_rel_diff']:.2g} %) with {new['n_params']} parameters instead of {win['n_params']}")
    return new


def _score_row(r: FitResult, name: str, d, d_val, lossobj, criterion: str, big: bool, folds: int, seed: int,
               fit_kw: dict, bar, held_out: HeldOut | None = None, scored: dict | None = None) -> dict:
    """The selection table's row of candidate ``name`` fitted as ``r``: its criterion's score (held-out error
    over ``folds`` folds or on ``d_val``, AIC/BIC, an image error), what is not identified, whether it fits the
    data (:func:`gonio.fit.gof.goodness_of_fit`) and conserves energy; raises :data:`CANDIDATE_ERRORS`. The model's
    values, the goodness of fit and the energy check are kept in ``scored[name]`` (the winner's report reuses them:
    :func:`gonio.fit.fit.add_report`)."""
    from gonio.fit.energy import albedo_check

    row = {"model": name, "n_params": r.n_params, "loss": r.loss, "cost": r.cost, "rms_rel": r.rms_rel,
           "chi2_red": r.chi2_red, "aic": r.aic, "bic": r.bic, "identifiable": r.identifiable,
           "at_bound": r.at_bound}
    if criterion == "cv":
        if big:
            row["cv"], row["cv_se"], row["cv_image_share"] = held_out(r)
        else:
            row["cv"], row["cv_se"] = _cv_score(d, name, lossobj, folds, seed, {**fit_kw, **_variant(r)}, bar,
                                                start={**r.params, **r.links})
    if criterion in IMAGE_CRITERIA:
        from gonio.fit import metrics as _metrics

        value = getattr(_metrics, IMAGE_CRITERIA[criterion])(r.model, d_val if big else d)
        row[criterion] = float("inf") if value is None else value
    row["score"] = row[criterion]
    unident = sorted(k for k, v in r.uncertainty.items() if np.any(np.isinf(np.asarray(v, dtype=float))))
    # a shape parameter (shared by R, G, B) on a bound: the term has no shape the data determine
    # (e.g. a second lobe at α = 1 soaking up residuals), so the model is not identified either
    unident += sorted(f"{k} (at its {v['value'].split()[0]} bound)" for k, v in r.at_bound.items()
                      if "value" in v and "." in k and k.rsplit(".", 1)[1] in _WIDTHS)
    if unident:
        row["unidentified"] = f"parameters not identified by the data: {', '.join(unident)}"
    values = np.asarray(r.model.eval(d.wi, d.wo), dtype=np.float64)
    g = goodness_of_fit(values, d, lossobj, r.n_params, seed=seed)
    row["fits"], row["fit_ratio"] = g["fits"], g["ratio"]
    energy = albedo_check(r.model)
    if scored is not None:
        scored[name] = (values, g, energy, seed)
    row["albedo_max"] = energy["albedo_max"]
    if not energy["ok"]:
        row["unphysical"] = (f"not energy conserving: directional albedo {energy['albedo_max']:.3g} > 1 at "
                             f"theta_i = {energy['theta_deg']:g} deg")
    return row


def select(data, candidates: Sequence[str] | None = None, *, criterion: str = "auto", loss: str = "auto",
           folds: int = 5, seed: int = 0, max_theta_deg: float | None = DEFAULT_MAX_THETA_DEG,
           progress: bool = False, equivalence: float = EQUIVALENCE, widen: bool = True, metal: bool = False,
           _done: dict | None = None, **fit_kw) -> Selection:
    """Fit every candidate model and choose one (criteria in the module docstring).

    ``candidates`` default to :data:`DEFAULT_CANDIDATES` (plus :data:`LARGE_TABLE_CANDIDATES` on large tables).

    Unknown candidate names are refused before any fit (one line). When the samples are anisotropic
    (:func:`gonio.tabulate.check_isotropy`) and no candidate is, :data:`ANISOTROPIC_CANDIDATES` are added.
    Above :data:`SELECT_N` samples the candidates are fitted on a seeded subset and scored on a disjoint
    one; the winner is refitted on all samples. Candidates that cannot be fitted are listed with status
    ``failed`` and the reason; if none can be fitted the first error is raised. A candidate whose
    parameters are not identified, whose terms are redundant or whose fitted parameters do not conserve
    energy is chosen only if no other remains (and says so). The criterion's choice gives way to the simplest
    candidate within ``equivalence`` of its predictions at every sample (module docstring). ``progress`` shows
    a tqdm bar on stderr.

    ``metal``: the sample is known to be a metal (a conductor). Prior knowledge the data cannot supply (a MERL metal's
    table reflects as little as a dark dielectric's): a candidate whose specular term has a normal-incidence
    reflectance below :data:`METAL_F0_MIN` (or a free Fresnel table, or no specular term) is then not a metal's and
    is excluded while one with a metal's Fresnel remains — the declaration constrains the choice as a bound
    constrains a parameter; a note says how much better the best excluded candidate predicts. On a large table
    :data:`METAL_CANDIDATES` are added: Löw et al.'s smooth-surface lobe and the data-driven D, each with a
    conductor's complex-index Fresnel bounded to a metal's F(0) and the lobe's own scale.
    """
    if criterion not in CRITERIA:
        raise ConfigError.field("--criterion", "criterion", criterion, f"must be one of {', '.join(CRITERIA)}")
    if not (isinstance(equivalence, (int, float)) and 0.0 <= equivalence < 1.0):
        raise ConfigError.field("--equivalence", "equivalence", equivalence, "must be a relative difference in [0, 1)")
    d_all = prepare(data, max_theta_deg=max_theta_deg)
    big = len(d_all) > 2 * SELECT_N
    if candidates is None:
        candidates = DEFAULT_CANDIDATES + (LARGE_TABLE_CANDIDATES if big else ())
    candidates = check_candidates(candidates)
    notes: list[str] = []
    if metal and big:
        candidates = candidates + tuple(c for c in METAL_CANDIDATES if c not in candidates)
    iso = _anisotropy(data)
    if iso is not None and iso.anisotropic:
        from gonio.fit.layout import model_class

        if all(model_class(c).isotropic for c in candidates):
            candidates = candidates + ANISOTROPIC_CANDIDATES
            notes.append(f"the data are anisotropic ({iso.describe()}): added {', '.join(ANISOTROPIC_CANDIDATES)}")
    lossobj = resolve_loss(loss, d_all)
    if criterion == "auto":
        criterion = "bic" if lossobj.name == "chi2" else "cv"
    if big:
        fit_idx, val_idx = large_table_split(d_all, seed)
        d, d_val = d_all.subset(fit_idx), d_all.subset(val_idx)
        notes.append(f"candidates fitted on {SELECT_N} of {len(d_all)} samples plus the {len(fit_idx) - SELECT_N} "
                     f"more its rendered spheres show, and scored on {len(val_idx)} others (seed {seed})")
    else:
        d, d_val = d_all, None
    fit_kw = {**fit_kw, "report": False}
    held_out = None
    if big and criterion == "cv":  # --image-weight 0 (the fits in the loss alone): the held-out loss alone too
        w = fit_kw.get("image_weight")
        held_out = HeldOut(d_val, lossobj, SELECT_IMAGE_WEIGHT if w is None or w > 0 else 0.0)
    if big:  # one local refinement per candidate, its global search on SEARCH_N of the subset (coarse to fine)
        fit_kw.setdefault("n_starts", 1)
        fit_kw.setdefault("search_n", SEARCH_N)
    n_fits = len(candidates) * (1 + (folds if criterion == "cv" and not big else 0)) + 1
    bar = _progress(n_fits, progress, "select")
    rows, fits, first_error = [], {}, None
    scored: dict = {}
    from gonio.fit.energy import albedo_check

    done = {} if _done is None else _done
    if criterion == "cv" and not big and len(d) < 2 * folds:
        bar.close()
        raise ConfigError.field("--folds", "folds", folds, f"{len(d)} samples are too few for {folds}-fold CV")
    for name in candidates:
        bar.set_postfix_str(name)
        if name in done:  # fitted before widening (the same subsets and seed): not fitted again
            row, r = dict(done[name][0]), done[name][1]
            rows.append(row)
            if r is not None:
                fits[name] = r
            else:
                first_error = first_error or DataError(f"{name}: {row['reason']}")
            bar.update(1 + (folds if criterion == "cv" and not big else 0))
            continue
        r = None
        try:  # a candidate that fails on all samples or in a fold is a failed row, never the end of the selection
            r = fit(d, name, loss=lossobj.name, seed=seed, **fit_kw)
            bar.update(1)
            row = _score_row(r, name, d, d_val, lossobj, criterion, big, folds, seed, fit_kw, bar, held_out, scored)
        except CANDIDATE_ERRORS as exc:
            whole = r is None and isinstance(exc, GonioError)  # its fit on all samples: its own message
            first_error = first_error or (exc if whole else DataError(f"{name}: {_one_line(exc)}"))
            row = {"model": name, "status": "failed", "reason": _one_line(exc)}
            rows.append(row)
            done[name] = (dict(row), None)
            bar.update(1 + (folds if criterion == "cv" and not big else 0))
            continue
        if metal and _not_a_metal(r.params):
            row["not_metal"] = _not_a_metal(r.params)
            row.setdefault("unphysical", row["not_metal"])
        rows.append(row)
        fits[name] = r
        done[name] = (dict(row), r)
    adjustment = ""
    ok = [r for r in rows if "score" in r]
    if criterion in ("aic", "bic") and lossobj.name == "chi2" and ok:
        reds = [r for r in ok if r["chi2_red"] is not None and np.isfinite(r["chi2_red"])]
        top = min(reds, key=lambda r: r["chi2_red"]) if reds else None
        scale = top["chi2_red"] if top is not None and top["chi2_red"] > INFLATE_ABOVE else 1.0
        if scale > 1.0:
            adjustment = (f"chi2 divided by {scale:.4g} = chi2_red of {top['model']} (the best-fitting candidate): "
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
        why = [r[k] for k in ("unidentified",) if k in r]
        if why:
            r["redundant"] = "; ".join(([r["redundant"]] if "redundant" in r else []) + why)
    if not ok:
        bar.close()
        raise first_error
    if criterion in IMAGE_CRITERIA and not any(np.isfinite(r["score"]) for r in ok):
        bar.close()
        raise ConfigError.field("--criterion", "criterion", criterion,
                                f"{d_all.source}: the samples are too sparse to render the spheres it compares")
    eligible = [r for r in ok if "redundant" not in r] or ok
    best_all = min(eligible, key=lambda r: r["score"])
    metals = [r for r in eligible if "not_metal" not in r]
    if metal and metals and len(metals) < len(eligible):  # declared a metal: a metal's Fresnel is a constraint
        for r in eligible:
            if "not_metal" in r:
                r["excluded"] = f"{r['not_metal']}: excluded while a candidate with a metal's Fresnel remains"
        eligible = metals
    best = min(eligible, key=lambda r: r["score"])
    if criterion == "cv":
        win, limit, within = one_se_choice(eligible)
        passed = any("unphysical" in r for r in within) and "unphysical" not in win
        for r in ok:
            if r is win:
                r["reason"] = (f"simplest {'physical ' if passed else ''}model whose held-out error {r['score']:.4g} "
                               f"is within one standard error of the best ({best['score']:.4g} + {best['cv_se']:.2g})")
            elif r not in eligible:
                r["reason"] = r.get("excluded") or r["redundant"]
            elif r["score"] <= limit and "unphysical" in r and "unphysical" not in win:
                r["reason"] = f"held-out error within one SE of the best but {r['unphysical']}"
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
                r["reason"] = f"{r.get('excluded') or r['redundant']} ({criterion.upper()} {r['score'] - win['score']:+.4g})"
            else:
                r["reason"] = f"{criterion.upper()} {r['score'] - win['score']:+.4g} over {win['model']}"
        if adjustment:
            for r in ok:
                r["reason"] += f"; {adjustment}" if r is win else ""
    win = _practically_equivalent(win, eligible, ok, fits, d, equivalence, criterion)
    if not win["fits"]:
        fitting = [r for r in eligible if r["fits"]]
        if fitting:  # the criterion chose a model that does not fit while another does: the best that fits
            new = min(fitting, key=lambda r: r["score"])
            new["reason"] = (f"the best-scoring candidate that fits the data ({criterion.upper()} {new['score']:.6g}); "
                             f"{win['model']} does not (residuals {win['fit_ratio']:.3g}x the noise)")
            win["reason"] = f"{win['reason']}; but it does not fit the data (residuals {win['fit_ratio']:.3g}x the noise)"
            win = new
        elif widen and big:
            notes.append(f"the candidate set was not widened ({len(d_all)} samples: each added candidate costs a "
                         f"subset fit; name more with candidates=)")
        elif widen:
            extra = tuple(c for c in WIDEN_CANDIDATES if c not in candidates)
            if extra:
                bar.close()
                why = (f"no candidate fits the data (the best, {win['model']}, leaves residuals "
                       f"{win['fit_ratio']:.3g}x the noise): added {', '.join(extra)}")
                sel = select(data, candidates + extra, criterion=criterion, loss=loss, folds=folds, seed=seed,
                             max_theta_deg=max_theta_deg, progress=progress, equivalence=equivalence, widen=False,
                             metal=metal, _done=done, **{k: v for k, v in fit_kw.items() if k != "report"})
                sel.notes.insert(0, why)
                sel.winner.notes.insert(0, why)
                return sel
    if "redundant" in win:
        win["reason"] += f"; chosen although {win['redundant']} (no other candidate remains)"
    if "unphysical" in win:
        win["reason"] += f"; {win['unphysical']}"
        if metal and not metals:
            notes.append(f"declared a metal, but no candidate has a metal's Fresnel: {win['model']} kept")
    if metal and "not_metal" in best_all and "not_metal" not in win:
        se = max(best_all.get("cv_se") or 0.0, 1e-300)
        gap = (f" ({(win['score'] - best_all['score']) / se:.3g} standard errors of the held-out error)"
               if criterion == "cv" else "")
        notes.append(f"declared a metal: chosen among the candidates with a metal's Fresnel (normal-incidence reflectance "
                     f">= {METAL_F0_MIN:g}); without that constraint {best_all['model']} scores {best_all['score']:.4g} "
                     f"against {win['score']:.4g}{gap}, with {best_all['not_metal'].split(' (the sample')[0]}")
    if win.get("at_bound"):
        win["reason"] += "; parameters at a bound: " + ", ".join(win["at_bound"])
    for r in ok:
        if not r["fits"] and r.get("fit_ratio") is not None and "does not fit" not in r["reason"]:
            r["reason"] += f"; does not fit the data (residuals {r['fit_ratio']:.3g}x the noise)"
    for r in rows:
        if "score" in r:
            r["status"] = "chosen" if r is win else "rejected"
    bar.set_postfix_str(f"{win['model']} on all samples")
    if big and len(d_all) <= REFIT_MAX:
        w = fits[win["model"]]
        winner = fit(d_all, win["model"], loss=lossobj.name, seed=seed, start={**w.params, **w.links},
                     **{**fit_kw, **_variant(w), "report": True})
        win.update(rms_rel=winner.rms_rel, at_bound=winner.at_bound)
        fits[win["model"]] = winner
    else:
        if big:
            notes.append(f"{len(d_all)} samples: the winner's parameters and uncertainties are those of its fit on "
                         f"{SELECT_N} samples (not refitted on all; its error measures are on all samples)")
        from gonio.fit.fit import add_report
        from gonio.fit.gof import GOF_N

        # its values, goodness of fit and energy check as scored, where that was on the same samples (the goodness
        # of fit's seed picks its subset only above GOF_N samples; the report's is 0)
        hit = scored.get(win["model"]) if d is d_all else None
        if hit is not None and hit[3] != 0 and len(d_all) > GOF_N:
            hit = (hit[0], None, hit[2], hit[3])
        add_report(fits[win["model"]], d_all, None if hit is None else hit[:3])
    bar.update(1)
    bar.close()
    sel = Selection(fits[win["model"]], criterion, rows, fits, adjustment)
    if not win["fits"]:
        sel.misfit = (f"no candidate fits the data: the best, {win['model']}, leaves residuals {win['fit_ratio']:.3g}x "
                      f"the noise (tried {', '.join(r['model'] for r in ok)})")
        notes.append(sel.misfit)
    sel.notes = notes
    sel.winner.notes[:0] = notes
    return sel
