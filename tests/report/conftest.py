"""Fixtures shared by the report and viewer tests, once per test run (per xdist worker): one headless
Chromium, one simulated session and MERL table, one fit of the session (``gonio fit --json``) and one
``gonio report`` of both inputs. Screenshots go to ``screenshots/`` in the run's temp directory."""

from __future__ import annotations

import contextlib
import hashlib
import io
import shutil
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from gonio.brdf import make
from gonio.cli.main import main
from gonio.io.merl import MerlTable, cell_directions, write_merl
from tests.debian import require

ARGS = ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run", "--disable-background-networking",
        "--disable-component-update", "--disable-sync",
        # V8 records source positions as it compiles, instead of parsing a function again when they are first asked
        # for: under Playwright's DevTools session they are (a plain headless Chromium does not ask), and parsing
        # Plotly's 4.8 MB script again cost ~0.3 CPU s of every page's renderer. --max-opt=1: no tier above
        # Sparkplug (V8's baseline compiler); optimising Plotly's functions with Maglev and Turbofan in the background
        # cost a page more (~0.08 CPU s) than it saved in pages that live a second or two
        "--js-flags=--no-enable-lazy-source-positions --max-opt=1"]
#: Features off beside Playwright's own (PLAYWRIGHT_DISABLED; a second --disable-features replaces the first): every
#: browser context is a window whose omnibox popup is a WebUI page preloaded in a renderer of its own (~0.4 CPU s each)
NOT_NEEDED = ["WebUIOmniboxPopup", "WebUIOmniboxAimPopup"]
#: Playwright's --disable-features (1.65); :func:`browser` checks the running browser's command line and adds any
#: it is missing
PLAYWRIGHT_DISABLED = ["AvoidUnnecessaryBeforeUnloadCheckSync", "DestroyProfileOnBrowserClose", "HttpsUpgrades",
                       "HttpsFirstBalancedModeAutoEnable", "LensOverlay", "MediaRouter", "PaintHolding",
                       "ThirdPartyStoragePartitioning", "AvoidCorsURLLoaderRestartOnRedirect", "TcpPortRandomizationWin",
                       "OptimizationHints", "NetworkTimeServiceQuerying", "AimEnabled", "PreconnectToSearch",
                       "msForceBrowserSignIn", "msEdgeUpdateLaunchServicesPreferredVersion"]


def _digest(d: Path) -> dict:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(d.iterdir())}


@pytest.fixture(scope="session")
def digest():
    """``digest(DIR)``: SHA-256 of every file of a directory, to show that nothing was written."""
    return _digest


@pytest.fixture(scope="session")
def cells():
    """The MERL grid's cell directions (wi, wo, above): 1.5 M directions, computed once."""
    return cell_directions()


@pytest.fixture(scope="session")
def inputs(tmp_path_factory, cells, copy_small_session):
    d = tmp_path_factory.mktemp("report")
    session = copy_small_session(d / "session")  # the small in-plane session (tests/conftest.py)
    wi, wo, _ = cells
    v = make("microfacet", kd=0.2, ks=0.6, alpha=0.2, f0=0.9).eval(wi, wo)
    v[(wi[..., 2] <= 0) | (wo[..., 2] <= 0)] = np.nan
    write_merl(d / "table.binary", MerlTable(v))
    return session, d / "table.binary"


@pytest.fixture(scope="session")
def fit_json(inputs, tmp_path_factory):
    """``gonio fit SESSION --model microfacet --json``: the model the viewer tests show."""
    session, _ = inputs
    out = tmp_path_factory.mktemp("fit") / "fit.json"
    assert main(["fit", str(session), "--model", "microfacet", "--json", str(out), "--quiet"]) == 0
    return out


@pytest.fixture(scope="session")
def report(inputs, tmp_path_factory):
    """``gonio report SESSION TABLE -o report.html`` (models fitted on the fly): the page, what the
    command printed, and the session directory's digest before and after (the report only reads)."""
    session, table = inputs
    out = tmp_path_factory.mktemp("html") / "report.html"
    before = _digest(session)
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        rc = main(["report", str(session), str(table), "-o", str(out)])
    assert rc == 0
    return SimpleNamespace(path=out, stdout=buf.getvalue(), before=before, after=_digest(session))


def _launch(p, disabled: list[str]):
    return p.chromium.launch(executable_path=shutil.which("chromium"), args=[*ARGS, "--disable-features=" + ",".join(disabled)])


def _disabled_features(b) -> list[list[str]]:
    """The ``--disable-features`` lists of the running browser's command line, in order (Playwright's first)."""
    cdp = b.new_browser_cdp_session()
    line = cdp.send("SystemInfo.getInfo")["commandLine"]
    cdp.detach()
    return [a.split("=", 1)[1].split(",") for a in line.split() if a.startswith("--disable-features=")]


@pytest.fixture(scope="session")
def browser():
    """One headless Debian Chromium for every browser test of the run (Playwright drives it)."""
    require("the HTML report in a real browser", "chromium", python=("playwright", "gonio[test]"))
    from playwright import sync_api

    with sync_api.sync_playwright() as p:
        b = _launch(p, PLAYWRIGHT_DISABLED + NOT_NEEDED)
        missing = [f for f in _disabled_features(b)[0] if f not in PLAYWRIGHT_DISABLED]
        if missing:  # another Playwright, which disables more: its features and ours
            b.close()
            b = _launch(p, PLAYWRIGHT_DISABLED + missing + NOT_NEEDED)
        yield b
        b.close()


@pytest.fixture(scope="session")
def screenshots(tmp_path_factory):
    """Where the browser tests leave their screenshots (kept as artifacts of the run)."""
    d = tmp_path_factory.getbasetemp() / "screenshots"
    d.mkdir(exist_ok=True)
    return d
