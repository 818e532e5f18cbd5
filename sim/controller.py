"""Emulator of the rig controller: serves ``firmware_protocol`` on a pseudo-terminal.

It is written from ``firmware_protocol/SPEC.md`` and uses only :mod:`firmware_protocol.codec` (never the
host client), so a host/emulator agreement is evidence that both follow the spec. Simulated physics:

* **Light** with warm-up drift: relative radiant intensity
  ``I(t) = L · (1 − d · exp(−(t − t_on)/τ))`` after switch-on at ``t_on`` (level ``L``, depth ``d``,
  time constant ``τ``), the first-order (Newtonian) thermal response of a lamp reaching equilibrium;
  0 when off. :meth:`ControllerEmulator.light_output` exposes it so the simulated camera sees the same
  drift as the photodiode.
* **Photodiode**: each sample is ``g · I(t) + ε``, ``ε ~ N(0, σ²)`` from a seeded generator; the reply
  carries the mean of ``n`` samples and its standard uncertainty ``s/√n`` (``σ`` itself when n = 1).
* **Temperature**: ``T = T_amb + ΔT · L · (1 − exp(−(t − t_on)/τ_th))`` while on, ``T_amb`` when off;
  :meth:`ControllerEmulator.set_heat_sink` pins it (a failed fan, a hot lab). Above ``OVERTEMP_C`` the
  light is cut and OVERTEMP latches until the temperature is below the limit by ``OVERTEMP_HYSTERESIS_C``
  (SPEC.md §4.2), as the firmware does.
* **Watchdog** (SPEC.md §6): silence is measured on the emulator's :class:`Clock` (the SimClock shared
  with the host). Every valid frame feeds it; before handling each frame, on every idle tick (≈50 ms
  real time) and in :meth:`light_output`, the emulator checks ``now − last_valid_frame > period`` and
  if so switches the light off and sets WATCHDOG_TRIPPED. So a host that advances the SimClock past the
  period without a heartbeat finds the light off at its next request, deterministically.
* **Faults**: link faults on replies (:class:`sim.faults.LinkFaults`), plus :meth:`reset` /
  :meth:`inject_reset` (a brown-out that forgets light, watchdog period, handshake and the duplicate
  cache), and the E-stop / interlock inputs (:meth:`set_estop`, :meth:`set_interlock`).
"""

from __future__ import annotations

import math
import threading
from collections import Counter

import numpy as np

from firmware_protocol import codec as fp
from sim.faults import LinkFaults
from sim.pty import PtyServer

ALL_CAPABILITIES = fp.CAP_DIMMING | fp.CAP_PHOTODIODE | fp.CAP_TRIGGER | fp.CAP_TEMPERATURE | fp.CAP_INTERLOCK
FIRMWARE_VERSION = 0x0100
OVERTEMP_C = 70.0
OVERTEMP_HYSTERESIS_C = 5.0  #: OVERTEMP clears below OVERTEMP_C minus this (the firmware's FW_OVERTEMP_HYSTERESIS_CENTI)


