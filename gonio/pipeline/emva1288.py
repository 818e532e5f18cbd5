"""The camera's noise and response measured as EMVA Standard 1288 (Release 4.0, 2021) defines it
(``gonio camera noise``): the photon-transfer method on pairs of frames of a uniform target.

Every formula below is the standard's (R4.0 "General" model: ``μ_y = μ_y.dark + K μ_e``,
``σ_y² = K² σ_d² + σ_q² + K (μ_y − μ_y.dark)``, with ``σ_q² = 1/12 DN²``):

* per exposure, two light frames A, B and two dark frames: ``μ_y = ½(⟨A⟩ + ⟨B⟩)`` and the temporal variance
  from their difference, free of the fixed pattern: ``σ_y² = ½[⟨(A − B)²⟩ − (⟨A⟩ − ⟨B⟩)²]`` (R4.0 §6.3: the
  mean square of the difference of the frames' deviations from their own means, halved);
* **system gain** K (DN/e⁻): the slope of ``σ_y² − σ_y.dark²`` against ``μ_y − μ_y.dark`` (the photon transfer
  curve) through the origin, fitted from the darkest step up to 70 % of saturation (§6.4), weighted by the
  variance estimates' own variance (``2σ⁴/N``); its σ from the fit's residuals;
* **temporal dark noise** ``σ_d = √(σ_y.dark² − σ_q²) / K`` (e⁻) at the shortest exposure; below
  ``σ_y.dark = 0.5 DN`` the quantization hides it and only an upper bound is stated (§6.4);
* **saturation** at the maximum of the photon transfer curve's variance; **saturation capacity**
  ``μ_e.sat = (μ_y.sat − μ_y.dark) / K`` (§6.5); a series whose variance still rises at its end did not reach it;
* **dark current** (e⁻/s): the slope of ``μ_y.dark`` against exposure time over K (§7.1);
* **linearity error**: ``δ = (μ_y − μ_y.dark − fit)/fit``, fit a line through the origin against exposure time over
  5–95 % of saturation; ``LE = (max δ − min δ)/2`` (§6.6);
* **DSNU / PRNU** from ``L`` averaged frames dark and at ~50 % saturation: the averaged image's spatial variance
  less the temporal part left after averaging, ``s_y² = var(⟨y⟩_L) − σ_y²/L``; ``DSNU = s_y.dark / K`` (e⁻),
  ``PRNU = √(s_y.50² − s_y.dark²) / (μ_y.50 − μ_y.dark)`` (§8.2).

Colour frames: one channel (green by default: R4.0 §2.3 measures each channel of a colour camera on its own).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np

from gonio.errors import ConfigError, DataError

__all__ = ["pair_stats", "Step", "EmvaData", "EmvaResult", "analyse", "capture_series", "QUANTIZATION_VAR"]

#: Variance of the uniform quantization error of one digital number (DN²).
QUANTIZATION_VAR = 1.0 / 12.0


def pair_stats(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """``(μ_y, σ_y²)`` of two frames of the same exposure (module docstring; R4.0 §6.3)."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    ma, mb = float(a.mean()), float(b.mean())
    return 0.5 * (ma + mb), 0.5 * (float(np.mean((a - b) ** 2)) - (ma - mb) ** 2)


@dataclass(frozen=True)
class Step:
    """One exposure of the series: time (s), light pair (μ_y, σ_y²) and dark pair (μ_y.dark, σ_y.dark²), DN."""

    exposure: float
    mean: float
    var: float
    dark_mean: float
    dark_var: float


@dataclass(frozen=True)
class EmvaData:
    """What :func:`capture_series` measured: the steps, the long dark pairs, the averaged stacks' spatial
    variances and means at ~50 % saturation, pixels per frame, saturation level (DN) and bit depth."""

    steps: tuple[Step, ...]
    dark_steps: tuple[Step, ...]
    stack: dict
    pixels: int
    saturation_dn: float
    bit_depth: int
    channel: str = "mono"


