"""The rig controller emulated by the compiled reference firmware (host build) behind a pty.

``firmware_protocol/firmware`` is built as a shared library (``make -C firmware_protocol/firmware
host``, done on first use) and loaded with ctypes. The protocol logic — framing, handshake, catalogue,
duplicate rule, watchdog, E-stop latch, soft start, photodiode statistics, trigger — is the
firmware's own C code; this module only supplies what the hardware would: simulated time (the
:class:`~sim.clock.SimClock` drives the firmware's timer HAL), the E-stop / interlock pins, and the
physics behind the ADC (the light's output follows the firmware's PWM duty with the warm-up model of
:class:`sim.controller.ControllerEmulator`; the photodiode adds seeded Gaussian noise; the temperature
sensor follows the same thermal model). Reply link faults (:class:`sim.faults.LinkFaults`) stay on the
Python side of the pty: they model the cable, not the controller.
"""

from __future__ import annotations

import ctypes
import math
import threading
from collections import Counter
from pathlib import Path


from firmware_protocol import codec as fp
from gonio import childproc
from sim.controller import ALL_CAPABILITIES, OVERTEMP_C, ControllerEmulator
from sim.faults import LinkFaults

FIRMWARE_DIR = Path(__file__).resolve().parent.parent / "firmware_protocol" / "firmware"
LIBRARY = FIRMWARE_DIR / "build" / "libgoniofw.so"
#: ADC counts of the host build at full level (16-bit converter: fine enough to carry σ = 0.002).
PD_FULL_COUNTS = 50_000

_ADC_FN = ctypes.CFUNCTYPE(ctypes.c_uint16, ctypes.c_void_p)
_TEMP_FN = ctypes.CFUNCTYPE(ctypes.c_int16, ctypes.c_void_p)
_lib_lock = threading.Lock()
_lib = None


class FwConfig(ctypes.Structure):
    """``fw_config`` of fw.h."""
    _fields_ = [("capabilities", ctypes.c_uint16), ("major", ctypes.c_uint8), ("minor", ctypes.c_uint8),
                ("pd_full_counts", ctypes.c_uint16),
                ("pd_noise_e6", ctypes.c_uint32), ("soft_start_ms", ctypes.c_uint16),
                ("overtemp_centi", ctypes.c_int16)]


def build_library() -> Path:
    """Build the host firmware library with ``make`` if it is missing or older than its sources."""
    import fcntl

    srcs = list(FIRMWARE_DIR.glob("*.[ch]")) + list((FIRMWARE_DIR.parent / "c").glob("fp_codec.[ch]"))
    LIBRARY.parent.mkdir(exist_ok=True)
    with open(LIBRARY.parent / ".lock", "w") as lock:  # one build at a time across processes
        fcntl.flock(lock, fcntl.LOCK_EX)
        _make_if_stale(srcs)
    return LIBRARY


def _make_if_stale(srcs) -> None:
    if not LIBRARY.exists() or LIBRARY.stat().st_mtime < max(p.stat().st_mtime for p in srcs):
        r = childproc.run(["make", "-s", "-C", str(FIRMWARE_DIR), "host"], capture_output=True, text=True)
        if r.returncode:
            raise RuntimeError(f"building {LIBRARY} failed: {r.stderr.strip() or r.stdout.strip()}")


def library():
    """The loaded host firmware (built on first use)."""
    global _lib
    with _lib_lock:
        if _lib is None:
            lib = ctypes.CDLL(str(build_library()))
            vp, u64 = ctypes.c_void_p, ctypes.c_uint64
            lib.fwhost_new.restype = vp
            lib.fwhost_new.argtypes = [ctypes.POINTER(FwConfig), u64, _ADC_FN, _TEMP_FN, vp]
            lib.fwhost_free.argtypes = [vp]
            lib.fwhost_default_config.argtypes = [ctypes.POINTER(FwConfig)]
            lib.fwhost_config_size.restype = ctypes.c_size_t
            lib.fwhost_set_time.argtypes = [vp, u64]
            lib.fwhost_reset.argtypes = [vp]
            lib.fwhost_brownout.argtypes = [vp]
            lib.fwhost_set_inputs.argtypes = [vp, ctypes.c_int, ctypes.c_int]
            lib.fwhost_rx.restype = ctypes.c_size_t
            lib.fwhost_rx.argtypes = [vp, ctypes.c_char_p, ctypes.c_size_t]
            lib.fwhost_take_tx.restype = ctypes.c_size_t
            lib.fwhost_take_tx.argtypes = [vp, ctypes.c_char_p, ctypes.c_size_t]
            lib.fwhost_state.argtypes = [vp, ctypes.POINTER(u64)]
            lib.fwhost_rejects.argtypes = [vp, ctypes.POINTER(ctypes.c_uint32)]
            lib.fwhost_executed.restype = ctypes.c_uint32
            lib.fwhost_executed.argtypes = [vp, ctypes.c_uint8]
            if lib.fwhost_config_size() != ctypes.sizeof(FwConfig):
                raise RuntimeError("firmware library and sim/firmware.py disagree on fw_config")
            _lib = lib
        return _lib


