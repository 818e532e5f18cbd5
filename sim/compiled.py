"""Which path the simulated camera's per-pixel work takes in a process: numba's compiled kernels
(:func:`sim.sensor_noise.expose_compiled`, :func:`sim.camera.board_points_compiled`,
:func:`sim.camera.shade_board_compiled`) or their NumPy references, which give the same frames bit for bit."""

from __future__ import annotations

import functools
import sys
import time

from sim.sensor_noise import compiled_available

__all__ = ["use_compiled", "pick", "COLD_SECONDS"]


#: What the compiled paths cost a process that has not loaded numba before their first frame: importing numba, its
#: first dispatch (which loads all of numba's implementation registries, and through them scipy.linalg) and the
#: kernels' machine code from numba's disk cache, ~0.35-0.45 CPU s, more than all the frames of a short simulated
#: session take with NumPy (3-8x slower per value than compiled). So a process takes the NumPy paths until they have
#: cost it this much CPU time, then the compiled ones: rent until the rent paid reaches the price, which costs at most
#: twice the better of the two (Karlin et al., "Competitive snoopy caching", Algorithmica 3, 1988; as
#: gonio.io.merl_index.COLD_VALUES). Either path gives the same frames bit for bit.
COLD_SECONDS = 0.4
_NUMPY_SECONDS = [0.0]  #: CPU time the NumPy paths chosen by :func:`pick` took in this process


def _warm() -> bool:
    """numba is loaded in this process (its kernels then load for little)."""
    return "numba" in sys.modules


def use_compiled() -> bool:
    """Whether a frame now takes the compiled paths: numba installed and either loaded already or the NumPy paths
    have taken :data:`COLD_SECONDS` of CPU time in this process."""
    return compiled_available() and (_warm() or _NUMPY_SECONDS[0] >= COLD_SECONDS)


def pick(compiled, reference):
    """``compiled`` if :func:`use_compiled`, else ``reference`` (its bit-for-bit NumPy twin), whose calls' CPU time
    (this thread's) counts toward :data:`COLD_SECONDS`."""
    if use_compiled():
        return compiled

    @functools.wraps(reference)
    def renting(*args, **kw):
        t0 = time.thread_time()
        try:
            return reference(*args, **kw)
        finally:
            _NUMPY_SECONDS[0] += time.thread_time() - t0

    return renting