@dataclass(frozen=True)
class EmvaResult:
    """The characterisation (module docstring), every σ a standard uncertainty; ``notes``: what is only a bound
    or was not reached."""

    gain: float
    gain_sigma: float
    read_noise_e: float
    read_noise_sigma: float
    dark_offset_dn: float
    dark_current_e_s: float
    dark_current_sigma: float
    saturation_dn: float
    saturation_capacity_e: float | None
    linearity_error_percent: float
    dsnu_e: float
    prnu_percent: float
    fit_points: int
    bit_depth: int
    channel: str
    notes: tuple[str, ...] = field(default=())

    def noise_table(self) -> dict:
        """The CAMERA.toml ``[noise]`` keys (:class:`gonio.pipeline.target.NoiseModel`)."""
        out = {"dn_per_electron": self.gain, "read_noise_e": self.read_noise_e}
        if self.saturation_capacity_e is not None:
            out["full_well_e"] = self.saturation_capacity_e
        return out

    def emva_table(self) -> dict:
        """Everything measured, for CAMERA.toml's ``[emva1288]`` (informational)."""
        d = {"standard": "EMVA 1288 R4.0", "channel": self.channel, "bit_depth": self.bit_depth,
             "dn_per_electron_sigma": self.gain_sigma, "read_noise_e_sigma": self.read_noise_sigma,
             "dark_offset_dn": self.dark_offset_dn, "dark_current_e_per_s": self.dark_current_e_s,
             "dark_current_sigma": self.dark_current_sigma, "saturation_dn": self.saturation_dn,
             "linearity_error_percent": self.linearity_error_percent, "dsnu_e": self.dsnu_e,
             "prnu_percent": self.prnu_percent, "photon_transfer_points": self.fit_points}
        if self.notes:
            d["notes"] = list(self.notes)
        return d

    def lines(self) -> list[str]:
        sat = f"{self.saturation_capacity_e:.0f} e⁻" if self.saturation_capacity_e is not None else "not reached"
        out = [f"EMVA 1288 (R4.0), {self.channel} channel, {self.bit_depth}-bit, {self.fit_points} photon-transfer points:",
               f"  system gain K            {self.gain:.5g} ± {self.gain_sigma:.2g} DN/e⁻ ({1 / self.gain:.4g} e⁻/DN)",
               f"  temporal dark noise σ_d  {self.read_noise_e:.4g} ± {self.read_noise_sigma:.2g} e⁻",
               f"  dark offset              {self.dark_offset_dn:.2f} DN",
               f"  dark current             {self.dark_current_e_s:.4g} ± {self.dark_current_sigma:.2g} e⁻/s",
               f"  saturation               {self.saturation_dn:.0f} DN, capacity {sat}",
               f"  linearity error          {self.linearity_error_percent:.2f} %",
               f"  DSNU                     {self.dsnu_e:.3g} e⁻",
               f"  PRNU                     {self.prnu_percent:.3g} %"]
        return out + [f"  note: {n}" for n in self.notes]


def _through_origin(x: np.ndarray, y: np.ndarray, w: np.ndarray) -> tuple[float, float]:
    """Weighted least squares slope of ``y = b x`` and its standard error from the weighted residuals."""
    sxx = float(np.sum(w * x * x))
    b = float(np.sum(w * x * y)) / sxx
    n = len(x)
    s2 = float(np.sum(w * (y - b * x) ** 2)) / max(n - 1, 1)
    return b, math.sqrt(s2 / sxx)


def analyse(data: EmvaData) -> EmvaResult:
    """The EMVA 1288 quantities of a measured series (module docstring). DataError when the series cannot give
    them (too few steps below saturation, no signal)."""
    st = sorted(data.steps, key=lambda s: s.exposure)
    if len(st) < 5:
        raise DataError(f"photon transfer: {len(st)} exposure steps; at least 5 are needed (EMVA 1288 asks for 50)")
    t = np.array([s.exposure for s in st])
    mu = np.array([s.mean - s.dark_mean for s in st])
    var = np.array([s.var - s.dark_var for s in st])
    notes = []
    raw_var = np.array([s.var for s in st])
    k_sat = int(np.argmax(raw_var))
    reached = k_sat < len(st) - 1
    if not reached:
        notes.append("saturation not reached (the variance still rises at the longest exposure): extend the series")
    mu_sat = mu[k_sat]
    fit = (mu > 0) & (mu <= 0.7 * mu_sat) & (np.arange(len(st)) < k_sat + (0 if reached else 1))
    if fit.sum() < 3:
        raise DataError(f"photon transfer: {int(fit.sum())} steps between dark and 70 % of saturation; at least 3 "
                        "are needed: more steps, or a dimmer light")
    w = 1.0 / np.maximum(raw_var[fit], 1e-12) ** 2  # var(σ²) ∝ σ⁴
    K, K_sig = _through_origin(mu[fit], var[fit], w)
    if not K > 0:
        raise DataError(f"photon transfer: slope K = {K:.3g} DN/e⁻: the variance does not grow with the signal "
                        "(no light on the sensor, or a non-linear camera)")
    d0 = st[0]
    n = data.pixels
    if d0.dark_var < 0.25:
        sd = math.sqrt(max(d0.dark_var - QUANTIZATION_VAR, 0.0) + QUANTIZATION_VAR) / K
        notes.append(f"σ_y.dark = {math.sqrt(max(d0.dark_var, 0)):.2f} DN < 0.5 DN: the quantization hides the dark "
                     f"noise; read noise ≤ {sd:.3g} e⁻ (an upper bound)")
        read, read_sig = sd, sd
    else:
        read = math.sqrt(d0.dark_var - QUANTIZATION_VAR) / K
        rel_var = math.sqrt(2.0 / n) * d0.dark_var / (2.0 * (d0.dark_var - QUANTIZATION_VAR))
        read_sig = read * math.hypot(rel_var, K_sig / K)
    darks = sorted(list(data.dark_steps) + [Step(s.exposure, s.dark_mean, s.dark_var, s.dark_mean, s.dark_var)
                                             for s in st], key=lambda s: s.exposure)
    td = np.array([s.exposure for s in darks])
    md = np.array([s.mean for s in darks])
    if np.ptp(td) > 0:
        A = np.stack([np.ones_like(td), td], axis=1)
        coef, res, *_ = np.linalg.lstsq(A, md, rcond=None)
        s2 = float(np.sum((md - A @ coef) ** 2)) / max(len(td) - 2, 1)
        cov = s2 * np.linalg.inv(A.T @ A)
        dark_current, dark_sig = coef[1] / K, math.sqrt(cov[1, 1]) / K
    else:
        dark_current, dark_sig = float("nan"), float("nan")
    lin = (mu >= 0.05 * mu_sat) & (mu <= 0.95 * mu_sat) & (np.arange(len(st)) <= k_sat)
    le = float("nan")
    if lin.sum() >= 3:
        slope, _ = _through_origin(t[lin], mu[lin], np.ones(int(lin.sum())))
        delta = (mu[lin] - slope * t[lin]) / (slope * t[lin]) * 100.0
        le = float((delta.max() - delta.min()) / 2.0)
    else:
        notes.append("linearity error: fewer than 3 steps between 5 % and 95 % of saturation")
    sk = data.stack
    L = sk["frames"]
    s2_dark = max(sk["dark_spatial_var"] - sk["dark_temporal_var"] / L, 0.0)
    s2_50 = max(sk["spatial_var"] - sk["temporal_var"] / L, 0.0)
    dsnu = math.sqrt(s2_dark) / K
    prnu = math.sqrt(max(s2_50 - s2_dark, 0.0)) / max(sk["mean"] - sk["dark_mean"], 1e-12) * 100.0
    cap = float(mu_sat / K) if reached else None
    return EmvaResult(K, K_sig, read, read_sig, d0.dark_mean, float(dark_current), float(dark_sig),
                      float(st[k_sat].mean), cap, le, dsnu, prnu, int(fit.sum()), data.bit_depth, data.channel,
                      tuple(notes))


