"""The reference firmware's AVR build running in simavr (an emulated ATmega328P), UART on a pty.

``make -C firmware_protocol/firmware simavr`` builds ``goniofw.elf`` (avr-gcc) and the bridge
``fw_simavr`` (against libsimavr; its UART is simavr's ``uart_pty`` part); :class:`SimavrController`
starts the bridge and gives the pty's :attr:`path`, to open with
:class:`gonio.rig.controller.RigController` or ``gonio controller --port``. Time there is emulated CPU
cycles (the firmware's Timer0), paced to about real time by simavr while the CPU sleeps; the
photodiode input follows the light's PWM registers, the temperature sensor reads 25 °C, and the
E-stop loop is opened and closed with :meth:`set_estop` (SIGUSR1/SIGUSR2 to the bridge).
"""

from __future__ import annotations

import glob
import os
import select
import shutil
import signal
import subprocess
import threading
import time

from gonio import childproc
from sim.firmware import FIRMWARE_DIR

BRIDGE = FIRMWARE_DIR / "build" / "fw_simavr"
ELF = FIRMWARE_DIR / "build" / "goniofw.elf"

#: The Debian packages the AVR build and its emulation need, each with a file that shows it is installed
#: (commands are looked up on PATH).
DEBIAN_PACKAGES = {
    "make": lambda: shutil.which("make"),
    "gcc": lambda: shutil.which("cc") or shutil.which("gcc"),  # the bridge is a host program
    "gcc-avr": lambda: shutil.which("avr-gcc"),
    "binutils-avr": lambda: shutil.which("avr-objcopy") and shutil.which("avr-size"),
    "avr-libc": lambda: glob.glob("/usr/lib/avr/include/avr/io.h"),
    "libsimavr-dev": lambda: glob.glob("/usr/include/simavr/sim_avr.h") and glob.glob("/usr/lib/*/libsimavr.so*"),
}


def missing_packages() -> list[str]:
    """The Debian packages of :data:`DEBIAN_PACKAGES` that are not installed (empty when all are)."""
    return [name for name, present in DEBIAN_PACKAGES.items() if not present()]


def build() -> str:
    """Build the AVR firmware and the bridge; returns make's output (flash/RAM use line included).
    Missing Debian packages are named before anything is run."""
    import fcntl

    missing = missing_packages()
    if missing:
        raise RuntimeError(f"the AVR build in simavr needs Debian packages {' '.join(missing)}: "
                           f"apt-get install {' '.join(missing)}")
    (FIRMWARE_DIR / "build").mkdir(exist_ok=True)
    with open(FIRMWARE_DIR / "build" / ".lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        r = childproc.run(["make", "-C", str(FIRMWARE_DIR), "simavr"], capture_output=True, text=True)
    if r.returncode:
        raise RuntimeError(f"make simavr failed: {(r.stderr or r.stdout).strip()[-500:]}")
    return r.stdout


def avr_size() -> tuple[int, int]:
    """(flash, RAM) bytes of the AVR build, from ``make size`` (which fails over the chip's limits)."""
    import re

    build()
    r = childproc.run(["make", "-s", "-C", str(FIRMWARE_DIR), "size"], capture_output=True, text=True)
    m = re.search(r"flash (\d+) / \d+ bytes, RAM (\d+) /", r.stdout)
    if r.returncode or not m:
        raise RuntimeError(f"make size: {(r.stderr or r.stdout).strip()}")
    return int(m.group(1)), int(m.group(2))


class SimavrController:
    """The AVR firmware in simavr behind a pty (start/stop, or use as a context manager)."""

    def __init__(self, clock=None, *, faults=None, seed: int = 0, **_physics):
        from sim.faults import LinkFaults

        self.proc: subprocess.Popen | None = None
        self.path = ""
        self.clock = clock
        self.faults = faults or LinkFaults()  # kept for the SimRig's per-pose reseeding; not applied here
        if any(getattr(self.faults, k, 0) for k in ("delay_rate", "drop_rate", "corrupt_rate", "short_rate")):
            raise ValueError("simavr controller: link faults are not supported (use controller = 'firmware')")
        self._duty = 0
        self._reader = None
        #: lengths of the trigger pulses on pin PD7, µs of emulated time, as the bridge measured them
        self.pulses_us: list[float] = []

    def start(self, timeout: float = 10.0) -> "SimavrController":
        build()
        # the bridge dies with this process, however it dies (kill -9 included: gonio.childproc)
        self.proc = childproc.popen([str(BRIDGE), str(ELF)], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
        fd, out = self.proc.stdout.fileno(), b""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            ready, _, _ = select.select([fd], [], [], 0.2)
            if ready:
                chunk = os.read(fd, 4096)
                out += chunk
                for line in out.decode(errors="replace").splitlines():
                    if line.startswith("PTY ") and out.endswith(b"\n"):
                        self.path = line.split()[1]
                        self._reader = threading.Thread(target=self._read_reports, args=(fd,), daemon=True)
                        self._reader.start()
                        time.sleep(0.2)  # the firmware's boot (a few emulated ms)
                        return self
                if not chunk:
                    break
        err = out.decode(errors="replace")[-300:]
        self.stop()
        raise RuntimeError(f"fw_simavr did not report its pty: {err.strip()}")

    def _read_reports(self, fd: int) -> None:
        buf = b""
        while True:
            try:
                chunk = os.read(fd, 4096)
            except OSError:
                return
            if not chunk:
                return
            buf += chunk
            *lines, buf = buf.split(b"\n")
            for line in lines:
                if line.startswith(b"LIGHT "):
                    self._duty = int(line.split()[1])
                elif line.startswith(b"PULSE "):
                    self.pulses_us.append(int(line.split()[1]) / 1000.0)

    def light_output(self) -> float:
        """Relative light output now, from the PWM duty the firmware set (no warm-up model here)."""
        return self._duty / 65535.0

    def reseed(self, seed) -> None:
        """Nothing to reseed: the photodiode model in the bridge is noiseless."""

    def inject_reset(self) -> None:
        raise NotImplementedError("simavr controller: brown-out injection is a host-build feature (controller = 'firmware')")

    def set_estop(self, pressed: bool) -> None:
        """Open (pressed) or close the E-stop loop on pin PD2."""
        os.kill(self.proc.pid, signal.SIGUSR1 if pressed else signal.SIGUSR2)

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(5)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        if self.proc is not None:
            if self._reader is not None:
                self._reader.join(2)
            self.proc.stdout.close()
        self.proc = None

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()
