"""``gonio view``'s server defends itself: only requests addressed to this machine by name and port are
answered (DNS-rebinding defence), every query parameter of every endpoint is validated (400 with one
line naming it, never a default image), idle connections are closed within seconds and cannot lock the
user out, and a client that goes away leaves no traceback. Real sockets against a real server."""

from __future__ import annotations

import http.client
import socket
import struct
import threading
import time

import pytest

from gonio.report import load_entries
from gonio.viewer import endpoints, make_server
from tests.report.browser import serving


@pytest.fixture(scope="module")
def entries(inputs, fit_json):
    session, _ = inputs
    return load_entries([str(session)], [str(fit_json)])


@pytest.fixture(scope="module")
def server(entries):
    """The viewer of the small session with its fit, idle connections closed after 1 s, 8 at most."""
    srv = make_server(entries, idle_timeout=1.0, max_connections=8)
    with serving(srv) as url:
        yield srv, srv.server_address[1], url


def _get(port: int, path: str, host: str | None = "default", extra: list | None = None):
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=30)
    conn.putrequest("GET", path, skip_host=True, skip_accept_encoding=True)
    if host is not None:
        conn.putheader("Host", f"127.0.0.1:{port}" if host == "default" else host)
    for name, value in extra or []:
        conn.putheader(name, value)
    conn.endheaders()
    r = conn.getresponse()
    body = r.read()
    conn.close()
    return r.status, body, r


@pytest.mark.parametrize("host, status", [
    ("127.0.0.1:{p}", 200), ("localhost:{p}", 200), ("LocalHost:{p}", 200), ("[::1]:{p}", 200),
    ("evil.example:{p}", 421), ("evil.example", 421), ("127.0.0.1", 421), ("127.0.0.1:1", 421),
    ("localhost.:{p}", 421), ("127.0.0.1.nip.io:{p}", 421), ("0.0.0.0:{p}", 421), (None, 400)])
def test_only_requests_addressed_to_this_machine_are_answered(server, host, status):
    _srv, port, _url = server
    for path in ("/", "/sphere.png", "/slice.json"):
        code, body, r = _get(port, path, host.format(p=port) if host else None)
        assert code == status, (host, path, code, body[:200])
        if status != 200:
            assert body.decode().count("\n") == 1 and "Host" in body.decode()  # one line, saying why
            assert r.headers["Content-Security-Policy"]


def test_two_host_headers_are_refused(server):
    _srv, port, _url = server
    code, body, _ = _get(port, "/", extra=[("Host", "evil.example")])
    assert code == 400 and b"Host" in body


def _bad_values(p) -> list[str]:
    """Values of parameter ``p`` that must be refused: not numbers, not finite, out of range, not plain."""
    bad = ["abc", "nan", "NaN", "inf", "-inf", "1e999", "", "%201", "0x10", "1_0", "%EF%BC%91", "+", "1e", "--1",
           f"{p.lo - 1:g}"]
    if p.hi is not None:
        bad.append(f"{p.hi + 1:g}")
        bad.append(f"{p.hi + 1e-6}" if p.kind is float else f"{p.hi + 1}")
    if p.kind is int:
        bad += ["1.5", "0.0", "1e0"]
    return bad


def test_every_parameter_of_every_endpoint_is_validated(server, entries):
    _srv, port, _url = server
    n = 0
    for path, spec in endpoints(entries).items():
        for name, p in spec.items():
            for value in _bad_values(p):
                code, body, _ = _get(port, f"{path}?{name}={value}")
                text = body.decode()
                assert code == 400, (path, name, value, code)
                assert text.startswith(f"{name} = ") and text.count("\n") == 1, text  # one line naming it
                n += 1
    assert n > 60
    code, body, _ = _get(port, "/sphere.png?theta=abc")
    assert code == 400 and body == b"theta = 'abc': not a number in [0, 89]\n"


