"""Is there a signal in a lit frame? Black, all-saturated and stale (repeated) frames are refused before use.

:func:`gonio.pipeline.hdr.check_frame` checks what a frame *is* (dtype, shape, bit depth, metadata); this
module checks what it *shows*: every lit frame of a pose holds the white reference and the ChArUco board,
so a frame whose brightest pixels are at the black level (within the read noise) saw no light (a lens cap,
a light that did not fire, a trigger that came too early); a frame at full scale nearly everywhere saw
nothing but overload; and a frame bit-for-bit equal to the previous one is a driver handing out an old
buffer (two exposures of a real sensor never agree in every pixel: shot and read noise). Any of these is
a :class:`FrameSignalError` (a :class:`~gonio.pipeline.hdr.BadFrame`): the pipeline retakes the frame a
bounded number of times, then the session runner flags the pose instead of storing a wrong sample.

Dark frames (light off) are black by design and are not checked here; metering frames are checked for
repeats, and for black only against a dark frame of their exposure (a dim or saturated metering frame is
what re-metering is for; without a dark frame "black" and "dim" cannot be told apart). The bracket's
frames, which the metering put in range, get every check.
"""

from __future__ import annotations

import math
import weakref

import numpy as np

from gonio.pipeline.hdr import BadFrame

__all__ = ["FrameSignalError", "SignalCheck", "BLACK_SIGMAS", "SATURATED_FRACTION"]

#: A lit frame is black if not one pixel is more than this many dark-noise standard deviations (EMVA 1288
#: temporal dark noise, from the calibration's noise model) above the black level: read noise alone reaches
#: ~4.5 σ in a megapixel, so this is "no photon anywhere", not "dim" (a dim pose is re-metered instead).
BLACK_SIGMAS = 6.0
#: A frame is all-saturated if at least this fraction of its pixels is at the linear limit.
SATURATED_FRACTION = 0.98
#: Dark frames whose black thresholds :class:`SignalCheck` keeps (more than an exposure ladder has rungs).
DARK_THRESHOLDS_KEPT = 16


class FrameSignalError(BadFrame):
    """A lit frame without a usable signal: black, all-saturated or a repeat of the previous frame."""


