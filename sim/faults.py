"""Fault injection on a simulated serial link: dropped, corrupted, delayed and garbage-prefixed replies.

Faults are either random (rates, drawn from a seeded generator, so a run is reproducible) or
scheduled one-shot (:meth:`LinkFaults.inject_next`), which tests use to cause exactly one fault.
Delays are in *real* seconds: they exercise the host's real-time serial timeouts.
"""

from __future__ import annotations

import threading
from collections import deque
from dataclasses import dataclass, field

import numpy as np

KINDS = ("drop", "corrupt", "delay", "garbage", "truncate", "short")


@dataclass
class LinkFaults:
    """Random and scheduled faults applied to each reply an emulator sends.

    Attributes
    ----------
    drop_rate, corrupt_rate, delay_rate, garbage_rate, truncate_rate : float
        Probability per reply of: no reply at all; one bit flipped; reply sent ``delay_s`` late;
        random bytes sent before the reply; reply cut short.
    short_rate : float
        Probability of a reply that is *well formed but short*: re-framed by the emulator with fewer
        parameter bytes and a valid checksum (:meth:`apply`'s ``reframe``), so only a receiver that checks
        the length against its request notices; without ``reframe`` it is truncated.
    delay_s : float
        Lateness of a delayed reply, real seconds.
    seed : int
        Seed of the generator that draws random faults.
    """

    drop_rate: float = 0.0
    corrupt_rate: float = 0.0
    delay_rate: float = 0.0
    garbage_rate: float = 0.0
    truncate_rate: float = 0.0
    short_rate: float = 0.0
    delay_s: float = 0.25
    seed: int = 0
    _queue: deque = field(default_factory=deque, repr=False)
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)
    counts: dict = field(default_factory=lambda: {k: 0 for k in KINDS})

    def __post_init__(self):
        self._rng = np.random.default_rng(self.seed)

    def reseed(self, seed) -> None:
        """Restart the generator of random faults from ``seed`` (a Generator or anything
        ``numpy.random.default_rng`` takes; :meth:`sim.rig.SimRig.begin_pose` gives each pose its own)."""
        with self._lock:
            self._rng = np.random.default_rng(seed)

    def inject_next(self, kind: str, times: int = 1) -> None:
        """Apply fault ``kind`` (one of :data:`KINDS`) to the next ``times`` replies."""
        if kind not in KINDS:
            raise ValueError(f"unknown fault kind {kind!r}; known: {', '.join(KINDS)}")
        with self._lock:
            self._queue.extend([kind] * times)

    def can_fail(self) -> bool:
        """Whether any reply may still be lost, late or damaged: a fault rate above zero or a fault queued."""
        with self._lock:
            queued = bool(self._queue)
        return queued or any(getattr(self, f"{k}_rate") > 0 for k in ("drop", "corrupt", "delay", "garbage",
                                                                       "truncate", "short"))

    def _draw(self) -> str | None:
        with self._lock:
            if self._queue:
                return self._queue.popleft()
            u = self._rng.random()
        for kind, rate in (("drop", self.drop_rate), ("corrupt", self.corrupt_rate), ("delay", self.delay_rate),
                           ("garbage", self.garbage_rate), ("truncate", self.truncate_rate),
                           ("short", self.short_rate)):
            if u < rate:
                return kind
            u -= rate
        return None

    def apply(self, reply: bytes, reframe=None) -> tuple[float, bytes] | None:
        """Decide the fate of ``reply``: ``None`` (dropped) or ``(delay_seconds, bytes_to_send)``.
        ``reframe(reply, keep)`` rebuilds a reply with only ``keep`` of its payload bytes (for ``short``)."""
        kind = self._draw()
        if kind is None or not reply:
            return 0.0, reply
        self.counts[kind] += 1
        if kind == "drop":
            return None
        if kind == "delay":
            return self.delay_s, reply
        with self._lock:
            if kind == "corrupt":
                b = bytearray(reply)
                i = int(self._rng.integers(len(b)))
                b[i] ^= 1 << int(self._rng.integers(8))
                return 0.0, bytes(b)
            if kind == "short" and reframe is not None:
                short = reframe(reply, self._rng)
                if short is not None:
                    return 0.0, short
            if kind == "garbage":
                return 0.0, self._rng.integers(0, 256, int(self._rng.integers(1, 8)), dtype=np.uint8).tobytes() + reply
            return 0.0, reply[: int(self._rng.integers(len(reply)))]  # truncate


