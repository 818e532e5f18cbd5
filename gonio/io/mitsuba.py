"""Export a fitted model as a Mitsuba 3 BSDF, where Mitsuba has plugins that reproduce it exactly.

Exact correspondences (f is the BRDF, both sides):

* ``lambert(albedo)`` = Mitsuba ``diffuse`` with ``reflectance = albedo`` (f = ρ/π);
* a GGX/Beckmann lobe ``microfacet(kd = 0, ks, alpha, f0 = 1)`` = ``roughconductor`` with
  ``material = "none"`` (F = 1), ``specular_reflectance = ks``, the same ``distribution`` and ``alpha``
  (Walter et al. 2007 with Smith G; Mitsuba's Beckmann uses the same rational G1 approximation:
  tests/brdf/test_reference.py checks gonio against Mitsuba 3's values, max rel. error 3.9e-6);
* a sum of such terms (``microfacet`` with kd > 0, ``lambert+ggx``, ``lambert+2beckmann``, ...) =
  nested ``blendbsdf``: ``blend(A, B, w) = (1 − w) A + w B``, so with term weights p_k (Σ p_k = 1,
  p_k ∝ the term's largest reflectance) and each term's reflectance divided by its p_k the blend is
  the sum exactly (Mitsuba 3 documentation, plugins ``diffuse``, ``roughconductor``, ``blendbsdf``).

Schlick's Fresnel with f0 < 1 has no exact Mitsuba counterpart (its conductor/dielectric plugins use
the exact Fresnel equations). Such a lobe is exported, with ``approx=True`` (``--approx``), as the closest
plugin: ``roughconductor`` with the exact Fresnel equations of a dielectric of the same normal
reflectance (``eta = (1 + √f0)/(1 − √f0)`` per channel, ``k = 0``: Mitsuba's ``fresnel_conductor``
reduces to the dielectric one), the same distribution and α, ``specular_reflectance = ks``; the
cosine-weighted relative error against the model is printed (:mod:`gonio.io.approx`). An f0 within
:data:`F0_TOLERANCE` of 1 (a fit that printed "1") exports as ``material = "none"``, its error printed.
Without ``approx`` those are refused with the reason and the error.

A diffuse term under one dielectric lobe (a grey f0 < 1: plastics, clear coats) has a second candidate
with ``approx``: ``roughplastic`` (:mod:`gonio.io.mitsuba_plastic`: η from f0, the same distribution, α and
ks, the diffuse reflectance matched in least squares); whichever of the two has the smaller error is
written, and the other's error is printed beside it.

Models with no Mitsuba counterpart (ABC, GTR, Phong, Blinn-Phong, Ward, Lafortune, Oren-Nayar,
Cook-Torrance, Ashikhmin-Shirley) are refused with the reason; with ``approx`` a ``lambert+ggx`` fitted to
the model's values (:func:`gonio.io.approx.closest_lobes`) is exported instead, its error against the
model itself printed.
"""

from __future__ import annotations

import json
from xml.sax.saxutils import quoteattr

import numpy as np

from gonio.errors import ConfigError

__all__ = ["to_mitsuba_dict", "to_mitsuba_xml", "write_mitsuba", "mitsuba_export", "mitsuba_eval", "F0_TOLERANCE"]

#: |f0 − 1| up to which a lobe exports as F = 1 (``material = "none"``), its (tiny) error printed.
F0_TOLERANCE = 1e-3


def _rgb(v) -> list[float]:
    a = np.broadcast_to(np.asarray(v, dtype=np.float64), (3,))
    return [float(x) for x in a]


