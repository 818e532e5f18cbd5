"""Strings from outside — a session directory's name, a fit file's name, a manifest's material, rig, plan,
exit status and notes — are shown as text wherever they land (HTML text, attributes, Plotly titles and
legends, JSON in the page, matplotlib titles, SVG), and no script they carry runs: checked in a real
headless browser (Debian's Chromium) with the pages' Content-Security-Policy enforced, and again with it
bypassed, so that escaping alone is shown to hold. A script would set ``window.__pwned`` or open a dialog."""

from __future__ import annotations

import html
import json
import re
import shutil
import urllib.request
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from gonio.cli.main import main
from gonio.page import json_data, script_hash
from tests.report.browser import FIGURES_DRAWN, opened, serving, wait_until

#: A session directory's name (no "/": a file name cannot hold one).
DIR_NAME = "<img src=x onerror=window.__pwned=1> \"'><svg onload=window.__pwned=2> <!-- é θ 😀 &amp;"
#: A fit file's name: its model label in the report is "microfacet (NAME)".
FIT_NAME = "'><img src=x onerror=window.__pwned=3>.json"
#: What a manifest or an API caller may carry, "/" included.
SCRIPTY = "</script><script>window.__pwned=4</script><!-- <b>bold</b> \u2028 ]]> -->"

PWNED = "window.__pwned === undefined"
NO_HANDLERS = ("!Array.from(document.querySelectorAll('*')).some(e => Array.from(e.attributes)"
               ".some(a => a.name.startsWith('on')))")
#: Every script element is the page's own: data blocks, Plotly, the figure script, the viewer's script.
SCRIPTS = "Array.from(document.querySelectorAll('script:not([type=\"application/json\"])')).length"


@pytest.fixture(scope="module")
def hostile(inputs, fit_json, tmp_path_factory):
    """A copy of the small session under :data:`DIR_NAME` with a hostile manifest, and the run's fit
    saved as :data:`FIT_NAME`."""
    session, _ = inputs
    d = tmp_path_factory.mktemp("hostile")
    s = shutil.copytree(session, d / DIR_NAME)
    m = json.loads((s / "manifest.json").read_text())
    m["material"]["label"] = "red <i>plastic</i> " + SCRIPTY
    m["material"]["notes"] = SCRIPTY
    m["rig"]["name"] = SCRIPTY
    m["plan"]["generator"] = DIR_NAME
    m["exit_status"] = SCRIPTY
    (s / "manifest.json").write_text(json.dumps(m))
    fit = d / FIT_NAME
    shutil.copy(fit_json, fit)
    return s, fit


@pytest.fixture(scope="module")
def hostile_report(hostile, tmp_path_factory):
    """``gonio report HOSTILE --model HOSTILE_FIT -o r.html``: the page."""
    session, fit = hostile
    out = tmp_path_factory.mktemp("hostile-report") / "r.html"
    assert main(["report", str(session), "--model", str(fit), "-o", str(out)]) == 0
    return out


def _no_script_ran(p):
    page = p.page
    assert page.evaluate(PWNED), "a hostile string ran as script"
    assert not p.dialogs
    assert page.evaluate(NO_HANDLERS), "an event-handler attribute came from a hostile string"
    assert page.evaluate("document.querySelectorAll('img:not([src^=\"data:\"]):not(.live)').length") == 0
    assert not p.errors, p.errors  # no script error, and nothing the policy had to refuse


