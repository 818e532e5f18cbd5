"""Frame checks, frame averaging and the HDR merge of linear frames; response recovery for 8-bit cameras.

The linear merge is an inverse-variance weighted mean of per-exposure rate estimates (Granados et
al., "Optimal HDR reconstruction with linear digital cameras", CVPR 2010: weights = 1/σ² from the
camera noise model, saturated values excluded). Weights come from the noise model evaluated at a
first-pass pooled rate, not at each frame's own value, so noisy low values do not get extra weight.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from gonio.camera_model import lookup_response
from gonio.errors import HardwareError
from gonio.pipeline.target import CameraCalibration, NoiseModel
from gonio.rig.interfaces import Frame

__all__ = ["BadFrame", "check_frame", "ExposureStack", "average_frames", "merge_linear", "HdrImage",
           "calibrate_response", "linearize"]

#: A raw value this close (fraction of the linear range) to the linear limit counts as saturated.
SATURATION_MARGIN = 0.02


class BadFrame(HardwareError):
    """The camera returned a frame the pipeline cannot interpret (shape, dtype, metadata)."""


def check_frame(frame: Frame, calib: CameraCalibration) -> np.ndarray:
    """Validate a frame against the calibration; return its pixels as (H, W, C).

    Raises :class:`BadFrame` naming the offending field: not a Frame, non-integer dtype, shape other
    than the calibrated (H, W) or (H, W, 3), bit depth the dtype cannot hold, values above the bit
    depth, non-positive or non-finite exposure/gain.
    """
    if not isinstance(frame, Frame):
        raise BadFrame(f"camera frame: expected a Frame, got {type(frame).__name__}", device="camera")
    px = frame.pixels
    if not isinstance(px, np.ndarray) or px.dtype not in (np.uint8, np.uint16):
        raise BadFrame(f"camera frame: pixels.dtype = {getattr(px, 'dtype', type(px))}: must be uint8 or uint16",
                       device="camera")
    want = (calib.height, calib.width)
    if px.shape[:2] != want or px.ndim not in (2, 3) or (px.ndim == 3 and px.shape[2] != 3):
        raise BadFrame(f"camera frame: pixels.shape = {px.shape}: expected {want} or {want + (3,)}", device="camera")
    if frame.bit_depth not in (8, 10, 12, 14, 16) or frame.bit_depth > 8 * px.dtype.itemsize:
        raise BadFrame(f"camera frame: bit_depth = {frame.bit_depth}: does not fit {px.dtype}", device="camera")
    if not (np.isfinite(frame.exposure) and frame.exposure > 0 and np.isfinite(frame.gain) and frame.gain > 0):
        raise BadFrame(f"camera frame: exposure/gain = {frame.exposure!r}/{frame.gain!r}: must be positive",
                       device="camera")
    if px.dtype == np.uint16 and int(px.max()) > frame.saturation_level:
        raise BadFrame(f"camera frame: max value {int(px.max())} exceeds bit_depth {frame.bit_depth}",
                       device="camera")
    return px if px.ndim == 3 else px[..., None]


@dataclass
class ExposureStack:
    """Frames of one exposure, averaged over a region (raw DN), with what the merge needs."""

    exposure: float
    gain: float
    n: int
    mean: np.ndarray  # (h, w, C) mean raw value
    max: np.ndarray  # (h, w, C) largest raw value of the n frames
    light: float  # mean relative light output (photodiode) during the frames
    black_level: float
    linear_limit: float  # raw value where the response stops being linear
    light_rel_var: float = 0.0  # relative variance of ``light`` (photodiode noise of the mean reading)


def average_frames(pixels: Sequence[np.ndarray], frames: Sequence[Frame], light: Sequence[float],
                   limit: float, region=(slice(None), slice(None)), light_u: Sequence[float] | None = None
                   ) -> ExposureStack:
    """Average ``pixels`` (checked (H, W, C) arrays of ``frames``, same exposure) over ``region``.

    ``light_u`` are the standard uncertainties of the photodiode readings ``light``; the mean
    reading's relative variance is ``Σu² / n² / P̄²`` (independent readings).
    """
    crop = [p[region] for p in pixels]
    if len(crop) == 1:  # one frame is its own mean and maximum (x / 1 is x): no stack, no reductions
        mean = mx = crop[0].astype(np.float64)
    else:
        stack = np.stack(crop).astype(np.float64)
        mean, mx = stack.mean(axis=0), stack.max(axis=0)
    f0 = frames[0]
    p = float(np.mean(light))
    rel = 0.0
    if light_u is not None and p > 0:
        u = np.asarray(light_u, dtype=np.float64)
        rel = float(np.sum(u**2)) / len(u) ** 2 / p**2
    return ExposureStack(exposure=f0.exposure, gain=f0.gain, n=len(crop), mean=mean,
                         max=mx, light=p, black_level=f0.black_level, linear_limit=limit,
                         light_rel_var=rel)


@dataclass
class HdrImage:
    """Merged radiometric image: DN per second at gain 1 per unit light output, above dark.

    ``var`` is its variance from the frames' noise; ``saturated`` marks pixels saturated in every
    exposure (rate = NaN); ``used`` counts the exposures that contributed to each pixel.
    ``light_weight`` (K, h, w, C) is each exposure's share ``w_k x_k / Σ w x`` of the merged value —
    the sensitivity ``−∂ ln x / ∂ ln P_k`` to exposure k's photodiode reading — and
    ``light_rel_var`` (K,) those readings' relative variances: the photodiode noise is kept apart
    because it is correlated across all pixels of an exposure (it partly cancels in f = sample/white).
    """

    rate: np.ndarray
    var: np.ndarray
    saturated: np.ndarray
    used: np.ndarray
    light_weight: np.ndarray | None = None
    light_rel_var: np.ndarray | None = None


def merge_linear(stacks: Sequence[ExposureStack], darks: Sequence[tuple[np.ndarray, np.ndarray]],
                 noise: NoiseModel) -> HdrImage:
    """SNR-weighted merge of dark-subtracted linear exposures (vectorized over pixels).

    Per exposure k: ``x_k = (mean_k − dark_k) / (t_k G_k P_k)`` (P = relative light output from the
    photodiode), ``σ²(x_k) = (σ²_y(s_k)/n_k + σ²_dark,k) / (t_k G_k P_k)²`` with ``σ²_y`` from the
    EMVA 1288 model (:class:`NoiseModel`) at the predicted signal ``s_k``. Values within
    :data:`SATURATION_MARGIN` of the linear limit in any of the n frames are excluded.
    Merged ``x = Σ w_k x_k / Σ w_k``, ``w_k = 1/σ²(x_k)``, ``σ²(x) = 1/Σ w_k`` (Granados et al. 2010).
    ``darks[k]`` is ``(dark mean raw, variance of that mean)`` over the same region.
    """
    xs, scales, ok, dark_sig, dark_var = [], [], [], [], []
    for st, (dmean, dvar) in zip(stacks, darks):
        scale = st.exposure * st.gain * st.light
        thr = st.linear_limit - SATURATION_MARGIN * (st.linear_limit - st.black_level)
        good = st.max < thr
        if scale <= 0:
            good = np.zeros_like(good)
            scale = 1.0
        xs.append((st.mean - dmean) / scale)
        scales.append(scale)
        ok.append(good)
        dark_sig.append(dmean - st.black_level)
        dark_var.append(dvar)
    ok_arr = np.stack(ok)
    x_ok = np.where(ok_arr, np.stack(xs), 0.0)  # the values that count (0 elsewhere), used by both passes
    sc = np.asarray(scales)[:, None, None, None]
    # pass 1: weights ∝ exposure (shot-noise-limited SNR), pooled rate estimate
    w1 = np.where(ok_arr, sc, 0.0)
    sw1 = w1.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        rate1 = np.where(sw1 > 0, (w1 * x_ok).sum(axis=0) / np.where(sw1 > 0, sw1, 1.0), np.nan)
    # pass 2: inverse variance from the noise model at the predicted signal
    gains = np.asarray([s.gain for s in stacks])[:, None, None, None]
    ns = np.asarray([s.n for s in stacks])[:, None, None, None]
    pred = np.maximum(np.nan_to_num(rate1), 0.0) * sc + np.stack(dark_sig)
    var_k = (noise.variance(pred, gains) / ns + np.stack(dark_var)) / sc**2
    w2 = np.where(ok_arr, 1.0 / var_k, 0.0)
    sw2 = w2.sum(axis=0)
    sat = sw2 <= 0
    wx = w2 * x_ok
    with np.errstate(invalid="ignore", divide="ignore"):
        num = wx.sum(axis=0)
        sw2_ = np.where(sat, 1.0, sw2)
        rate = np.where(sat, np.nan, num / sw2_)
        var = np.where(sat, np.nan, 1.0 / sw2_)
        nz = num != 0
        share = wx / np.where(nz, num, 1.0)
        if not nz.all():  # where the merged value is 0 the shares are the weights'
            share = np.where(nz, share, w2 / sw2_)
    return HdrImage(rate=rate, var=var, saturated=sat, used=ok_arr.sum(axis=0), light_weight=share,
                    light_rel_var=np.asarray([s.light_rel_var for s in stacks], dtype=np.float64))


def calibrate_response(images: Sequence[np.ndarray], exposures: Sequence[float], samples: int = 70) -> np.ndarray:
    """Camera response of an 8-bit non-linear camera from a bracket (Debevec & Malik, SIGGRAPH 1997).

    Uses ``cv2.createCalibrateDebevec``; exposure times are passed as ``np.float32`` (float64 makes
    OpenCV's Merge*/Calibrate* silently return inf/NaN, FIELD-NOTES.md). Returns the inverse response,
    shape (256, 1, 3) float32: relative exposure for each 8-bit value.
    """
    import cv2

    imgs = [np.ascontiguousarray(np.broadcast_to(im[..., None], im.shape + (3,)) if im.ndim == 2 else im)
            for im in images]
    times = np.asarray(exposures, dtype=np.float32)
    return cv2.createCalibrateDebevec(samples=samples).process(imgs, times)


def linearize(pixels: np.ndarray, response: np.ndarray) -> np.ndarray:
    """Map 8-bit values through an inverse response from :func:`calibrate_response` (per channel;
    :func:`gonio.camera_model.lookup_response`)."""
    return lookup_response(pixels, response)
