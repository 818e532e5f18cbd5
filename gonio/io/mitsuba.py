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
the exact Fresnel equations), nor have Phong, Blinn-Phong, Ward, Lafortune, Oren-Nayar, Cook-Torrance
and Ashikhmin-Shirley as gonio defines them: those are refused with a one-line error rather than
approximated (fit with ``--fix f0=1`` to get an exportable lobe whose ks carries the reflectance).
"""

from __future__ import annotations

import json
from xml.sax.saxutils import quoteattr

import numpy as np

from gonio.errors import ConfigError

__all__ = ["to_mitsuba_dict", "to_mitsuba_xml", "write_mitsuba"]


def _rgb(v) -> list[float]:
    a = np.broadcast_to(np.asarray(v, dtype=np.float64), (3,))
    return [float(x) for x in a]


def _terms(model, source: str) -> list[tuple[str, dict, list[float]]]:
    """``(plugin, parameters, reflectance rgb)`` of each additive term of ``model``."""
    from gonio.brdf.lambert import Lambert
    from gonio.brdf.lobes import Sum
    from gonio.brdf.microfacet import Microfacet

    if isinstance(model, Sum):
        return [t for part in model.parts for t in _terms(part, source)]
    if isinstance(model, Lambert):
        return [("diffuse", {}, _rgb(model.albedo))]
    if isinstance(model, Microfacet):
        if not np.allclose(np.asarray(model.f0, dtype=np.float64), 1.0, rtol=0, atol=1e-12):
            raise ConfigError.field(source, f"{model.name}.f0", _rgb(model.f0),
                                    "Schlick's Fresnel with f0 < 1 has no exact Mitsuba 3 plugin; "
                                    "fit with --fix f0=1 to export")
        terms = [("diffuse", {}, _rgb(model.kd))] if np.any(np.asarray(model.kd) > 0) else []
        return terms + [("roughconductor", {"material": "none", "distribution": str(model.distribution),
                                            "alpha": float(model.alpha)}, _rgb(model.ks))]
    raise ConfigError.field(source, "model", model.name,
                            "has no exact Mitsuba 3 counterpart (exportable: lambert, microfacet with f0 = 1, "
                            "and sums of lambert/ggx/beckmann lobes)")


def _plugin(kind: str, params: dict, rgb: list[float]) -> dict:
    key = "reflectance" if kind == "diffuse" else "specular_reflectance"
    return {"type": kind, **params, key: {"type": "rgb", "value": rgb}}


def to_mitsuba_dict(model, source: str = "--mitsuba") -> dict:
    """The Mitsuba 3 BSDF dictionary (for ``mitsuba.load_dict``) reproducing ``model`` exactly."""
    terms = [t for t in _terms(model, source) if max(t[2]) > 0] or _terms(model, source)[:1]
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


def to_mitsuba_xml(model, source: str = "--mitsuba") -> str:
    """The same BSDF as a Mitsuba 3 scene-file ``<bsdf>`` element."""

    def emit(d: dict, name: str | None, depth: int) -> list[str]:
        pad = "    " * depth
        attr = f" type={quoteattr(d['type'])}" + (f" name={quoteattr(name)}" if name else "")
        lines = [f"{pad}<bsdf{attr}>"]
        for k, v in d.items():
            if k == "type":
                continue
            if isinstance(v, dict) and v.get("type") == "rgb":
                lines.append(f"{pad}    <rgb name={quoteattr(k)} value=\"{', '.join(f'{x:.9g}' for x in v['value'])}\"/>")
            elif isinstance(v, dict):
                lines += emit(v, None, depth + 1)
            elif isinstance(v, float):
                lines.append(f"{pad}    <float name={quoteattr(k)} value=\"{v:.9g}\"/>")
            else:
                lines.append(f"{pad}    <string name={quoteattr(k)} value={quoteattr(str(v))}/>")
        return lines + [f"{pad}</bsdf>"]

    return "\n".join(emit(to_mitsuba_dict(model, source), None, 0)) + "\n"


def write_mitsuba(model, path) -> None:
    """``path`` ending in ``.xml``: the scene-file element; otherwise the dictionary as JSON."""
    from pathlib import Path

    p = Path(path)
    text = to_mitsuba_xml(model) if p.suffix.lower() == ".xml" else json.dumps(to_mitsuba_dict(model), indent=2) + "\n"
    try:
        p.write_text(text, encoding="utf-8")
    except OSError as exc:
        raise ConfigError.field("--mitsuba", "mitsuba", str(p), f"cannot write ({exc.strerror or exc})") from None
