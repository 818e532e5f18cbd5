"""A material on one page: the self-contained HTML report of ``gonio report`` and the page ``gonio view``
serves.

For each input (a session directory, a MERL table, an NPZ/CSV export) the report shows what was
measured and how (manifest summary: rig, plan, lab time, flags), the coverage of the directions, BRDF
slices in the plane of incidence at several incidence angles (measured points with ±1σ bars, the table
and the fitted models as curves), the residuals of each fitted model, a table of its parameters with
uncertainties and the notes of the fit (parameters on a bound, not identified), and lit spheres
(:mod:`gonio.render`): the measured data and each model under the same lights, side by side, with a
relative-error image. Several inputs give one comparison page.

Figures are Plotly (https://plotly.com/python/, :mod:`gonio.report_figures`), whose JavaScript is
embedded once in the page, so the file opens without a network; sphere images are embedded PNGs.
``pip install 'gonio[report]'``. Every string from an input (names, manifest fields, notes, a fit JSON's
labels, error messages) is escaped where it lands, and the page states a Content-Security-Policy that lets
only its own scripts run (:mod:`gonio.page`).
"""

from __future__ import annotations

import base64
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from gonio.errors import ConfigError
from gonio.page import Page, text
from gonio.render import png_bytes, white_point
from gonio.report_figures import (coverage_figure, model_styles, plotly_js, residual_figure, slice_angles,
                                  slice_figure)

__all__ = ["Entry", "load_entries", "build_report", "report_page", "sphere_panel", "slice_figure", "fit_table",
           "comparison_table", "LIGHT_ANGLES_DEG", "SPHERE_SIZE"]

#: Light polar angles (degrees from the view axis) of the sphere panels.
LIGHT_ANGLES_DEG = (0.0, 35.0, 70.0)
#: On-the-fly fits use at most this many samples (a random subset, seed 0): a preview in seconds, not
#: minutes, for a full MERL table (1.46 M cells); ``gonio fit`` + ``--model FIT.json`` fits them all.
MAX_PREVIEW_FIT_SAMPLES = 20000
#: Side of the rendered spheres (pixels), in the report and the viewer.
SPHERE_SIZE = 256


@dataclass
class Entry:
    """One input of a report: the measured data and the models fitted to it (name → FitResult)."""

    name: str
    data: object  # gonio.io.source.Measured
    fits: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)


