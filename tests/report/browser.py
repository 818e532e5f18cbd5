"""Helpers of the browser tests: a page opened in its own context that records what a hostile page would
make happen (console errors, including Content-Security-Policy refusals; page errors; dialogs), and a wait
that works under the pages' policy (Playwright's ``wait_for_function`` evaluates a string, which a policy
without ``'unsafe-eval'`` refuses; ``evaluate`` goes through the DevTools protocol and is not refused)."""

from __future__ import annotations

import threading
import time
from contextlib import contextmanager
from types import SimpleNamespace


@contextmanager
def opened(browser, url, *, offline: bool = False, bypass_csp: bool = False, viewport=(1300, 1500)):
    """``with opened(browser, url) as p``: ``p.page``, ``p.errors`` (console errors and page errors),
    ``p.dialogs`` (messages of alert/confirm/prompt, dismissed). ``offline``: only ``file:`` and the
    page's own server answer; ``bypass_csp``: the page's policy is not enforced (to test escaping alone)."""
    ctx = browser.new_context(viewport={"width": viewport[0], "height": viewport[1]}, bypass_csp=bypass_csp)
    if offline:
        ctx.route("**/*", lambda route: route.continue_() if route.request.url.startswith(("file:", "http://127.0.0.1"))
                  else route.abort())
    page = ctx.new_page()
    p = SimpleNamespace(page=page, errors=[], dialogs=[])
    page.on("console", lambda m: p.errors.append(m.text) if m.type == "error" else None)
    page.on("pageerror", lambda e: p.errors.append(str(e)))
    page.on("dialog", lambda d: (p.dialogs.append(d.message), d.dismiss()))
    try:
        page.goto(url)
        page.wait_for_load_state("load")
        yield p
    finally:
        ctx.close()


def wait_until(page, expression: str, timeout: float = 30.0):
    """Poll ``page.evaluate(expression)`` until it is truthy (returned) or ``timeout`` seconds pass."""
    deadline = time.monotonic() + timeout
    while True:
        value = page.evaluate(expression)
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"not true within {timeout:g} s: {expression}")
        page.wait_for_timeout(50)


@contextmanager
def serving(server):
    """Run a :func:`gonio.viewer.make_server` server in a thread; yields its base URL, stops it after."""
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}"
    finally:
        server.shutdown()
        server.server_close()


FIGURES_DRAWN = ("Array.from(document.querySelectorAll('div.figure')).every(f => f.querySelector('.main-svg') !== null)"
                 " && document.querySelectorAll('div.figure').length > 0")