def _terms(model, source: str, approx: bool = False, reasons: list | None = None) -> list[tuple[str, dict, list[float]]]:
    """``(plugin, parameters, reflectance rgb)`` of each additive term of ``model``; ``reasons`` collects
    why the terms are not exact (approximations are made only with ``approx`` or within tolerance)."""
    from gonio.brdf.lambert import Lambert
    from gonio.brdf.lobes import Sum
    from gonio.brdf.microfacet import Microfacet

    reasons = [] if reasons is None else reasons
    if isinstance(model, Sum):
        return [t for part in model.parts for t in _terms(part, source, approx, reasons)]
    if isinstance(model, Lambert):
        return [("diffuse", {}, _rgb(model.albedo))]
    if isinstance(model, Microfacet):
        f0 = np.asarray(_rgb(model.f0))
        lobe = {"distribution": str(model.distribution), "alpha": float(model.alpha)}
        if np.all(f0 == 1.0):
            lobe = {"material": "none", **lobe}
        elif np.all(np.abs(f0 - 1.0) <= F0_TOLERANCE):
            reasons.append(f"f0 = {', '.join(f'{x:.7g}' for x in f0)} exported as 1 (within {F0_TOLERANCE:g})")
            lobe = {"material": "none", **lobe}
        elif approx:
            reasons.append("Schlick's Fresnel replaced by the exact Fresnel equations of the same normal "
                           "reflectance (eta from f0, k = 0)")
            sq = np.sqrt(np.clip(f0, 0.0, 1.0 - 1e-12))
            lobe = {**lobe, "eta": {"type": "rgb", "value": [float(x) for x in (1 + sq) / (1 - sq)]},
                    "k": {"type": "rgb", "value": [0.0, 0.0, 0.0]}}
        else:
            raise ConfigError.field(source, f"{model.name}.f0", _rgb(model.f0),
                                    "Schlick's Fresnel with f0 < 1 has no exact Mitsuba 3 plugin; pass --approx for "
                                    "the closest (roughconductor with the exact Fresnel equations, its error printed) "
                                    "or fit with --fix f0=1")
        terms = [("diffuse", {}, _rgb(model.kd))] if np.any(np.asarray(model.kd) > 0) else []
        return terms + [("roughconductor", lobe, _rgb(model.ks))]
    if approx:
        from gonio.io.approx import closest_lobes

        stand_in, why = closest_lobes(model, "Mitsuba 3")
        reasons.append(why)
        return _terms(stand_in, source, approx, reasons)
    raise ConfigError.field(source, "model", model.name,
                            "has no exact Mitsuba 3 counterpart (exportable: lambert, microfacet with f0 = 1, "
                            "and sums of lambert/ggx/beckmann lobes); pass --approx for the closest (a lambert+ggx "
                            "fitted to it, its error printed)")


def _reflectance(rgb: list[float]) -> dict:
    """An RGB reflectance as Mitsuba 3 accepts it: ``{"type": "rgb", "value": rgb}`` when every value is in
    [0, 1], else an ``srgb`` texture with ``unbounded = true``.

    Mitsuba 3 turns an ``rgb`` reflectance into its ``srgb`` texture, which refuses a colour outside [0, 1]
    unless ``unbounded`` is set ("Invalid RGB reflectance value ..., must be in the range [0, 1]!":
    mitsuba-renderer/mitsuba3 ``src/textures/srgb.cpp``; ``src/core/xml.cpp`` ``create_texture_from_rgb`` sets
    ``unbounded`` only for ``eta``, ``k``, ``int_ior``, ``ext_ior``). A blend term's reflectance is divided by
    its weight, so it exceeds 1 whenever the terms' largest reflectances add up to more than 1.
    """
    if all(0.0 <= c <= 1.0 for c in rgb):
        return {"type": "rgb", "value": rgb}
    return {"type": "srgb", "color": rgb, "unbounded": True}


def _rgb_of(spec: dict) -> np.ndarray:
    """The RGB values of a :func:`_reflectance` (an ``rgb`` value or an ``srgb`` texture's colour)."""
    return np.asarray(spec["color"] if spec.get("type") == "srgb" else spec["value"], dtype=np.float64)


def _plugin(kind: str, params: dict, rgb: list[float]) -> dict:
    key = "reflectance" if kind == "diffuse" else "specular_reflectance"
    return {"type": kind, **params, key: _reflectance(rgb)}


