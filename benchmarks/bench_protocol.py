"""Rig-controller protocol: decoder throughput (Python, C), round-trip latency over a pty, retry cost.

``python -m benchmarks protocol [--quick]``. Ratios are against a baseline measured in the same run.
"""

from __future__ import annotations

import shutil
import statistics
import subprocess
from gonio import childproc  # children die with this process
import tempfile
import time
from pathlib import Path

import serial

from benchmarks.common import Table, time_call
from firmware_protocol import C_DIR
from firmware_protocol import codec as fp


def _frames(n: int) -> bytes:
    """n encoded replies of mixed types and sizes (as a controller would send)."""
    msgs = [fp.encode_message("HEARTBEAT_REPLY", 1), fp.encode_message("SET_LIGHT_REPLY", 2, on=1, level=40000),
            fp.encode_message("STATUS_REPLY", 3, flags=4, level=65535, temperature=2600, uptime_ms=12345678,
                              watchdog_ms=10000, reset_cause=1),
            fp.encode_message("READ_PHOTODIODE_REPLY", 4, samples=16, mean=987654, sem=321, time_ms=123457, span_us=1560),
            fp.encode_message("TRIGGER_REPLY", 5, exposure_us=20000, count=77)]
    return b"".join(msgs[i % len(msgs)] for i in range(n))


def _c_frames_per_s(n: int) -> tuple[float, float] | None:
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        return None
    with tempfile.TemporaryDirectory() as tmp:
        exe = Path(tmp) / "fp_test"
        childproc.run([cc, "-std=c99", "-O2", "-o", str(exe), str(C_DIR / "fp_codec.c"), str(C_DIR / "fp_test.c")],
                       check=True, capture_output=True, timeout=120)
        out = childproc.run([str(exe), "bench", str(n)], check=True, capture_output=True, text=True, timeout=120)
    kv = dict(x.split("=") for x in out.stdout.split())
    secs = float(kv["seconds"])
    return int(kv["frames"]) / secs, int(kv["bytes"]) / secs


