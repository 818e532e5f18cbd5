"""Export a fitted model as a glTF 2.0 material (metallic-roughness + ``KHR_materials_specular`` +
``KHR_materials_ior``), on a sphere, as a self-contained ``.gltf`` (JSON, buffer as a data URI) that
Blender and game engines import.

The material's BRDF is the glTF 2.0 specification's Appendix B ("BRDF implementation") with the
Fresnel term of ``KHR_materials_specular`` (its "Implementation" section) and the F0 of
``KHR_materials_ior``::

    α = roughness²
    D = α² / (π ((n·h)² (α² − 1) + 1)²)                                   (Trowbridge-Reitz / GGX)
    V = 1 / (2 (|n·v| sqrt(α² + (1 − α²)(n·l)²) + |n·l| sqrt(α² + (1 − α²)(n·v)²)))
                                       (the height-correlated Smith G / (4 |n·l| |n·v|), Appendix B "Specular BRDF")
    w = (1 − v·h)⁵
    F_d = F0_d + (specular − F0_d) w,   F0_d = min(((ior − 1)/(ior + 1))² · specularColor, 1) · specular
    F_m = baseColor + (1 − baseColor) w
    f = (1 − metallic) (F_d · D · V + (1 − max(F_d)) · baseColor / π) + metallic · F_m · D · V

(the ratified ``KHR_materials_specular``, KhronosGroup/glTF extensions/2.0/Khronos/KHR_materials_specular/README.md
"Implementation": the diffuse base is weighted by 1 − max_value(dielectric_fresnel), one number for the three
channels, not by (1 − F) per channel as in the extension's first draft).

A lambert alone is this material exactly (metallic 0, specular 0). gonio's GGX lobe
``ks·D·G·F_schlick(f0)/(4 cosθi cosθo)`` maps onto it with the same D and Fresnel form when ks is grey
(metallic 0, baseColor 0, specular = ks, F0 = ks·f0 through ior and specularColor), or ks = 1 (metallic 1,
baseColor = f0), but its G is the *separable* Smith G1(l) G1(v), glTF's the height-correlated one (larger
towards grazing): an approximation whose error grows with α (below the tolerance for α ≲ 0.05). A diffuse
term beside a lobe is weighted by (1 − F) in glTF and not in gonio, one lobe only, GGX only: those are
approximations too (:mod:`gonio.io.approx`), the closest under the mapping (the base colour by least
squares), with the error printed — the error of the specification's BRDF (tests/io/test_renderer_exports.py
evaluates it from the exported document by the specification's formulas, independently of this module).
"""

from __future__ import annotations

import base64
import json

import numpy as np

from gonio.io.approx import Exported, decompose, direction_pairs, relative_error

__all__ = ["gltf_material", "gltf_eval", "to_gltf", "write_gltf"]


def _dot(a, b):
    return np.sum(a * b, axis=-1)


def gltf_eval(mat: dict, wi, wo) -> np.ndarray:
    """f (1/sr, RGB) of a material given as ``{"baseColor", "metallic", "roughness", "ior", "specular",
    "specularColor"}`` by the formulas of the module docstring (0 below the horizon)."""
    wi = np.asarray(wi, dtype=np.float64)
    wo = np.asarray(wo, dtype=np.float64)
    n_l, n_v = wi[..., 2], wo[..., 2]
    h = wi + wo
    h = h / np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-300)
    n_h, v_h = h[..., 2], _dot(wo, h)
    a = float(mat["roughness"]) ** 2
    a2 = a * a
    d = a2 / (np.pi * (n_h * n_h * (a2 - 1.0) + 1.0) ** 2)

    with np.errstate(invalid="ignore", divide="ignore"):  # the height-correlated visibility ν
        v = 0.5 / (np.abs(n_v) * np.sqrt(a2 + (1.0 - a2) * n_l * n_l) + np.abs(n_l) * np.sqrt(a2 + (1.0 - a2) * n_v * n_v))
    base = np.asarray(mat["baseColor"], dtype=np.float64)
    m = float(mat["metallic"])
    ior = float(mat["ior"])
    f0_ior = 1.0 if ior == 0 else ((ior - 1.0) / (ior + 1.0)) ** 2
    spec = float(mat["specular"])
    w = ((1.0 - v_h) ** 5)[..., None]
    f0_d = np.minimum(f0_ior * np.asarray(mat["specularColor"], dtype=np.float64), 1.0) * spec
    fr_d = f0_d + (spec - f0_d) * w  # dielectric_fresnel (RGB)
    fr_m = base + (1.0 - base) * w  # conductor_fresnel of the metal BRDF
    lobe = (d * v)[..., None]
    dielectric = fr_d * lobe + (1.0 - np.max(fr_d, axis=-1, keepdims=True)) * base / np.pi
    f = (1 - m) * dielectric + m * fr_m * lobe
    above = (n_l > 0) & (n_v > 0)
    return np.where(above[..., None], np.nan_to_num(f), 0.0)


