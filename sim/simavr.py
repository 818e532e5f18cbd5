"""The reference firmware's AVR build running in simavr (an emulated ATmega328P), behind a pty.

``make -C firmware_protocol/firmware simavr`` builds ``goniofw.elf`` (avr-gcc) and the bridge
``fw_simavr`` (against libsimavr); :class:`SimavrController` serves a pty (:attr:`path`, to open with
:class:`gonio.rig.controller.RigController` or ``gonio controller --port``) and drives the bridge over its
stdin/stdout **in lockstep with the clock**: before bytes from the host reach the emulated USART (at the
wire's pace) and on every idle tick, the firmware runs until its emulated time (CPU cycles since its
power-on) reaches the clock's time since :meth:`start` — never paced by real time, never ahead of the
clock except while it is handling a request. So a session on a :class:`~sim.clock.SimClock` is
reproducible for a seed (the same requests at the same clock times meet the same emulated cycles), and on
a real clock emulated time follows real time.

Physics (in the bridge, at every ADC conversion): the photodiode follows the light's PWM duty with the lamp
warm-up of :class:`sim.controller.ControllerEmulator` (``I = L (1 − d exp(−(t − t_on)/τ))``) and seeded
Gaussian noise (:meth:`reseed` per pose); :meth:`light_output` gives the camera the same warm-up on the same
time base; the heat-sink sensor reads 25 °C unless :meth:`set_heat_sink` says otherwise; :meth:`set_estop`
opens the E-stop loop; :meth:`hang` makes the firmware's main loop hang (its hardware watchdog must reset it).
"""

from __future__ import annotations

import glob
import math
import shutil
import subprocess
import threading

import numpy as np

from gonio import childproc
from sim.firmware import FIRMWARE_DIR
from sim.pty import PtyServer

BRIDGE = FIRMWARE_DIR / "build" / "fw_simavr"
#: Emulated time the firmware runs at start, before the clock's time (its boot: UART set up, handshake-ready)
BOOT_S = 0.01
RX_CHUNK = 1024  #: bytes per RX command
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


def ms_ticks_address() -> int:
    """Data-space address of the firmware's millisecond counter ``ms_ticks`` (hal_avr.c), from the .elf's symbols
    (``avr-nm``; SRAM symbols carry avr-gcc's 0x800000 data-space offset); 0 if not found."""
    r = childproc.run(["avr-nm", str(ELF)], capture_output=True, text=True)
    for line in r.stdout.splitlines():
        parts = line.split()
        if len(parts) == 3 and parts[2] == "ms_ticks":
            return int(parts[0], 16) & 0xFFFF
    return 0