@pytest.mark.parametrize("bypass_csp", [False, True], ids=["with-policy", "escaping-alone"])
def test_report_of_a_hostile_session_shows_names_as_text(browser, hostile_report, bypass_csp):
    with opened(browser, hostile_report.as_uri(), offline=True, bypass_csp=bypass_csp) as p:
        page = p.page
        wait_until(page, FIGURES_DRAWN)
        _no_script_ran(p)
        assert page.evaluate(SCRIPTS) == 2  # Plotly and the figure script
        assert page.inner_text("section.entry h2") == DIR_NAME
        assert DIR_NAME in page.inner_text("h1")
        summary = page.inner_text("table.summary")
        for value in ("red <i>plastic</i> " + SCRIPTY.replace("\u2028", ""), DIR_NAME):
            assert all(part in summary for part in value.split()), value
        titles = page.evaluate("Array.from(document.querySelectorAll('.gtitle')).map(t => t.textContent)")
        assert titles and all(t.startswith(DIR_NAME + ":") for t in titles), titles  # Plotly drew them as written
        legend = page.evaluate("Array.from(document.querySelectorAll('.legendtext')).map(t => t.textContent)")
        assert f"microfacet ({FIT_NAME})" in legend
        assert page.get_attribute("img.sphere", "alt").startswith(f"microfacet ({FIT_NAME})")


def test_viewer_shows_hostile_names_as_text_everywhere(browser, hostile, screenshots):
    from gonio.report import load_entries
    from gonio.viewer import make_server

    session, fit = hostile
    entries = load_entries([str(session)], [str(fit)])
    entries[0].name = SCRIPTY + DIR_NAME  # through the API an input may be named anything, "</script>" too
    server = make_server(entries, title="view " + SCRIPTY)
    with serving(server) as url:
        for bypass_csp in (False, True):
            with opened(browser, url + "/", bypass_csp=bypass_csp) as p:
                page = p.page
                wait_until(page, "document.getElementById('live-0-0').naturalWidth > 0 && "
                                 "document.querySelector('#live-slice-0 .gtitle') !== null")
                wait_until(page, FIGURES_DRAWN)
                _no_script_ran(p)
                assert page.evaluate(SCRIPTS) == 3  # Plotly, the figure script, the viewer's script
                name = SCRIPTY.replace("\u2028", " ") + DIR_NAME
                assert page.inner_text("section.live h2").replace("\u2028", " ") == "Interactive: " + name
                live_title = page.text_content("#live-slice-0 .gtitle")
                assert live_title.replace("\u2028", " ").startswith(name)
                assert page.inner_text("#live-0-0 + figcaption").startswith(f"microfacet ({FIT_NAME})")
                assert page.get_attribute("#live-0-0", "alt") == f"microfacet ({FIT_NAME})"
                assert page.title() == "view " + SCRIPTY
                if not bypass_csp:
                    page.screenshot(path=str(screenshots / "viewer-hostile.png"))


def test_the_policy_refuses_a_script_the_page_did_not_bring(browser, report, tmp_path):
    """Defence in depth: were an escape ever missed, the page's policy still refuses the script."""
    text = report.path.read_text()
    injected = tmp_path / "injected.html"
    injected.write_text(text.replace("</body>", "<script>window.__pwned=9</script>"
                                                "<img src=x onerror=\"window.__pwned=10\"></body>"))
    with opened(browser, injected.as_uri(), offline=True) as p:
        wait_until(p.page, FIGURES_DRAWN)  # the page's own scripts run
        assert p.page.evaluate(PWNED)
        assert any("Content Security Policy" in e for e in p.errors), p.errors
    # the policy names exactly the page's inline scripts, by hash, and allows nothing else to run
    policy = html.unescape(re.search(r'<meta http-equiv="Content-Security-Policy" content="([^"]+)"', text).group(1))
    script_src = re.search(r"script-src ([^;]+)", policy).group(1).split()
    inline = re.findall(r"<script>(.*?)</script>", text, flags=re.S)
    assert sorted(script_src) == sorted({script_hash(s) for s in inline}) and len(inline) == 2
    assert "unsafe" not in " ".join(script_src) and "default-src 'none'" in policy