def load_entries(sources: Sequence[str], fit_files: Sequence[str] = (), *, fit_models: Sequence[str] = ("microfacet",),
                 fit_kw: dict | None = None) -> list[Entry]:
    """Read every source (:func:`gonio.load`); attach the models of ``fit_files`` (``gonio fit --json``;
    all of them apply to every source) or, without them, fit ``fit_models`` now."""
    import gonio
    from gonio.brdf import make

    entries = []
    given = []
    for f in fit_files:
        try:
            report = json.loads(Path(f).read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            raise ConfigError.field("--model", "model", f, f"cannot read the fit JSON ({exc})") from None
        if not isinstance(report, dict) or not isinstance(report.get("model"), str):
            raise ConfigError.field("--model", "model", f, "not a gonio fit --json result")
        given.append((f"{report['model']} ({Path(f).name})", make(report["model"], source=f, **report.get("params", {})),
                      report))
    for src in sources:
        data = gonio.load(src)
        if data.samples is not None and len(data.samples) == 0 and data.table is None:
            from gonio.errors import DataError

            raise DataError(f"{src}: holds no samples to show (an empty export or a session stopped before its "
                            "first pose)")
        e = Entry(Path(src).name or str(src), data)
        if given:
            e.fits = {label: (model, scored_on(model, rep, data)) for label, model, rep in given}
        elif fit_models:
            samples = preview_samples(data, e.notes)
            from gonio.api import calibration_modes

            geometry = calibration_modes(data)  # the calibration's error in the fits' σ, as gonio fit has it
            kw = {**({"geometry": geometry} if geometry is not None else {}), **(fit_kw or {})}
            for m in fit_models:
                try:
                    r = gonio.fit(samples, m, **kw)
                    e.fits[m] = (r.model, {**r.to_dict(), "uncertainty": r.uncertainty})
                except Exception as exc:  # noqa: BLE001 - a failed fit is shown, not fatal to the report
                    e.notes.append(f"fit of {m} failed: {exc}")
        entries.append(e)
    return entries


def model_errors(model, samples, n_params: int = 0) -> dict:
    """``rms_rel`` and ``chi2_red`` of ``model`` on ``samples`` as :func:`gonio.fit.fit.fit` reports them
    for its own fit (gonio/fit/fit.py): on the samples :func:`gonio.fit.data.prepare` keeps,
    rms_rel = √(Σ (cos θi (m − y))² / Σ (cos θi y)²) and, where the samples state every σ,
    χ²/dof = Σ ((m − y)/σ)² / (3N − k), k = ``n_params``; None where not defined."""
    from gonio.errors import DataError
    from gonio.fit.data import prepare

    try:
        d = prepare(samples)
    except DataError:
        return {"rms_rel": None, "chi2_red": None, "n": 0}
    m = np.asarray(model.eval(d.wi, d.wo), dtype=np.float64)
    c = d.cos_i[:, None]
    rms = float(np.sqrt(np.sum((c * (m - d.y)) ** 2) / max(np.sum((c * d.y) ** 2), 1e-300)))
    chi2 = None
    if d.sigma is not None:
        chi2 = float(np.sum(((m - d.y) / d.sigma) ** 2) / max(3 * len(d) - int(n_params), 1))
    return {"rms_rel": rms if np.isfinite(rms) else None, "chi2_red": chi2, "n": len(d)}


def scored_on(model, rep: dict, data) -> dict:
    """A saved fit's report with its errors measured on ``data`` (:func:`model_errors`): the JSON's own
    errors are those of the data it was fitted to, and one FIT.json is shown for every input."""
    own = rep.get("error") or {}
    err = model_errors(model, data.to_samples(), rep.get("n_params") or 0)
    note = (f"errors on this input's {err['n']} samples; the fit's own (on its {rep.get('n_used', '?')} samples): "
            f"relative RMS {_fmt(own.get('rms_rel'))}, χ²/dof {_fmt(own.get('chi2_red'))}")
    return {**rep, "error": {"rms_rel": err["rms_rel"], "chi2_red": err["chi2_red"]},
            "notes": [*(rep.get("notes") or []), note]}


def preview_samples(data, notes: list | None = None, limit: int = MAX_PREVIEW_FIT_SAMPLES):
    """The samples of ``data`` for an on-the-fly fit: all of them, or a random subset of ``limit``
    (seed 0, so the report is reproducible), said in ``notes``."""
    samples = data.to_samples()
    if len(samples) <= limit:
        return samples
    index = np.sort(np.random.default_rng(0).choice(len(samples), size=limit, replace=False))
    if notes is not None:
        notes.append(f"models fitted on {limit} of {len(samples)} samples (random subset, for speed); "
                     "gonio fit + --model FIT.json fits all of them")
    return samples.subset(index)


def _png(img: np.ndarray, mask: np.ndarray | None = None) -> str:
    return "data:image/png;base64," + base64.b64encode(png_bytes(img, mask)).decode("ascii")


def sphere_images(brdf, theta_deg: float, phi_deg: float = 0.0, *, size: int = SPHERE_SIZE, white=None):
    """(radiance, 8-bit image) of ``brdf`` on a sphere lit from (θ, φ) (degrees)."""
    from gonio.render import light_from_angles, render_sphere, tonemap

    r = render_sphere(brdf, [light_from_angles(theta_deg, phi_deg)], size=size)
    return r.radiance, tonemap(r.radiance, white=white), r


#: Samples (not a table) are rendered as a measured sphere only above this count.
MIN_SAMPLES_FOR_SPHERE = 2000
#: Relative error at the top of the error images' colour scale.
ERROR_SCALE = 0.2


def error_image(rel: np.ndarray, scale: float = ERROR_SCALE) -> np.ndarray:
    """8-bit RGB image of a relative error map: 0 → black, ``scale`` or more → yellow (inferno)."""
    import cv2

    level = np.rint(255 * np.clip(np.nan_to_num(rel / scale), 0, 1)).astype(np.uint8)
    return cv2.applyColorMap(level, cv2.COLORMAP_INFERNO)[..., ::-1]


def renders_measured(data) -> bool:
    """Whether the measured data are drawn on a sphere: a table, or more than
    :data:`MIN_SAMPLES_FOR_SPHERE` samples (fewer leave most pixels without a measurement)."""
    return data.table is not None or (data.samples is not None and len(data.samples) > MIN_SAMPLES_FOR_SPHERE)


def sphere_sources(entry: Entry) -> list[tuple[str, object]]:
    """``(label, brdf)`` of every sphere of an entry: the measured data (if :func:`renders_measured`),
    then each fitted model (the report's columns and the viewer's live images)."""
    return ([("measured", entry.data)] if renders_measured(entry.data) else []) + \
        [(label, model) for label, (model, _rep) in entry.fits.items()]


def sphere_panel(entry: Entry, *, size: int = SPHERE_SIZE) -> str:
    """HTML table: one row per light angle; the measured data, each model, and |model − data| / data."""
    data = entry.data
    measured = data if renders_measured(data) else None
    rows = []
    head = ["light θ"] + (["measured"] if measured is not None else []) + list(entry.fits) + \
        ([f"error of {k}" for k in entry.fits] if measured is not None else [])
    for theta in LIGHT_ANGLES_DEG:
        cells = [f"{theta:g}°"]
        ref = white = None
        if measured is not None:
            try:
                rad, img, r = sphere_images(measured, theta, size=size)
                ref, white = rad, white_point(rad)  # the models' spheres on the measured one's scale
                cells.append(f'<img class="sphere" alt="measured, light at {theta:g} deg" src="{_png(img, r.mask)}">'
                             + (f"<br><small>{r.missing} px not measured</small>" if r.missing else ""))
            except Exception as exc:  # noqa: BLE001 - e.g. anisotropic samples that do not tabulate
                cells.append(f"<small>cannot render the measured data: {text(str(exc)[:200])}</small>")
                ref = white = None
        errs = []
        for label, (model, _rep) in entry.fits.items():
            rad, img, rm = sphere_images(model, theta, size=size, white=white)
            cells.append(f'<img class="sphere" alt="{text(label)}, light at {theta:g} deg" src="{_png(img, rm.mask)}">')
            if ref is not None:
                with np.errstate(divide="ignore", invalid="ignore"):
                    rel = np.where(ref > 0, np.abs(rad - ref) / ref, 0.0).mean(axis=-1)
                err_img = error_image(rel)
                lit = ref.sum(-1) > 0
                errs.append(f'<img class="sphere" alt="error of {text(label)}" src="{_png(err_img, rm.mask)}"><br>'
                            f"<small>median {100 * float(np.median(rel[lit])) if np.any(lit) else 0:.1f} %</small>")
        cells += errs
        rows.append("<tr>" + "".join(f"<td>{c}</td>" for c in cells) + "</tr>")
    sparse = "" if measured is not None else (
        f"<p class='sparse'>{len(data.samples) if data.samples is not None else 0} samples are too few to render the "
        f"measured data on a sphere (more than {MIN_SAMPLES_FOR_SPHERE} needed: most pixels would have no "
        "measurement); the fitted models are shown.</p>")
    caption = ("<p><small>Error images: |model − measured| / measured, mean of R, G, B; colour map inferno: black "
               f"0 %, yellow {100 * ERROR_SCALE:g} % or more.</small></p>") if measured is not None and entry.fits else ""
    return (sparse + '<div class="scroll"><table class="spheres"><tr>' + "".join(f"<th>{text(h)}</th>" for h in head)
            + "</tr>" + "".join(rows) + "</table></div>" + caption)


def _bounds(model) -> dict:
    try:
        return dict(model.bounds())
    except Exception:  # noqa: BLE001 - a measured table or a model without fitting bounds
        return {}


def _on_bound(v, lo, hi) -> bool:
    """A value within 1e-9 (relative) of its bound: the fit is limited there, not identified by the data."""
    vals = np.atleast_1d(np.asarray(v, dtype=np.float64))
    tol = 1e-9 * np.maximum(1.0, np.abs(vals))
    return bool(np.any(np.abs(vals - lo) <= tol) or (np.isfinite(hi) and np.any(np.abs(vals - hi) <= tol)))


def fit_table(entry: Entry) -> str:
    """Per model: error, then parameter, value, standard uncertainty, fitting bounds and whether the value
    sits on a bound (then it is limited by the bound, not determined by the data)."""
    rows = []
    for label, (model, rep) in entry.fits.items():
        unc = rep.get("uncertainty") or {}
        err = rep.get("error") or {}
        bounds = _bounds(model)
        lines = []
        for k, v in (rep.get("params") or {}).items():
            b = bounds.get(k)
            flag = ""
            if b is not None and not isinstance(v, str):
                try:
                    flag = "on a bound" if _on_bound(v, *b) else ""
                except (TypeError, ValueError):
                    flag = ""
            lines.append(f"<tr><td>{text(k)}</td><td>{text(_fmt(v))}</td>"
                         f"<td>{text(_fmt(unc.get(k)))}</td>"
                         f"<td>{text('[' + _fmt(float(b[0])) + ', ' + _fmt(float(b[1])) + ']') if b else '–'}</td>"
                         f"<td class='flag'>{flag}</td></tr>")
        notes = "".join(f"<li>{text(str(n))}</li>" for n in rep.get("notes") or [])
        rows.append(f"<h4>{text(label)}</h4><p>relative RMS error {text(_fmt(err.get('rms_rel')))}, "
                    f"χ²/dof {text(_fmt(err.get('chi2_red')))}</p><table class='params'><tr><th>parameter</th><th>value</th>"
                    f"<th>standard uncertainty</th><th>bounds</th><th></th></tr>{''.join(lines)}</table>"
                    + (f"<ul>{notes}</ul>" if notes else ""))
    return "".join(rows) or "<p>No model fitted.</p>"


def comparison_table(entries: Sequence[Entry]) -> str:
    """Several inputs: one row per input and model, with the fit's errors, to compare at a glance."""
    rows = []
    for k, e in enumerate(entries):
        for label, (_model, rep) in e.fits.items() or [("–", (None, {}))]:
            err = rep.get("error") or {}
            rows.append(f"<tr><td><a href='#entry-{k}'>{text(e.name)}</a></td><td>{text(str(e.data.kind))}</td>"
                        f"<td>{text(label)}</td><td>{text(_fmt(err.get('rms_rel')))}</td><td>{text(_fmt(err.get('chi2_red')))}</td></tr>")
    return ("<table class='comparison'><tr><th>input</th><th>kind</th><th>model</th><th>relative RMS error</th>"
            "<th>χ²/dof</th></tr>" + "".join(rows) + "</table>")


def _fmt(v) -> str:
    if v is None:
        return "–"
    if isinstance(v, (list, tuple)):
        return ", ".join(_fmt(x) for x in v)
    if isinstance(v, float):
        return f"{v:.5g}"
    return str(v)


def summary_html(entry: Entry) -> str:
    m = entry.data.manifest if isinstance(entry.data.manifest, dict) else {}
    items = [("kind", entry.data.kind), ("path", str(entry.data.path))]
    if entry.data.samples is not None:
        s = entry.data.samples
        items.append(("samples", f"{len(s)} ({int(np.count_nonzero(s.flags))} flagged)"))
    if m:
        plan = m.get("plan") if isinstance(m.get("plan"), dict) else {}
        rig = m.get("rig") if isinstance(m.get("rig"), dict) else {}
        runs = [r.get("lab_time_s") for r in m.get("runs") or [] if isinstance(r, dict)]
        lab = sum(t for t in runs if isinstance(t, (int, float)))
        from gonio.io.material_toml import describe_material

        items += [("material", describe_material(m.get("material"))), ("rig", str(rig.get("name", "–"))),
                  ("plan", f"{plan.get('generator', '–')}, {plan.get('n_poses', '–')} poses"),
                  ("lab time", f"{lab:.0f} s" if runs else "–"), ("exit status", str(m.get("exit_status")))]
    items += [("note", n) for n in entry.notes]
    return "<table class='summary'>" + "".join(f"<tr><th>{text(k)}</th><td>{text(str(v))}</td></tr>"
                                               for k, v in items) + "</table>"


STYLE = """body{font-family:sans-serif;margin:1.5em;max-width:1500px}th{white-space:nowrap}h2{border-bottom:1px solid #ccc}
table{border-collapse:collapse}td,th{padding:3px 8px;text-align:left;vertical-align:top}
img.sphere,img.live{width:256px;height:256px;background:#404040}
.figure{display:inline-block;width:48%;min-width:420px}.figure.wide{display:block;width:100%}
.no-slice{color:#a00}section.live{border:1px solid #ccc;border-radius:6px;padding:0 1em 1em;margin-bottom:2em}
section.live figure{display:inline-block;margin:0 1em .8em 0}section.live .slider{display:inline-block;margin-right:2em}
section.live input[type=range]{width:260px;vertical-align:middle}.live-slice{height:360px}
.live-error{color:#a00}.scroll{overflow-x:auto}"""

#: The one script that draws every figure of a page from its JSON data block (``script.plotly-figure``,
#: ``data-target`` the element to draw in): fixed code, so its hash in the page's policy never changes.
DRAW_FIGURES_JS = ("document.querySelectorAll('script.plotly-figure').forEach(function (s) {"
                   "var f = JSON.parse(s.textContent);"
                   "Plotly.newPlot(s.dataset.target, f.data, f.layout, {responsive: true, displaylogo: false});});")


def _figure(page: Page, div_id: str, fig, css: str = "figure") -> None:
    page.add(f"<div class='{css}' id='fig-{div_id}'><div id='plot-{div_id}'></div></div>")
    page.data(f"data-{div_id}", fig, css_class="plotly-figure", data_target=f"plot-{div_id}")


def report_page(entries: Sequence[Entry], *, title: str = "gonio report", lead_html: str = "",
                same_origin: bool = False) -> Page:
    """The report as a :class:`gonio.page.Page` (Plotly's JavaScript inlined: no network needed);
    ``lead_html`` (escaped markup) comes first, under the title — the viewer's controls;
    ``same_origin``: the page may load images and data from its own server (the viewer)."""
    page = Page(title, STYLE, same_origin=same_origin).script(plotly_js(), head=True)
    page.add(f"<h1>{text(title)}</h1>{lead_html}")
    styles = model_styles(entries)
    if len(entries) > 1:
        page.add(f"<h2>Comparison</h2>{comparison_table(entries)}")
    for k, e in enumerate(entries):
        page.add(f"<section class='entry' id='entry-{k}'><h2>{text(e.name)}</h2>{summary_html(e)}"
                 "<h3>Coverage and residuals</h3>")
        has_samples = e.data.samples is not None and len(e.data.samples) > 0
        if has_samples:  # an empty figure is not drawn: one line says why there is none
            _figure(page, f"{k}-0", coverage_figure(e))
        if has_samples and e.fits:
            _figure(page, f"{k}-1", residual_figure(e, styles))
        if not (has_samples and e.fits):
            page.add("<p class='none'>" + ("No model fitted: no residuals." if has_samples else
                                           f"A {text(e.data.kind)} table: no samples to map or to take residuals on.")
                     + "</p>")
        angles = slice_angles(e)
        page.add("<h3>Slices in the plane of incidence</h3>")
        if not angles:
            page.add("<p class='no-slice'>No measured samples lie in a plane of incidence (within ±2.5°): no "
                     "slice to draw; the coverage map shows where the samples are.</p>")
        for j, t in enumerate(angles):
            _figure(page, f"{k}-{j + 2}", slice_figure(e, t, styles=styles), "figure wide")
        page.add(f"<h3>Fitted models</h3>{fit_table(e)}<h3>Rendered spheres</h3>{sphere_panel(e)}</section>")
    return page.script(DRAW_FIGURES_JS)


def build_report(entries: Sequence[Entry], *, title: str = "gonio report") -> str:
    """The whole page as one HTML string (:func:`report_page`)."""
    return report_page(entries, title=title).render()
