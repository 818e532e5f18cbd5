"""The Plotly figures of the report and the viewer: coverage of the directions, BRDF slices in the plane of
incidence, residuals. Every label that names something from outside (an input, a model) goes through
:func:`gonio.page.plotly_text`, so Plotly shows it as written.

Slices are drawn one panel per colour channel (R, G, B) so that the series can be told apart by colour
and dash: measured points in black with ±1σ bars, a measured table in grey, and each model its own
colour *and* dash (:func:`model_styles`, the same for a model across every input of a page). A log axis
gets one labelled tick per decade, or 1-2-5 ticks when the data span less (:func:`log_ticks`).
"""

from __future__ import annotations

import functools
import math

import numpy as np

from gonio.errors import ConfigError
from gonio.page import plotly_text
from gonio.plots import in_plane, inplane_dirs

__all__ = ["plotly", "model_styles", "slice_figure", "slice_has_data", "slice_angles", "coverage_figure",
           "residual_figure", "log_ticks", "SLICE_THETA_I_DEG", "SLICE_TOL_DEG"]

#: Incidence angles of the slices of a table (degrees).
SLICE_THETA_I_DEG = (15.0, 30.0, 45.0, 60.0)
#: Angular tolerance selecting measured samples for a slice: θi and the plane (degrees).
SLICE_TOL_DEG = 2.5
#: Model colours (Tableau 10 without black and grey, which mean "measured" and "table") and dashes.
MODEL_COLOURS = ("#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b", "#e377c2", "#17becf")
MODEL_DASHES = ("dash", "dot", "dashdot", "longdash", "longdashdot")
MEASURED, TABLE = "#000000", "#7f7f7f"
#: A slice's log axis shows at most this many decades below its largest value.
MAX_DECADES = 5.0


@functools.lru_cache(maxsize=1)
def plotly_js() -> str:
    """Plotly's JavaScript (``plotly.offline.get_plotlyjs()``, 4.8 MB read from its package), read once a process."""
    return plotly().get_plotlyjs()


def plotly():
    """``plotly.offline`` (whose JavaScript the pages embed), or :class:`ConfigError` with the install hint."""
    try:
        import plotly.offline
    except ImportError:
        raise ConfigError("the report and the viewer need Plotly: pip install 'gonio[report]'") from None
    return plotly.offline


def values(a) -> list:
    """An array as a JSON list for a figure: NaN and ±inf as ``null`` (a gap: JSON has no NaN)."""
    a = np.asarray(a, dtype=np.float64)
    return np.where(np.isfinite(a), a, None).tolist()


def figure(data: list, layout: dict) -> dict:
    """A Plotly figure as plain data (``{"data", "layout"}``, https://plotly.com/javascript/reference/):
    what ``Plotly.newPlot`` takes and :func:`gonio.page.json_data` embeds; no Plotly needed in Python."""
    return {"data": data, "layout": {"template": TEMPLATE, **layout}}


#: The look of every figure: Plotly's default colours on a light grid.
TEMPLATE = {"layout": {"font": {"color": "#2a3f5f"}, "plot_bgcolor": "#E5ECF6", "paper_bgcolor": "white",
                       "xaxis": {"gridcolor": "white", "zerolinecolor": "white"},
                       "yaxis": {"gridcolor": "white", "zerolinecolor": "white"},
                       "polar": {"bgcolor": "#E5ECF6", "radialaxis": {"gridcolor": "white"},
                                 "angularaxis": {"gridcolor": "white"}}}}


def model_styles(entries) -> dict[str, tuple[str, str]]:
    """``{model label: (colour, dash)}`` over every entry, in order of first appearance: a model keeps its
    style across a comparison page, and two models never share both colour and dash (up to 40 models)."""
    labels = list(dict.fromkeys(label for e in entries for label in e.fits))
    return {label: (MODEL_COLOURS[k % len(MODEL_COLOURS)], MODEL_DASHES[k % len(MODEL_DASHES)])
            for k, label in enumerate(labels)}


def log_ticks(lo: float, hi: float) -> tuple[list[float], list[str]]:
    """Ticks of a log axis from ``lo`` to ``hi`` (> 0) that do not crowd: 10^k for every decade (every
    n-th when more than 6), or 1, 2, 5 × 10^k (then 1…9 × 10^k) when that leaves fewer than three; a
    range too narrow for those gets evenly spaced round values."""
    a, b = math.floor(math.log10(lo)), math.ceil(math.log10(hi))
    inside = (lambda v: lo * (1 - 1e-9) <= v <= hi * (1 + 1e-9))
    step = max(1, math.ceil((b - a) / 6))
    vals = [10.0 ** k for k in range(a, b + 1, step) if inside(10.0 ** k)]
    for mantissas in ((1, 2, 5), tuple(range(1, 10))):
        if len(vals) >= 3:
            break
        vals = [m * 10.0 ** k for k in range(a, b + 1) for m in mantissas if inside(m * 10.0 ** k)]
    if len(vals) < 2:  # less than a factor of 1.5: round values on a linear step (1, 2 or 5 × 10^k)
        unit = 10.0 ** math.floor(math.log10(hi - lo))
        d = next(m * unit for m in (0.1, 0.2, 0.5, 1.0) if (hi - lo) / (m * unit) <= 6)
        vals = [k * d for k in range(math.ceil(lo / d), math.floor(hi / d) + 1)]
    vals = [float(f"{v:.12g}") for v in vals]  # 6 × 0.1 is 0.6, not 0.6000000000000001
    return vals, [f"{v:.3g}" for v in vals]


