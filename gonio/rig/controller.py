"""Host client of the rig controller (light, photodiode, camera trigger, status, watchdog).

Speaks ``firmware_protocol`` (see ``firmware_protocol/SPEC.md``) over any pyserial-like port: an object
with ``write``, ``read``, ``in_waiting``, ``reset_input_buffer``, ``timeout`` and ``close``. Use
:meth:`RigController.open` for a device path or a pyserial URL.

Reliability rules (SPEC.md §5):

* every request carries a sequence number; a retry re-sends the *same* bytes (same seq); the controller
  executes a retried idempotent request again (its reply says what holds now) and answers a retried TRIGGER
  from its cache, so a trigger fires once (protocol 2.2; a 2.1 controller answers every duplicate from its
  cache, so a SET_LIGHT that needed a retry is confirmed with a STATUS);
* a reply is accepted only if its type answers the request and its seq matches; anything else (a late
  reply to an earlier, timed-out request) is discarded;
* after a failed attempt (timeout or corrupted reply) the client waits briefly and flushes its input
  (port buffer and decoder), then retries, at most ``retries`` times; then it raises
  :class:`~gonio.errors.HardwareTimeout` or :class:`~gonio.errors.ChecksumError`;
* before the HELLO the input is flushed (bytes an earlier host session left on the port are no reply);
* ERROR replies become :class:`~gonio.errors.EmergencyStop` (code ESTOP), :class:`~gonio.errors.SafetyStop`
  (code OVERTEMP) or
  :class:`~gonio.errors.ControllerError` with the controller's ``code``; NOT_READY means the controller
  reset: the client re-handshakes, restores the watchdog period and the light it last commanded
  (the light then warms up again; the photodiode reports that drift) and retries once.

Versions (SPEC.md §3): the session speaks the lower of the host's and the controller's minor version
(:attr:`RigController.session_minor`); from 2.1 on, photodiode readings carry the controller's timestamp.

Watchdog: every request feeds the controller's watchdog. During long waits call :meth:`wait`, which
sleeps on the :class:`Clock` in steps of at most half the watchdog period and sends a heartbeat between
steps, and after the last one if the controller has not heard from this client for more than half the
period: it returns with the watchdog fed within the last half period, as it is after any request; with a
simulated clock the controller measures silence on that same clock.
Serial deadlines are real time (``time.monotonic``), as a serial timeout is; protocol time is the Clock.
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass

from firmware_protocol import codec as fp
from gonio.errors import (ChecksumError, ConfigError, ControllerError, EmergencyStop, HardwareError, HardwareTimeout,
                          SafetyStop)
from gonio.rig.clock import RealClock
from gonio.rig.interfaces import ControllerStatus, PhotodiodeReading

REQUIRED_CAPABILITIES = fp.CAP_PHOTODIODE | fp.CAP_TRIGGER
CAPABILITY_NAMES = {fp.CAP_DIMMING: "dimming", fp.CAP_PHOTODIODE: "photodiode", fp.CAP_TRIGGER: "trigger",
                    fp.CAP_TEMPERATURE: "temperature", fp.CAP_INTERLOCK: "interlock"}


@dataclass(frozen=True)
class ControllerInfo:
    """What the controller said in its HELLO reply."""

    major: int
    minor: int
    capabilities: int
    firmware: int
    max_payload: int
    watchdog_s: float


class RigController:
    """Client of the rig controller; implements :class:`gonio.rig.interfaces.RigController`.

    Parameters
    ----------
    port : serial.Serial-like
        An open port (its ``timeout`` is set to a short poll interval).
    clock : Clock, optional
        Protocol time (trigger pulses, :meth:`wait`); :class:`RealClock` by default.
    timeout : float
        Real seconds to wait for each reply attempt.
    retries : int
        Extra attempts after a timeout or corrupted reply (bounded).
    watchdog : float
        Watchdog period sent to the controller at :meth:`connect`, seconds (0.1 .. 3600).
    device : str
        Name used in error messages.
    """

    def __init__(self, port, *, clock=None, timeout: float = 0.25, retries: int = 3, watchdog: float = 10.0,
                 device: str = "rig controller", required_capabilities: int = REQUIRED_CAPABILITIES):
        if not (fp.WATCHDOG_MIN_MS <= round(watchdog * 1000) <= fp.WATCHDOG_MAX_MS):
            raise ConfigError.field(device, "watchdog", watchdog, "must be in [0.1, 3600] seconds")
        if retries < 0 or timeout <= 0:
            raise ConfigError.field(device, "retries/timeout", (retries, timeout), "need retries >= 0, timeout > 0")
        self._port = port
        self.clock = clock if clock is not None else RealClock()
        self.timeout, self.retries, self.watchdog = float(timeout), int(retries), float(watchdog)
        self.device = device
        self.required_capabilities = required_capabilities
        self.flush_delay = 0.01  #: real seconds to let a late reply arrive before flushing
        self.corrupt_grace = 0.02  #: after a corrupted segment, wait this long for a valid reply
        self._decoder = fp.Decoder()
        self._lock = threading.RLock()
        self._seq = 0
        self._light = (False, 0)  # last commanded (on, level u16), restored after a controller reset
        self._pulse_end = -math.inf
        self.info: ControllerInfo | None = None
        self.retry_count = 0  #: attempts repeated after a timeout or corrupted reply
        self.stale_replies = 0  #: valid frames discarded because they did not answer the request
        self.resets_seen = 0  #: controller resets detected (NOT_READY) and recovered from
        self._recovering = False
        self._needs_flush = False  # the last exchange failed: flush before the next one
        #: minor version of this session: min(host's, controller's); None before the handshake
        self.session_minor: int | None = None
        self._exchange_times = (0.0, 0.0, 0.0, 1)  # Clock at first send, last send, reply; attempts
        self._fed = -math.inf  # Clock time of the last request answered (it fed the controller's watchdog)
        if hasattr(port, "timeout"):
            port.timeout = 0.02

    # -- construction ---------------------------------------------------------------------------
    @classmethod
    def open(cls, path_or_url: str, *, clock=None, baudrate: int = 115200, connect: bool = True,
             **kwargs) -> "RigController":
        """Open a device path (``/dev/ttyACM0``, a pty) or a pyserial URL, and :meth:`connect`."""
        import serial

        try:
            port = serial.serial_for_url(path_or_url, baudrate=baudrate, timeout=0.02)
        except (serial.SerialException, ValueError) as e:
            raise ConfigError.field(None, "controller port", path_or_url, f"cannot open: {e}") from None
        ctl = cls(port, clock=clock, device=kwargs.pop("device", f"rig controller {path_or_url}"), **kwargs)
        if connect:
            try:
                ctl.connect()
            except BaseException:
                port.close()
                raise
        return ctl

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    # -- handshake --------------------------------------------------------------------------------
    def connect(self) -> ControllerInfo:
        """HELLO (protocol version and capability check), then set the watchdog period."""
        with self._lock:
            self.session_minor = None  # the HELLO reply's size is the same in every minor version
            self._needs_flush = True  # whatever an earlier session left on the port is no reply to this one
            r = self._transact("HELLO", major=fp.PROTOCOL_MAJOR, minor=fp.PROTOCOL_MINOR)
            if r["major"] != fp.PROTOCOL_MAJOR:
                raise ControllerError(f"{self.device}: controller speaks protocol {r['major']}.{r['minor']}, "
                                      f"host speaks {fp.PROTOCOL_MAJOR}.{fp.PROTOCOL_MINOR}",
                                      device=self.device, code=fp.ERR_VERSION)
            missing = self.required_capabilities & ~r["capabilities"]
            if missing:
                names = [n for bit, n in CAPABILITY_NAMES.items() if missing & bit]
                raise ControllerError(f"{self.device}: controller lacks capabilities: {', '.join(names)}",
                                      device=self.device)
            self.session_minor = min(r["minor"], fp.PROTOCOL_MINOR)
            w = self._transact("SET_WATCHDOG", period_ms=int(round(self.watchdog * 1000)))
            self.info = ControllerInfo(r["major"], r["minor"], r["capabilities"], r["firmware"], r["max_payload"],
                                       w["period_ms"] / 1000.0)
            return self.info

    # -- RigController protocol -----------------------------------------------------------------
    def set_light(self, on: bool, level: float = 1.0) -> None:
        """Switch the light on/off at relative ``level`` in [0, 1] (EmergencyStop if E-stop/interlock)."""
        if not (isinstance(level, (int, float)) and 0.0 <= level <= 1.0):
            raise ConfigError.field(self.device, "light level", level, "must be a number in [0, 1]")
        lvl = int(round(level * fp.LEVEL_FULL_SCALE))
        with self._lock:
            self._light = (False, 0) if not on else self._light  # off is remembered even if the reply is lost
            self._transact("SET_LIGHT", on=int(bool(on)), level=lvl)
            self._light = (bool(on), lvl)
            if on and self._exchange_times[3] > 1 and (self.session_minor or 0) < 2:
                # a 2.1 controller answers a retry from its duplicate cache: the reply may describe the first
                # attempt, not now (an E-stop may have cut the light in between); STATUS says what holds now
                st = self.status()
                if not st.light_on:
                    self._light = (False, 0)
                    raise SafetyStop(f"{self.device}: light off after a retried switch-on: "
                                     f"{st.unsafe_reason(True) or 'the controller switched it off'}",
                                     device=self.device)

    def read_photodiode(self, samples: int = 1) -> PhotodiodeReading:
        """Mean of ``samples`` (1..255) photodiode readings and its standard uncertainty (relative units).

        Returns a :class:`~gonio.rig.interfaces.PhotodiodeReading`: it unpacks as ``(mean, sem)`` and says
        when the reading was taken. ``uptime`` and ``span`` are the controller's (protocol ≥ 2.1; None from a
        2.0 controller). ``time`` places the middle of the sampling window on this client's Clock: the
        window lies between the request leaving and the reply arriving, so the middle is in
        ``[sent + span/2, received − span/2]``; the controller replies as soon as it has sampled, so
        ``received − span/2`` is taken (too late by the reply's transmission, ~2 ms at 115 200 baud). If the
        exchange needed retries the reading may come from any attempt (a retry is answered from the
        controller's cache), and the middle of the interval from the first send is taken instead. A 2.0
        controller sends no span: ``time`` is then the reply's arrival.
        """
        if isinstance(samples, bool) or not isinstance(samples, int) or not 1 <= samples <= 255:
            raise ConfigError.field(self.device, "photodiode samples", samples, "must be an integer in [1, 255]")
        r = self._transact("READ_PHOTODIODE", samples=samples)
        first, _last, received, attempts = self._exchange_times
        if "time_ms" not in r.values:
            return PhotodiodeReading(r["mean"] * fp.MICRO, r["sem"] * fp.MICRO, samples=r["samples"], time=received)
        span = r["span_us"] * fp.MICRO
        lo, hi = first + span / 2, received - span / 2
        t = hi if attempts == 1 and hi >= lo else (lo + hi) / 2
        return PhotodiodeReading(r["mean"] * fp.MICRO, r["sem"] * fp.MICRO, samples=r["samples"], time=t,
                                 uptime=r["time_ms"] / 1000.0, span=span)

    def trigger_camera(self, exposure: float) -> None:
        """Start a trigger pulse of ``exposure`` seconds (1 µs .. 600 s).

        Returns when the pulse has started; if the previous pulse is still running (on the Clock),
        first waits for its end, so back-to-back triggers never get BUSY.
        """
        us = round(exposure * 1e6) if isinstance(exposure, (int, float)) and math.isfinite(exposure) else -1
        if not 1 <= us <= 600_000_000:
            raise ConfigError.field(self.device, "trigger exposure", exposure, "must be in [1e-6, 600] seconds")
        with self._lock:
            remaining = self._pulse_end - self.clock.now()
            if remaining > 0:
                self.clock.sleep(remaining)
            self._transact("TRIGGER", exposure_us=us)
            self._pulse_end = self.clock.now() + us * fp.MICRO

    def status(self) -> ControllerStatus:
        """E-stop, interlock, light, temperature, uptime; ``flags`` holds all SPEC.md status bits; the cause of the
        controller's last reset (protocol ≥ 2.2, else None).

        A controller that reset since the handshake answers STATUS (NOT_CONFIGURED set, the 2.0 payload: it no
        longer knows this host's version, SPEC.md §3): the client then re-handshakes and restores the watchdog
        period and the light, as after NOT_READY, and returns the status read after that (with its reset cause)."""
        with self._lock:
            r = self._transact("STATUS")
            if r["flags"] & fp.FLAG_NOT_CONFIGURED and self.info is not None and not self._recovering:
                self._recover_reset()
                r = self._transact("STATUS")
        f = r["flags"]
        cause = r.values.get("reset_cause")
        return ControllerStatus(estop=bool(f & fp.FLAG_ESTOP), interlock_open=bool(f & fp.FLAG_INTERLOCK_OPEN),
                                light_on=bool(f & fp.FLAG_LIGHT_ON), light_level=r["level"] / fp.LEVEL_FULL_SCALE,
                                temperature_c=r["temperature"] / 100.0, uptime_s=r["uptime_ms"] / 1000.0, flags=f,
                                reset_cause=None if cause is None else fp.RESET_CAUSES.get(cause, f"code {cause}"))

    def heartbeat(self) -> None:
        """Feed the controller's watchdog."""
        self._transact("HEARTBEAT")

    def wait(self, seconds: float) -> None:
        """Sleep ``seconds`` on the Clock while keeping the watchdog fed: a heartbeat between steps of at most
        period/2, and after the last step only if the last request this client sent is more than period/2
        ago (a settle of a fraction of a second right after a request needs none: the controller's silence
        when this returns is at most period/2 either way, as after any request)."""
        step = self.watchdog / 2.0
        end = self.clock.now() + max(0.0, float(seconds))
        for _ in range(int(math.ceil(max(0.0, seconds) / step)) + 1):  # bounded
            left = end - self.clock.now()
            if left <= 0:
                break
            self.clock.sleep(min(step, left))
            if left > step or self.clock.now() - self._fed > step:
                self.heartbeat()

    def set_watchdog(self, seconds: float) -> None:
        """Change the controller's watchdog period (0.1 .. 3600 s)."""
        ms = round(seconds * 1000) if isinstance(seconds, (int, float)) and math.isfinite(seconds) else -1
        if not fp.WATCHDOG_MIN_MS <= ms <= fp.WATCHDOG_MAX_MS:
            raise ConfigError.field(self.device, "watchdog", seconds, "must be in [0.1, 3600] seconds")
        with self._lock:
            self._transact("SET_WATCHDOG", period_ms=ms)
            self.watchdog = ms / 1000.0

    def close(self) -> None:
        """Switch the light off if the controller answers, then release the port (idempotent)."""
        if self._port is None:
            return
        try:
            if self.info is not None:
                self._transact("SET_LIGHT", on=0, level=0)
        except Exception:  # noqa: BLE001 - closing must release the port whatever the device does
            pass
        finally:
            self._port.close()
            self._port = None

    # -- transport --------------------------------------------------------------------------------
    def _transact(self, name: str, **values: int) -> fp.Message:
        code, payload = fp.pack_payload(name, values)
        with self._lock:
            if self._port is None:
                raise ConfigError.field(self.device, "port", None, "controller is closed")
            for _ in range(2):  # second pass only after recovering from a controller reset
                self._seq = (self._seq + 1) & 0xFF
                try:
                    reply = self._exchange(name, code, self._seq, fp.encode_frame(code, self._seq, payload))
                except OSError as exc:  # pyserial's SerialException too: the board unplugged or powered off
                    raise HardwareError(f"{self.device}: {name}: serial link lost ({exc}); the controller "
                                        "unplugged or powered off?", device=self.device) from None
                if reply.name != "ERROR":
                    return reply
                err = reply["code"]
                if err == fp.ERR_NOT_READY and name != "HELLO" and self._recover_reset():
                    continue
                what = fp.ERROR_NAMES.get(err, f"0x{err:02X}")
                if err == fp.ERR_ESTOP:  # say what a person must do, not the wire's error name
                    raise EmergencyStop(f"{self.device}: E-stop pressed or enclosure interlock open ({name} refused)",
                                        device=self.device, code=err)
                if err == fp.ERR_OVERTEMP:
                    raise SafetyStop(f"{self.device}: light source over its temperature limit ({name} refused): "
                                     "let it cool", device=self.device, code=err)
                raise ControllerError(f"{self.device}: {name} refused: {what} (code {err})", device=self.device,
                                      code=err)
            raise ControllerError(f"{self.device}: {name} refused: NOT_READY again after re-handshake",
                                  device=self.device, code=fp.ERR_NOT_READY)

    def _recover_reset(self) -> bool:
        if self._recovering:
            return False
        self._recovering = True
        try:
            self.resets_seen += 1
            self.connect()
            on, lvl = self._light
            if on:
                self._transact("SET_LIGHT", on=1, level=lvl)
            return True
        finally:
            self._recovering = False

    def _exchange(self, name: str, code: int, seq: int, wire: bytes) -> fp.Message:
        corrupt = False
        first = None
        for attempt in range(self.retries + 1):
            if attempt:
                self.retry_count += 1
            if attempt or self._needs_flush:
                self._flush()
            sent = self.clock.now()
            first = sent if first is None else first
            self._port.write(wire)
            reply, corrupt = self._await(code, seq)
            self._needs_flush = reply is None
            if reply is not None:
                self._exchange_times = (first, sent, self.clock.now(), attempt + 1)
                self._fed = sent
                return reply
        tries = self.retries + 1
        if corrupt:
            raise ChecksumError(f"{self.device}: corrupted reply to {name} (seq {seq}) on all {tries} attempts",
                                device=self.device)
        raise HardwareTimeout(f"{self.device}: no reply to {name} (seq {seq}) after {tries} attempts "
                              f"of {self.timeout:g} s", device=self.device)

    def _await(self, code: int, seq: int) -> tuple[fp.Message | None, bool]:
        """Read until the reply to (code, seq) arrives or the deadline passes; (reply, saw_corrupt)."""
        deadline = time.monotonic() + self.timeout
        corrupt = False
        while True:
            now = time.monotonic()
            if now >= deadline:
                return None, corrupt
            data = self._port.read(max(1, self._port.in_waiting))
            for ev in self._decoder.feed(data):
                if isinstance(ev, fp.Reject):
                    corrupt = True
                    deadline = min(deadline, time.monotonic() + self.corrupt_grace)
                    continue
                if ev.seq != seq or ev.type not in (code | fp.REPLY_BIT, fp.ERROR):
                    self.stale_replies += 1
                    continue
                try:  # a reset controller answers STATUS before any HELLO with the 2.0 payload (SPEC.md §3)
                    msg = fp.decode_message(ev, None if code == fp.STATUS else self.session_minor)
                except fp.ProtocolError:
                    corrupt = True
                    continue
                if msg.name == "ERROR" and msg["request"] != code:
                    self.stale_replies += 1
                    continue
                return msg, corrupt

    def _flush(self) -> None:
        """Let a late reply arrive, then drop everything buffered (port and decoder)."""
        time.sleep(self.flush_delay)  # real time: this is serial-line timing, not protocol time
        self._port.reset_input_buffer()
        self._decoder.reset()
        self._needs_flush = False


def clear_to_move(ctl) -> None:
    """An EmergencyStop naming the controller's stop reason (E-stop, interlock, over-temperature) before any byte
    that moves a servo; nothing when the rig is clear (``gonio servo move`` and ``gonio servo setup`` ask it)."""
    from gonio.errors import EmergencyStop

    what = ctl.status().stop_reason
    if what:
        raise EmergencyStop(f"{ctl.device}: {what}: nothing was sent to the servo", device=ctl.device)
