"""One process at a time compiles each of the simulator's numba kernels: several gonio processes on one machine (a
lab's batch, a notebook and a CLI, a test run's workers and the `gonio` processes they start) that reach a kernel
before numba's disk cache holds it no longer all compile it at once (~1-3 CPU s each for the sensor chain's
kernels), each only to write the same cache.

Each kernel (a numba dispatcher with ``cache=True``) has a lock file beside its cache (``<module>.<name>.compile-lock``
in the dispatcher's cache directory). :func:`serialized` makes its compilations, which numba's dispatcher starts
when a call's argument types have no machine code yet in the process (``Dispatcher._compile_for_args``: the cache is
read there too), hold the lock (``flock``, exclusive): a second process that needs the kernel meanwhile waits for
it, without using the CPU, and then loads the first one's machine code from the cache. :func:`busy` tells a caller
that can do without the kernel (:func:`sim.compiled.pick`: the NumPy paths give the same frames bit for bit) that
another process is compiling it now, so that it keeps using those instead of waiting.

A lock is the kernel's own, never the module's or the cache's (a process compiling one kernel does not hold up
another), and is held only while numba compiles or loads one kernel, which calls no other locked kernel: no process
holds one lock while it waits for another, so no deadlock. An ``flock`` is released by the kernel when its process
ends, however it ends (a killed compiler does not stop the others compiling). Where there is no lock to take (no
``fcntl``, a dispatcher without a disk cache, a lock file that cannot be opened: an unwritable cache directory) a
kernel compiles as numba does by itself. The BRDF's kernels (gonio.brdf.compiled) are not served this way: their
NumPy twins may differ in the last bits, so a result would depend on which process compiled first."""

from __future__ import annotations

import contextlib
import os
import threading

try:
    import fcntl
except ImportError:  # no flock (Windows): every process compiles for itself, as numba does
    fcntl = None

__all__ = ["serialized", "busy", "lock_path"]

_FILES: dict[str, object] = {}  #: lock path -> this process's open lock file (None: it cannot be opened)
_THREADS: dict[str, threading.Lock] = {}  #: lock path -> the lock of this process's threads (flock is per file)
_GUARD = threading.Lock()


def lock_path(kernel) -> str | None:
    """The lock file of ``kernel`` (a numba dispatcher): in its cache directory, named after its function; None for
    a dispatcher without a disk cache."""
    cache = getattr(getattr(kernel, "stats", None), "cache_path", None)
    if fcntl is None or not cache:
        return None
    f = kernel.py_func
    return os.path.join(cache, f"{f.__module__}.{f.__qualname__}.compile-lock")


def _lock(path: str):
    """``(file, thread lock)`` of ``path`` in this process (the file opened once and kept); file None where it cannot
    be opened."""
    with _GUARD:
        if path not in _FILES:
            try:
                os.makedirs(os.path.dirname(path), exist_ok=True)
                _FILES[path] = open(path, "a")
            except OSError:
                _FILES[path] = None
            _THREADS[path] = threading.Lock()
        return _FILES[path], _THREADS[path]


@contextlib.contextmanager
def _held(path: str):
    f, threads = _lock(path)
    with threads:
        if f is None:
            yield
            return
        try:
            fcntl.flock(f, fcntl.LOCK_EX)
        except OSError:  # a filesystem without locks: as numba does by itself
            yield
            return
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)


def serialized(kernel):
    """``kernel`` (a numba dispatcher), its compilations (and loads from the cache) each holding its lock; returned."""
    path = lock_path(kernel)
    if path is not None:
        compile_for_args = kernel._compile_for_args

        def _compile_for_args(*args, **kw):
            with _held(path):
                return compile_for_args(*args, **kw)

        kernel._compile_for_args = _compile_for_args  # numba's dispatcher looks it up on the instance
    return kernel


def busy(kernels) -> bool:
    """Whether one of ``kernels`` (numba dispatchers) is being compiled now by another process (or another thread of
    this one): its lock is held. Takes no lock for longer than it takes to ask."""
    for kernel in kernels:
        path = lock_path(kernel)
        if path is None:
            continue
        f, threads = _lock(path)
        if not threads.acquire(blocking=False):
            return True
        try:
            if f is None:
                continue
            try:
                fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                return True
            except OSError:
                continue
            fcntl.flock(f, fcntl.LOCK_UN)
        finally:
            threads.release()
    return False
