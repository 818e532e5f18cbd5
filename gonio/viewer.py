"""``gonio view``: the report, interactive, served on 127.0.0.1.

The page starts with one interactive panel per input — sliders for the light's polar angle and azimuth
re-render the lit spheres (measured and each model) on the server (``/sphere.png``: :mod:`gonio.render`
at :data:`gonio.report.SPHERE_SIZE` pixels; rendering there needs no copy of the data in the browser), and
a slider for the incidence angle re-draws the in-plane slice (``/slice.json``: the Plotly figure as JSON)
— and the whole report follows below. Nothing is ever written: the server only reads the inputs it was
started with.

The server is for the user's own browser only, and it defends itself as such:

- **Host check** (DNS rebinding, https://en.wikipedia.org/wiki/DNS_rebinding): a request whose ``Host``
  is not ``127.0.0.1``, ``localhost`` or ``[::1]`` with the server's port is answered 421 (no ``Host``:
  400), so a page of another site whose name was re-pointed at 127.0.0.1 reads nothing;
- **Content-Security-Policy** (:mod:`gonio.page`): only the page's own scripts run (by hash); nothing is
  loaded from another origin; no other site may frame it;
- **bounded connections**: an idle connection (no complete request) is closed after
  :data:`IDLE_TIMEOUT_S`; at most :data:`MAX_CONNECTIONS` are open, and a new one beyond that closes the
  connection idle the longest, so idle connections cannot lock the user out;
- **parameters validated** (:mod:`gonio.viewer_params`): a value that is not a finite number in range,
  an unknown or repeated parameter is answered 400 with one line naming it — never a default image;
- a client that goes away (reset, broken pipe, timeout) ends its connection quietly; any other error is
  one line on stderr and a 500, never a traceback.
"""

from __future__ import annotations

import socket
import sys
import threading
import time
import urllib.parse
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

from gonio.page import json_data, text
from gonio.render import png_bytes
from gonio.report import SPHERE_SIZE, Entry, report_page, slice_figure, sphere_images, sphere_sources
from gonio.report_figures import model_styles
from gonio.viewer_params import BadRequest, Param, parse_query

__all__ = ["make_server", "interactive_panel", "ViewerServer", "IDLE_TIMEOUT_S", "MAX_CONNECTIONS"]

#: Seconds a connection may stay without sending a whole request (or without reading the answer).
IDLE_TIMEOUT_S = 5.0
#: Connections open at once; beyond, the one idle the longest is closed (a browser opens about six).
MAX_CONNECTIONS = 32

#: The viewer's one script (fixed code: its hash is in the page's policy). Each ``section.live`` names its
#: entry and sphere count; a slider asks the server for new renders; a sphere still loading is not asked
#: again until it arrives (the last position wins), so a dragged slider does not queue renders.
VIEWER_JS = r"""
document.querySelectorAll('section.live').forEach(function (sec) {
  var k = sec.dataset.entry, n = +sec.dataset.spheres;
  function el(name) { return document.getElementById(name + '-' + k); }
  function shown(name) { return document.getElementById(name + '-' + k + '-v'); }
  function show(img, url) {
    if (img.dataset.busy === '1') { img.dataset.next = url; return; }
    img.dataset.busy = '1'; img.dataset.next = ''; img.src = url;
  }
  function done(ev) {
    var img = ev.target, next = img.dataset.next;
    img.dataset.busy = '0';
    var cap = document.getElementById(img.id + '-error');
    if (ev.type === 'error') {
      fetch(img.src).then(function (r) { return r.text(); }).then(function (t) { cap.textContent = t; });
    } else { cap.textContent = ''; }
    if (next) { show(img, next); }
  }
  function spheres() {
    var t = el('theta').value, p = el('phi').value;
    shown('theta').textContent = t; shown('phi').textContent = p;
    for (var j = 0; j < n; j++) {
      show(document.getElementById('live-' + k + '-' + j),
           '/sphere.png?entry=' + k + '&which=' + j + '&theta=' + t + '&phi=' + p);
    }
  }
  function slice() {
    var ti = el('ti').value;
    shown('ti').textContent = ti;
    fetch('/slice.json?entry=' + k + '&theta_i=' + ti).then(function (r) {
      if (!r.ok) { return r.text().then(function (t) { throw new Error(t); }); }
      return r.json();
    }).then(function (fig) {
      el('live-slice-error').textContent = '';
      Plotly.react('live-slice-' + k, fig.data, fig.layout);
    }).catch(function (e) { el('live-slice-error').textContent = String(e.message || e); });
  }
  for (var j = 0; j < n; j++) {
    var img = document.getElementById('live-' + k + '-' + j);
    img.addEventListener('load', done); img.addEventListener('error', done);
  }
  el('theta').addEventListener('input', spheres);
  el('phi').addEventListener('input', spheres);
  el('ti').addEventListener('input', slice);
  spheres(); slice();
});
"""


