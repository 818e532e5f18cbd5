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
