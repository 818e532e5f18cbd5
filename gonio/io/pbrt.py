"""Export a fitted model as a pbrt-v4 scene-file material (``MakeNamedMaterial`` blocks: ``diffuse``,
``conductor``, ``mix``, or ``coateddiffuse`` for plastics: :mod:`gonio.io.pbrt_coated`), with the
approximation error printed where pbrt cannot reproduce the model.

pbrt-v4's materials (Pharr, Jakob, Humphreys, *Physically Based Rendering*, 4th ed., 2023, ch. 9;
pbrt-v4 ``materials.h``/``bxdfs.h``):

* ``diffuse``: f = R/π, R clamped to [0, 1]. A lambert term is this exactly.
* ``conductor`` with ``spectrum reflectance r`` (eta = 1, k = 2√r/√(1 − r), so F(0) = r),
  ``roughness α`` with ``remaproughness false``: f = D(h) F(|wo·h|) G(wo, wi) / (4 cosθi cosθo) with
  Trowbridge-Reitz D (= GGX), the *height-correlated* Smith G = 1/(1 + Λ(wo) + Λ(wi)),
  Λ(w) = (√(1 + α² tan²θ) − 1)/2, and the exact Fresnel equations of a conductor
  (``FrComplex``: r∥ = (η cos θi − cos θt)/(η cos θi + cos θt), r⊥ = (cos θi − η cos θt)/(cos θi + η cos θt),
  F = (|r∥|² + |r⊥|²)/2, sin²θt = sin²θi/η², η = eta + i k).
* ``mix`` of two named materials with ``amount`` a: material 1 is chosen with probability a, so the
  expected BRDF is (1 − a)·m0 + a·m1 (``MixMaterial::ChooseMaterial``).

A gonio sum ``diffuse/π + Σ ks·D·G·F_schlick(f0)/(4 cosθi cosθo)`` becomes a mix of one diffuse and one
conductor per lobe with weights (w_d = max diffuse, w_k = mean ks; a black diffuse fills 1 − Σw). The
lobes are approximations (pbrt's G is height-correlated, gonio's separable; its Fresnel is a
conductor's, not Schlick's; Trowbridge-Reitz only): :mod:`gonio.io.approx` measures the error.
"""

from __future__ import annotations

import numpy as np

from gonio.io.approx import Exported, decompose, direction_pairs, relative_error

__all__ = ["pbrt_terms", "pbrt_eval", "to_pbrt", "write_pbrt", "fr_complex", "SMOOTH_ALPHA"]

#: pbrt-v4 renders a Trowbridge-Reitz conductor with α below this as a perfect mirror, whose BRDF is 0 at every
#: pair of directions (``TrowbridgeReitzDistribution::EffectivelySmooth``, src/pbrt/util/scattering.h:
#: α < 1e-3; ``ConductorBxDF::f`` returns 0 then): :func:`pbrt_eval` evaluates such a lobe so, and says so.
SMOOTH_ALPHA = 1e-3


def fr_complex(cos_i, eta) -> np.ndarray:
    """pbrt-v4's ``FrComplex`` (unpolarized Fresnel reflectance of a conductor, complex eta)."""
    c = np.clip(np.asarray(cos_i, dtype=np.float64), 0.0, 1.0)[..., None]
    eta = np.asarray(eta, dtype=np.complex128)
    sin2_i = 1.0 - c * c
    sin2_t = sin2_i / (eta * eta)
    cos_t = np.sqrt(1.0 - sin2_t)
    r_parl = (eta * c - cos_t) / (eta * c + cos_t)
    r_perp = (c - eta * cos_t) / (c + eta * cos_t)
    return (np.abs(r_parl) ** 2 + np.abs(r_perp) ** 2) / 2.0