def decoder_table(quick: bool) -> Table:
    n = 2000 if quick else 20000
    data = _frames(n)
    t = Table("Frame decoder throughput", ["decoder", "frames/s", "MB/s", "× baseline"], baseline=0, default=1,
              why_default="the host client feeds whatever `in_waiting` holds: one reply per read, ~10-20 bytes")

    def whole():
        assert len(fp.Decoder().feed(data)) == n

    chunks = data.split(b"\x00\x00")
    per_frame = [chunks[0] + b"\x00"] + [b"\x00" + c + b"\x00" for c in chunks[1:-1]] + [b"\x00" + chunks[-1]]

    def frame_chunks():
        d = fp.Decoder()
        k = 0
        for c in per_frame:
            k += len(d.feed(c))
        assert k == n

    small = data[: len(data) // 10]
    m = len(fp.Decoder().feed(small))

    def bytewise():
        d = fp.Decoder()
        for i in range(len(small)):
            d.feed(small[i:i + 1])

    base = time_call(whole, min_time=0.1 if quick else 0.3)
    rows = [("Python, one chunk", n / base, len(data) / base)]
    s = time_call(frame_chunks, min_time=0.1 if quick else 0.3)
    rows.append(("Python, one frame per feed", n / s, len(data) / s))
    s = time_call(bytewise, min_time=0.1 if quick else 0.3)
    rows.append(("Python, one byte per feed", m / s, len(small) / s))
    c = _c_frames_per_s(200_000 if quick else 2_000_000)
    if c is not None:
        rows.append(("C99 codec, byte-at-a-time (firmware style)", c[0], c[1]))
    for name, fps, bps in rows:
        t.add(name, fps, bps / 1e6, fps / rows[0][1])
    if c is None:
        t.notes.append("no C compiler: C row missing")
    return t


def _percentile(xs: list[float], q: float) -> float:
    xs = sorted(xs)
    return xs[min(len(xs) - 1, int(round(q * (len(xs) - 1))))]


def latency_table(quick: bool) -> Table:
    from gonio.rig.controller import RigController
    from sim.clock import SimClock
    from sim.controller import ControllerEmulator
    from sim.pty import PtyServer

    class Echo(PtyServer):
        def on_bytes(self, data):
            self.send(data)

    n = 100 if quick else 1000
    t = Table("Round trip over a pty (host client ↔ emulator)", ["call", "median µs", "p95 µs", "× baseline"],
              baseline=0, default=1, why_default="heartbeat is the cheapest full protocol transaction")
    frame = fp.encode_message("HEARTBEAT", 1)
    with Echo("echo") as echo, serial.Serial(echo.path, timeout=0.5) as port:
        lat = []
        for _ in range(n):
            t0 = time.perf_counter()
            port.write(frame)
            got = b""
            while len(got) < len(frame):
                chunk = port.read(len(frame) - len(got))
                if not chunk:
                    break
                got += chunk
            lat.append(time.perf_counter() - t0)
    rows = [("raw pty echo of an 8-byte frame", lat)]
    clock = SimClock()
    with ControllerEmulator(clock) as emu, RigController.open(emu.path, clock=clock) as ctl:
        ctl.set_light(True, 1.0)
        for name, call in (("heartbeat()", ctl.heartbeat), ("status()", ctl.status),
                           ("read_photodiode(16)", lambda: ctl.read_photodiode(16)),
                           ("trigger_camera(1 ms)", lambda: ctl.trigger_camera(1e-3))):
            lat = []
            for _ in range(n):
                t0 = time.perf_counter()
                call()
                lat.append(time.perf_counter() - t0)
            rows.append((name, lat))
    base = statistics.median(rows[0][1])
    for name, lat in rows:
        med = statistics.median(lat)
        t.add(name, med * 1e6, _percentile(lat, 0.95) * 1e6, med / base)
    return t


def retry_table(quick: bool) -> Table:
    from gonio.rig.controller import RigController
    from sim.clock import SimClock
    from sim.controller import ControllerEmulator
    from sim.faults import LinkFaults

    n = 60 if quick else 400
    t = Table(f"Retry cost under injected reply faults ({n} TRIGGER commands, 5 % of replies faulted)",
              ["fault", "timeout s", "ms/command", "retries/command", "executed once", "× baseline"],
              baseline=0, default=1, why_default="gonio's default timeout 0.25 s with 3 retries")
    cases = [("none", {}, 0.25), ("drop", {"drop_rate": 0.05}, 0.25), ("drop", {"drop_rate": 0.05}, 0.1),
             ("corrupt", {"corrupt_rate": 0.05}, 0.25), ("truncate", {"truncate_rate": 0.05}, 0.25),
             ("garbage", {"garbage_rate": 0.05}, 0.25), ("delay 0.3 s", {"delay_rate": 0.05, "delay_s": 0.3}, 0.25)]
    base = None
    for name, rates, timeout in cases:
        clock = SimClock()
        with ControllerEmulator(clock, faults=LinkFaults(seed=5, **rates)) as emu, \
                RigController.open(emu.path, clock=clock, timeout=timeout) as ctl:
            t0 = time.perf_counter()
            for _ in range(n):
                ctl.trigger_camera(1e-3)
            dt = (time.perf_counter() - t0) / n
            once = emu.executed["TRIGGER"] == n
            retries = ctl.retry_count / n
        base = base or dt
        t.add(name, timeout, dt * 1e3, retries, "yes" if once else "NO", dt / base)
    t.notes.append("drop, delay and truncate cost one reply timeout (a cut reply lacks its closing delimiter, so "
                   "nothing is rejected before the deadline); corrupt costs the 20 ms corrupt grace; garbage "
                   "before a reply costs nothing (the leading 00 delimiter isolates it)")
    return t


def firmware_table(quick: bool) -> list[Table]:
    """The reference firmware: AVR flash/RAM use, and one command's round trip through each
    controller implementation (Python emulator, firmware host build, AVR build in simavr)."""
    from gonio.rig.controller import RigController
    from sim.clock import SimClock
    from sim.controller import ControllerEmulator
    from sim.firmware import FirmwareController
    from sim.simavr import SimavrController, avr_size

    flash, ram = avr_size()
    size = Table("Reference firmware, ATmega328P build (make avr)", ["memory", "bytes", "limit", "% of limit"], baseline=None,
                 notes=["limits: 32 KiB flash less a 512-byte boot loader; 2 KiB RAM less 512 bytes kept for "
                        "the stack (static RAM = .data + .bss)"])
    size.add("flash (.text + .data)", flash, 32 * 1024 - 512, 100.0 * flash / (32 * 1024 - 512))
    size.add("static RAM (.data + .bss)", ram, 1536, 100.0 * ram / 1536)
    n = 20 if quick else 200
    t = Table("status() round trip by controller implementation", ["controller", "median ms", "p95 ms", "× baseline"],
              baseline=0, default=1, why_default="gonio measure --sim runs the firmware's host build",
              notes=["simavr: emulated 16 MHz ATmega328P, 115200 baud at the wire's pace, in lockstep with a "
                     "SimClock (sim/simavr.py: the pty relayed to the bridge over its stdin)"])
    rows = []
    for name, make in (("Python emulator (sim.controller)", lambda c: ControllerEmulator(c)),
                       ("firmware, host build (sim.firmware)", lambda c: FirmwareController(c)),
                       ("firmware, AVR build in simavr (sim.simavr)", None)):
        clock = SimClock()
        dev = make(clock) if make else SimavrController(clock)
        with dev:
            with RigController.open(dev.path, clock=clock) as ctl:
                lat = []
                for _ in range(n):
                    t0 = time.perf_counter()
                    ctl.status()
                    lat.append(time.perf_counter() - t0)
        rows.append((name, lat))
    base = statistics.median(rows[0][1])
    for name, lat in rows:
        med = statistics.median(lat)
        t.add(name, med * 1e3, _percentile(lat, 0.95) * 1e3, med / base)
    return [size, t]


def run(quick: bool = False) -> list[Table]:
    return [decoder_table(quick), latency_table(quick), retry_table(quick), *firmware_table(quick)]
