"""Which path the simulated camera's per-pixel work takes in a process: numba's compiled kernels
(:func:`sim.sensor_noise.expose_compiled`, :func:`sim.camera.board_points_compiled`,
:func:`sim.camera.shade_board_compiled`) or their NumPy references, which give the same frames bit for bit."""

from __future__ import annotations

import functools
import sys
import time

from sim import compile_lock
from sim.sensor_noise import compiled_available

__all__ = ["use_compiled", "pick", "expect", "COLD_SECONDS"]


#: What the compiled paths cost a process that has not loaded numba before their first frame: importing numba, its
#: first dispatch (which loads all of numba's implementation registries, and through them scipy.linalg) and the
#: kernels' machine code from numba's disk cache, ~0.35-0.45 CPU s, more than all the frames of a short simulated
#: session take with NumPy (3-8x slower per value than compiled). So a process takes the NumPy paths until they have
#: cost it this much CPU time, then the compiled ones: rent until the rent paid reaches the price, which costs at most
#: twice the better of the two (Karlin et al., "Competitive snoopy caching", Algorithmica 3, 1988; as
#: gonio.io.merl_index.COLD_VALUES). Either path gives the same frames bit for bit.
COLD_SECONDS = 0.4
_NUMPY_SECONDS = [0.0]  #: CPU time the NumPy paths chosen by :func:`pick` took in this process
_BOUGHT = [False]  #: :func:`expect` forecast more than :data:`COLD_SECONDS` of NumPy frames in this process

#: What the NumPy paths cost a simulated session, per value of a frame (its pixels × 3 channels): its dark set (the
#: most, ~25 frames of Poisson values, a dark signal of 0.01-10 e-) and each pose. Measured (CPU s, NumPy paths
#: throughout) on `gonio measure --sim` sessions of 12 and 19 poses at 240x180 and of 19 and 38 poses at 320x240:
#: 0.26, 0.28, 0.47, 0.56 s, i.e. ~1.7 µs and ~21 ns a value.
DARK_SET_SECONDS, POSE_SECONDS = 1.7e-6, 2.1e-8


def expect(frame_values: int, poses: int, sessions: int = 1) -> None:
    """A session of ``poses`` poses with frames of ``frame_values`` values is about to start (or ``sessions`` of them,
    ``poses`` in all, one dark set each, in this process one after another): when its NumPy frames
    would take :data:`COLD_SECONDS` or more (:data:`DARK_SET_SECONDS`, :data:`POSE_SECONDS`), the compiled paths from
    its first frame, instead of renting until the rent paid reaches the price and then buying as well (the forecast
    of ski rental with predictions: Purohit, Svitkina and Kumar, "Improving online algorithms via ML predictions",
    NeurIPS 2018; a forecast of less keeps the rule of :data:`COLD_SECONDS`)."""
    if frame_values * (sessions * DARK_SET_SECONDS + poses * POSE_SECONDS) >= COLD_SECONDS:
        _BOUGHT[0] = True


def _warm() -> bool:
    """numba is loaded in this process (its kernels then load for little)."""
    return "numba" in sys.modules


def use_compiled() -> bool:
    """Whether a frame now takes the compiled paths: numba installed and either loaded already, or the NumPy paths
    have taken :data:`COLD_SECONDS` of CPU time in this process, or :func:`expect` forecast that they would."""
    return compiled_available() and (_warm() or _BOUGHT[0] or _NUMPY_SECONDS[0] >= COLD_SECONDS)


#: The compiled paths this process has taken (their kernels compiled or loaded from numba's cache, or being so).
_STARTED: set = set()


def _compiling_elsewhere(compiled) -> bool:
    """Until this process first takes ``compiled``: whether another process is compiling one of its kernels now
    (``compiled.kernels()``, :func:`sim.compile_lock.busy`). Once taken, a kernel it has not compiled yet (other
    argument types) waits for its lock instead (:func:`sim.compile_lock.serialized`)."""
    if compiled in _STARTED:
        return False
    kernels = getattr(compiled, "kernels", None)
    if kernels is not None and compile_lock.busy(kernels()):
        return True
    _STARTED.add(compiled)
    return False


def pick(compiled, reference):
    """``compiled`` if :func:`use_compiled`, else ``reference`` (its bit-for-bit NumPy twin), whose calls' CPU time
    (this thread's) counts toward :data:`COLD_SECONDS`. ``reference`` too while another process is compiling
    ``compiled``'s kernels before this one has taken it (:func:`_compiling_elsewhere`): one process compiles each,
    the others keep making the same frames with NumPy until numba's cache holds it, then load it from there."""
    if use_compiled() and not _compiling_elsewhere(compiled):
        return compiled

    @functools.wraps(reference)
    def renting(*args, **kw):
        t0 = time.thread_time()
        frame = reference(*args, **kw)  # a call that raises is not counted: the rent is what frames cost
        _NUMPY_SECONDS[0] += time.thread_time() - t0
        return frame

    return renting
