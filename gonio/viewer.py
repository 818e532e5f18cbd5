"""``gonio view``: the report's content, interactive, served on 127.0.0.1.

The page is the report (:func:`gonio.report.build_report`) with one interactive panel per input:
sliders for the light's polar angle and azimuth re-render the lit spheres (measured and each model) on
the server (``/sphere.png``: :mod:`gonio.render` is fast enough at 128² pixels, and rendering there needs
no copy of the data in the browser), and a slider for the incidence angle re-draws the in-plane slice
(``/slice.json``: the Plotly figure as JSON). Nothing is ever written: the server only reads the inputs
it was started with.
"""

from __future__ import annotations

import html
import threading
import urllib.parse
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

from gonio.render import png_bytes
from gonio.report import Entry, build_report, slice_figure, sphere_images, sphere_sources

__all__ = ["make_server", "interactive_panel"]


def interactive_panel(k: int, entry: Entry) -> str:
    """Sliders and images of entry ``k``; the script fetches new renders as the sliders move."""
    labels = [html.escape(label) for label, _ in sphere_sources(entry)]
    imgs = "".join(f"<figure style='display:inline-block'><img id='live-{k}-{j}' class='live' width=192 height=192 "
                   f"alt='{lab}'><figcaption>{lab}</figcaption></figure>" for j, lab in enumerate(labels))
    return f"""
<section class='live' id='live-{k}'><h2>Interactive: {entry.name}</h2>
<label>light θ <input type=range id='theta-{k}' min=0 max=85 value=35 step=1></label> <span id='theta-{k}-v'>35</span>°
<label>light φ <input type=range id='phi-{k}' min=0 max=359 value=0 step=1></label> <span id='phi-{k}-v'>0</span>°
<div>{imgs}</div>
<label>incidence θi <input type=range id='ti-{k}' min=0 max=80 value=30 step=1></label> <span id='ti-{k}-v'>30</span>°
<div id='live-slice-{k}' style='width:700px;height:360px'></div>
<script>
(function() {{
  const k = {k}, n = {len(labels)};
  function spheres() {{
    const t = document.getElementById('theta-' + k).value, p = document.getElementById('phi-' + k).value;
    document.getElementById('theta-' + k + '-v').textContent = t;
    document.getElementById('phi-' + k + '-v').textContent = p;
    for (let j = 0; j < n; j++) {{
      document.getElementById('live-' + k + '-' + j).src = '/sphere.png?entry=' + k + '&which=' + j + '&theta=' + t + '&phi=' + p;
    }}
  }}
  function slice() {{
    const ti = document.getElementById('ti-' + k).value;
    document.getElementById('ti-' + k + '-v').textContent = ti;
    fetch('/slice.json?entry=' + k + '&theta_i=' + ti).then(r => r.json()).then(
      fig => Plotly.react('live-slice-' + k, fig.data, fig.layout));
  }}
  document.getElementById('theta-' + k).addEventListener('input', spheres);
  document.getElementById('phi-' + k).addEventListener('input', spheres);
  document.getElementById('ti-' + k).addEventListener('input', slice);
  spheres(); slice();
}})();
</script></section>"""


def _number(query: dict, key: str, lo: float, hi: float, default: float) -> float:
    try:
        v = float(query.get(key, [default])[0])
    except ValueError:
        return default
    return min(max(v, lo), hi) if v == v else default


def make_server(entries: list[Entry], *, port: int = 0, title: str = "gonio view") -> ThreadingHTTPServer:
    """An HTTP server on 127.0.0.1 (``port`` 0: a free one; ``server.server_address[1]`` says which)."""

    page = build_report(entries, title=title,
                        extra_html="".join(interactive_panel(k, e) for k, e in enumerate(entries))).encode("utf-8")
    lock = threading.Lock()

    class Handler(BaseHTTPRequestHandler):
        def log_message(self, *args):  # quiet: the terminal shows the URL, not every request
            pass

        def _send(self, code: int, body: bytes, kind: str) -> None:
            self.send_response(code)
            self.send_header("Content-Type", kind)
            self.send_header("Content-Length", str(len(body)))
            self.send_header("Cache-Control", "no-store")
            self.end_headers()
            self.wfile.write(body)

        def do_GET(self):  # noqa: N802 - http.server's name
            url = urllib.parse.urlparse(self.path)
            q = urllib.parse.parse_qs(url.query)
            if url.path in ("/", "/index.html"):
                return self._send(200, page, "text/html; charset=utf-8")
            if url.path == "/favicon.ico":
                return self._send(204, b"", "image/x-icon")
            k = int(_number(q, "entry", 0, len(entries) - 1, 0))
            e = entries[k]
            if url.path == "/sphere.png":
                sources = [brdf for _label, brdf in sphere_sources(e)]
                if not sources:
                    return self._send(404, b"no sphere", "text/plain")
                j = int(_number(q, "which", 0, len(sources) - 1, 0))
                with lock:  # numpy/cv2 are thread-safe here, but one render at a time keeps memory flat
                    try:
                        _rad, img, r = sphere_images(sources[j], _number(q, "theta", 0, 89, 35),
                                                     _number(q, "phi", 0, 360, 0), size=128)
                        mask = r.mask
                    except Exception:  # noqa: BLE001 - e.g. samples that do not tabulate: a black sphere
                        import numpy as np

                        img, mask = np.zeros((128, 128, 3), np.uint8), None
                return self._send(200, png_bytes(img, mask), "image/png")
            if url.path == "/slice.json":
                fig = slice_figure(e, _number(q, "theta_i", 0, 85, 30))
                return self._send(200, fig.to_json().encode("utf-8"), "application/json")
            return self._send(404, b"not found", "text/plain")

    return ThreadingHTTPServer(("127.0.0.1", port), Handler)