def _log_axis(values: list[np.ndarray]) -> dict:
    """Plotly y-axis settings for a log axis showing ``values`` (their positive finite part)."""
    v = np.concatenate([np.ravel(x) for x in values]) if values else np.zeros(0)
    v = v[np.isfinite(v) & (v > 0)]
    if not v.size:
        return dict(type="log")
    hi = float(v.max())
    lo = max(float(v.min()), hi * 10.0 ** -MAX_DECADES)
    lo, hi = lo / 1.25, hi * 1.25
    vals, labels = log_ticks(lo, hi)
    return dict(type="log", range=[math.log10(lo), math.log10(hi)], tickvals=vals, ticktext=labels)


def _measured_in_slice(entry, theta_i_deg: float, tol_deg: float):
    s = entry.data.samples
    if s is None or not len(s):
        return None, None
    mask, signed = in_plane(s, theta_i_deg, tol_deg)
    return s.subset(mask), signed[mask]


def slice_has_data(entry, theta_i_deg: float, tol_deg: float = SLICE_TOL_DEG) -> bool:
    """Whether a slice at θi shows measured data: samples in the plane within ``tol_deg``, or a table."""
    if entry.data.table is not None:
        return True
    s, _ = _measured_in_slice(entry, theta_i_deg, tol_deg)
    return s is not None and len(s) > 0


def slice_angles(entry, k: int = 4, tol_deg: float = SLICE_TOL_DEG) -> list[float]:
    """The θi of an entry's slices: for samples, up to ``k`` incidences (most in-plane samples first, at
    least 5° apart) that have samples in the plane — a slice without data is not drawn; none at all:
    ``[]``. For a table, :data:`SLICE_THETA_I_DEG`."""
    s = entry.data.samples
    if s is None or not len(s):
        return list(SLICE_THETA_I_DEG)
    mask, _ = in_plane(s, None, tol_deg)
    ti = np.round(np.degrees(s.angles()[0][mask]))
    vals, counts = np.unique(ti, return_counts=True)
    chosen: list[float] = []
    for v in vals[np.argsort(-counts, kind="stable")]:
        if all(abs(v - c) >= 5.0 for c in chosen):
            chosen.append(float(v))
        if len(chosen) == k:
            break
    return sorted(chosen)