def test_the_viewer_sends_its_policy_on_every_answer(hostile):
    from gonio.report import load_entries
    from gonio.viewer import make_server

    session, fit = hostile
    server = make_server(load_entries([str(session)], [str(fit)]))
    with serving(server) as url:
        for path in ("/", "/sphere.png", "/slice.json", "/sphere.png?theta=abc", "/nothing"):
            try:
                r = urllib.request.urlopen(url + path, timeout=30)
            except urllib.error.HTTPError as err:
                r = err
            policy = r.headers["Content-Security-Policy"]
            assert "frame-ancestors 'none'" in policy and "default-src 'none'" in policy, path
            assert re.search(r"script-src ('sha256-[A-Za-z0-9+/=]+' ?)+;", policy), policy
            assert r.headers["X-Content-Type-Options"] == "nosniff"


@pytest.mark.parametrize("value", [SCRIPTY, "</SCRIPT >", "<!--", "a\u2028b\u2029c", {"k</script>": ["<!--", 1.5]}])
def test_json_in_a_page_cannot_end_its_script_element(value):
    s = json_data(value)
    assert "<" not in s and ">" not in s and "\u2028" not in s and "\u2029" not in s
    assert json.loads(s) == value  # the same data for JSON.parse


# -- matplotlib: titles drawn as written, SVG escaped -----------------------------------------------------
def test_plot_titles_are_literal_and_an_svg_of_a_hostile_session_runs_nothing(browser, hostile, tmp_path):
    from gonio import load, plots

    session, _fit = hostile
    samples = load(session).samples
    fig = plots.inplane(samples=samples, title="costs $5 and $\\frac{$ " + SCRIPTY)
    plots.save(fig, tmp_path / "dollar.png")  # a "$" is a dollar sign: mathtext would fail to parse this
    assert fig.axes[0].get_title().startswith("costs $5 and $\\frac{$ ")
    for kind in ("inplane", "coverage"):  # the name as an axes title, and as the figure's title
        out = tmp_path / f"{kind}.svg"
        assert main(["plot", str(session), "--kind", kind, "-o", str(out)]) == 0
        root = ET.parse(out).getroot()  # well-formed XML: nothing broke out of its text or comment
        assert not [e for e in root.iter() if e.tag.endswith("script") or any(a.startswith("on") for a in e.attrib)]
        with opened(browser, out.as_uri(), offline=True) as p:
            assert p.page.evaluate(PWNED) and not p.dialogs and not p.errors


def test_api_plot_title_with_every_hostile_string_renders(tmp_path):
    from gonio import plots
    from gonio.samples import SampleSet
    from gonio.geometry import from_spherical

    t = np.radians(np.arange(5, 80, 5.0))
    wo = from_spherical(t, np.full_like(t, np.pi))
    wi = np.broadcast_to(from_spherical(np.radians(30.0), 0.0), wo.shape)
    s = SampleSet(wi, wo, np.full((len(t), 3), 0.1), np.full((len(t), 3), 0.01))
    for title in (SCRIPTY + DIR_NAME, "$\\undefinedmacro$ $$ 50% \\n ^_{}"):
        fig = plots.coverage(samples=s, title=title)
        path = plots.save(fig, tmp_path / "c.svg")
        ET.parse(path)
        assert fig.get_suptitle() == title



@pytest.mark.parametrize("source, refused", [
    ("a</script>b", True), ("x</SCRIPT y", True), ("</ScRiPt", True), ("<!-- c", True), ("if (a<!--b) {}", True),
    ("var s = '</scrİpt' + '</ſcript' + '</scr\u0131pt';", False), ("a < b && c > d; '</div>'", False),
    ("x = '<\\/script>'; y = '</scrip' + 't>';", False)])
def test_a_page_refuses_exactly_the_scripts_an_html_parser_would_end_or_change(source, refused):
    """Page.script refuses an inline script holding ``</script`` in any ASCII letter case (where an HTML parser
    ends the element) or ``<!--``: the same verdict as ``"</script" in source.lower() or "<!--" in source``
    (non-ASCII look-alikes İ, ſ, ı pass, as the parser does not end the element at them)."""
    from gonio.page import Page

    assert refused == ("</script" in source.lower() or "<!--" in source)
    if refused:
        with pytest.raises(ValueError, match="must not contain"):
            Page("t").script(source)
    else:
        assert Page("t").script(source).scripts == [source]