FRAME_KINDS = ("black", "stale", "saturated", "wrong_size", "nan", "timeout")


@dataclass
class FrameFaults:
    """Faults of the simulated camera, applied to each frame it returns (:meth:`apply`).

    ``black``: every pixel at the black level (a lens cap, a dead trigger, a light that did not fire);
    ``stale``: the previous frame returned again (a driver that hands out an old buffer); ``saturated``:
    every pixel at full scale; ``wrong_size``: the frame cropped to half its height; ``nan``: float
    pixels holding NaN (a broken conversion); ``timeout``: no frame, :class:`~gonio.errors.HardwareTimeout`.
    Random (per-frame rates from a generator that :meth:`sim.rig.SimRig.begin_pose` reseeds per pose) or
    scheduled (:meth:`inject_next`). :meth:`from_spec` reads ``"black=0.05,stale=0.01"`` (the CLI's
    ``--sim-frame-faults``) or ``"black=1"`` (every frame).
    """

    rates: dict = field(default_factory=dict)
    seed: int = 0
    _queue: deque = field(default_factory=deque, repr=False)
    counts: dict = field(default_factory=lambda: {k: 0 for k in FRAME_KINDS})

    def __post_init__(self):
        unknown = set(self.rates) - set(FRAME_KINDS)
        if unknown:
            raise ValueError(f"unknown frame fault {sorted(unknown)[0]!r}; known: {', '.join(FRAME_KINDS)}")
        self._rng = np.random.default_rng(self.seed)
        self._last = None

    @classmethod
    def from_spec(cls, spec: str, seed: int = 0) -> "FrameFaults":
        """``"kind=rate,kind=rate"`` (rates in [0, 1]); ValueError naming the bad part."""
        rates = {}
        for part in filter(None, (p.strip() for p in str(spec or "").split(","))):
            kind, _, value = part.partition("=")
            try:
                rate = float(value)
            except ValueError:
                raise ValueError(f"frame fault {part!r}: expected KIND=RATE") from None
            if kind not in FRAME_KINDS or not 0.0 <= rate <= 1.0:
                raise ValueError(f"frame fault {part!r}: KIND one of {', '.join(FRAME_KINDS)}, RATE in [0, 1]")
            rates[kind] = rate
        return cls(rates=rates, seed=seed)

    def reseed(self, seed) -> None:
        self._rng = np.random.default_rng(seed)

    def inject_next(self, kind: str, times: int = 1) -> None:
        if kind not in FRAME_KINDS:
            raise ValueError(f"unknown frame fault {kind!r}; known: {', '.join(FRAME_KINDS)}")
        self._queue.extend([kind] * times)

    def _draw(self) -> str | None:
        if self._queue:
            return self._queue.popleft()
        if not self.rates:
            return None
        u = self._rng.random()
        for kind in FRAME_KINDS:
            rate = self.rates.get(kind, 0.0)
            if u < rate:
                return kind
            u -= rate
        return None

    def apply(self, capture):
        """The frame ``capture()`` returns, or its faulty version (or a timeout)."""

        from gonio.errors import HardwareTimeout

        kind = self._draw()
        if kind == "timeout":
            self.counts[kind] += 1
            raise HardwareTimeout("sim camera: no frame within the capture timeout", device="sim-camera")
        frame = capture()
        out = self._fault(kind, frame)
        self._last = out  # what the host received: a stale frame repeats exactly this
        return out

    def _fault(self, kind, frame):
        import dataclasses

        if kind is None:
            return frame
        self.counts[kind] += 1
        px = frame.pixels
        if kind == "stale" and self._last is not None:
            return dataclasses.replace(self._last, timestamp=frame.timestamp)
        if kind == "black":
            px = np.full_like(px, int(frame.black_level))
        elif kind == "saturated":
            px = np.full_like(px, (1 << frame.bit_depth) - 1)
        elif kind == "wrong_size":
            px = px[: px.shape[0] // 2].copy()
        elif kind == "nan":
            px = np.full(px.shape, np.nan, dtype=np.float32)
        return dataclasses.replace(frame, pixels=px)
