"""What a reader sees: the viewer's sliders come first (the report below), every model's curves have their
own colour and dash, a slice without measured data is not drawn among the others (the viewer says "no
measured data"), no "Error images" caption without error images, log axes whose labels do not crowd,
coverage labels off the data, and 256-pixel spheres. Checked on the figures' data and, where it is about
the page, in a real headless browser (screenshots kept in ``screenshots/``)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from gonio.brdf import make
from gonio.geometry import from_spherical
from gonio.io.source import Measured
from gonio.report import Entry, build_report, load_entries, sphere_panel
from gonio.report_figures import MEASURED, TABLE, log_ticks, model_styles, slice_angles, slice_figure
from gonio.samples import SampleSet
from tests.report.browser import FIGURES_DRAWN, opened, serving, wait_until

LAMBERT = (make("lambert", albedo=[0.3, 0.12, 0.06]), {"params": {"albedo": [0.3, 0.12, 0.06]}})


@pytest.fixture(scope="module")
def compared(inputs, fit_json):
    """The session and the table, each with the run's fit and a Lambert model: a comparison page."""
    session, table = inputs
    entries = load_entries([str(session), str(table)], [str(fit_json)])
    for e in entries:
        e.fits["lambert"] = LAMBERT
    return entries


@pytest.fixture(scope="module")
def compared_page(compared, tmp_path_factory):
    out = tmp_path_factory.mktemp("layout") / "compared.html"
    out.write_text(build_report(compared, title="comparison"))
    return out


def _model_traces(fig) -> dict:
    styles: dict = {}
    for tr in fig["data"]:
        if tr.get("mode") == "lines":
            styles.setdefault(tr["name"], set()).add((tr["line"]["color"], tr["line"].get("dash", "solid")))
    return styles


def test_each_model_has_its_own_colour_and_dash_on_every_input(compared):
    styles = model_styles(compared)
    for e in compared:
        fig = slice_figure(e, 30.0, styles=styles)
        got = _model_traces(fig)
        models = {k: v for k, v in got.items() if k != "table"}
        assert len(models) == 2 and all(len(v) == 1 for v in models.values())  # one style per model, all channels
        pairs = [next(iter(v)) for v in models.values()]
        assert len({c for c, _ in pairs}) == 2 and len({d for _, d in pairs}) == 2  # colour AND dash differ
        assert not {c for c, _ in pairs} & {MEASURED, TABLE}
        assert {k: next(iter(v)) for k, v in models.items()} == {k: styles[k] for k in models}  # same on every input
    assert len(set(model_styles([Entry(str(k), None, fits={f"m{j}": None for j in range(40)}) for k in range(1)]).values())) == 40


def _synthetic(theta_i_in_plane: float, theta_i_off_plane: float) -> Entry:
    """Samples at one θi in the plane of incidence (10) and many more at another θi, all 90° out of it."""
    t = np.radians(np.linspace(-70, 70, 10))
    wo_in = from_spherical(np.abs(t), np.where(t >= 0, np.pi, 0.0))
    wo_off = from_spherical(np.radians(np.linspace(10, 70, 40)), np.full(40, np.pi / 2))
    wi = np.concatenate([np.broadcast_to(from_spherical(np.radians(theta_i_in_plane), 0.0), wo_in.shape),
                         np.broadcast_to(from_spherical(np.radians(theta_i_off_plane), 0.0), wo_off.shape)])
    wo = np.concatenate([wo_in, wo_off])
    s = SampleSet(wi, wo, np.full((50, 3), 0.1), np.full((50, 3), 0.01))
    return Entry("synthetic", Measured(Path("synthetic"), "session", {}, samples=s), fits={"lambert": LAMBERT})


def test_a_slice_without_measured_data_is_not_drawn_and_the_viewer_says_so():
    e = _synthetic(30.0, 50.0)  # θi = 50° has the most samples, none of them in the plane
    assert slice_angles(e) == [30.0]
    assert "no measured data" not in str(slice_figure(e, 30.0)["layout"].get("annotations"))
    at_50 = slice_figure(e, 50.0)  # the viewer's slider may go there: said, not an empty plot among the others
    assert not [tr for tr in at_50["data"] if tr.get("mode") == "markers"]
    assert any("no measured data" in a["text"] for a in at_50["layout"]["annotations"])
    page = build_report([e])
    assert page.count('class="plotly-figure"') == 3  # coverage, residuals, the one slice with data
    nowhere = _synthetic(30.0, 50.0)
    nowhere.data.samples.wo[:10] = from_spherical(np.radians(np.linspace(10, 70, 10)), np.full(10, np.pi / 2))
    assert slice_angles(nowhere) == [] and "No measured samples lie in a plane of incidence" in build_report([nowhere])


def test_error_images_are_captioned_only_where_there_are_some(compared):
    session, table = compared
    sparse = sphere_panel(session)  # too few samples for a measured sphere: no error images, no caption
    assert "error of" not in sparse and "Error images" not in sparse and "too few to render" in sparse
    full = sphere_panel(table)
    assert full.count('alt="error of ') == 3 * 2 and "Error images" in full
    assert sphere_panel(Entry("t", table.data)).count("Error images") == 0  # a table without a model: none


@pytest.mark.parametrize("lo, hi", [(0.02, 0.17), (0.016, 5.0), (1e-4, 10.0), (1e-12, 1e3), (0.5, 0.6), (3.0, 3.5),
                                    (1e-3, 1e-2)])
