"""The pty transport of the emulators, through a real pyserial client."""

import serial

from sim.faults import LinkFaults
from sim.pty import PtyServer


class Echo(PtyServer):
    def on_bytes(self, data):
        self.send(data.upper())


def _read(port, n):
    out = b""
    while len(out) < n:
        chunk = port.read(n - len(out))
        if not chunk:
            break
        out += chunk
    return out


def test_echo_over_real_pty_and_faults():
    with Echo("echo", LinkFaults(seed=3)) as dev:
        with serial.Serial(dev.path, 115200, timeout=0.5) as port:
            port.write(b"hello")
            assert _read(port, 5) == b"HELLO"
            dev.faults.inject_next("drop")
            port.write(b"lost")
            assert _read(port, 4) == b""
            dev.faults.inject_next("corrupt")
            port.write(b"abcd")
            got = _read(port, 4)
            assert len(got) == 4 and got != b"ABCD"
            assert sum(bin(a ^ b).count("1") for a, b in zip(got, b"ABCD")) == 1
            dev.faults.inject_next("delay")
            port.write(b"late")
            port.timeout = 0.05
            assert _read(port, 4) == b""
            port.timeout = 1.0
            assert _read(port, 4) == b"LATE"
        assert dev.faults.counts["drop"] == 1
        # the client closed its port: the server survives and a new client works
        with serial.Serial(dev.path, 115200, timeout=0.5) as port:
            port.write(b"again")
            assert _read(port, 5) == b"AGAIN"