def to_mitsuba_dict(model, source: str = "--mitsuba", approx: bool = False, reasons: list | None = None) -> dict:
    """The Mitsuba 3 BSDF dictionary (for ``mitsuba.load_dict``) reproducing ``model`` exactly (or, with
    ``approx``, the closest; ``reasons`` receives why it is not exact)."""
    reasons = [] if reasons is None else reasons
    all_terms = _terms(model, source, approx, reasons)
    terms = [t for t in all_terms if max(t[2]) > 0] or all_terms[:1]
    size = np.array([max(max(rgb), 1e-300) for _, _, rgb in terms])
    p = size / size.sum()  # term weights; each reflectance / p_k, so Σ p_k · (term / p_k) = the sum

    def nest(k: int, mass: float) -> dict:
        """Terms k.. blended with weights p_j / mass (mass = Σ_{j≥k} p_j) over T_j / p_j: Σ_{j≥k} T_j / mass."""
        kind, params, rgb = terms[k]
        head = _plugin(kind, params, [c / p[k] for c in rgb])
        if k == len(terms) - 1:
            return head
        rest = mass - p[k]
        return {"type": "blendbsdf", "weight": float(rest / mass), "bsdf_0": head, "bsdf_1": nest(k + 1, rest)}

    if len(terms) == 1:
        kind, params, rgb = terms[0]
        return _plugin(kind, params, rgb)
    return nest(0, 1.0)


#: The scene-format version the root ``<bsdf>`` element declares: Mitsuba 3 loads a file (``mitsuba.load_file``,
#: ``<include>``) only when its root element has one ("missing version attribute in root element")
XML_VERSION = "3.0.0"


def to_mitsuba_xml(model, source: str = "--mitsuba", approx: bool = False) -> str:
    """The same BSDF as a Mitsuba 3 ``<bsdf>`` element with ``version`` (:data:`XML_VERSION`): a file
    ``mitsuba.load_file`` loads and a scene can ``<include>``; pasted into a scene, drop the attribute."""
    return _xml(to_mitsuba_dict(model, source, approx))


def _xml(bsdf: dict) -> str:
    """A BSDF dictionary as a Mitsuba 3 ``<bsdf>`` element, the root declaring :data:`XML_VERSION`."""

    def emit(d: dict, name: str | None, depth: int) -> list[str]:
        pad = "    " * depth
        attr = (f" type={quoteattr(d['type'])}" + (f" name={quoteattr(name)}" if name else "")
                + (f" version={quoteattr(XML_VERSION)}" if depth == 0 else ""))
        lines = [f"{pad}<bsdf{attr}>"]
        for k, v in d.items():
            if k == "type":
                continue
            if isinstance(v, dict) and v.get("type") == "rgb":
                lines.append(f"{pad}    <rgb name={quoteattr(k)} value=\"{', '.join(f'{x:.9g}' for x in v['value'])}\"/>")
            elif isinstance(v, dict) and v.get("type") == "srgb":  # an unbounded reflectance (_reflectance)
                lines += [f"{pad}    <texture type=\"srgb\" name={quoteattr(k)}>",
                          f"{pad}        <rgb name=\"color\" value=\"{', '.join(f'{x:.9g}' for x in v['color'])}\"/>",
                          f"{pad}        <boolean name=\"unbounded\" value=\"{str(bool(v['unbounded'])).lower()}\"/>",
                          f"{pad}    </texture>"]
            elif isinstance(v, dict):
                lines += emit(v, None, depth + 1)
            elif isinstance(v, bool):
                lines.append(f"{pad}    <boolean name={quoteattr(k)} value=\"{str(v).lower()}\"/>")
            elif isinstance(v, float):
                lines.append(f"{pad}    <float name={quoteattr(k)} value=\"{v:.9g}\"/>")
            else:
                lines.append(f"{pad}    <string name={quoteattr(k)} value={quoteattr(str(v))}/>")
        return lines + [f"{pad}</bsdf>"]

    return "\n".join(emit(bsdf, None, 0)) + "\n"


