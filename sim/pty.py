"""Serve a byte-level device protocol on a pseudo-terminal.

The host opens :attr:`PtyServer.path` (``/dev/pts/N``) exactly as it would open a USB serial
adapter, so the real client code (pyserial, dynamixel-sdk) runs unchanged. Facts this relies on
(FIELD-NOTES.md): the slave is put in raw mode and the server keeps the slave fd open, otherwise
reading the master raises EIO once the client closes the port; baud rates are not paced on a pty.
"""

from __future__ import annotations

import os
import select
import threading
import time
import tty

from sim.faults import LinkFaults


#: Linux ``TCGETS2`` ioctl (asm-generic/ioctls.h: ``_IOR('T', 0x2A, struct termios2)``, 44 bytes), as pyserial uses.
_TCGETS2 = 0x802C542A


class PtyServer:
    """Base class of the emulators: a reader thread passes incoming bytes to :meth:`on_bytes`;
    replies go out through :meth:`send`, which applies the link's :class:`LinkFaults`; the replies
    made while handling one read go out in one write (a sync read's status packets together).

    Subclasses implement :meth:`on_bytes`. Use as a context manager or call :meth:`start` and
    :meth:`stop`.
    """

    def __init__(self, name: str = "device", faults: LinkFaults | None = None):
        self.name = name
        self.faults = faults or LinkFaults()
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        tty.setraw(self._master)
        self.path = os.ttyname(self._slave)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._write_lock = threading.Lock()
        self.silent = False  #: when True the device receives but never answers (unplugged / powered off)
        self.bytes_in = 0
        self.bytes_out = 0
        #: replies made while handling one read from the host, written together when it is handled (one
        #: write instead of one per reply: fewer wake-ups of the host; same bytes, same order)
        self._pending: list[bytes] | None = None
        self._loop_ident: int | None = None

    #: The reply deadline (real seconds) a host's driver gets from :attr:`reply_timeout` on a link without faults.
    FAULTLESS_REPLY_TIMEOUT = 5.0

    @property
    def reply_timeout(self) -> float | None:
        """The reply deadline (real seconds) a host's driver should use with this emulator, or None for the
        driver's own default. An emulator answers at once on this machine, so without link faults
        (:meth:`sim.faults.LinkFaults.can_fail`) only the machine's load makes a reply late; a driver that then
        times out retries, and a retried request is executed again (SPEC.md section 5: a new photodiode reading,
        new noise) or, after the last retry, stops the pose for a recovery — so a seeded session would depend on
        the load (a SIGKILL-and-resume test's pose differed from the uninterrupted run's under load ~15). A
        generous deadline costs nothing where no reply is ever lost. On a faulty link: None, so the driver's
        retries run at their real pace (what fault tests exercise)."""
        return None if self.faults.can_fail() else self.FAULTLESS_REPLY_TIMEOUT

    # -- lifecycle ----------------------------------------------------------------------------
    def start(self) -> "PtyServer":
        if self._thread is None:
            self._thread = threading.Thread(target=self._loop, name=f"pty-{self.name}", daemon=True)
            self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        for fd in (self._master, self._slave):
            try:
                os.close(fd)
            except OSError:
                pass

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()

    def serve_interactively(self, seconds: float) -> None:  # pragma: no cover - interactive tool
        """Start, print :attr:`path` (for the command-line tools to open) and serve for ``seconds``
        of real time or until Ctrl-C, then stop. Used by ``python -m sim.servo_bus`` / ``sim.controller``."""
        import time

        with self:
            print(self.path, flush=True)
            deadline = time.monotonic() + seconds
            try:
                while time.monotonic() < deadline:
                    time.sleep(0.2)
            except KeyboardInterrupt:
                pass

    def line_baud(self) -> int | None:
        """The rate (bits/s) the host set on its end of the line, from the pty's termios (``TCGETS2``: the
        kernel keeps the rate pyserial set, standard or custom, e.g. 4,500,000); None where it cannot be read.
        A pty does not pace bytes by it (FIELD-NOTES.md); an emulator uses it to decide who hears a packet."""
        import array
        import fcntl

        buf = array.array("I", [0] * 16)  # struct termios2: 4 flags, c_line + c_cc[19], c_ispeed, c_ospeed
        try:
            fcntl.ioctl(self._slave, _TCGETS2, buf)
        except OSError:
            return None
        return int(buf[10]) or None

    # -- I/O ----------------------------------------------------------------------------------
    def _loop(self) -> None:
        self._loop_ident = threading.get_ident()
        while not self._stop.is_set():
            try:
                ready, _, _ = select.select([self._master], [], [], 0.05)
                if not ready:
                    self.on_idle()
                    continue
                data = os.read(self._master, 4096)
            except OSError:
                if self._stop.is_set():
                    return
                time.sleep(0.01)
                continue
            if data:
                self.bytes_in += len(data)
                self._pending = []
                try:
                    self.on_bytes(data)
                finally:
                    out, self._pending = b"".join(self._pending), None
                    if out:
                        self._write(out)

    def on_bytes(self, data: bytes) -> None:  # pragma: no cover - abstract
        """Handle bytes from the host (called on the reader thread)."""
        raise NotImplementedError

    #: ``reframe(reply, rng) -> bytes | None``: a well-formed but shorter reply (the ``short`` link fault);
    #: None: the protocol has no such notion and ``short`` faults truncate.
    reframe = None

    def on_idle(self) -> None:
        """Called about every 50 ms of real time when no bytes arrive (watchdogs, timers)."""

    def send(self, reply: bytes, *, faults: bool = True) -> None:
        """Send ``reply`` to the host, through the link faults unless ``faults`` is False."""
        if self.silent or not reply:
            return
        fate = self.faults.apply(reply, self.reframe) if faults else (0.0, reply)
        if fate is None:
            return
        delay, data = fate
        if delay <= 0 and self._pending is not None and threading.get_ident() == self._loop_ident:
            self._pending.append(data)  # replies to one read go out in one write (see _loop)
        elif delay > 0:
            timer = threading.Timer(delay, self._write, args=(data,))
            timer.daemon = True
            timer.start()
        else:
            self._write(data)

    def _write(self, data: bytes) -> None:
        with self._write_lock:
            view = memoryview(data)
            while view:
                try:
                    n = os.write(self._master, view)
                except BlockingIOError:
                    time.sleep(0.001)
                    continue
                except OSError:
                    return  # closed
                self.bytes_out += n
                view = view[n:]