class _Executed(Counter):
    """``executed`` by message name, read from the firmware's counters."""

    def __init__(self, owner):
        super().__init__()
        self._owner = owner

    def __missing__(self, name):
        spec = fp.BY_NAME.get(name)
        if spec is None or not 1 <= spec.code <= 7:
            return 0
        return self._owner._lib.fwhost_executed(self._owner._h, spec.code)


class FirmwareController(ControllerEmulator):
    """Drop-in for :class:`sim.controller.ControllerEmulator` whose logic is the compiled firmware.

    Same constructor and the same observables (``light_output``, ``light_on``, ``executed``,
    ``duplicates``, ``trigger_times``, ``set_estop``, ``inject_reset`` ...). ``soft_start_ms`` is the
    firmware's light ramp (0 by default here, so that a photodiode read at the same simulated instant
    as the switch-on sees the set level, as the Python emulator does).
    """

    def __init__(self, clock, *, faults: LinkFaults | None = None, seed: int = 0, warmup_depth: float = 0.05,
                 warmup_tau: float = 120.0, pd_gain: float = 1.0, pd_noise: float = 0.002, ambient_c: float = 25.0,
                 heating_c: float = 15.0, thermal_tau: float = 600.0, capabilities: int = ALL_CAPABILITIES,
                 major: int = fp.PROTOCOL_MAJOR, minor: int = fp.PROTOCOL_MINOR, name: str = "controller",
                 soft_start_ms: int = 0):
        self._lib = library()
        self._h = None
        self._adc_cb = _ADC_FN(lambda _ctx: self._adc_sample())
        self._temp_cb = _TEMP_FN(lambda _ctx: int(round(self._temperature(self.clock.now()) * 100)))
        cfg = FwConfig()
        self._lib.fwhost_default_config(ctypes.byref(cfg))
        cfg.capabilities, cfg.major, cfg.minor = int(capabilities), int(major), int(minor)
        cfg.pd_full_counts = PD_FULL_COUNTS
        cfg.pd_noise_e6, cfg.soft_start_ms = int(round(pd_noise / fp.MICRO)), int(soft_start_ms)
        cfg.overtemp_centi = int(round(OVERTEMP_C * 100))
        self._cfg = cfg
        self._estop_in = self._interlock_in = False
        self._known_triggers = 0
        super().__init__(clock, faults=faults, seed=seed, warmup_depth=warmup_depth, warmup_tau=warmup_tau,
                         pd_gain=pd_gain, pd_noise=pd_noise, ambient_c=ambient_c, heating_c=heating_c,
                         thermal_tau=thermal_tau, capabilities=capabilities, major=major, minor=minor, name=name)
        self.executed = _Executed(self)

    # -- the HAL's side ------------------------------------------------------------------------
    def _us(self, t: float) -> int:
        return max(0, int(round(t * 1e6)))

    def _state(self) -> list[int]:
        s = (ctypes.c_uint64 * 17)()
        self._lib.fwhost_state(self._h, s)
        return list(s)

    def _tick(self) -> float:
        """Bring the firmware's timer to the clock's time and let it poll; returns the time."""
        now = self.clock.now()
        self._lib.fwhost_set_time(self._h, self._us(now))
        return now

    def _output(self, now: float) -> float:
        duty, on_since_us = (lambda s: (s[0], s[10]))(self._state())
        if not duty:
            return 0.0
        return duty / fp.LEVEL_FULL_SCALE * (
            1.0 - self.warmup_depth * math.exp(-(now - on_since_us * 1e-6) / self.warmup_tau))

    def _temperature(self, now: float) -> float:
        if getattr(self, "heat_sink_c", None) is not None:
            return self.heat_sink_c
        if self._h is None:
            return self.ambient_c
        duty, on_since_us = (lambda s: (s[0], s[10]))(self._state())
        if not duty:
            return self.ambient_c
        return self.ambient_c + self.heating_c * duty / fp.LEVEL_FULL_SCALE * (
            1.0 - math.exp(-(now - on_since_us * 1e-6) / self.thermal_tau))

    def _adc_sample(self) -> int:
        x = self.pd_gain * self._output(self.clock.now()) + self._rng.normal(0.0, self.pd_noise)
        return int(min(max(round(x * PD_FULL_COUNTS), 0), 0xFFFF))

    # -- state ---------------------------------------------------------------------------------
    def _power_on(self) -> None:
        now = self.clock.now()
        self._boot = now
        if self._h is None:
            self._h = self._lib.fwhost_new(ctypes.byref(self._cfg), self._us(now), self._adc_cb, self._temp_cb, None)
            if not self._h:
                raise MemoryError("fwhost_new")
        else:
            self._lib.fwhost_set_time(self._h, self._us(now))
            self._lib.fwhost_reset(self._h)
        self._lib.fwhost_set_inputs(self._h, int(self._estop_in), int(self._interlock_in))
        self._known_triggers = 0

    def set_heat_sink(self, celsius: float | None) -> None:
        with self._lock:
            self.heat_sink_c = None if celsius is None else float(celsius)
            self._tick()  # the firmware reads its sensor every 10 ms of its time, and at every STATUS and switch-on

    def inject_reset(self) -> None:
        with self._lock:
            self.resets += 1
            self._lib.fwhost_brownout(self._h)

    def set_estop(self, pressed: bool) -> None:
        with self._lock:
            self._estop_in = bool(pressed)
            self._tick()
            self._lib.fwhost_set_inputs(self._h, int(self._estop_in), int(self._interlock_in))

    def set_interlock(self, open_: bool) -> None:
        with self._lock:
            self._interlock_in = bool(open_)
            self._tick()
            self._lib.fwhost_set_inputs(self._h, int(self._estop_in), int(self._interlock_in))

    def light_output(self) -> float:
        with self._lock:
            return self._output(self._tick())

    @property
    def light_on(self) -> bool:
        with self._lock:
            self._tick()
            return bool(self._state()[1])

    @property
    def watchdog_period(self) -> float:
        with self._lock:
            return self._state()[8] / 1000.0

    @property
    def duplicates(self) -> int:
        return self._state()[7] if self._h is not None else 0

    @duplicates.setter
    def duplicates(self, _value) -> None:  # the base class initialises it; the firmware counts
        pass

    @property
    def _decoder(self):
        """The firmware's receive statistics, shaped like :class:`firmware_protocol.codec.Decoder`'s."""
        class _Stats:
            pass
        st = _Stats()
        r = (ctypes.c_uint32 * 4)()
        if self._h is not None:
            self._lib.fwhost_rejects(self._h, r)
        st.rejects = dict(zip(fp.VERDICTS, list(r)))
        st.reset = lambda: None
        return st

    @_decoder.setter
    def _decoder(self, _value) -> None:  # the base class creates a Python decoder; the firmware has its own
        pass

    @property
    def photodiode_time(self) -> float:
        """Uptime (s) at the middle of the last photodiode reading, as the firmware recorded it."""
        return self._state()[9] / 1000.0

    @property
    def session_minor(self) -> int:
        """The minor version of the fields the firmware's replies carry (min of host's and its own)."""
        return self._state()[14]

    # -- the UART ------------------------------------------------------------------------------
    def on_idle(self) -> None:
        with self._lock:
            self._tick()

    def on_bytes(self, data: bytes) -> None:
        with self._lock:
            now = self._tick()
            n = self._lib.fwhost_rx(self._h, bytes(data), len(data))
            buf = ctypes.create_string_buffer(max(n, 1))
            got = self._lib.fwhost_take_tx(self._h, buf, n) if n else 0
            out = buf.raw[:got]
            count = self._state()[5]
            self.trigger_times.extend([now] * (count - self._known_triggers))
            self._known_triggers = count
        for seg in out.split(b"\x00"):  # one reply per frame, so link faults hit frames as before
            if seg:
                self.send(b"\x00" + seg + b"\x00")

    def __del__(self):
        h, self._h = getattr(self, "_h", None), None
        if h:
            self._lib.fwhost_free(h)
