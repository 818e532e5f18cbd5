"""Exposure control: a bracket that puts the sample and the white reference in the linear range, and
enough frames per exposure to reach the target signal-to-noise ratio."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from gonio.errors import ConfigError
from gonio.pipeline.target import NoiseModel

__all__ = ["CapturePlan", "ExposureSettings", "plan_bracket", "exposure_ladder"]


@dataclass(frozen=True)
class CapturePlan:
    """Exposures (s, shortest first), frames averaged at each, and the analogue gain."""

    exposures: tuple[float, ...]
    frames: tuple[int, ...]
    gain: float = 1.0

    def __post_init__(self):
        if not self.exposures or len(self.exposures) != len(self.frames):
            raise ConfigError.field(None, "capture.frames", self.frames, "needs one count per exposure")
        if any(not (t > 0 and math.isfinite(t)) for t in self.exposures):
            raise ConfigError.field(None, "capture.exposures", self.exposures, "must be positive seconds")
        if any(int(n) < 1 for n in self.frames):
            raise ConfigError.field(None, "capture.frames", self.frames, "must be >= 1")


@dataclass(frozen=True)
class ExposureSettings:
    """How brackets are chosen.

    Attributes
    ----------
    high : float
        Brightest relevant pixel at the shortest exposure, as a fraction of the linear range.
    low : float
        Dimmest relevant pixel at the longest exposure, as a fraction of the linear range.
    step : float
        Exposure ratio between bracket members.
    max_brackets, min_frames, max_frames : int
    target_snr : float
        Wanted SNR of one sample (mean over its pixels) of the dimmest region.
    min_exposure, max_exposure : float
        Seconds.
    ladder : tuple of float, optional
        Allowed exposures (s, ascending). When given, every bracket member is a rung of the ladder, so a
        session can measure the dark frames of all the exposures it may use before the first pose
        (:func:`exposure_ladder`); without it exposures are continuous.
    """

    high: float = 0.75
    low: float = 0.25
    step: float = 4.0
    max_brackets: int = 3
    min_frames: int = 1
    max_frames: int = 8
    target_snr: float = 300.0
    min_exposure: float = 1e-5
    max_exposure: float = 2.0
    ladder: tuple[float, ...] | None = None

    def __post_init__(self):
        if self.ladder is not None:
            rungs = tuple(float(t) for t in self.ladder)
            if not rungs or any(not (t > 0 and math.isfinite(t)) for t in rungs) or list(rungs) != sorted(set(rungs)):
                raise ConfigError.field(None, "exposure.ladder", self.ladder, "needs ascending positive seconds")
            object.__setattr__(self, "ladder", rungs)
        if not (0 < self.low < 1 and 0 < self.high < 1):
            raise ConfigError.field(None, "exposure.high/low", (self.high, self.low), "must be in (0, 1)")
        if self.step <= 1:
            raise ConfigError.field(None, "exposure.step", self.step, "must be > 1")
        if self.max_brackets < 1 or self.max_frames < self.min_frames or self.min_frames < 1:
            raise ConfigError.field(None, "exposure.frames", (self.min_frames, self.max_frames), "needs 1 <= min <= max")


def plan_bracket(rate_bright: float, rate_dim: float, range_dn: float, n_pixels: int, noise: NoiseModel,
                 settings: ExposureSettings, gain: float = 1.0, dark_dn_per_s: float = 0.0) -> CapturePlan:
    """Choose a bracket from metered signal rates (DN/s at gain 1 above black).

    Shortest exposure ``t₁ = high · range / rate_bright`` (brightest pixel below saturation); then
    ×``step`` until the dimmest pixel reaches ``low · range`` or ``max_brackets``. Frames at the longest
    exposure: ``n = ⌈(SNR_target / (SNR_px √N_pix))²⌉`` where ``SNR_px`` is the dimmest pixel's SNR
    there under the EMVA 1288 noise model, clamped to [min_frames, max_frames]. A shorter exposure
    ``t_k`` only serves pixels that saturate at ``t_{k+1}`` (the merge weights each exposure by its inverse
    variance, :func:`gonio.pipeline.hdr.merge_linear`, Granados et al. 2010), whose signal at ``t_k`` is at
    least ``(1 − margin) · range · t_k / t_{k+1}``: its frames are the same formula at that signal (or at the
    dimmest pixel's, if brighter), never more than the longest exposure's. Averaging the longest
    exposure's frame count at every exposure would only buy SNR the bright pixels already have.
    With ``settings.ladder``, ``t₁`` is rounded down to a rung (the brightest pixel stays below
    ``high``) and the bracket continues on the following rungs.
    """
    s = settings
    rate_bright = max(float(rate_bright), 1e-12)
    rate_dim = min(max(float(rate_dim), 1e-12), rate_bright)
    g = float(gain)
    t1 = s.high * range_dn / (rate_bright * g)
    if s.ladder is None:
        t1 = float(np.clip(t1, s.min_exposure, s.max_exposure))
        candidates = [min(t1 * s.step**k, s.max_exposure) for k in range(s.max_brackets)]
    else:
        rungs = np.asarray(s.ladder, dtype=np.float64)
        candidates = rungs[max(int(np.searchsorted(rungs, t1 * (1 + 1e-9), side="right")) - 1, 0):].tolist()
    exposures: list[float] = []
    for t in candidates:  # longer exposures until the dimmest region reaches `low` of the range
        if exposures and (t <= exposures[-1] or len(exposures) >= s.max_brackets
                          or rate_dim * g * exposures[-1] >= s.low * range_dn * (1 - 1e-9)):
            break
        exposures.append(float(t))
    from gonio.pipeline.hdr import SATURATION_MARGIN

    n_long = _frames(exposures[-1], rate_dim, range_dn, n_pixels, noise, s, g, dark_dn_per_s)
    frames = [min(n_long, _frames(t, max(rate_dim, (1 - SATURATION_MARGIN) * range_dn / (g * t_next)), range_dn,
                                  n_pixels, noise, s, g, dark_dn_per_s))
              for t, t_next in zip(exposures[:-1], exposures[1:])]
    return CapturePlan(tuple(exposures), (*frames, n_long), g)


def _frames(t_long, rate_dim, range_dn, n_pixels, noise, s, g, dark_dn_per_s) -> int:
    """Frames per exposure for the target SNR of the dimmest region at the longest exposure."""
    sig = min(rate_dim * g * t_long, range_dn)
    var = float(noise.variance(sig + dark_dn_per_s * g * t_long, g))
    snr_px = sig / math.sqrt(var) if var > 0 else float("inf")
    need = (s.target_snr / max(snr_px * math.sqrt(max(n_pixels, 1)), 1e-12)) ** 2
    return int(min(max(math.ceil(need), s.min_frames), s.max_frames))


def exposure_ladder(expected, step: float, *, extra: int = 2, lo: float = 1e-5, hi: float = 2.0) -> tuple[float, ...]:
    """The rungs automatic exposure may use: the ``expected`` bracket extended by ``extra`` rungs of
    ratio ``step`` below its shortest and above its longest exposure, kept within ``[lo, hi]``."""
    exp = sorted(float(t) for t in expected)
    below = [exp[0] / step**k for k in range(extra, 0, -1)]
    above = [exp[-1] * step**k for k in range(1, extra + 1)]
    return tuple(t for t in (*below, *exp, *above) if lo * (1 - 1e-12) <= t <= hi * (1 + 1e-12))