def test_log_ticks_do_not_crowd(lo, hi):
    vals, labels = log_ticks(lo, hi)
    assert 2 <= len(vals) <= 9 and len(set(labels)) == len(labels)
    assert all(lo <= v <= hi for v in vals)
    span = math.log10(hi / lo)
    assert min(math.log10(b / a) for a, b in zip(vals, vals[1:])) >= 0.09 * span, vals  # evenly apart, not a cluster
    if span > 3:
        assert all(math.isclose(math.log10(v), round(math.log10(v))) for v in vals)  # whole decades


OVERLAPS = """(sel) => {
  const r = Array.from(document.querySelectorAll(sel)).map(e => e.getBoundingClientRect()).filter(b => b.width > 0);
  let n = 0;
  for (let i = 0; i < r.length; i++) for (let j = i + 1; j < r.length; j++) {
    const a = r[i], b = r[j];
    if (a.left < b.right && b.left < a.right && a.top < b.bottom && b.top < a.bottom) n++;
  }
  return [r.length, n];
}"""
TEXT_ON_POINTS = """(id) => {
  const fig = document.getElementById(id);
  const pts = Array.from(fig.querySelectorAll('.point')).map(e => e.getBoundingClientRect());
  const area = fig.querySelector('.polarlayer, .polar').getBoundingClientRect();
  const txt = Array.from(fig.querySelectorAll('text')).map(e => e.getBoundingClientRect())
      .filter(b => b.width > 0 && b.left >= area.left && b.right <= area.right && b.top >= area.top && b.bottom <= area.bottom);
  let n = 0;
  for (const t of txt) for (const p of pts) if (t.left < p.right && p.left < t.right && t.top < p.bottom && p.top < t.bottom) n++;
  return [pts.length, n];
}"""


def test_comparison_page_reads_well_in_a_browser(browser, compared_page, screenshots):
    with opened(browser, compared_page.as_uri(), offline=True) as p:
        page = p.page
        wait_until(page, FIGURES_DRAWN)
        assert not p.errors, p.errors
        # log axes: the labels of every slice's BRDF axis do not touch each other
        for k in range(2):
            n, overlaps = page.evaluate(OVERLAPS, f"#plot-{k}-2 .yaxislayer-above .ytick text")
            assert n >= 2 and overlaps == 0, (k, n, overlaps)
        # the coverage map: no label inside the plot over a data point
        n_points, on_points = page.evaluate(TEXT_ON_POINTS, "plot-0-0")
        assert n_points > 100 and on_points == 0
        # spheres are drawn at 256 px
        sizes = page.evaluate("Array.from(document.querySelectorAll('img.sphere')).map(i => [i.naturalWidth, i.width])")
        assert sizes and all(s == [256, 256] for s in sizes), sizes
        # the legend of a slice names each model once
        legend = page.evaluate("Array.from(document.querySelectorAll('#plot-1-2 .legendtext')).map(t => t.textContent)")
        assert sorted(legend) == sorted(["table", "microfacet (fit.json)", "lambert"]), legend
        page.locator("#fig-1-2").screenshot(path=str(screenshots / "slice-compared.png"))
        page.locator("#fig-0-0").screenshot(path=str(screenshots / "coverage.png"))


def test_viewer_controls_come_first_then_the_report(browser, compared, screenshots):
    from gonio.viewer import make_server

    server = make_server(compared)
    with serving(server) as url, opened(browser, url + "/", viewport=(1300, 900)) as p:
        page = p.page
        wait_until(page, "document.getElementById('live-1-0').naturalWidth > 0 && "
                         "document.querySelector('#live-slice-1 .main-svg') !== null")
        top = page.evaluate("(s) => document.querySelector(s).getBoundingClientRect().top", "#theta-0")
        assert top < 200  # the sliders are on the first screen, not after the report
        first_report = page.evaluate("document.querySelector('section.entry').getBoundingClientRect().top")
        last_control = page.evaluate("document.getElementById('live-slice-1').getBoundingClientRect().bottom")
        assert last_control <= first_report  # every interactive panel above the report
        measured = page.evaluate("[document.getElementById('live-1-0').naturalWidth, "
                                 "document.getElementById('live-1-0').alt]")
        assert measured == [256, "measured"]  # the table's measured sphere first, at 256 px
        assert not p.errors, p.errors
        page.screenshot(path=str(screenshots / "viewer-layout.png"))


def test_no_empty_figure_for_a_table_and_none_without_a_model(compared):
    _session, table = compared
    page = build_report([table])
    assert 'id="data-0-0"' not in page and 'id="data-0-1"' not in page  # no coverage map, no residuals: no samples
    assert "no samples to map or to take residuals on" in page and page.count('class="plotly-figure"') == 4
    bare = Entry("bare", _synthetic(30.0, 50.0).data)
    assert "No model fitted: no residuals." in build_report([bare])


def test_matplotlib_polar_maps_write_no_label_over_the_data():
    from gonio import plots

    e = _synthetic(30.0, 50.0)
    for fig in (plots.coverage(samples=e.data.samples), plots.polar_slice(samples=e.data.samples, theta_i_deg=30.0)):
        fig.canvas.draw()
        polar = [ax for ax in fig.axes if ax.name == "polar"]
        assert polar and all(not t.get_text() for ax in polar for t in ax.get_yticklabels())
        assert all("rings at θ = 30°, 60°, 90°" in ax.get_title() for ax in polar)  # said in the title instead