class SignalCheck:
    """Checks lit frames one after another (it remembers the previous frame's digest to catch repeats).

    ``noise`` is the calibration's :class:`~gonio.pipeline.target.NoiseModel` (its dark noise sets the black
    threshold); ``limit(frame)`` the largest raw value on the linear response.
    """

    def __init__(self, noise, limit):
        self.noise, self.limit = noise, limit
        self._last: np.ndarray | None = None  # a copy of the previous frame's pixels (bytes compared: exact)
        #: black thresholds per (dark frame, gain): a bracket alternates between its exposures' dark frames
        self._dark_thr: dict[tuple[int, float], tuple] = {}
        self._sat_thr: tuple | None = None  #: (dtype, shape, threshold) and its image (_count_at_or_above)

    def _is_repeat(self, px: np.ndarray) -> bool:
        """Whether ``px`` is bit for bit the previous frame, and remember it. A copy is kept (a driver may hand
        out the same buffer again, refilled or not); comparing bytes costs less than hashing them."""
        cur = np.ascontiguousarray(px)
        last = self._last
        # the first row first: two exposures differ there (noise), so the whole frame is compared only when it agrees
        same = (last is not None and last.shape == cur.shape and last.dtype == cur.dtype
                and np.array_equal(last[:1].view(np.uint8), cur[:1].view(np.uint8))
                and np.array_equal(last.view(np.uint8), cur.view(np.uint8)))
        if last is not None and last.shape == cur.shape and last.dtype == cur.dtype:
            np.copyto(last, cur)
        else:
            self._last = cur.copy()
        return same

    def _dark_thresholds(self, dark, gain: float) -> tuple[np.ndarray, dict]:
        """For the quarter of the pixels checked: a raw value above which a pixel is certainly more than
        :data:`BLACK_SIGMAS` σ above the dark frame (σ: :meth:`_dark_sigma`), cached per dark frame and gain (a
        session's dark set, one frame per exposure of its ladder); and a dict the integer form of that raw value
        is kept in per frame dtype (:meth:`_surely_above`)."""
        key = (id(dark), float(gain))
        hit = self._dark_thr.get(key)
        if hit is None or hit[0]() is not dark:  # DarkFrame is frozen: the object is the key (weakly held)
            live = {k: v for k, v in self._dark_thr.items() if v[0]() is not None}  # forget dark frames gone
            self._dark_thr = live if len(live) < DARK_THRESHOLDS_KEPT else {}
            # z = (x − mean)/σ > BLACK_SIGMAS for every x above this (float64, margins far above rounding)
            m64 = dark.mean[::2, ::2].astype(np.float64)
            above = m64 + (BLACK_SIGMAS * (1 + 1e-9)) * self._dark_sigma(dark, gain).astype(np.float64) \
                + 1e-9 * (np.abs(m64) + 1.0)
            hit = self._dark_thr[key] = (weakref.ref(dark), (above, {}))  # the dark frame itself is not kept alive
        return hit[1]

    def _dark_sigma(self, dark, gain: float) -> np.ndarray:
        """The noise σ of the quarter's pixels of a frame with the light off: the dark frame's and the sensor's."""
        return np.sqrt(dark.var[::2, ::2] + self.noise.variance(0.0, gain))  # as the z-scores have always used it

    @staticmethod
    def _surely_above(px: np.ndarray, above: np.ndarray, ints: dict) -> bool:
        """``np.any(px[::2, ::2] > above)``. For an unsigned-integer frame of the dark frame's shape, one
        contiguous comparison of the whole frame with an integer image of the same dtype (kept in ``ints``): for
        an integer x, ``x > a`` ⟺ ``x > ⌊a⌋`` (a finite), so the quarter's pixels get ⌊a⌋ clipped to the dtype's
        largest value M (x > a ≥ M is never true: M stands for it, and for a = NaN, which no x exceeds), and
        the other pixels get M, which no pixel exceeds; where some a < 0 every pixel of the quarter there is
        above it, whatever the frame. The strided quarter read element by element costs ~4× the whole frame."""
        if px.dtype.kind != "u" or px.ndim != 3 or px[::2, ::2].shape != above.shape:
            return bool(np.any(px[::2, ::2] > above))
        key = (px.dtype, px.shape)
        hit = ints.get(key)
        if hit is None:
            top = np.iinfo(px.dtype).max
            thr = np.full(px.shape, top, dtype=px.dtype)
            thr[::2, ::2] = np.where(np.isnan(above), top, np.clip(np.floor(above), 0, top))
            hit = ints[key] = (thr, bool(np.any(above < 0)))
        thr, always = hit
        # every 8th row first (rows of the quarter; a lit frame has a pixel above there): a pixel found there is
        # one of the whole comparison's, and only a frame with none there is compared whole
        return always or bool(np.any(px[::8] > thr[::8])) or bool(np.any(px > thr))

    def _count_at_or_above(self, px: np.ndarray, limit: float) -> int:
        """``np.count_nonzero(px[::2, ::2] >= limit)``. For an unsigned-integer frame and a finite limit L, one
        contiguous comparison of the whole frame: for an integer x, ``x ≥ L`` ⟺ ``x > ⌈L⌉ − 1``; the quarter's
        pixels get ⌈L⌉ − 1 and the others the dtype's largest value M, which no pixel exceeds (L ≤ 0: every pixel
        of the quarter counts; ⌈L⌉ − 1 ≥ M: none does). The threshold image is kept for the last shape, dtype and
        limit (a session's frames share them)."""
        sub_size = px[::2, ::2].size
        if px.dtype.kind != "u" or not math.isfinite(limit):
            return int(np.count_nonzero(px[::2, ::2] >= limit))
        top = int(np.iinfo(px.dtype).max)
        c = math.ceil(limit) - 1
        if c < 0:
            return sub_size
        if c >= top:
            return 0
        if int(px.max()) <= c:  # no pixel of the frame at L or above (the usual frame): none of the quarter either
            return 0
        key = (px.dtype, px.shape, c)
        if self._sat_thr is None or self._sat_thr[0] != key:
            thr = np.full(px.shape, top, dtype=px.dtype)
            thr[::2, ::2] = c
            self._sat_thr = (key, thr)
        return int(np.count_nonzero(px > self._sat_thr[1]))

    def dark_frame(self, frame, px: np.ndarray) -> None:
        """A dark frame (light off) is black by design; it must still be a new frame and not overload."""
        self(frame, px, levels=False)
        if self._count_at_or_above(px, self.limit(frame)) >= SATURATED_FRACTION * px[::2, ::2].size:
            raise FrameSignalError("camera dark frame: saturated everywhere with the light off", device="camera")

    def __call__(self, frame, px: np.ndarray, *, levels: bool = True, dark=None) -> None:
        """Raise :class:`FrameSignalError` naming the fault; otherwise remember the frame. ``levels=False``
        (metering frames, which may be dim or saturated: the pipeline re-meters them) checks repeats only."""
        stale = self._is_repeat(px)
        sub = px[::2, ::2]  # a quarter of the pixels is plenty for both statistics
        if stale and sub.min() != sub.max():  # a uniform frame (black, saturated) repeats legitimately: see below
            raise FrameSignalError("camera frame: identical to the previous frame (stale: the camera returned an "
                                   "old buffer)", device="camera")
        if not levels and dark is None:
            return
        if dark is not None:  # against this exposure's dark frame: dark current is not light
            above, ints = self._dark_thresholds(dark, frame.gain)
            # one pixel surely above the threshold settles it; otherwise the z-scores themselves decide
            black, top = False, np.inf
            if not self._surely_above(px, above, ints):
                top = float(((sub.astype(np.float64) - dark.mean[::2, ::2]) / self._dark_sigma(dark, frame.gain)).max())
                black = top <= BLACK_SIGMAS
            what = f"no pixel above the noise of its dark frame, highest {top:+.1f} σ"
        else:
            sigma = float(np.sqrt(self.noise.variance(0.0, frame.gain)))
            top = float(px.max())
            black = top <= frame.black_level + max(BLACK_SIGMAS * sigma, 1.0)
            what = f"brightest pixel {top:.0f} at the black level {frame.black_level:g}"
        if black:
            raise FrameSignalError(f"camera frame: black ({what}: no light reached the sensor)", device="camera")
        if not levels:
            return
        limit = self.limit(frame)
        if self._count_at_or_above(px, float(limit)) >= SATURATED_FRACTION * sub.size:
            raise FrameSignalError(f"camera frame: saturated everywhere (≥ {SATURATED_FRACTION:.0%} of the pixels at "
                                   f"{limit:g})", device="camera")