def _slider(k: int, name: str, label: str, lo: int, hi: int, value: int) -> str:
    return (f"<label class='slider'>{label} <input type=range id='{name}-{k}' min={lo} max={hi} value={value} "
            f"step=1> <span id='{name}-{k}-v'>{value}</span>°</label>")


def interactive_panel(k: int, entry: Entry) -> str:
    """Sliders and live images of entry ``k`` (markup only: :data:`VIEWER_JS` drives every panel)."""
    labels = [text(label) for label, _ in sphere_sources(entry)]
    imgs = "".join(f"<figure><img id='live-{k}-{j}' class='live' width={SPHERE_SIZE} height={SPHERE_SIZE} alt='{lab}'>"
                   f"<figcaption>{lab} <span class='live-error' id='live-{k}-{j}-error'></span></figcaption></figure>"
                   for j, lab in enumerate(labels))
    none = "" if labels else "<p>No sphere to render: no model and too few samples.</p>"
    return (f"<section class='live' id='live-{k}' data-entry='{k}' data-spheres='{len(labels)}'>"
            f"<h2>Interactive: {text(entry.name)}</h2>"
            f"<div>{_slider(k, 'theta', 'light θ', 0, 85, 35)}{_slider(k, 'phi', 'light φ', 0, 359, 0)}</div>"
            f"<div>{imgs}{none}</div><div>{_slider(k, 'ti', 'incidence θi', 0, 80, 30)}"
            f"<span class='live-error' id='live-slice-error-{k}'></span></div>"
            f"<div class='live-slice' id='live-slice-{k}'></div></section>")


def endpoints(entries: list[Entry]) -> dict[str, dict[str, Param]]:
    """Every endpoint's parameters: name → :class:`Param` (type, range, default)."""
    last = max(len(entries) - 1, 0)
    return {"/": {}, "/index.html": {}, "/favicon.ico": {},
            "/sphere.png": {"entry": Param(int, 0, last, 0), "which": Param(int, 0, None, 0),
                            "theta": Param(float, 0.0, 89.0, 35.0), "phi": Param(float, 0.0, 360.0, 0.0)},
            "/slice.json": {"entry": Param(int, 0, last, 0), "theta_i": Param(float, 0.0, 85.0, 30.0)}}


def allowed_hosts(port: int) -> set[str]:
    """The ``Host`` values of a request to this server from the user's browser (lower case)."""
    names = ("127.0.0.1", "localhost", "[::1]")
    return {f"{n}:{port}" for n in names} | (set(names) if port == 80 else set())


class ViewerServer(ThreadingHTTPServer):
    """A threading HTTP server that bounds its connections (module docstring): ``evicted`` counts idle
    connections closed to make room."""

    daemon_threads = True
    request_queue_size = 64

    def __init__(self, address, handler, *, max_connections: int = MAX_CONNECTIONS):
        self.max_connections = max_connections
        self.evicted = 0
        self._open: dict[socket.socket, list] = {}  # socket -> [opened at (monotonic s), busy answering]
        self._open_lock = threading.Lock()
        super().__init__(address, handler)

    def process_request(self, request, client_address):
        with self._open_lock:
            idle = [(t, s) for s, (t, busy) in self._open.items() if not busy]
            if len(self._open) >= self.max_connections and idle:
                victim = min(idle, key=lambda ts: ts[0])[1]
                del self._open[victim]
                self.evicted += 1
                try:
                    victim.shutdown(socket.SHUT_RDWR)  # its thread's read returns at once; it closes it
                except OSError:
                    pass
            full = len(self._open) >= self.max_connections
            if not full:
                self._open[request] = [time.monotonic(), False]
        if full:  # every one is answering: come back later (outside the lock: shutdown_request takes it)
            try:
                request.settimeout(1.0)
                request.sendall(b"HTTP/1.0 503 Service Unavailable\r\nContent-Length: 0\r\nRetry-After: 1\r\n\r\n")
            except OSError:
                pass
            self.shutdown_request(request)
            return
        super().process_request(request, client_address)

    def mark_busy(self, request) -> None:
        with self._open_lock:
            if request in self._open:
                self._open[request][1] = True

    def shutdown_request(self, request):
        with self._open_lock:
            self._open.pop(request, None)
        super().shutdown_request(request)

    def handle_error(self, request, client_address):
        exc = sys.exc_info()[1]
        if isinstance(exc, (ConnectionError, TimeoutError)):  # the client went away or stalled: nothing to say
            return
        print(f"gonio view: error answering {client_address[0]}: {type(exc).__name__}: {exc}", file=sys.stderr)


