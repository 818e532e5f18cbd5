"""The log-relative mapping of BRDF values in which a prior is linear.

Nielsen, Jensen & Ramamoorthi ("On optimal, minimal BRDF sampling for reflectance acquisition", ACM TOG 34(6),
2015, §4) map a BRDF to ln((f·w + ε)/(f_ref·w + ε)), w = cos θi·cos θo, ε = 10⁻³, f_ref the median of the
training materials. gonio's prior uses the same log-relative form *without the cosine factor*:

    u = ln( (f + ε) / (f_ref + ε) ),   ε = 10⁻³ (1/sr),

because the prior lives on a coarse grid and is interpolated to any direction: with the cosine inside, u
varies with w wherever f·w ≈ ε (dark materials over wide ranges, every material near the horizon), and
trilinear interpolation of u between nodes cost 3× more cube-root error on the real materials (docs/prior.md)
than interpolating the cosine-free u. The cosine weighting Nielsen et al. use to de-emphasise grazing
directions enters instead through the error measure (the nodes' shares of the MERL cells) and each sample's σ.
Nielsen et al.'s own mapping is kept for their method in :mod:`gonio.prior.nielsen`.

Inverse: ``f = max((f_ref + ε)·eᵘ − ε, 0)``. Uncertainty by the delta method (first-order propagation, GUM
JCGM 100:2008 §5.1.2): ``σ_u = σ_f/(f + ε)`` and back ``σ_f = (f + ε)·σ_u``.
"""

from __future__ import annotations

import numpy as np

__all__ = ["EPSILON", "cos_weight", "to_mapped", "from_mapped", "sigma_to_mapped", "sigma_from_mapped"]

#: ε of the mapping, 1/sr (Nielsen et al. 2015's value).
EPSILON = 1e-3

#: Smallest ``f + ε`` a noisy (negative) measured value is clipped to before the logarithm, as a fraction of ε.
_FLOOR = 0.5


def cos_weight(wi, wo) -> np.ndarray:
    """``w = max(cos θi, 0)·max(cos θo, 0)`` of direction pairs ``(..., 3)``; shape ``(...)``."""
    return np.clip(np.asarray(wi)[..., 2], 0.0, None) * np.clip(np.asarray(wo)[..., 2], 0.0, None)


def _like(a, ref) -> np.ndarray:
    """``a`` as float64 with a trailing axis added when ``ref`` has one more (the RGB axis)."""
    a = np.asarray(a, dtype=np.float64)
    return a[..., None] if a.ndim < np.ndim(ref) else a


def to_mapped(f, f_ref, eps: float = EPSILON) -> np.ndarray:
    """u = ln((f + ε)/(f_ref + ε)); ``f`` may have a trailing RGB axis that ``f_ref`` lacks. A negative noisy
    value is clipped so that f + ε ≥ ε/2."""
    f = np.asarray(f, dtype=np.float64)
    return np.log(np.maximum(f + eps, _FLOOR * eps)) - np.log(_like(f_ref, f) + eps)


def from_mapped(u, f_ref, eps: float = EPSILON) -> np.ndarray:
    """f = max((f_ref + ε)·eᵘ − ε, 0)."""
    u = np.asarray(u, dtype=np.float64)
    with np.errstate(over="ignore"):
        f = (_like(f_ref, u) + eps) * np.exp(u) - eps
    return np.maximum(np.nan_to_num(f, nan=0.0, posinf=np.finfo(float).max), 0.0)


def sigma_to_mapped(f, sigma, eps: float = EPSILON) -> np.ndarray:
    """σ_u = σ_f/(f + ε) (delta method); f + ε floored as in :func:`to_mapped`."""
    f = np.asarray(f, dtype=np.float64)
    return np.asarray(sigma, dtype=np.float64) / np.maximum(f + eps, _FLOOR * eps)


def sigma_from_mapped(f, sigma_u, eps: float = EPSILON) -> np.ndarray:
    """σ_f = (f + ε)·σ_u (delta method)."""
    return (np.asarray(f, dtype=np.float64) + eps) * np.asarray(sigma_u, dtype=np.float64)