def _conductor(r, alpha, wi, wo) -> np.ndarray:
    r = np.minimum(np.asarray(r, dtype=np.float64), 0.9999)
    k = 2.0 * np.sqrt(r) / np.sqrt(1.0 - r)
    h = wi + wo
    h = h / np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-300)
    a2 = alpha * alpha
    cos2 = h[..., 2] ** 2
    tan2 = (1.0 - cos2) / np.maximum(cos2, 1e-300)
    d = 1.0 / (np.pi * a2 * cos2 * cos2 * (1.0 + tan2 / a2) ** 2)

    def lam(w):
        c2 = w[..., 2] ** 2
        t2 = (1.0 - c2) / np.maximum(c2, 1e-300)
        return (np.sqrt(1.0 + a2 * t2) - 1.0) / 2.0

    g = 1.0 / (1.0 + lam(wo) + lam(wi))
    f = fr_complex(np.abs(np.sum(wo * h, axis=-1)), 1.0 + 1j * k)
    return (d * g / (4.0 * wi[..., 2] * wo[..., 2]))[..., None] * f


def pbrt_eval(terms, wi, wo) -> np.ndarray:
    """Expected f (1/sr, RGB) of the flattened mix ``[(weight, "diffuse", {"reflectance"}) |
    (weight, "conductor", {"reflectance", "roughness"})]`` (module docstring), 0 below the horizon."""
    wi = np.asarray(wi, dtype=np.float64)
    wo = np.asarray(wo, dtype=np.float64)
    above = (wi[..., 2] > 0) & (wo[..., 2] > 0)
    total = np.zeros(wi.shape[:-1] + (3,))
    for w, kind, p in terms:
        if kind == "diffuse":
            v = np.broadcast_to(np.clip(p["reflectance"], 0, 1) / np.pi, total.shape)
        elif p["roughness"] < SMOOTH_ALPHA:  # a perfect mirror: 0 at every pair of directions
            continue
        else:
            with np.errstate(invalid="ignore", divide="ignore"):
                v = _conductor(p["reflectance"], p["roughness"], wi, wo)
        total = total + w * v
    return np.where(above[..., None], np.nan_to_num(total), 0.0)


def pbrt_terms(model, approx: bool = False) -> tuple[list, list[str]]:
    """The weighted terms of the closest pbrt-v4 material and why it is not exact (``approx``: a model pbrt
    has no counterpart for is taken as :func:`gonio.io.approx.closest_lobes`)."""
    reasons: list[str] = []
    dec = decompose(model, "pbrt", approx=approx, reasons=reasons)
    terms = []
    d = dec.diffuse
    if np.any(d > 0):
        w = float(np.max(d))
        terms.append([w, "diffuse", {"reflectance": d / w}])
    for lobe in dec.lobes:
        w = float(np.mean(lobe.ks))
        if w <= 0:
            continue
        r = lobe.ks * lobe.f0 / w
        if np.any(r >= 0.9999):
            reasons.append("normal-incidence reflectance clipped below 1")
        if lobe.alpha < SMOOTH_ALPHA:
            reasons.append(f"alpha {lobe.alpha:.3g} < {SMOOTH_ALPHA:g}: pbrt-v4 renders the lobe as a perfect mirror")
        terms.append([w, "conductor", {"reflectance": np.minimum(r, 0.9999), "roughness": lobe.alpha}])
    if dec.lobes:
        reasons.append("pbrt's conductor has height-correlated Smith G and a conductor's Fresnel, gonio's lobe "
                       "separable G and Schlick's")
    if any(lb.distribution != "ggx" for lb in dec.lobes):
        reasons.append("pbrt has Trowbridge-Reitz (GGX) only; Beckmann lobes exported with the same alpha")
    if any(np.ptp(lb.ks) > 0 for lb in dec.lobes):
        reasons.append("a lobe's weight is grey in a mix; coloured ks went into its reflectance")
    total = sum(t[0] for t in terms)
    if total > 1:
        reasons.append(f"the terms' weights add up to {total:.3g} > 1: scaled down to 1")
        for t in terms:
            t[0] /= total
    elif total < 1 and terms and not (len(terms) == 1 and terms[0][1] == "diffuse"):
        terms.append([1.0 - total, "diffuse", {"reflectance": np.zeros(3)}])
    if len(terms) == 1 and terms[0][1] == "diffuse":  # a lambert alone: the albedo itself, exact
        terms = [[1.0, "diffuse", {"reflectance": d}]]
        if np.any(d > 1):
            reasons.append("reflectance clipped to 1")
    if not terms:
        terms = [[1.0, "diffuse", {"reflectance": np.zeros(3)}]]
    return [tuple(t) for t in terms], reasons


