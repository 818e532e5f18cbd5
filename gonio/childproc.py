"""Child processes that never outlive their parent.

A child gonio or the simulator starts (the simavr bridge, the firmware's ``make`` runs, a compiler, the
Aravis fake camera, an emulator served as a subprocess, a batch's worker processes) must not keep running —
at a full core, holding a pty or a port — after the Python process that started it died, however it died
(``kill -9`` included, where no ``finally`` and no ``atexit`` runs).

On Linux the kernel does it: ``prctl(PR_SET_PDEATHSIG, SIGKILL)`` (prctl(2)) in the child, between fork and
exec (``preexec_fn``), asks for SIGKILL when the parent dies; the parent may already have died before the
call, so the child then checks ``getppid()`` against the parent's pid and exits (the race prctl(2)'s notes
describe). The signal is tied to the parent *thread* that forked: start children from a thread that lives
as long as they should (gonio starts them from the main thread). Children that can watch their parent
themselves (the simavr bridge reads its stdin, a pipe, and exits at its end) do that too. Elsewhere this is
a no-op.
"""

from __future__ import annotations

import ctypes
import os
import signal
import subprocess
import sys

__all__ = ["die_with_parent", "popen", "run", "worker_init"]

PR_SET_PDEATHSIG = 1  #: <linux/prctl.h>


def _prctl():
    if not sys.platform.startswith("linux"):
        return None
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        return libc.prctl
    except (OSError, AttributeError):  # pragma: no cover - a libc without prctl
        return None


_PRCTL = _prctl()


def die_with_parent(parent_pid: int | None = None, sig: int = signal.SIGKILL):
    """A ``preexec_fn`` that makes the child receive ``sig`` when its parent dies (Linux; else a no-op).

    ``parent_pid``: the parent's pid, taken *before* the fork (default: this process's); if the parent is
    already gone when the child runs this, the child exits at once."""
    parent = os.getpid() if parent_pid is None else int(parent_pid)

    def preexec() -> None:
        if _PRCTL is not None:
            _PRCTL(PR_SET_PDEATHSIG, int(sig), 0, 0, 0)
            if os.getppid() != parent:  # the parent died before prctl: no signal will come
                os._exit(1)

    return preexec


def worker_init() -> None:
    """``initializer`` of a process pool's workers: the worker dies with the process that started it."""
    die_with_parent(os.getppid())()


def popen(args, **kwargs) -> subprocess.Popen:
    """:class:`subprocess.Popen` whose child dies with this process (:func:`die_with_parent`)."""
    kwargs.setdefault("preexec_fn", die_with_parent())
    return subprocess.Popen(args, **kwargs)


def run(args, **kwargs) -> subprocess.CompletedProcess:
    """:func:`subprocess.run` whose child dies with this process (:func:`die_with_parent`)."""
    kwargs.setdefault("preexec_fn", die_with_parent())
    return subprocess.run(args, **kwargs)