@pytest.mark.parametrize("query, says", [
    ("which=1", "which = 1: input 0 has 1 sphere(s) (0..0)"),  # one model, too few samples for a measured one
    ("entry=1", "entry = '1': out of range"),
    ("theta=1&theta=2", "theta is given twice"),
    ("colour=red", "unknown parameter 'colour'"),
    ("theta", "malformed query"),
    ("theta=%ff", "malformed query"),
    ("&".join(f"x{k}=1" for k in range(40)), "too many parameters"),
])
def test_malformed_queries_are_refused_with_one_line(server, query, says):
    _srv, port, _url = server
    code, body, _ = _get(port, f"/sphere.png?{query}")
    assert code == 400 and says in body.decode() and body.decode().count("\n") == 1, body


def test_valid_parameters_and_defaults_are_answered(server):
    _srv, port, _url = server
    code, body, r = _get(port, "/sphere.png?entry=0&which=0&theta=12.5&phi=359.5")
    assert code == 200 and body[:8] == b"\x89PNG\r\n\x1a\n" and r.headers["Content-Type"] == "image/png"
    assert _get(port, "/sphere.png")[0] == 200  # absent: the documented defaults
    code, body, _ = _get(port, "/slice.json?theta_i=0")
    assert code == 200 and body.startswith(b'{"data"')
    assert _get(port, "/?x=1")[0] == 400 and _get(port, "/no-such-page")[0] == 404


def _closed_by_server(sock: socket.socket, timeout: float) -> bool:
    sock.settimeout(timeout)
    try:
        return sock.recv(1) == b""
    except (ConnectionResetError, BrokenPipeError):
        return True
    except (TimeoutError, socket.timeout):
        return False


def test_idle_connections_are_closed_and_cannot_lock_the_user_out(server):
    srv, port, _url = server
    threads_before = threading.active_count()
    evicted_before = srv.evicted
    idle = [socket.create_connection(("127.0.0.1", port)) for _ in range(60)]
    slow = socket.create_connection(("127.0.0.1", port))
    slow.sendall(b"GET / HTTP/1.1\r\nHo")  # a request that never ends (slowloris)
    try:
        # the user's request is answered although 61 connections (> 8 allowed) sit idle
        code, body, _ = _get(port, "/sphere.png")
        assert code == 200 and body[:4] == b"\x89PNG"
        assert srv.evicted - evicted_before >= 60 - 8  # idle ones made room
        assert threading.active_count() <= threads_before + 8 + 2  # bounded, not one thread each
        start = time.monotonic()
        assert all(_closed_by_server(s, 10.0) for s in [*idle, slow])  # every idle one ends within seconds
        assert time.monotonic() - start < 10.0
    finally:
        for s in [*idle, slow]:
            s.close()


def test_a_client_that_goes_away_leaves_no_traceback(server, capfd):
    srv, port, _url = server
    for path in ("/", "/sphere.png?theta=10", "/slice.json"):
        for _ in range(3):
            s = socket.create_connection(("127.0.0.1", port))
            s.sendall(f"GET {path} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n\r\n".encode())
            s.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))  # reset, not a clean close
            s.close()
    time.sleep(0.5)
    assert _get(port, "/")[0] == 200  # still serving
    err = capfd.readouterr().err
    assert "Traceback" not in err and "Error" not in err, err


def test_when_every_connection_is_answering_a_new_one_gets_503_and_the_server_goes_on(entries):
    srv = make_server(entries, idle_timeout=2.0, max_connections=2)
    with serving(srv):
        port = srv.server_address[1]
        readers = []
        for _ in range(2):  # two clients that ask for the page and do not read it: both connections busy
            s = socket.socket()
            s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
            s.connect(("127.0.0.1", port))
            s.sendall(f"GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n\r\n".encode())
            readers.append(s)
        time.sleep(0.5)
        try:
            assert _get(port, "/favicon.ico")[0] == 503  # refused at once, not queued behind them
        finally:
            for s in readers:
                s.close()
        time.sleep(0.5)
        assert _get(port, "/favicon.ico")[0] == 204  # and the server still answers (it once deadlocked here)