def _fmt(v) -> str:
    return " ".join(f"{float(x):.9g}" for x in np.atleast_1d(v))


def _text(terms, name: str) -> str:
    lines = [f"# pbrt-v4 material written by gonio: use it with  NamedMaterial \"{name}\""]
    names = []
    for k, (_, kind, p) in enumerate(terms):
        n = name if len(terms) == 1 else f"{name}-{k}"
        names.append(n)
        if kind == "diffuse":
            lines.append(f'MakeNamedMaterial "{n}" "string type" "diffuse" "rgb reflectance" [ {_fmt(p["reflectance"])} ]')
        else:
            lines.append(f'MakeNamedMaterial "{n}" "string type" "conductor" "rgb reflectance" [ {_fmt(p["reflectance"])} ]'
                         f' "float roughness" {p["roughness"]:.9g} "bool remaproughness" false')
    if len(terms) > 1:  # nest: mix(T_k, rest) with amount = mass(rest) / mass(T_k..)
        weights = [t[0] for t in terms]
        inner = names[-1]
        for k in range(len(terms) - 2, -1, -1):
            mass = sum(weights[k:])
            amount = (mass - weights[k]) / mass
            n = name if k == 0 else f"{name}-mix{k}"
            lines.append(f'MakeNamedMaterial "{n}" "string type" "mix" "string materials" [ "{names[k]}" "{inner}" ]'
                         f' "float amount" {amount:.9g}')
            inner = n
    return "\n".join(lines) + "\n"


def to_pbrt(model, name: str = "gonio", approx: bool = False) -> Exported:
    """The pbrt-v4 material text, with its error against ``model``: the mix of diffuse and conductors
    (:func:`pbrt_terms`), or, for a diffuse term under one dielectric lobe (a plastic, a clear coat: grey
    f0 < 1), pbrt-v4's ``coateddiffuse`` fitted to it (:mod:`gonio.io.pbrt_coated`, evaluated by pbrt-v4's own
    layered walk's expectation) when that is closer; the other's error is said beside it."""
    terms, reasons = pbrt_terms(model, approx)
    wi, wo = direction_pairs()
    want = model.eval(wi, wo)
    err = relative_error(pbrt_eval(terms, wi, wo), want)
    coated = _coated_candidate(model, err)
    if coated is not None:
        from gonio.io.pbrt_coated import coated_eval, coated_text

        params, notes = coated
        cerr = relative_error(coated_eval(params, wi, wo), want)
        if cerr < err:
            header = f'# pbrt-v4 material written by gonio: use it with  NamedMaterial "{name}"'
            why = ["pbrt-v4 coateddiffuse (a rough dielectric over a Lambertian base: exact dielectric Fresnel, "
                   "height-correlated G, the base seen through the coating) fitted to the model", *notes,
                   f"closer than diffuse + conductor ({100 * err:.2f} %)"]
            return Exported("pbrt-v4", f"{header}\n{coated_text(params, name)}\n", cerr, why)
        reasons.append(f"closer than coateddiffuse ({100 * cerr:.2f} %)")
    return Exported("pbrt-v4", _text(terms, name), err, reasons)


def _coated_candidate(model, err: float):
    """``fit_coated``'s parameters and notes for a diffuse term under one lobe with a grey f0 < 1 (a dielectric)
    that the mix does not reproduce, else None."""
    from gonio.io.approx import TOLERANCE, single_dielectric

    dec = single_dielectric(model, "pbrt", 0.999) if err >= TOLERANCE else None
    if dec is None or dec.lobes[0].alpha < SMOOTH_ALPHA:
        return None
    lobe = dec.lobes[0]
    f0 = float(lobe.f0[0])
    from gonio.io.pbrt_coated import fit_coated

    eta = (1.0 + np.sqrt(f0)) / (1.0 - np.sqrt(f0))
    return fit_coated(model, lobe.alpha, float(eta))


def write_pbrt(model, path, *, approx: bool = False, option: str = "--pbrt") -> Exported:
    """Write ``model`` as ``path`` (.pbrt); refused unless exact or ``approx``."""
    from pathlib import Path

    return to_pbrt(model, name=Path(path).stem, approx=approx).check(approx, option).write(path, option)