def _ior_for(f0: float) -> float:
    """The ior whose ((ior − 1)/(ior + 1))² is f0 (0 for f0 = 1, the extension's convention)."""
    if f0 >= 1.0:
        return 0.0
    s = np.sqrt(max(f0, 0.0))
    return float((1 + s) / (1 - s))


def gltf_material(model, approx: bool = False) -> tuple[dict, list[str]]:
    """The closest glTF material (dict as :func:`gltf_eval` takes) and why it is not exact (``approx``: a
    model glTF has no counterpart for is taken as :func:`gonio.io.approx.closest_lobes`)."""
    reasons: list[str] = []
    dec = decompose(model, "glTF", approx=approx, reasons=reasons)
    d = dec.diffuse
    if not dec.lobes:
        if np.any(d > 1):
            reasons.append("baseColor clipped to 1")
        return {"baseColor": np.clip(d, 0, 1), "metallic": 0.0, "roughness": 1.0, "ior": 1.5, "specular": 0.0,
                "specularColor": np.ones(3)}, reasons
    reasons.append("glTF's visibility is the height-correlated Smith G, gonio's lobe the separable one")
    order = sorted(range(len(dec.lobes)), key=lambda k: -float(np.mean(dec.lobes[k].ks)))
    lobe = dec.lobes[order[0]]
    if len(dec.lobes) > 1:
        reasons.append(f"glTF has one specular lobe: {len(dec.lobes) - 1} weaker lobe(s) left out")
    if lobe.distribution != "ggx":
        reasons.append(f"glTF's distribution is GGX, the lobe's {lobe.distribution} (same alpha)")
    rough = float(np.sqrt(lobe.alpha))
    ks, f0 = lobe.ks, lobe.f0
    if not np.any(d > 0) and np.all(ks == 1.0):
        return {"baseColor": np.clip(f0, 0, 1), "metallic": 1.0, "roughness": rough, "ior": 1.5, "specular": 1.0,
                "specularColor": np.ones(3)}, reasons
    spec = float(np.mean(ks))
    if np.ptp(ks) > 0:
        reasons.append("glTF's grazing reflectance (specular) is grey; ks is coloured")
    f0_eff = ks * f0 / spec if spec > 0 else np.zeros(3)
    peak = float(np.max(f0_eff))
    if peak > 1:
        reasons.append("normal-incidence reflectance above the grazing one clipped")
        f0_eff = np.minimum(f0_eff, 1.0)
        peak = 1.0
    ior = _ior_for(peak)
    colour = f0_eff / peak if peak > 0 else np.ones(3)
    mat = {"baseColor": np.zeros(3), "metallic": 0.0, "roughness": rough, "ior": ior, "specular": spec,
           "specularColor": colour}
    if np.any(d > 0):
        reasons.append("glTF weights the diffuse term by (1 − F), gonio does not")  # F: its largest channel
        wi, wo = direction_pairs(2048, seed=7)
        spec_only = gltf_eval(mat, wi, wo)
        one = gltf_eval({**mat, "baseColor": np.ones(3)}, wi, wo) - spec_only  # (1 − max F)/π
        target = model.eval(wi, wo) - spec_only
        base = np.sum(one * target, axis=0) / np.maximum(np.sum(one * one, axis=0), 1e-300)
        if np.any(base > 1):
            reasons.append("baseColor clipped to 1")
        mat["baseColor"] = np.clip(base, 0.0, 1.0)
    return mat, reasons


