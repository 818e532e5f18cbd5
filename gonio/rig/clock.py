"""Clocks: hardware code asks a :class:`~gonio.rig.interfaces.Clock` for time, never ``time`` directly.

:class:`RealClock` sleeps for real. The simulated clock (``sim.clock.SimClock``) advances simulated
time at once, so a session that takes hours on a rig takes seconds in CI and still reports lab time.
"""

from __future__ import annotations

import time


class RealClock:
    """Wall-clock time from :func:`time.monotonic`; :meth:`sleep` really sleeps."""

    simulated = False

    def now(self) -> float:
        """Seconds since an arbitrary origin (monotonic)."""
        return time.monotonic()

    def sleep(self, seconds: float) -> None:
        """Block for ``seconds`` (non-positive values return at once)."""
        if seconds > 0:
            time.sleep(seconds)