class ControllerEmulator(PtyServer):
    """The rig controller on a pty; open :attr:`path` with :class:`gonio.rig.controller.RigController`.

    Parameters
    ----------
    clock : Clock
        Simulated (or real) time shared with the host; the emulator only reads it, never sleeps it.
    faults : LinkFaults, optional
        Faults applied to every reply.
    seed : int
        Seed of the photodiode noise.
    warmup_depth, warmup_tau : float
        Relative output deficit at switch-on (d) and its time constant τ in seconds.
    pd_gain, pd_noise : float
        Photodiode gain g and per-sample noise σ (relative units).
    ambient_c, heating_c, thermal_tau : float
        Temperature model: T_amb, ΔT at full level, τ_th (seconds).
    capabilities, major, minor : int
        What HELLO reports (tests change them to exercise the host's checks; ``minor = 0`` acts as a
        protocol 2.0 controller, whose photodiode replies carry no timestamp).
    """

    def __init__(self, clock, *, faults: LinkFaults | None = None, seed: int = 0, warmup_depth: float = 0.05,
                 warmup_tau: float = 120.0, pd_gain: float = 1.0, pd_noise: float = 0.002, ambient_c: float = 25.0,
                 heating_c: float = 15.0, thermal_tau: float = 600.0, capabilities: int = ALL_CAPABILITIES,
                 major: int = fp.PROTOCOL_MAJOR, minor: int = fp.PROTOCOL_MINOR, name: str = "controller"):
        super().__init__(name, faults)
        self.clock = clock
        self.warmup_depth, self.warmup_tau = float(warmup_depth), float(warmup_tau)
        self.pd_gain, self.pd_noise = float(pd_gain), float(pd_noise)
        self.ambient_c, self.heating_c, self.thermal_tau = float(ambient_c), float(heating_c), float(thermal_tau)
        self.capabilities, self.major, self.minor = int(capabilities), int(major), int(minor)
        self._rng = np.random.default_rng(seed)
        self._lock = threading.RLock()
        self._decoder = fp.Decoder()
        self._estop = False
        self._interlock_open = False
        self.executed: Counter = Counter()  #: requests executed, by message name (duplicates excluded)
        self.duplicates = 0  #: retried requests answered from the duplicate cache
        self.resets = 0
        self.trigger_times: list[float] = []  #: clock times of the trigger pulses since creation
        self._reset_pending = False
        self.heat_sink_c: float | None = None  #: temperature pinned by :meth:`set_heat_sink` (None: the model)
        self._reset_cause = fp.RESET_POWER_ON
        self._power_on()

    # -- state --------------------------------------------------------------------------------
    def _power_on(self) -> None:
        now = self.clock.now()
        self._boot = now
        self._configured = False
        self.session_minor = 0  #: min(host's minor from HELLO, own minor): the fields replies carry
        self._light_on = False
        self._level = 0
        self._on_since = now
        self._watchdog_ms = fp.DEFAULT_WATCHDOG_MS
        self._last_rx = now
        self._tripped = False
        self._overtemp = False
        self._trigger_end = -math.inf
        self._trigger_count = 0
        self._cache: tuple[int, int, bytes, bytes] | None = None  # (type, seq, payload, reply bytes)
        self._decoder.reset()

    def reset(self) -> None:
        """Reset now, forgetting all state (light off, default watchdog, no handshake, empty cache)."""
        with self._lock:
            self.resets += 1
            self._reset_cause = fp.RESET_EXTERNAL
            self._power_on()

    def set_heat_sink(self, celsius: float | None) -> None:
        """Pin the light source's temperature at ``celsius`` (None: back to the thermal model); the controller
        acts on it at its next check (a tick, a request), as it would on its sensor."""
        with self._lock:
            self.heat_sink_c = None if celsius is None else float(celsius)
            self._check_watchdog(self.clock.now())

    def reseed(self, seed) -> None:
        """Restart the photodiode noise generator from ``seed`` (anything ``numpy.random.default_rng``
        takes, e.g. ``[session seed, pose index]``): the readings that follow depend only on the seed,
        the light's state and the requests, not on what was read before."""
        with self._lock:
            self._rng = np.random.default_rng(seed)

    def inject_reset(self) -> None:
        """Reset when the next valid frame arrives, before handling it (a brown-out mid-session)."""
        with self._lock:
            self._reset_pending = True

    def set_estop(self, pressed: bool) -> None:
        """Press or release the E-stop; pressing switches the light off at once."""
        with self._lock:
            self._estop = bool(pressed)
            if pressed:
                self._light_on = False

    def set_interlock(self, open_: bool) -> None:
        """Open or close the enclosure interlock; opening switches the light off at once."""
        with self._lock:
            self._interlock_open = bool(open_)
            if open_:
                self._light_on = False

    # -- models -------------------------------------------------------------------------------
    def _check_watchdog(self, now: float) -> None:
        """The controller's periodic checks: host silence (watchdog) and over-temperature (SPEC.md §4.2, §6)."""
        if self._light_on and now - self._last_rx > self._watchdog_ms / 1000.0:
            self._light_on = False
            self._tripped = True
        t = self._temperature(now)
        if t > OVERTEMP_C:
            self._overtemp = True
        elif t < OVERTEMP_C - OVERTEMP_HYSTERESIS_C:
            self._overtemp = False
        if self._overtemp:
            self._light_on = False

    def _output(self, now: float) -> float:
        if not self._light_on:
            return 0.0
        lvl = self._level / fp.LEVEL_FULL_SCALE
        return lvl * (1.0 - self.warmup_depth * math.exp(-(now - self._on_since) / self.warmup_tau))

    def _temperature(self, now: float) -> float:
        if self.heat_sink_c is not None:
            return self.heat_sink_c
        if not self._light_on:
            return self.ambient_c
        lvl = self._level / fp.LEVEL_FULL_SCALE
        return self.ambient_c + self.heating_c * lvl * (1.0 - math.exp(-(now - self._on_since) / self.thermal_tau))

    def light_output(self) -> float:
        """True relative radiant intensity of the light now (0 when off), after the watchdog check."""
        with self._lock:
            now = self.clock.now()
            self._check_watchdog(now)
            return self._output(now)

    @property
    def light_on(self) -> bool:
        with self._lock:
            self._check_watchdog(self.clock.now())
            return self._light_on

    @property
    def watchdog_period(self) -> float:
        """Current watchdog period in seconds."""
        return self._watchdog_ms / 1000.0

    # -- protocol -----------------------------------------------------------------------------
    def on_idle(self) -> None:
        with self._lock:
            self._check_watchdog(self.clock.now())

    def on_bytes(self, data: bytes) -> None:
        with self._lock:
            events = self._decoder.feed(data)
        for ev in events:
            if isinstance(ev, fp.Frame):  # corrupted segments are dropped silently (SPEC.md §5)
                reply = self._handle(ev)
                if reply:
                    self.send(reply)

    def _handle(self, frame: fp.Frame) -> bytes | None:
        with self._lock:
            if self._reset_pending:
                self._reset_pending = False
                self.resets += 1
                self._reset_cause = fp.RESET_BROWN_OUT
                self._power_on()
            now = self.clock.now()
            self._check_watchdog(now)
            self._last_rx = now
            if frame.type & fp.REPLY_BIT:
                return None  # replies are never answered
            c = self._cache
            # only a non-idempotent request is answered from the cache; any other is executed again, so its
            # reply says what holds now (a retried SET_LIGHT after an E-stop cut gets ESTOP) (SPEC.md §5)
            if (c is not None and frame.type in fp.NON_IDEMPOTENT
                    and (c[0], c[1], c[2]) == (frame.type, frame.seq, frame.payload)):
                self.duplicates += 1
                return c[3]
            reply = self._execute(frame, now)
            if frame.type == fp.HELLO:
                self._cache = None
            else:
                self._cache = (frame.type, frame.seq, frame.payload, reply)
            return reply

    def _error(self, frame: fp.Frame, code: int) -> bytes:
        return fp.encode_message("ERROR", frame.seq, code=code, request=frame.type)

    def _execute(self, frame: fp.Frame, now: float) -> bytes:
        try:
            msg = fp.decode_message(frame)
        except fp.ProtocolError:
            known = frame.type in fp.MESSAGES
            return self._error(frame, fp.ERR_BAD_LENGTH if known else fp.ERR_UNKNOWN_TYPE)
        if fp.check_ranges(msg) is not None:
            return self._error(frame, fp.ERR_BAD_VALUE)
        if not self._configured and frame.type not in (fp.HELLO, fp.STATUS):
            return self._error(frame, fp.ERR_NOT_READY)
        v, seq = msg.values, frame.seq
        reply_name = msg.name + "_REPLY"
        if frame.type == fp.HELLO:
            if v["major"] != self.major:
                return self._error(frame, fp.ERR_VERSION)
            self._configured = True
            self.session_minor = min(v["minor"], self.minor)
            out = dict(major=self.major, minor=self.minor, capabilities=self.capabilities,
                       firmware=FIRMWARE_VERSION, max_payload=fp.MAX_PAYLOAD, watchdog_ms=self._watchdog_ms)
        elif frame.type == fp.HEARTBEAT:
            out = {}
        elif frame.type == fp.SET_LIGHT:
            if v["on"]:
                if self._estop or self._interlock_open:
                    return self._error(frame, fp.ERR_ESTOP)
                if self._overtemp:  # evaluated by _check_watchdog just before this frame
                    return self._error(frame, fp.ERR_OVERTEMP)
                if not self._light_on:
                    self._on_since = now
                self._light_on, self._level, self._tripped = True, v["level"], False
            else:
                self._light_on = False
            out = dict(on=int(self._light_on), level=v["level"])
        elif frame.type == fp.READ_PHOTODIODE:
            n = v["samples"]
            x = self.pd_gain * self._output(now) + self._rng.normal(0.0, self.pd_noise, n)
            sem = x.std(ddof=1) / math.sqrt(n) if n > 1 else self.pd_noise
            # all n samples are taken at this instant of the Clock: span 0, time = uptime now (SPEC.md §4.4)
            out = dict(samples=n, mean=_u32(x.mean() / fp.MICRO), sem=_u32(sem / fp.MICRO),
                       time_ms=_u32((now - self._boot) * 1000), span_us=0)
        elif frame.type == fp.TRIGGER:
            if now < self._trigger_end:
                return self._error(frame, fp.ERR_BUSY)
            self._trigger_end = now + v["exposure_us"] * fp.MICRO
            self._trigger_count += 1
            self.trigger_times.append(now)
            out = dict(exposure_us=v["exposure_us"], count=self._trigger_count)
        elif frame.type == fp.STATUS:
            out = dict(flags=self._flags(now), level=self._level if self._light_on else 0,
                       temperature=int(round(self._temperature(now) * 100)),
                       uptime_ms=_u32((now - self._boot) * 1000), watchdog_ms=self._watchdog_ms,
                       reset_cause=self._reset_cause)
        elif frame.type == fp.SET_WATCHDOG:
            self._watchdog_ms = v["period_ms"]
            out = dict(period_ms=self._watchdog_ms)
        else:  # a request type in the catalogue without a handler would be a bug of this emulator
            return self._error(frame, fp.ERR_UNKNOWN_TYPE)
        self.executed[msg.name] += 1
        return fp.encode_message(reply_name, seq, session_minor=self.session_minor, **out)

    def _flags(self, now: float) -> int:
        flags = 0
        for cond, bit in ((self._estop, fp.FLAG_ESTOP), (self._interlock_open, fp.FLAG_INTERLOCK_OPEN),
                          (self._light_on, fp.FLAG_LIGHT_ON), (self._tripped, fp.FLAG_WATCHDOG_TRIPPED),
                          (not self._configured, fp.FLAG_NOT_CONFIGURED),
                          (self._overtemp, fp.FLAG_OVERTEMP),
                          (now < self._trigger_end, fp.FLAG_TRIGGER_ACTIVE)):
            if cond:
                flags |= bit
        return flags


def _u32(x: float) -> int:
    """Round and clamp to the u32 wire range."""
    return int(min(max(round(x), 0), 0xFFFFFFFF))


def main(argv=None) -> int:  # pragma: no cover - interactive tool
    """Serve the emulator on a pty in real time and print its path (try ``gonio controller`` on it)."""
    import argparse

    from gonio.rig.clock import RealClock

    ap = argparse.ArgumentParser(prog="python -m sim.controller",
                                 description="Serve the emulated rig controller on a pty (real time).")
    ap.add_argument("--seconds", type=float, default=3600.0, help="serve this long, then exit")
    ap.add_argument("--estop", action="store_true", help="start with the E-stop pressed")
    ap.add_argument("--seed", type=int, default=0, help="photodiode noise seed")
    args = ap.parse_args(argv)
    emu = ControllerEmulator(RealClock(), seed=args.seed)
    emu.set_estop(args.estop)
    emu.serve_interactively(args.seconds)
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
