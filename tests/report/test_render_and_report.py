"""Lit spheres (gonio.render), the self-contained HTML report and the interactive viewer, opened in a real
headless browser (Debian's Chromium driven by Playwright; one browser, session, fit and report shared by
the tests: conftest.py). Screenshots are kept in ``screenshots/`` of the run's temp dir."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from gonio.brdf import make
from gonio.cli.main import main
from gonio.io.merl import MerlTable
from gonio.lights import DirectionalLight, PointLight, SpotLight
from gonio.render import light_from_angles, render_sphere, sphere_points, tonemap
from tests.report.browser import FIGURES_DRAWN, opened, serving, wait_until

REPO = Path(__file__).resolve().parents[2]


# -- the renderer ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("theta, phi", [(0, 0), (40, 30), (75, 200)])
def test_lambertian_sphere_follows_the_cosine_law(theta, phi):
    albedo = np.array([0.5, 0.3, 0.2])
    light = light_from_angles(theta, phi, irradiance=2.0)
    r = render_sphere(make("lambert", albedo=albedo), [light], size=64)
    mask, n = sphere_points(64)
    expected = albedo / np.pi * 2.0 * np.maximum(0.0, n @ -light.direction)[..., None] * mask[..., None]
    assert np.max(np.abs(r.radiance - expected)) < 1e-6 and r.missing == 0
    assert np.all(r.radiance[~mask] == 0)


def test_lights_add_and_a_spot_light_lights_only_its_cone():
    m = make("lambert", albedo=0.8)
    a, b = light_from_angles(20), PointLight([0.0, 0.0, 1.0], 0.3)
    both = render_sphere(m, [a, b], size=48).radiance
    assert np.allclose(both, render_sphere(m, [a], size=48).radiance + render_sphere(m, [b], size=48).radiance)
    spot = SpotLight([0.0, 0.0, 1.0], [0.0, 0.0, -1.0], 1.0, hotspot=np.radians(2), falloff=np.radians(3))
    img = render_sphere(m, [spot], size=64).radiance.sum(-1)
    mask, n = sphere_points(64)
    r_xy = np.hypot(n[..., 0], n[..., 1]) * 0.05  # the sphere's radius is 5 cm, the spot 1 m away
    assert np.all(img[mask & (r_xy > np.tan(np.radians(3.2)) * 0.96)] == 0)
    assert np.all(img[mask & (r_xy < np.tan(np.radians(1.5)) * 0.95)] > 0)


def test_a_measured_table_renders_like_its_model_and_ambient_is_lambert_exact(cells):
    model = make("lambert+ggx", **{"diffuse.albedo": [0.4, 0.3, 0.2], "lobe1.alpha": 0.3, "lobe1.f0": 0.9})
    wi, wo, _ = cells
    v = model.eval(wi, wo)
    v[(wi[..., 2] <= 0) | (wo[..., 2] <= 0)] = np.nan
    table = MerlTable(v)
    lights = [light_from_angles(30, 0), light_from_angles(60, 120, 0.5)]
    a, b = render_sphere(table, lights, size=64), render_sphere(model, lights, size=64)
    lit = b.radiance.sum(-1) > 1e-3 * b.radiance.sum(-1).max()
    rel = np.abs(a.radiance - b.radiance)[lit] / b.radiance[lit]
    assert np.median(rel) < 0.02
    # lit from the viewer: wi == wo in every pixel, where the reference's acos(wi · h) rounds to NaN
    a, b = render_sphere(table, [light_from_angles(0)], size=96), render_sphere(model, [light_from_angles(0)], size=96)
    assert a.missing == 0 and np.median(np.abs(a.radiance - b.radiance)[b.mask] / b.radiance[b.mask]) < 0.02
    amb = render_sphere(make("lambert", albedo=0.6), [], size=32, ambient=2.0)
    assert np.allclose(amb.radiance[amb.mask], 0.6 * 2.0)
    img = tonemap(b.radiance)
    assert img.dtype == np.uint8 and img.max() == 255 and img[~b.mask].max() == 0


# -- report and viewer in a real browser (shared fixtures: conftest.py) -----------------------------------
def test_report_is_self_contained_and_only_reads(report):
    assert "wrote" in report.stdout
    assert report.after == report.before  # the report only reads
    text = report.path.read_text()
    import re

    assert re.search(r"\d+ samples are too few to render the measured data", text)  # said, not silently left out
    assert "random subset" in text  # the table's on-the-fly fit is a preview on a subset, and says so
    assert not re.search(r"<(script|link|img)[^>]+(src|href)=[\"']https?:", text)  # nothing fetched from a network


def test_report_opens_offline_and_every_figure_renders(browser, report, screenshots):
    with opened(browser, report.path.as_uri(), offline=True) as p:
        page = p.page
        wait_until(page, FIGURES_DRAWN)
        n_fig = page.locator("div.figure").count()
        assert n_fig >= 2 * 3  # per input: coverage, residuals, slices
        spheres = page.locator("img.sphere")
        assert spheres.count() >= 2 * 3
        widths = page.evaluate("Array.from(document.querySelectorAll('img.sphere')).map(i => i.naturalWidth)")
        assert min(widths) > 0
        assert page.locator("table.comparison tr").count() == 1 + 2  # two inputs: one comparison table
        assert not p.errors, p.errors  # nothing refused by the page's policy, no script error
        shot = screenshots / "report.png"
        page.screenshot(path=str(shot), full_page=True)
        print(f"report screenshot: {shot}")


def test_viewer_sliders_rerender_and_nothing_is_written(browser, inputs, fit_json, screenshots, digest):
    from gonio.report import load_entries
    from gonio.viewer import make_server

    session, _table = inputs
    before = digest(session)
    server = make_server(load_entries([str(session)], [str(fit_json)]), port=0)  # the run's fit, not a new one
    with serving(server) as url, opened(browser, url + "/") as p:
        page = p.page
        wait_until(page, "document.getElementById('live-0-0').naturalWidth > 0")
        assert page.locator("img.live").count() == 1  # sparse samples: no measured sphere, the model's
        src0 = page.get_attribute("#live-0-0", "src")
        png0 = urllib.request.urlopen(url + src0).read()
        page.fill("#theta-0", "70")
        page.dispatch_event("#theta-0", "input")
        wait_until(page, "document.getElementById('live-0-0').src.indexOf('theta=70') >= 0")
        src1 = page.get_attribute("#live-0-0", "src")
        png1 = urllib.request.urlopen(url + src1).read()
        assert src1 != src0 and png1 != png0  # the rendered sphere changed with the light
        page.fill("#ti-0", "50")
        page.dispatch_event("#ti-0", "input")
        wait_until(page, "document.getElementById('live-slice-0').querySelector('.main-svg') !== null")
        assert not p.errors, p.errors
        page.screenshot(path=str(screenshots / "viewer.png"))
        print(f"viewer screenshot: {screenshots / 'viewer.png'}")
    assert digest(session) == before


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["ctrl-c", "sigterm"])
def test_view_command_serves_and_stops_cleanly_on_ctrl_c(inputs, fit_json, sig):
    session, _ = inputs
    # started with SIGINT ignored, as a program that ignores Ctrl-C would start it: `gonio view` arms it itself
    old = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        proc = subprocess.Popen([sys.executable, "-m", "gonio.cli.main", "view", str(session), "--model",
                                 str(fit_json), "--no-browser"],
                                cwd=REPO, env={**os.environ, "PYTHONPATH": str(REPO)}, stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True)
    finally:
        signal.signal(signal.SIGINT, old)
    try:
        line = proc.stdout.readline()
        assert line.startswith("gonio view: serving http://127.0.0.1:"), line
        url = line.split()[3]
        with urllib.request.urlopen(url, timeout=30) as page:
            assert b"<html" in page.read()
        proc.send_signal(sig)
        out, err = proc.communicate(timeout=30)
    finally:
        proc.kill()
    assert proc.returncode == 0 and "stopped" in out and "Traceback" not in err


def test_model_json_gives_bounds_flags_and_transparent_spheres(inputs, fit_json, tmp_path, capsys):
    import base64
    import re

    import cv2

    from gonio.report import Entry, fit_table

    session, _ = inputs
    out = tmp_path / "r.html"
    assert main(["report", str(session), "--model", str(fit_json), "-o", str(out)]) == 0
    assert "wrote" in capsys.readouterr().out
    text = out.read_text()
    assert "microfacet (fit.json)" in text and "<th>bounds</th>" in text and "<h2>Comparison</h2>" not in text
    uri = re.search(r'class="sphere" alt="microfacet[^"]*" src="data:image/png;base64,([^"]+)"', text).group(1)
    img = cv2.imdecode(np.frombuffer(base64.b64decode(uri), np.uint8), cv2.IMREAD_UNCHANGED)
    assert img.shape[2] == 4 and img[0, 0, 3] == 0 and img[img.shape[0] // 2, img.shape[1] // 2, 3] == 255
    # a value on its fitting bound is said so; one inside is not
    model = make("lambert", albedo=[0.0, 0.5, 0.5])
    rep = {"params": {"albedo": [0.0, 0.5, 0.5]}, "uncertainty": {"albedo": [0.01, 0.01, 0.01]}}
    assert "on a bound" in fit_table(Entry("x", None, fits={"lambert": (model, rep)}))
    rep["params"]["albedo"] = [0.2, 0.5, 0.5]
    assert "on a bound" not in fit_table(Entry("x", None, fits={"lambert": (model, rep)}))