def _plane(frame, channel: int | None) -> np.ndarray:
    px = np.asarray(frame.pixels)
    if not getattr(frame, "linear", True):
        raise ConfigError.field("--camera", "linear", False, "EMVA 1288 characterises a linear camera; this one "
                                "encodes a response curve (an 8-bit webcam: use its raw mode, or `gonio camera "
                                "response`)")
    if px.ndim == 3:
        return px[..., 1 if channel is None else channel]
    return px


def capture_series(camera, light: Callable[[bool], None], exposures: Sequence[float], *, gain: float = 1.0,
                   average: int = 16, dark_exposures: Sequence[float] = (), channel: int | None = None,
                   on_step: Callable[[str], None] | None = None) -> EmvaData:
    """Capture what :func:`analyse` needs from ``camera`` looking at a uniform target lit by ``light(on)``:
    a light pair and a dark pair per exposure of ``exposures``, dark pairs at ``dark_exposures`` (long ones, for
    the dark current), and ``average`` frames light and dark at the exposure nearest 50 % of saturation."""
    say = on_step or (lambda _m: None)

    def grab(t):
        f = camera.capture(float(t), gain)
        return _plane(f, channel), f

    light(True)
    lit = []
    for k, t in enumerate(exposures):
        (a, f), (b, _) = grab(t), grab(t)
        lit.append((t, *pair_stats(a, b)))
        if k % 10 == 9:
            say(f"{k + 1}/{len(exposures)} light pairs")
    sat = float((1 << f.bit_depth) - 1)
    means = np.array([m for _, m, _ in lit])
    t50 = exposures[int(np.argmin(np.abs(means - (means[0] + 0.5 * (means.max() - means[0])))))]
    stack_lit = np.mean([grab(t50)[0].astype(np.float64) for _ in range(average)], axis=0)
    light(False)
    say("dark frames")
    steps = []
    for t, m, v in lit:
        (a, _), (b, _) = grab(t), grab(t)
        steps.append(Step(float(t), m, v, *pair_stats(a, b)))
    dark_steps = []
    for t in dark_exposures:
        (a, _), (b, _) = grab(t), grab(t)
        dm, dv = pair_stats(a, b)
        dark_steps.append(Step(float(t), dm, dv, dm, dv))
    stack_dark = np.mean([grab(t50)[0].astype(np.float64) for _ in range(average)], axis=0)
    s50 = next(s for s in steps if s.exposure == t50)
    stack = {"frames": int(average), "exposure": float(t50), "mean": float(stack_lit.mean()),
             "spatial_var": float(stack_lit.var()), "temporal_var": s50.var, "dark_mean": float(stack_dark.mean()),
             "dark_spatial_var": float(stack_dark.var()), "dark_temporal_var": s50.dark_var}
    name = "mono" if np.asarray(f.pixels).ndim == 2 else "RGB"[1 if channel is None else channel]
    return EmvaData(tuple(steps), tuple(dark_steps), stack, int(a.size), sat, int(f.bit_depth), name)
