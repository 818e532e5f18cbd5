"""Simulated time shared by the host code and the emulators.

``sleep(dt)`` advances simulated time by ``dt`` at once (no real waiting), so motion, warm-up and
exposure that take hours in a lab take milliseconds here, while :meth:`now` still reports lab time.
"""

from __future__ import annotations

import threading


class SimClock:
    """A thread-safe simulated clock (implements :class:`gonio.rig.interfaces.Clock`).

    Parameters
    ----------
    start : float
        Simulated time at creation, in seconds.
    """

    simulated = True

    def __init__(self, start: float = 0.0):
        self._t = float(start)
        self._lock = threading.Lock()

    def now(self) -> float:
        """Current simulated time in seconds."""
        with self._lock:
            return self._t

    def sleep(self, seconds: float) -> None:
        """Advance simulated time by ``seconds`` (non-positive values do nothing)."""
        if seconds > 0:
            with self._lock:
                self._t += float(seconds)

    def advance_to(self, t: float) -> None:
        """Advance to absolute time ``t`` if it is in the future (never goes back)."""
        with self._lock:
            self._t = max(self._t, float(t))
