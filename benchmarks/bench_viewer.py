"""``gonio view``'s server under hostile load, against Python's stock ``ThreadingHTTPServer`` serving the
same page (what the viewer was before issue 32: no idle timeout, one thread per connection, no Host
check, no parameter check), both measured in this run:

* **idle connections**: N connections that send nothing — how many are still open after the
  observation window, threads the server holds while they are, and how long a normal request takes
  meanwhile (goal: all closed within a few seconds; threads bounded; the request answered);
* **fuzzed requests**: random query strings on every endpoint (bad numbers, NaN, inf, out of range,
  unknown, repeated, malformed, long) and random ``Host`` values — answers 200 to a bad parameter or
  a foreign Host (goal 0), 5xx (goal 0);
* **clients that go away**: connections reset while the page is being sent — tracebacks printed
  (goal 0), server still answering.

``python -m benchmarks viewer [--quick]``. The tests check each behaviour on a small scale
(tests/report/test_viewer_server.py).
"""

from __future__ import annotations

import contextlib
import http.client
import io
import random
import socket
import struct
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import numpy as np

from benchmarks.common import Table


def _entries():
    """A small input (an in-plane scan at two incidences) with a Lambert model: what the server shows."""
    from gonio.brdf import make
    from gonio.geometry import from_spherical
    from gonio.io.source import Measured
    from gonio.report import Entry
    from gonio.samples import SampleSet

    t = np.radians(np.linspace(-70, 70, 29))
    wo = np.concatenate([from_spherical(np.abs(t), np.where(t >= 0, np.pi, 0.0))] * 2)
    wi = np.concatenate([np.broadcast_to(from_spherical(np.radians(a), 0.0), (29, 3)) for a in (30.0, 50.0)])
    model = make("lambert", albedo=[0.5, 0.3, 0.2])
    f = model.eval(wi, wo)
    s = SampleSet(wi, wo, f, 0.01 * f + 1e-4)
    return [Entry("bench", Measured(Path("bench"), "session", {}, samples=s),
                  fits={"lambert": (model, {"params": {"albedo": [0.5, 0.3, 0.2]}})})]


def _stock_server(page: bytes) -> ThreadingHTTPServer:
    class Stock(BaseHTTPRequestHandler):
        def log_message(self, *args):
            pass

        def do_GET(self):  # noqa: N802
            self.send_response(200)
            self.send_header("Content-Length", str(len(page)))
            self.end_headers()
            self.wfile.write(page)

    class Server(ThreadingHTTPServer):
        request_queue_size = 64  # as gonio view's: the listen backlog is not what is compared

    srv = Server(("127.0.0.1", 0), Stock)
    srv.handle_error = lambda request, address: None  # the stock one prints a traceback; not measured here
    return srv


@contextlib.contextmanager
def _running(server):
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield server.server_address[1]
    finally:
        server.shutdown()
        server.server_close()


def _get(port: int, path: str, host: str | None = None):
    c = http.client.HTTPConnection("127.0.0.1", port, timeout=30)
    c.putrequest("GET", path, skip_host=True, skip_accept_encoding=True)
    c.putheader("Host", host if host is not None else f"127.0.0.1:{port}")
    c.endheaders()
    r = c.getresponse()
    body = r.read()
    c.close()
    return r.status, body


def _open_after(socks, window: float) -> int:
    """How many of ``socks`` the server has not closed by ``window`` seconds from now."""
    deadline = time.monotonic() + window
    open_ = set(range(len(socks)))
    while open_ and time.monotonic() < deadline:
        for i in list(open_):
            socks[i].settimeout(0.0)
            try:
                if socks[i].recv(1) == b"":
                    open_.discard(i)
            except (BlockingIOError, InterruptedError):
                pass
            except OSError:
                open_.discard(i)
        time.sleep(0.05)
    return len(open_)


def idle_flood(server, n: int, window: float) -> dict:
    with _running(server) as port:
        threads0 = threading.active_count()
        socks = [socket.create_connection(("127.0.0.1", port)) for _ in range(n)]
        time.sleep(0.3)
        threads = threading.active_count() - threads0
        t0 = time.perf_counter()
        status, _ = _get(port, "/")
        latency = time.perf_counter() - t0
        t0 = time.monotonic()
        still = _open_after(socks, window)
        closed_after = time.monotonic() - t0 if still == 0 else float("nan")
        for s in socks:
            s.close()
    return {"threads": threads, "status": status, "latency_ms": 1e3 * latency, "still_open": still,
            "closed_after_s": closed_after}