def make_server(entries: list[Entry], *, port: int = 0, title: str = "gonio view",
                max_connections: int = MAX_CONNECTIONS, idle_timeout: float = IDLE_TIMEOUT_S) -> ViewerServer:
    """An HTTP server on 127.0.0.1 (``port`` 0: a free one; ``server.server_address[1]`` says which)."""
    styles = model_styles(entries)
    page = report_page(entries, title=title, same_origin=True,
                       lead_html="".join(interactive_panel(k, e) for k, e in enumerate(entries))).script(VIEWER_JS)
    body, policy = page.render().encode("utf-8"), page.csp(header=True)
    params = endpoints(entries)
    lock = threading.Lock()

    class Handler(BaseHTTPRequestHandler):
        timeout = idle_timeout  # socket timeout: an idle or stalled connection ends (handle_one_request)
        server_version = "gonio-view"

        def log_message(self, *args):  # quiet: the terminal shows the URL, not every request
            pass

        def parse_request(self):
            ok = super().parse_request()
            self.server.mark_busy(self.request)
            return ok

        def _send(self, code: int, body: bytes, kind: str = "text/plain; charset=utf-8") -> None:
            self.send_response(code)
            for name, value in (("Content-Type", kind), ("Content-Length", str(len(body))),
                                ("Cache-Control", "no-store"), ("Content-Security-Policy", policy),
                                ("X-Content-Type-Options", "nosniff"), ("X-Frame-Options", "DENY"),
                                ("Referrer-Policy", "no-referrer"), ("Cross-Origin-Resource-Policy", "same-origin")):
                self.send_header(name, value)
            self.end_headers()
            self.wfile.write(body)

        def _refuse(self, code: int, reason: str) -> None:
            self._send(code, (reason + "\n").encode("utf-8"))

        def do_GET(self):  # noqa: N802 - http.server's name
            hosts = self.headers.get_all("Host") or []
            if len(hosts) != 1:
                return self._refuse(400, "one Host header is required")
            if hosts[0].strip().lower() not in allowed_hosts(self.server.server_address[1]):
                return self._refuse(421, f"Host {hosts[0][:100]!r} is not this server (it answers "
                                         f"127.0.0.1:{self.server.server_address[1]} only)")
            url = urllib.parse.urlsplit(self.path)
            if url.path not in params:
                return self._refuse(404, f"no such page: {url.path[:100]}")
            try:
                q = parse_query(url.query, params[url.path])
                return self._answer(url.path, q)
            except BadRequest as exc:
                return self._refuse(400, str(exc))
            except (ConnectionError, TimeoutError):
                raise
            except Exception as exc:  # noqa: BLE001 - one line, never a traceback, and the server goes on
                msg = f"{url.path}: {type(exc).__name__}: {exc}".splitlines()[0][:300]
                print(f"gonio view: error answering {msg}", file=sys.stderr)
                return self._refuse(500, msg)

        def _answer(self, path: str, q: dict) -> None:
            if path in ("/", "/index.html"):
                return self._send(200, body, "text/html; charset=utf-8")
            if path == "/favicon.ico":
                return self._send(204, b"", "image/x-icon")
            e = entries[q["entry"]]
            if path == "/sphere.png":
                sources = sphere_sources(e)
                if q["which"] >= len(sources):
                    raise BadRequest(f"which = {q['which']}: input {q['entry']} has {len(sources)} sphere(s)"
                                     + (f" (0..{len(sources) - 1})" if sources else ""))
                with lock:  # one render at a time keeps memory flat
                    try:
                        _rad, img, r = sphere_images(sources[q["which"]][1], q["theta"], q["phi"], size=SPHERE_SIZE)
                    except Exception as exc:  # noqa: BLE001 - e.g. samples that do not tabulate: said, not black
                        return self._refuse(422, f"cannot render {sources[q['which']][0]}: {exc}".splitlines()[0][:300])
                return self._send(200, png_bytes(img, r.mask), "image/png")
            fig = slice_figure(e, q["theta_i"], styles=styles)
            return self._send(200, json_data(fig).encode("utf-8"), "application/json")

    return ViewerServer(("127.0.0.1", port), Handler, max_connections=max_connections)
