"""The result of a fit: parameters, standard uncertainties, errors and how they were obtained."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np


def _clean(x):
    """JSON-safe: arrays to lists, non-finite floats to None."""
    if isinstance(x, dict):
        return {k: _clean(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_clean(v) for v in x]
    if isinstance(x, np.ndarray):
        return _clean(x.tolist())
    if isinstance(x, (float, np.floating)):
        return float(x) if math.isfinite(x) else None
    if isinstance(x, np.integer):
        return int(x)
    return x


@dataclass
class FitResult:
    """One fitted model.

    Attributes
    ----------
    model_name : str
        Registry name; ``params`` rebuild it with :func:`gonio.brdf.make`. The evaluable model itself
        is :attr:`model`.
    params : dict
        Fitted parameters (RGB as 3 floats, shape parameters as floats, choices as strings).
    uncertainty : dict
        Standard uncertainty of every fitted parameter (same layout); ``inf`` where the data do not
        determine it (see ``notes``), ``nan`` where the value sits on a bound.
    loss : str
        Name of the minimized loss (:data:`gonio.fit.losses.LOSSES`).
    cost : float
        ½ Σ r² at the optimum.
    rms_rel : float
        Relative cosine-weighted RMS error √(Σ cos²θi (f_m − f)² / Σ cos²θi f²), whatever the loss.
    n_used, n_params : int
        Samples used (each has 3 channels) and free parameters.
    chi2_red : float or None
        χ²/(m − k) with the stated uncertainties (None without them).
    """

    model_name: str
    params: dict[str, Any]
    uncertainty: dict[str, Any]
    loss: str
    cost: float
    rms_rel: float
    n_used: int
    n_params: int
    chi2_red: float | None = None
    identifiable: bool = True
    method: str = ""
    n_evals: int = 0
    seconds: float = 0.0
    notes: list[str] = field(default_factory=list)
    heuristics: dict[str, Any] = field(default_factory=dict)
    dropped: dict[str, int] = field(default_factory=dict)
    #: For sums of lobes: largest |correlation| between parameters of two different terms and their
    #: names, ``(|ρ|, a, b)``; near 1 the data cannot tell the terms apart (see :mod:`gonio.fit.select`).
    redundancy: tuple | None = None
    #: Parameters at or near a bound of their range: name -> {channel or "value": "lower 0" / "upper 1"}
    #: (:func:`gonio.fit.fit.bound_report`). Such a value has no standard uncertainty and may mean the
    #: model cannot represent the data (e.g. a diffuse albedo of 1 under a specular peak).
    at_bound: dict = field(default_factory=dict)
    #: Error measures users compare fits with (:mod:`gonio.fit.metrics`): ``cbrt_rel``, ``image_rel``, ``delta_e``.
    metrics: dict = field(default_factory=dict)
    #: Fitted ratios of linked colours (:func:`gonio.fit.layout.linked_lobes`): ``{"lobe2.ks/lobe1.ks": w}``; the
    #: linked colour (``lobe2.ks``) is w times its source in ``params``, its uncertainty that of w (in ``uncertainty``).
    links: dict = field(default_factory=dict)
    #: Goodness of fit (:func:`gonio.fit.gof.goodness_of_fit`): ``fits``, ``ratio``, ``test``, χ² and residual
    #: structure; empty when not computed (``report=False``).
    goodness: dict = field(default_factory=dict)
    #: Directional-albedo check (:func:`gonio.fit.energy.albedo_check`): ``albedo_max``, ``theta_deg``, ``ok``.
    energy: dict = field(default_factory=dict)

    @property
    def n_residuals(self) -> int:
        return 3 * self.n_used

    @property
    def neg2_log_likelihood(self) -> float:
        """−2 ln L up to a constant: χ² when the loss is χ², else m ln(RSS/m) (Gaussian, unknown variance)."""
        m = self.n_residuals
        if self.loss == "chi2":
            return 2.0 * self.cost
        return m * math.log(max(2.0 * self.cost / m, 1e-300))

    @property
    def aic(self) -> float:
        """Akaike information criterion −2 ln L + 2k (Akaike 1974)."""
        return self.neg2_log_likelihood + 2.0 * self.n_params

    @property
    def bic(self) -> float:
        """Bayesian information criterion −2 ln L + k ln m (Schwarz 1978), m = number of residuals."""
        return self.neg2_log_likelihood + self.n_params * math.log(self.n_residuals)

    def build(self):
        """The fitted :class:`gonio.brdf.BRDF` instance (a new one at every call; see :attr:`model`)."""
        from gonio.brdf import make

        return make(self.model_name, source="fit result", **self.params)

    @property
    def model(self):
        """The fitted model as an evaluable :class:`gonio.brdf.BRDF`: ``result.model.eval(wi, wo)``."""
        built = self.__dict__.get("_built")
        if built is None or built[0] != (self.model_name, repr(self.params)):
            built = ((self.model_name, repr(self.params)), self.build())
            self.__dict__["_built"] = built
        return built[1]

    @property
    def errors(self) -> dict[str, Any]:
        """Every error measure of the fit by name (the ``error`` object of :meth:`to_dict`)."""
        return self.to_dict()["error"]

    def to_json(self, path=None, *, force: bool = False) -> str:
        """The JSON report (as ``gonio fit --json`` writes it); also written to ``path`` when given
        (an existing file only with ``force=True``)."""
        import json

        text = json.dumps({**self.to_dict(), "candidates": []}, indent=2, allow_nan=False) + "\n"
        if path is not None:
            _write_new(path, text, force)
        return text

    def eval(self, wi, wo):
        """The fitted model at direction pairs (1/sr, RGB): ``self.model.eval(wi, wo)``, so a result (and
        what :func:`gonio.load` reads from a fit JSON) evaluates like a model."""
        return self.model.eval(wi, wo)

    @classmethod
    def from_dict(cls, report, source: str = "fit result") -> "FitResult":
        """The result a :meth:`to_dict` report (``gonio fit --json``, also ``--select``'s: its winner is at
        the top level) describes; ``from_dict(r.to_dict()).to_dict() == r.to_dict()``. The model is built
        at once, so a bad name or parameter is one :class:`gonio.errors.DataError` line naming ``source``.
        Not recorded in the JSON: ``n_evals``, ``seconds`` (0); non-finite numbers come back as NaN."""
        from gonio.errors import ConfigError, DataError

        if isinstance(report, dict) and "model" not in report and isinstance(report.get("winner"), dict):
            report = report["winner"]
        if not isinstance(report, dict) or not isinstance(report.get("model"), str) \
                or not isinstance(report.get("params", {}), dict):
            raise DataError(f"{source}: expected a JSON object with \"model\" (a name) and \"params\" (an object)")
        err = report.get("error") if isinstance(report.get("error"), dict) else {}

        def num(v, default=math.nan):
            if v is None or isinstance(v, bool):
                return default
            if isinstance(v, list):
                return [num(x) for x in v]
            if isinstance(v, (int, float)):
                return float(v)
            raise DataError(f"{source}: not a fit result: {v!r} where a number is expected")

        def count(key):
            v = report.get(key, 0)
            if not isinstance(v, int) or isinstance(v, bool) or v < 0:
                raise DataError(f"{source}: {key} = {v!r}: must be a count (integer >= 0)")
            return v

        def table(key, kind=dict):
            v = report.get(key)
            if v is None:
                return kind()
            if not isinstance(v, kind):
                raise DataError(f"{source}: {key} = {str(v)[:40]!r}: must be a JSON {'object' if kind is dict else 'list'}")
            return v

        unc = table("uncertainty")
        metric_keys = ("cost", "rms_rel", "chi2_red", "aic", "bic")
        metrics = table("metrics") or {k: v for k, v in err.items() if k not in metric_keys}
        chi2 = err.get("chi2_red")
        red = report.get("redundancy")
        result = cls(
            model_name=report["model"], params=dict(report.get("params", {})),
            uncertainty={k: num(v) for k, v in unc.items()}, loss=str(report.get("loss", "")),
            cost=num(err.get("cost")), rms_rel=num(err.get("rms_rel")), n_used=count("n_used"),
            n_params=count("n_params"), chi2_red=None if chi2 is None else num(chi2),
            identifiable=bool(report.get("identifiable", True)), method=str(report.get("method", "")),
            notes=[str(n) for n in table("notes", list)], heuristics=table("heuristics"),
            dropped=table("dropped"), redundancy=tuple(red) if isinstance(red, list) else None,
            at_bound=table("at_bound"), metrics=metrics, goodness=table("goodness_of_fit"), energy=table("energy"))
        from gonio.brdf import make

        try:  # built once here, naming the file in a refusal; :attr:`model` keeps it
            built = make(result.model_name, source=source, **result.params)
        except ConfigError as exc:
            raise DataError(str(exc)) from None
        except TypeError as exc:  # a parameter of the wrong JSON type
            raise DataError(f"{source}: params: {exc}") from None
        result.__dict__["_built"] = ((result.model_name, repr(result.params)), built)
        return result

    @classmethod
    def from_json(cls, source) -> "FitResult":
        """Read a fit report: ``source`` is a path to ``gonio fit --json``'s file or the JSON text itself
        (:meth:`from_dict`); a file that is not JSON is one :class:`gonio.errors.DataError` line."""
        import json
        from pathlib import Path

        from gonio.errors import DataError

        if isinstance(source, str) and source.lstrip().startswith("{"):
            text, where = source, "fit JSON"
        else:
            where = str(source)
            try:
                text = Path(source).read_text(encoding="utf-8")
            except OSError as exc:
                raise DataError(f"{where}: cannot read ({exc.strerror or exc})") from None
            except UnicodeDecodeError:  # a table or an archive (gonio.load names which)
                raise DataError(f"{where}: not a fit result (gonio fit --json FIT.json): not a text file") from None
        try:
            report = json.loads(text)
        except ValueError as exc:
            raise DataError(f"{where}: not valid JSON ({exc})") from None
        return cls.from_dict(report, where)

    def __repr__(self) -> str:
        return "\n".join(self.summary_lines())

    def summary_lines(self) -> list[str]:
        """The human-readable table ``gonio fit`` prints: header, one row per parameter, notes."""
        head = (f"FitResult: {self.model_name}  loss {self.loss}  samples {self.n_used}  rms_rel {self.rms_rel:.4g}"
                + (f"  chi2_red {self.chi2_red:.4g}" if self.chi2_red is not None else "")
                + (f"  ({self.method}, {self.seconds:.2f} s)" if self.method else ""))
        lines = [head, f"  {'parameter':<18} {'value':<36} uncertainty"]
        rows = list(self.params.items()) + list(self.links.items())
        for k, v in rows:
            link = next((r for r in self.links if r.startswith(f"{k}/")), None)
            u = (_fmt(self.uncertainty[k]) if k in self.uncertainty
                 else f"(= {link} x {link.split('/', 1)[1]})" if link else "(fixed)")
            b = self.at_bound.get(k)
            flag = "  AT BOUND: " + ", ".join(f"{c} {w}" for c, w in b.items()) if b else ""
            lines.append(f"  {k:<18} {_fmt(v):<36} {u}{flag}")
        if self.metrics:
            # image_rel is None when no pixel of the rendered spheres has a measured sample near it
            lines.append("  error: " + "  ".join(f"{k} {'n/a' if v is None else _fmt(v)}" for k, v in self.metrics.items())
                         + "  (cube-root cosine-weighted, Ngan et al. 2005; rendered spheres; their mean CIELAB delta E"
                         + ("; n/a: the data are too sparse to render them" if None in self.metrics.values() else "")
                         + ")")
        if self.goodness:
            from gonio.fit.gof import describe

            lines.append(f"  fit: {describe(self.goodness)}")
        if self.energy:
            e = self.energy
            lines.append(f"  energy: max directional albedo {e['albedo_max']:.4g} at theta_i {e['theta_deg']:g} deg"
                         + ("" if e["ok"] else "  VIOLATES energy conservation (> 1)"))
        lines += [f"  note: {n}" for n in self.notes]
        return lines


    def to_dict(self) -> dict[str, Any]:
        """The JSON report of ``gonio fit --json`` (without ``candidates``)."""
        return _clean({
            "model": self.model_name,
            "params": self.params,
            "uncertainty": self.uncertainty,
            "loss": self.loss,
            "error": {"cost": self.cost, "rms_rel": self.rms_rel, "chi2_red": self.chi2_red,
                      "aic": self.aic, "bic": self.bic, **self.metrics},
            "n_used": self.n_used,
            "n_params": self.n_params,
            "identifiable": self.identifiable,
            "method": self.method,
            "notes": self.notes,
            "heuristics": self.heuristics,
            "dropped": self.dropped,
            "redundancy": list(self.redundancy) if self.redundancy else None,
            "at_bound": self.at_bound,
            "links": self.links,
            "metrics": self.metrics,
            "goodness_of_fit": self.goodness,
            "energy": self.energy,
        })

def _fmt(v) -> str:
    """A parameter value for a table: 5 significant digits, lists comma-separated, inf, '-' for nan; a table
    (a data-driven model's, more than 3 entries or rows) as its size and range (the JSON has every entry)."""
    if isinstance(v, (list, tuple, np.ndarray)):
        if len(v) > 3 or (len(v) and isinstance(v[0], (list, tuple, np.ndarray))):
            a = np.asarray(v, dtype=np.float64)
            fin = a[np.isfinite(a)]
            span = f"{fin.min():.4g} .. {fin.max():.4g}" if fin.size else "-"
            return f"table {'x'.join(str(n) for n in a.shape)}: {span}"
        return ", ".join(_fmt(x) for x in v)
    if isinstance(v, (float, np.floating)):
        return "inf" if math.isinf(v) else ("-" if math.isnan(v) else f"{v:.5g}")
    return str(v)


def _write_new(path, text: str, force: bool) -> None:
    """Write ``text`` to ``path`` (:func:`gonio.outputs.check_output`: not into a session, an existing
    file only with ``force``; one-line ConfigError)."""
    from gonio.errors import ConfigError
    from gonio.outputs import check_output, write_text_atomically

    p = check_output(path, option="output", force=force)

    try:
        write_text_atomically(p, text)
    except OSError as exc:
        raise ConfigError.field(None, "output", str(p), f"cannot write ({exc.strerror or exc})") from None