def slice_figure(entry, theta_i_deg: float, tol_deg: float = SLICE_TOL_DEG, *, styles: dict | None = None) -> dict:
    """The BRDF in the plane of incidence at θi, one panel per channel: measured samples (±1σ), table,
    models (``styles``: :func:`model_styles`; default: the entry's own). Log scale. Samples present but
    none in this slice: the panels say "no measured data" (the models are still drawn)."""
    styles = styles or model_styles([entry])
    data = entry.data
    s, x = _measured_in_slice(entry, theta_i_deg, tol_deg)
    t = np.linspace(-89.0, 89.0, 179)
    wi, wo = inplane_dirs(theta_i_deg, t)
    series = []  # (name, x, y (n, 3), sigma or None, trace style)
    if s is not None and len(s):
        order = np.argsort(x)
        series.append(("measured (±1σ)", x[order], s.f[order], s.sigma[order],
                       {"mode": "markers", "marker": {"color": MEASURED, "size": 5}}))
    if data.table is not None:
        series.append(("table", t, data.table.lookup(wi, wo), None,
                       {"mode": "lines", "line": {"color": TABLE, "width": 2}}))
    for label, (model, _rep) in entry.fits.items():
        colour, dash = styles.get(label, (MODEL_COLOURS[0], MODEL_DASHES[0]))
        series.append((plotly_text(label), t, np.asarray(model.eval(wi, wo)), None,
                       {"mode": "lines", "line": {"color": colour, "dash": dash, "width": 2}}))
    traces, shown = [], []
    for name, xs, ys, sig, style in series:
        for c in range(3):
            tr = {"type": "scatter", "x": values(xs), "y": values(ys[:, c]), "name": name, "legendgroup": name,
                  "showlegend": c == 0, "xaxis": f"x{c + 1 if c else ''}", "yaxis": f"y{c + 1 if c else ''}", **style}
            if sig is not None:
                tr["error_y"] = {"type": "data", "array": values(sig[:, c]), "visible": True, "color": MEASURED,
                                 "thickness": 1}
            traces.append(tr)
        shown += [ys, ys if sig is None else ys - sig]
    gap = 0.03
    width = (1 - 2 * gap) / 3
    layout = {"title": {"text": f"{plotly_text(entry.name)}: plane of incidence, θi = {theta_i_deg:g}°"},
              "height": 360, "margin": {"l": 60, "r": 20, "t": 70, "b": 50},
              "legend": {"orientation": "h", "x": 1, "xanchor": "right", "y": 1.2},
              "annotations": [{"text": f"{name} channel", "xref": "paper", "yref": "paper", "x": c * (width + gap) + width / 2,
                               "y": 1.0, "yanchor": "bottom", "showarrow": False, "font": {"size": 14}}
                              for c, name in enumerate(("red", "green", "blue"))]}
    yaxis = _log_axis(shown)
    for c in range(3):
        sfx = str(c + 1) if c else ""
        layout[f"xaxis{sfx}"] = {"domain": [c * (width + gap), c * (width + gap) + width], "range": [-90, 90],
                                 "tickvals": [-80, -40, 0, 40, 80], "anchor": f"y{sfx}",
                                 "title": {"text": "θo (deg), + on the specular side"}}
        layout[f"yaxis{sfx}"] = {**yaxis, "anchor": f"x{sfx}", **({"matches": "y", "showticklabels": False} if c else
                                                                {"title": {"text": "BRDF (1/sr)"}})}
    if s is not None and not len(s):
        layout["annotations"].append({"text": f"no measured data within ±{tol_deg:g}° of θi = {theta_i_deg:g}° in this "
                                              "plane", "xref": "paper", "yref": "paper", "x": 0.5, "y": 0.5,
                                      "showarrow": False, "font": {"size": 14, "color": "#a00"},
                                      "bgcolor": "rgba(255,255,255,0.8)"})
    return figure(traces, layout)


def coverage_figure(entry) -> dict:
    """Directions of the samples on a polar map (radius θ, angle φ; degrees). The rings' values are said
    in the title, not written inside the disc, where they would sit over the data."""
    s = entry.data.samples
    if s is None or not len(s):
        return figure([], {"title": {"text": f"{plotly_text(entry.name)}: a table (no samples to map)"}, "height": 300})
    ti, pi_, to, po = (np.degrees(a) for a in s.angles())
    traces = [{"type": "scatterpolar", "r": values(r), "theta": values(p), "mode": "markers", "name": name,
               "marker": {"size": 4, "color": colour}}
              for r, p, name, colour in ((ti, pi_, "wi (light)", "#ff7f0e"), (to, po, "wo (camera)", "#1f77b4"))]
    return figure(traces, {"title": {"text": f"{plotly_text(entry.name)}: {len(s)} samples<br><sub>angle φ; radius θ, "
                                             "rings at 30°, 60°, 90°</sub>"}, "height": 400, "margin": {"t": 90},
                           "polar": {"domain": {"y": [0, 0.86]},
                                     "radialaxis": {"range": [0, 90], "tickvals": [30, 60, 90], "showticklabels": False},
                                     "angularaxis": {"tickfont": {"size": 10}}}})


def residual_figure(entry, styles: dict | None = None) -> dict:
    """Histogram of (f − model)/σ (mean of R, G, B) for each model, in the model's colour."""
    s = entry.data.samples
    if s is None or not len(s) or not entry.fits:
        return figure([], {"title": {"text": f"{plotly_text(entry.name)}: no residuals (no samples or no model)"},
                           "height": 300})
    styles = styles or model_styles([entry])
    traces = []
    for label, (model, _rep) in entry.fits.items():
        with np.errstate(divide="ignore", invalid="ignore"):
            r = np.where(s.sigma > 0, (s.f - model.eval(s.wi, s.wo)) / s.sigma, np.nan).mean(axis=1)
        traces.append({"type": "histogram", "x": values(np.clip(r[np.isfinite(r)], -20, 20)), "name": plotly_text(label),
                       "opacity": 0.6, "nbinsx": 60, "histnorm": "probability density",
                       "marker": {"color": styles.get(label, (MODEL_COLOURS[0],))[0]}})
    return figure(traces, {"title": {"text": f"{plotly_text(entry.name)}: residuals (f − model)/σ, mean of R, G, B, "
                                             "clipped to ±20"}, "barmode": "overlay", "height": 320,
                           "xaxis": {"title": {"text": "(f − model) / σ"}},
                           "yaxis": {"title": {"text": "probability density"}}})