#: Values no parameter of any endpoint accepts (each a plain decimal out of every range, or not one).
BAD_VALUES = ("abc", "nan", "NaN", "inf", "-inf", "1e999", "", "%201", "0x10", "1_0", "%EF%BC%91", "+", "-1", "1e3",
              "361", "-0.5", "99999999999", "%ff", "1" * 300, "1e", "--1", "0x1p3", "Infinity")


def _fuzz_value(rng: random.Random) -> str:
    return rng.choice(BAD_VALUES)


def fuzz_requests(server, paths: dict, n: int, seed: int = 5) -> dict:
    rng = random.Random(seed)
    bad_ok = server_errors = foreign_ok = 0
    with _running(server) as port:
        for k in range(n):
            path = rng.choice(list(paths))
            names = list(paths[path]) or ["x"]
            q = "&".join(f"{rng.choice(names + ['bogus'])}={_fuzz_value(rng)}" for _ in range(rng.randint(1, 3)))
            if k % 5 == 0:  # a foreign Host, with a valid request
                host = rng.choice(["evil.example", f"evil.example:{port}", "127.0.0.1", f"localhost.:{port}",
                                   f"127.0.0.1:{port + 1}", "0.0.0.0", f"[::2]:{port}"])
                status, _ = _get(port, path, host)
                foreign_ok += status == 200
                continue
            status, _ = _get(port, f"{path}?{q}")
            bad_ok += status == 200
            server_errors += status >= 500
    return {"requests": n, "bad_ok": bad_ok, "server_errors": server_errors, "foreign_ok": foreign_ok}


def resets(server, n: int) -> dict:
    err = io.StringIO()
    with contextlib.redirect_stderr(err), _running(server) as port:
        for k in range(n):
            s = socket.create_connection(("127.0.0.1", port))
            s.sendall(f"GET {'/' if k % 2 else '/sphere.png'} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n\r\n".encode())
            s.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
            s.close()
        time.sleep(0.5)
        alive = _get(port, "/")[0] == 200
    return {"resets": n, "tracebacks": err.getvalue().count("Traceback"), "alive": alive}


def run(quick: bool = False) -> list[Table]:
    from gonio.viewer import IDLE_TIMEOUT_S, MAX_CONNECTIONS, endpoints, make_server

    entries = _entries()
    n_idle, window = (100, IDLE_TIMEOUT_S + 3.0) if quick else (300, 20.0)
    gonio_srv = make_server(entries)
    page = _get_page(gonio_srv)
    t = Table(f"{n_idle} idle connections (send nothing): still open after {window:g} s, server threads, a normal "
              "request meanwhile", ["server", "still open", "closed within s", "threads held", "request status",
                                    "request ms"], baseline=0, default=1)
    for name, srv in (("stock ThreadingHTTPServer", _stock_server(page)), ("gonio view", make_server(entries))):
        r = idle_flood(srv, n_idle, window)
        t.add(name, r["still_open"], r["closed_after_s"], r["threads"], r["status"], r["latency_ms"])
    t.notes.append(f"Goal: 0 still open (idle timeout {IDLE_TIMEOUT_S:g} s); threads ≤ {MAX_CONNECTIONS} (the "
                   "longest-idle connection is closed to make room); the request answered 200.")
    tables = [t]
    f = fuzz_requests(make_server(entries), endpoints(entries), 300 if quick else 2000)
    t = Table("Fuzzed requests (bad parameters on every endpoint; foreign Host headers)",
              ["requests", "bad parameter answered 200", "5xx", "foreign Host answered 200", "goal"])
    t.add(f["requests"], f["bad_ok"], f["server_errors"], f["foreign_ok"], "0 / 0 / 0")
    tables.append(t)
    r = resets(make_server(entries), 20 if quick else 100)
    t = Table("Clients that reset the connection while the answer is sent", ["resets", "tracebacks", "still serving",
                                                                             "goal"])
    t.add(r["resets"], r["tracebacks"], "yes" if r["alive"] else "NO", "0, yes")
    tables.append(t)
    return tables


def _get_page(server) -> bytes:
    with _running(server) as port:
        return _get(port, "/")[1]