class SimavrController(PtyServer):
    """The AVR firmware in simavr behind a pty, in lockstep with ``clock`` (start/stop, or a context manager).

    ``clock``: the simulator's clock (a :class:`~sim.clock.SimClock`), or None for real time. ``seed``,
    ``pd_noise``, ``warmup_depth``, ``warmup_tau``: the photodiode model (as
    :class:`sim.controller.ControllerEmulator`'s). Link faults are not supported (use the host build,
    ``controller = 'firmware'``, for those).
    """

    #: The reply deadline a host should give this emulator, real seconds. The emulated AVR shares the host's
    #: CPU: a 255-sample photodiode read is ~26 ms of emulated time but can take longer than the hardware
    #: default (0.25 s) of real time on a loaded machine, and a retried READ_PHOTODIODE is executed again
    #: (SPEC.md section 5), drawing new noise, so a seeded session would depend on the machine's load. With no
    #: link faults here a generous deadline costs nothing.
    reply_timeout = 5.0

    def __init__(self, clock=None, *, faults=None, seed: int = 0, pd_noise: float = 0.002, warmup_depth: float = 0.05,
                 warmup_tau: float = 120.0, name: str = "controller", **_physics):
        from gonio.rig.clock import RealClock
        from sim.faults import LinkFaults

        faults = faults or LinkFaults()  # kept for the SimRig's per-pose reseeding; not applied here
        if any(getattr(faults, k, 0) for k in ("delay_rate", "drop_rate", "corrupt_rate", "short_rate")):
            raise ValueError("simavr controller: link faults are not supported (use controller = 'firmware')")
        super().__init__(name)
        self.faults = faults
        self.clock = clock if clock is not None else RealClock()
        self._simulated_clock = not isinstance(self.clock, RealClock)
        self.pd_noise, self.warmup_depth, self.warmup_tau = float(pd_noise), float(warmup_depth), float(warmup_tau)
        self.seed = seed
        self.proc: subprocess.Popen | None = None
        self._bridge_lock = threading.RLock()
        self._t0 = 0.0  # clock time of the firmware's power-on
        self._duty, self._on_since_us = 0, 0.0
        self.emulated_us = 0.0  #: the firmware's emulated time (us since power-on) after the last command
        #: lengths of the trigger pulses on pin PD7, µs of emulated time, as the bridge measured them
        self.pulses_us: list[float] = []

    # -- the bridge ------------------------------------------------------------------------------
    def start(self, timeout: float = 10.0) -> "SimavrController":
        if self.proc is not None:
            return self
        build()
        # the bridge dies with this process: SIGKILL from the kernel when it dies (gonio.childproc), and it
        # exits by itself at the end of its stdin, a pipe only this process holds
        self.proc = childproc.popen([str(BRIDGE), str(ELF)], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                    stderr=subprocess.DEVNULL, text=True, bufsize=1)
        self._t0 = self.clock.now() - BOOT_S  # the firmware booted BOOT_S before the clock's now
        for _ in range(100):  # simavr's own "Loaded ..." lines first
            line = self.proc.stdout.readline()
            if not line or line.strip() == "READY":
                break
        if line.strip() != "READY":
            self.stop()
            raise RuntimeError("fw_simavr did not start")
        self._command(f"TICKS {ms_ticks_address()}")  # lets the bridge skip idle time (fw_simavr.c)
        self._command(f"PD {self.pd_noise * 1e6:.0f} {self.warmup_depth * 1e6:.0f} {self.warmup_tau * 1e3:.0f}")
        self.reseed(self.seed)
        self._command(f"RUN {self._target_us()}")  # the firmware's boot
        return super().start()

    def _target_us(self) -> int:
        return max(0, int(round((self.clock.now() - self._t0) * 1e6)))

    def _command(self, line: str) -> None:
        """Send one command and handle the bridge's events up to its IDLE line (bytes the firmware sent go to
        the host)."""
        with self._bridge_lock:
            if self.proc is None or self.proc.poll() is not None:
                raise RuntimeError("fw_simavr is not running")
            self.proc.stdin.write(line + "\n")
            self.proc.stdin.flush()
            for _ in range(1_000_000):  # bounded: one line per event
                ev = self.proc.stdout.readline()
                if not ev:
                    raise RuntimeError("fw_simavr stopped")
                kind, _, rest = ev.strip().partition(" ")
                if kind == "IDLE":
                    self.emulated_us = float(rest)
                    return
                if kind == "TX":
                    self.send(bytes.fromhex(rest))
                elif kind == "LIGHT":
                    duty, since = rest.split()
                    self._duty, self._on_since_us = int(duty), float(since)
                elif kind == "PULSE":
                    self.pulses_us.append(int(rest) / 1000.0)
            raise RuntimeError("fw_simavr: no IDLE")

    # -- the pty ---------------------------------------------------------------------------------
    def on_bytes(self, data: bytes) -> None:
        with self._bridge_lock:
            self._command(f"RUN {self._target_us()}")
            data = bytes(data)
            for k in range(0, len(data), RX_CHUNK):  # the bridge reads lines of at most 8 KiB
                self._command("RX " + data[k:k + RX_CHUNK].hex())

    def on_idle(self) -> None:
        """On a real clock, the firmware keeps up with it between requests (its watchdog, the lamp's soft start).
        On a simulated clock it runs only when observed (bytes from the host, :meth:`light_output`, the pins):
        an idle tick comes at a real-time moment, and running to the clock's time then would make where the
        emulated CPU stands when the next request arrives depend on the machine's load (a seeded session's
        controller uptimes differed by 1 ms between runs under load)."""
        if self._simulated_clock:
            return
        with self._bridge_lock:
            if self.proc is not None:
                self._command(f"RUN {self._target_us()}")

    # -- the controller's observables and inputs --------------------------------------------------
    def light_output(self) -> float:
        """Relative light output now: the PWM duty the firmware set, with the lamp's warm-up since it switched
        on (the photodiode's model, on the same time base)."""
        with self._bridge_lock:
            if self.proc is not None:
                self._command(f"RUN {self._target_us()}")
            if not self._duty:
                return 0.0
            t = (self.emulated_us - self._on_since_us) * 1e-6
            return self._duty / 65535.0 * (1.0 - self.warmup_depth * math.exp(-t / self.warmup_tau))

    @property
    def light_on(self) -> bool:
        return self.light_output() > 0.0

    def reseed(self, seed) -> None:
        """Restart the photodiode noise from ``seed`` (an int, a SeedSequence or a numpy Generator)."""
        gen = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
        self._command(f"SEED {int(gen.integers(1, 2**63))}")

    def inject_reset(self) -> None:
        raise NotImplementedError("simavr controller: brown-out injection is a host-build feature (controller = 'firmware')")

    def set_estop(self, pressed: bool) -> None:
        """Open (pressed) or close the E-stop loop on pin PD2."""
        with self._bridge_lock:
            self._command(f"RUN {self._target_us()}")
            self._command(f"ESTOP {int(bool(pressed))}")

    def set_interlock(self, open_: bool) -> None:
        """Open or close the enclosure interlock on pin PD3."""
        with self._bridge_lock:
            self._command(f"RUN {self._target_us()}")
            self._command(f"INTERLOCK {int(bool(open_))}")

    def set_heat_sink(self, celsius: float | None) -> None:
        """The temperature the TMP36 on the light's heat sink reads (None: 25 °C)."""
        with self._bridge_lock:
            self._command(f"RUN {self._target_us()}")
            self._command(f"TEMP {int(round((25.0 if celsius is None else celsius) * 100))}")

    def hang(self) -> None:
        """Make the firmware's main loop hang (interrupts keep running; nothing feeds the hardware watchdog)."""
        with self._bridge_lock:
            self._command(f"RUN {self._target_us()}")
            self._command("HANG")

    def run_for(self, seconds: float) -> None:
        """Let the firmware run ``seconds`` of emulated time beyond the clock (a test's way to see what it
        does on its own, e.g. its watchdog reset, without moving the clock)."""
        with self._bridge_lock:
            self._command(f"RUN {int(self.emulated_us + seconds * 1e6)}")

    def stop(self) -> None:
        super().stop()
        with self._bridge_lock:
            if self.proc is not None:
                try:
                    self.proc.stdin.close()  # end of stdin: the bridge exits
                    self.proc.wait(5)
                except (OSError, subprocess.TimeoutExpired):
                    self.proc.kill()
                    self.proc.wait()
                self.proc.stdout.close()
            self.proc = None