def _sphere(n_lat: int = 24, n_lon: int = 48):
    th = np.linspace(0, np.pi, n_lat + 1)
    ph = np.linspace(0, 2 * np.pi, n_lon + 1)
    T, P = np.meshgrid(th, ph, indexing="ij")
    pos = np.stack([np.sin(T) * np.cos(P), np.cos(T), np.sin(T) * np.sin(P)], axis=-1).reshape(-1, 3).astype("<f4")
    idx = []
    w = n_lon + 1
    for i in range(n_lat):
        for j in range(n_lon):
            a, b, c, e = i * w + j, i * w + j + 1, (i + 1) * w + j, (i + 1) * w + j + 1
            idx += [a, c, b, b, c, e]
    return pos, np.asarray(idx, dtype="<u2")


def _document(mat: dict, name: str) -> dict:
    from gonio import __version__

    pos, idx = _sphere()
    blob = pos.tobytes() + pos.tobytes() + idx.tobytes()  # positions, normals (= positions), indices
    n = len(pos)
    material = {
        "name": name,
        "pbrMetallicRoughness": {"baseColorFactor": [*(float(x) for x in mat["baseColor"]), 1.0],
                                 "metallicFactor": float(mat["metallic"]), "roughnessFactor": float(mat["roughness"])},
        "extensions": {"KHR_materials_specular": {"specularFactor": float(mat["specular"]),
                                                  "specularColorFactor": [float(x) for x in mat["specularColor"]]},
                       "KHR_materials_ior": {"ior": float(mat["ior"])}},
    }
    return {
        "asset": {"version": "2.0", "generator": f"gonio {__version__}"},
        "extensionsUsed": ["KHR_materials_specular", "KHR_materials_ior"],
        "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0, "name": name}],
        "meshes": [{"name": name, "primitives": [{"attributes": {"POSITION": 0, "NORMAL": 1}, "indices": 2,
                                                   "material": 0}]}],
        "materials": [material],
        "buffers": [{"byteLength": len(blob),
                     "uri": "data:application/octet-stream;base64," + base64.b64encode(blob).decode("ascii")}],
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": pos.nbytes, "target": 34962},
                        {"buffer": 0, "byteOffset": pos.nbytes, "byteLength": pos.nbytes, "target": 34962},
                        {"buffer": 0, "byteOffset": 2 * pos.nbytes, "byteLength": idx.nbytes, "target": 34963}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": n, "type": "VEC3",
             "min": [float(x) for x in pos.min(axis=0)], "max": [float(x) for x in pos.max(axis=0)]},
            {"bufferView": 1, "componentType": 5126, "count": n, "type": "VEC3"},
            {"bufferView": 2, "componentType": 5123, "count": len(idx), "type": "SCALAR"},
        ],
    }


def to_gltf(model, name: str = "gonio material", approx: bool = False) -> Exported:
    """The glTF document (text) of the closest material, with its error against ``model``."""
    mat, reasons = gltf_material(model, approx)
    wi, wo = direction_pairs()
    err = relative_error(gltf_eval(mat, wi, wo), model.eval(wi, wo))
    return Exported("glTF", json.dumps(_document(mat, name), indent=1) + "\n", err, reasons)


def write_gltf(model, path, *, approx: bool = False, option: str = "--gltf") -> Exported:
    """Write ``model`` as ``path`` (.gltf); refused unless exact or ``approx`` (:meth:`Exported.check`)."""
    from pathlib import Path

    return to_gltf(model, name=Path(path).stem, approx=approx).check(approx, option).write(path, option)