def mitsuba_eval(d: dict, wi, wo) -> np.ndarray:
    """f (1/sr, RGB) of a BSDF dictionary by the plugins' definitions: ``diffuse`` ρ/π;
    ``roughconductor`` ks·D·G·F/(4 cosθi cosθo) with Walter et al.'s D and separable Smith G (gonio's
    microfacet lobe: tests/brdf/test_reference.py checks it against Mitsuba 3's values) and F = 1
    (``material = "none"``) or the conductor Fresnel equations of ``eta + i k``
    (:func:`gonio.io.pbrt.fr_complex`); ``blendbsdf`` (1 − w)·bsdf_0 + w·bsdf_1."""
    from gonio.brdf import make
    from gonio.io.pbrt import fr_complex

    wi = np.asarray(wi, dtype=np.float64)
    wo = np.asarray(wo, dtype=np.float64)
    if d["type"] == "diffuse":
        return make("lambert", albedo=1.0).eval(wi, wo) * _rgb_of(d["reflectance"])
    if d["type"] == "roughplastic":
        from gonio.io.mitsuba_plastic import roughplastic_eval

        return roughplastic_eval(d, wi, wo)
    if d["type"] == "roughconductor":
        lobe = make("microfacet", kd=0.0, ks=1.0, alpha=d["alpha"], f0=1.0, distribution=d["distribution"])
        v = lobe.eval(wi, wo) * _rgb_of(d["specular_reflectance"])
        if d.get("material") != "none":
            h = wi + wo
            h = h / np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-300)
            eta = np.asarray(d["eta"]["value"]) + 1j * np.asarray(d["k"]["value"])
            v = v * fr_complex(np.abs(np.sum(wo * h, axis=-1)), eta)
        return v
    return (1 - d["weight"]) * mitsuba_eval(d["bsdf_0"], wi, wo) + d["weight"] * mitsuba_eval(d["bsdf_1"], wi, wo)


def mitsuba_export(model, path=None, *, approx: bool = False, option: str = "--mitsuba"):
    """:class:`gonio.io.approx.Exported` for ``model``: the XML (``path`` ending in .xml) or load_dict JSON,
    its error against the model, why it is not exact. Refused unless exact, within tolerance, or ``approx``."""
    from pathlib import Path

    from gonio.io.approx import EXACT, Exported, direction_pairs, relative_error

    reasons: list[str] = []
    d = to_mitsuba_dict(model, option, approx, reasons)
    wi, wo = direction_pairs()
    want = model.eval(wi, wo)
    err = relative_error(mitsuba_eval(d, wi, wo), want)
    if approx and err >= EXACT:
        plastic = _roughplastic_candidate(model, wi, wo)
        if plastic is not None:
            pd, why = plastic
            perr = relative_error(mitsuba_eval(pd, wi, wo), want)
            if perr < err:
                reasons = why + [f"closer than diffuse + roughconductor ({100 * err:.2f} %)"]
                d, err = pd, perr
            else:
                reasons.append(f"closer than roughplastic ({100 * perr:.2f} %)")
    xml = path is not None and Path(path).suffix.lower() == ".xml"
    text = _xml(d) if xml else json.dumps(d, indent=2) + "\n"
    ex = Exported("Mitsuba 3", text, err, reasons)
    return ex.check(approx, option)  # exact, within tolerance, or asked for


def _roughplastic_candidate(model, wi, wo):
    """``(roughplastic dict, reasons)`` for a diffuse term plus one lobe of grey f0 < 1 (a dielectric: plastics,
    paints' clear coats), else None (:mod:`gonio.io.mitsuba_plastic`)."""
    from gonio.io.approx import single_dielectric
    from gonio.io.mitsuba_plastic import roughplastic_dict

    dec = single_dielectric(model, "Mitsuba 3", 1.0 - F0_TOLERANCE)
    if dec is None:
        return None
    lobe = dec.lobes[0]
    return roughplastic_dict(dec.diffuse, lobe.ks, float(lobe.f0[0]), lobe.alpha, lobe.distribution, wi, wo)


def write_mitsuba(model, path, *, approx: bool = False, option: str = "--mitsuba"):
    """``path`` ending in ``.xml``: the scene-file element; otherwise the dictionary as JSON. Returns the
    :class:`gonio.io.approx.Exported` (its :meth:`describe` says exact or the error). ``option`` is the
    command-line option named in a refusal (``--mitsuba`` of gonio fit, ``-o`` of gonio export)."""
    from pathlib import Path

    return mitsuba_export(model, Path(path), approx=approx, option=option).write(path, option)
