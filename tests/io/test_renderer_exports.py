"""pbrt-v4 and glTF 2.0 exports, evaluated here with the targets' published formulas (written in this
file from the glTF 2.0 spec's Appendix B + KHR_materials_specular/KHR_materials_ior, and pbrt-v4's
diffuse/conductor/mix materials), against the model: exact where the export says exact, and the printed
error is the true error where it says approximation. Also gonio fit --gltf/--pbrt/--approx and --fix names."""

from __future__ import annotations

import base64
import json
import re

import numpy as np
import pytest

from gonio.brdf import make
from gonio.cli.main import main
from gonio.errors import ConfigError
from gonio.geometry import from_spherical
from gonio.io.csv import write_csv
from gonio.io.gltf import to_gltf
from gonio.io.pbrt import to_pbrt
from gonio.samples import SampleSet


def pairs(n=3000, seed=5):
    rng = np.random.default_rng(seed)
    wi = from_spherical(np.arccos(rng.uniform(0.05, 1, n)), rng.uniform(0, 2 * np.pi, n))
    wo = from_spherical(np.arccos(rng.uniform(0.05, 1, n)), rng.uniform(0, 2 * np.pi, n))
    return wi, wo


# --- glTF 2.0, Appendix B (+ KHR_materials_specular, KHR_materials_ior) --------------------------------
def gltf_reference(doc: dict, wi, wo) -> np.ndarray:
    m = doc["materials"][0]
    pbr = m["pbrMetallicRoughness"]
    base = np.array(pbr.get("baseColorFactor", [1, 1, 1, 1])[:3])
    metallic = pbr.get("metallicFactor", 1.0)
    alpha = pbr.get("roughnessFactor", 1.0) ** 2
    ext = m.get("extensions", {})
    spec = ext.get("KHR_materials_specular", {}).get("specularFactor", 1.0)
    spec_col = np.array(ext.get("KHR_materials_specular", {}).get("specularColorFactor", [1, 1, 1]))
    ior = ext.get("KHR_materials_ior", {}).get("ior", 1.5)
    out = np.zeros(wi.shape[:-1] + (3,))
    for n in range(len(wi)):
        L, V = wi[n], wo[n]
        H = (L + V) / np.linalg.norm(L + V)
        NdotL, NdotV, NdotH, VdotH = L[2], V[2], H[2], V @ H
        LdotH = L @ H
        D = alpha ** 2 * (NdotH > 0) / (np.pi * (NdotH ** 2 * (alpha ** 2 - 1) + 1) ** 2)
        # glTF 2.0 Appendix B "Specular BRDF": the height-correlated Smith joint masking-shadowing function G
        # and MicrofacetBRDF = G D / (4 |N·L| |N·V|)
        G = (2 * abs(NdotL) * abs(NdotV) * (LdotH > 0) * (VdotH > 0)
             / (abs(NdotV) * np.sqrt(alpha ** 2 + (1 - alpha ** 2) * NdotL ** 2)
                + abs(NdotL) * np.sqrt(alpha ** 2 + (1 - alpha ** 2) * NdotV ** 2)))
        Vis = G / (4 * abs(NdotL) * abs(NdotV))
        ior_f0 = 1.0 if ior == 0 else ((ior - 1) / (ior + 1)) ** 2
        # KHR_materials_specular (ratified text, "Implementation"): dielectric_f0 = min(f0_ior * specularColor, 1)
        # * specular, dielectric_f90 = specular; dielectric_brdf = dielectric_fresnel * specular_brdf
        # + (1 - max_value(dielectric_fresnel)) * diffuse_brdf; glTF Appendix B: mix(dielectric, metal, metallic)
        F_d0 = np.minimum(ior_f0 * spec_col, 1.0) * spec
        F_d = F_d0 + (spec - F_d0) * (1 - VdotH) ** 5
        F_m = base + (1 - base) * (1 - VdotH) ** 5
        dielectric = F_d * D * Vis + (1 - F_d.max()) * base / np.pi
        out[n] = (1 - metallic) * dielectric + metallic * F_m * D * Vis
    return out


def test_gltf_diffuse_is_weighted_by_the_largest_fresnel_channel():
    """KHR_materials_specular (ratified): 'The base is weighted with 1 - weight * max_value(fresnel(ior, f0_color))'
    (KhronosGroup/glTF extensions/2.0/Khronos/KHR_materials_specular/README.md). gonio weighted it by (1 − F) per
    channel (the extension's first draft): with a coloured specularColor and a diffuse base its values differed
    from the specification's by up to 80 % and the printed error was 2.2 % instead of 6.6 % (found by QA)."""
    from gonio.io.gltf import gltf_eval

    mat = {"baseColor": np.array([0.5, 0.3, 0.1]), "metallic": 0.0, "roughness": 0.45, "ior": 3.0, "specular": 0.6,
           "specularColor": np.array([1.0, 0.5, 0.2])}
    wi, wo = pairs(300)
    f0 = 0.25 * mat["specularColor"] * 0.6  # ((3 - 1)/(3 + 1))² = 0.25
    h = (wi + wo) / np.linalg.norm(wi + wo, axis=-1, keepdims=True)
    F = f0 + (0.6 - f0) * ((1 - np.sum(wo * h, -1)) ** 5)[:, None]
    diffuse = gltf_eval(mat, wi, wo) - gltf_eval({**mat, "baseColor": np.zeros(3)}, wi, wo)
    np.testing.assert_allclose(diffuse, (1 - F.max(axis=1, keepdims=True)) * mat["baseColor"] / np.pi, rtol=1e-12)
    doc = {"materials": [{"pbrMetallicRoughness": {"baseColorFactor": [0.5, 0.3, 0.1, 1], "metallicFactor": 0.0,
                                                   "roughnessFactor": 0.45},
                          "extensions": {"KHR_materials_specular": {"specularFactor": 0.6,
                                                                    "specularColorFactor": [1.0, 0.5, 0.2]},
                                         "KHR_materials_ior": {"ior": 3.0}}}]}
    np.testing.assert_allclose(gltf_eval(mat, wi, wo), gltf_reference(doc, wi, wo), rtol=1e-12)


GLTF_CASES = [
    ("lambert", {"albedo": [0.6, 0.3, 0.1]}),
    ("microfacet", {"kd": 0.0, "ks": 0.7, "alpha": 0.2, "f0": [0.9, 0.6, 0.3], "distribution": "ggx"}),
    ("microfacet", {"kd": 0.0, "ks": 1.0, "alpha": 0.4, "f0": [0.95, 0.64, 0.54], "distribution": "ggx"}),
    ("lambert+ggx", {"diffuse.albedo": 0.0, "lobe1.ks": 0.5, "lobe1.alpha": 0.1, "lobe1.f0": 0.04}),
    ("microfacet", {"kd": [0.3, 0.12, 0.06], "ks": 0.8, "alpha": 0.25, "f0": 0.04, "distribution": "ggx"}),
]


@pytest.mark.parametrize("name, params", GLTF_CASES, ids=[f"{m[0]}-{i}" for i, m in enumerate(GLTF_CASES)])
def test_gltf_printed_error_is_the_specifications(name, params):
    """The printed error is what the glTF specification's BRDF gives: the exported document evaluated here by
    the specification's formulas (gltf_reference: a loop over the pairs, reading the JSON), the same
    cosine-weighted relative RMS over the same pairs. gonio printed 0.84 % for the default red plastic where
    the specification's BRDF is further off (its G is height-correlated, gonio's export evaluated it separable;
    found by an independent evaluation). Exact only for a lambert: a GGX lobe's separable G is not glTF's."""
    from gonio.io.approx import direction_pairs, relative_error

    model = make(name, **params)
    ex = to_gltf(model, approx=True)
    doc = json.loads(ex.text)
    wi, wo = direction_pairs()
    spec = gltf_reference(doc, wi, wo)
    assert relative_error(spec, model.eval(wi, wo)) == pytest.approx(ex.error, rel=1e-6, abs=1e-12)
    assert ex.exact == (name == "lambert")
    if not ex.exact:
        assert "height-correlated" in ex.describe() and ex.error < 0.05
    if name == "microfacet" and params["kd"] != 0.0:  # the default red plastic
        assert 0.01 < ex.error < 0.012


def test_gltf_approximation_error_is_the_true_error():
    from gonio.io.approx import direction_pairs, relative_error

    model = make("microfacet", kd=[0.3, 0.2, 0.1], ks=0.8, alpha=0.2, f0=0.04, distribution="ggx")
    ex = to_gltf(model)
    assert not ex.exact and "(1 − F)" in ex.describe() and "APPROXIMATION" in ex.describe()
    wi, wo = direction_pairs()
    wi, wo = wi[:1500], wo[:1500]
    independent = relative_error(gltf_reference(json.loads(ex.text), wi, wo), model.eval(wi, wo))
    assert independent == pytest.approx(ex.error, rel=0.15)  # same metric on a subset of the pairs
    assert 0 < ex.error < 0.05
    with pytest.raises(ConfigError, match=r"--gltf: .*cannot represent the model exactly .*pass --approx"):
        ex.check(False, "--gltf")


def test_gltf_document_is_valid_gltf_2():
    doc = json.loads(to_gltf(make("lambert", albedo=0.5)).text)
    assert doc["asset"]["version"] == "2.0"
    assert set(doc["extensionsUsed"]) == {"KHR_materials_specular", "KHR_materials_ior"}
    buf = doc["buffers"][0]
    head, data = buf["uri"].split(",", 1)
    assert head == "data:application/octet-stream;base64"
    blob = base64.b64decode(data)
    assert len(blob) == buf["byteLength"]
    sizes = {5126: 4, 5123: 2}
    comps = {"VEC3": 3, "SCALAR": 1}
    for acc in doc["accessors"]:
        view = doc["bufferViews"][acc["bufferView"]]
        assert view["byteOffset"] + view["byteLength"] <= len(blob)
        assert acc["count"] * sizes[acc["componentType"]] * comps[acc["type"]] == view["byteLength"]
    prim = doc["meshes"][0]["primitives"][0]
    pos = doc["accessors"][prim["attributes"]["POSITION"]]
    assert "min" in pos and "max" in pos  # required for POSITION
    iv = doc["bufferViews"][doc["accessors"][prim["indices"]]["bufferView"]]
    idx = np.frombuffer(blob[iv["byteOffset"]:iv["byteOffset"] + iv["byteLength"]], "<u2")
    assert idx.max() < pos["count"] and len(idx) % 3 == 0
    assert doc["nodes"][doc["scenes"][doc["scene"]]["nodes"][0]]["mesh"] == 0


# --- pbrt-v4: diffuse, conductor (Trowbridge-Reitz, height-correlated Smith, FrComplex), mix -------------
def _fr_complex(cos_i, eta):
    cos_i = min(max(cos_i, 0.0), 1.0)
    sin2_i = 1 - cos_i ** 2
    sin2_t = sin2_i / eta ** 2
    cos_t = np.sqrt(1 - sin2_t + 0j)
    r_parl = (eta * cos_i - cos_t) / (eta * cos_i + cos_t)
    r_perp = (cos_i - eta * cos_t) / (cos_i + eta * cos_t)
    return (abs(r_parl) ** 2 + abs(r_perp) ** 2) / 2


def _pbrt_material(mats, name, L, V):
    kind, p = mats[name]
    if kind == "diffuse":
        return np.clip(p["reflectance"], 0, 1) / np.pi
    if kind == "mix":
        a, b = p["materials"]
        return (1 - p["amount"]) * _pbrt_material(mats, a, L, V) + p["amount"] * _pbrt_material(mats, b, L, V)
    alpha = p["roughness"]
    if alpha < 1e-3:  # TrowbridgeReitzDistribution::EffectivelySmooth: a perfect mirror, f = 0 off the delta
        return np.zeros(3)
    H = (L + V) / np.linalg.norm(L + V)
    cos2 = H[2] ** 2
    tan2 = (1 - cos2) / cos2
    D = 1 / (np.pi * alpha ** 2 * cos2 ** 2 * (1 + tan2 / alpha ** 2) ** 2)

    def lam(w):
        t2 = (1 - w[2] ** 2) / w[2] ** 2
        return (np.sqrt(1 + alpha ** 2 * t2) - 1) / 2

    G = 1 / (1 + lam(V) + lam(L))
    out = np.zeros(3)
    for c, r in enumerate(p["reflectance"]):
        k = 2 * np.sqrt(r) / np.sqrt(1 - r)
        out[c] = D * _fr_complex(abs(V @ H), 1 + 1j * k) * G / (4 * L[2] * V[2])
    return out


def parse_pbrt(text: str):
    mats = {}
    for line in text.splitlines():
        if not line.startswith("MakeNamedMaterial"):
            continue
        name = re.match(r'MakeNamedMaterial "([^"]+)"', line).group(1)
        kind = re.search(r'"string type" "(\w+)"', line).group(1)
        p = {}
        if m := re.search(r'"rgb reflectance" \[ ([^\]]+) \]', line):
            p["reflectance"] = np.array([float(x) for x in m.group(1).split()])
        if m := re.search(r'"float roughness" (\S+)', line):
            p["roughness"] = float(m.group(1))
            assert '"bool remaproughness" false' in line
        if m := re.search(r'"string materials" \[ "([^"]+)" "([^"]+)" \]', line):
            p["materials"] = (m.group(1), m.group(2))
        if m := re.search(r'"float amount" (\S+)', line):
            p["amount"] = float(m.group(1))
        mats[name] = (kind, p)
    return mats


def pbrt_reference(text, name, wi, wo):
    mats = parse_pbrt(text)
    return np.array([_pbrt_material(mats, name, wi[n], wo[n]) for n in range(len(wi))])


def test_pbrt_lambert_is_exact():
    model = make("lambert", albedo=[0.6, 0.3, 0.1])
    ex = to_pbrt(model, name="paint")
    assert ex.exact and 'MakeNamedMaterial "paint" "string type" "diffuse"' in ex.text
    wi, wo = pairs(200)
    np.testing.assert_allclose(pbrt_reference(ex.text, "paint", wi, wo), model.eval(wi, wo), rtol=1e-9)


@pytest.mark.parametrize("name, params", [
    ("microfacet", {"kd": 0.0, "ks": 1.0, "alpha": 0.3, "f0": [0.95, 0.64, 0.54], "distribution": "ggx"}),
    ("lambert+2ggx", {"diffuse.albedo": [0.2, 0.1, 0.05], "lobe1.ks": 0.3, "lobe1.alpha": 0.3, "lobe1.f0": 0.9,
                      "lobe2.ks": 0.2, "lobe2.alpha": 0.08, "lobe2.f0": 0.9}),
])
def test_pbrt_approximation_is_what_pbrt_renders_and_its_error_is_true(name, params):
    from gonio.io.approx import direction_pairs, relative_error

    model = make(name, **params)
    ex = to_pbrt(model, name="m")
    assert not ex.exact and "height-correlated" in ex.describe()
    wi, wo = direction_pairs()
    wi, wo = wi[:600], wo[:600]
    ref = pbrt_reference(ex.text, "m", wi, wo)
    from gonio.io.pbrt import pbrt_eval, pbrt_terms

    np.testing.assert_allclose(pbrt_eval(pbrt_terms(model)[0], wi, wo), ref, rtol=1e-9, atol=1e-12)
    assert relative_error(ref, model.eval(wi, wo)) == pytest.approx(ex.error, rel=0.25)
    assert ex.error < 0.15  # the closest material is close


def test_pbrt_effectively_smooth_conductor_is_evaluated_as_pbrt_renders_it():
    """pbrt-v4 treats a Trowbridge-Reitz conductor with α < 1e-3 as a perfect mirror (EffectivelySmooth,
    src/pbrt/util/scattering.h; ConductorBxDF::f returns 0): gonio printed the error of a rough lobe pbrt never
    renders (0.56 % for α = 2e-4; found by QA). The export says so and its error is pbrt's (f = 0: 100 %)."""
    from gonio.io.pbrt import pbrt_eval, pbrt_terms

    model = make("microfacet", kd=0.0, ks=1.0, alpha=2e-4, f0=[0.95, 0.64, 0.54], distribution="ggx")
    ex = to_pbrt(model, name="m")
    assert '"float roughness" 0.0002 ' in ex.text and "pbrt-v4 renders the lobe as a perfect mirror" in ex.describe()
    assert ex.error == pytest.approx(1.0)
    wi, wo = pairs(300)
    np.testing.assert_allclose(pbrt_eval(pbrt_terms(model)[0], wi, wo), pbrt_reference(ex.text, "m", wi, wo), atol=0)


# --- CLI ----------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def plastic_csv(tmp_path_factory):
    model = make("lambert+ggx", **{"diffuse.albedo": [0.3, 0.2, 0.1], "lobe1.ks": 0.8, "lobe1.alpha": 0.2,
                                   "lobe1.f0": 0.04})
    rng = np.random.default_rng(2)
    ti, to, po = np.meshgrid(np.radians(np.arange(0, 76, 15.0)), np.radians(np.arange(0, 86, 5.0)),
                             np.radians(np.arange(0, 360, 15.0)), indexing="ij")
    wi = from_spherical(ti.ravel(), 0 * ti.ravel())
    wo = from_spherical(to.ravel(), po.ravel())
    f = model.eval(wi, wo)
    s = SampleSet(wi, wo, f * (1 + 0.005 * rng.normal(size=f.shape)), 0.005 * f + 1e-5)
    return write_csv(tmp_path_factory.mktemp("plastic") / "plastic.csv", s)


def test_fit_writes_renderer_materials_only_when_exact_or_approx(plastic_csv, tmp_path, capsys):
    js = tmp_path / "fit.json"
    code = main(["fit", str(plastic_csv), "--model", "lambert+ggx", "--json", str(js), "--gltf", str(tmp_path / "m.gltf")])
    err = capsys.readouterr().err
    assert code == 2 and "cannot represent the model exactly" in err and "--approx" in err and err.count("\n") == 2
    assert err.splitlines()[1] == "gonio fit: 1 of 2 outputs not written (--gltf); 1 written"
    assert js.exists() and not (tmp_path / "m.gltf").exists()  # the fit is never lost
    assert main(["fit", str(plastic_csv), "--model", "lambert+ggx", "--approx", "--gltf", str(tmp_path / "m.gltf"),
                 "--pbrt", str(tmp_path / "m.pbrt")]) == 0
    out = capsys.readouterr().out
    assert re.search(r"wrote .*m.gltf \(glTF: APPROXIMATION, cosine-weighted relative RMS error \d+\.\d\d %", out)
    assert re.search(r"wrote .*m.pbrt \(pbrt-v4: APPROXIMATION", out)
    assert json.loads((tmp_path / "m.gltf").read_text())["asset"]["version"] == "2.0"
    assert 'NamedMaterial' in (tmp_path / "m.pbrt").read_text()
    assert main(["fit", str(plastic_csv), "--pbrt", str(tmp_path / "bad.txt")]) == 2
    assert "must end in .pbrt" in capsys.readouterr().err


def test_fix_accepts_the_names_fit_prints(plastic_csv, tmp_path, capsys):
    for fix in ("f0=0.04", "lobe1.f0=0.04"):
        js = tmp_path / f"{fix}.json"
        assert main(["fit", str(plastic_csv), "--model", "lambert+ggx", "--fix", fix, "--json", str(js)]) == 0
        res = json.loads(js.read_text())
        assert res["params"]["lobe1.f0"] in (0.04, [0.04, 0.04, 0.04])
        assert "lobe1.f0" not in res["uncertainty"]
    capsys.readouterr()
    assert main(["fit", str(plastic_csv), "--model", "lambert+2ggx", "--fix", "f0=1", "--json",
                 str(tmp_path / "two.json")]) == 0  # a tied f0 applies to every lobe
    res = json.loads((tmp_path / "two.json").read_text())
    assert res["params"]["lobe1.f0"] in (1.0, [1.0, 1.0, 1.0]) and res["params"]["lobe2.f0"] in (1.0, [1.0, 1.0, 1.0])
    capsys.readouterr()
    assert main(["fit", str(plastic_csv), "--model", "lambert+ggx", "--fix", "beta=1"]) == 2
    err = capsys.readouterr().err
    assert "lambert+ggx.beta" in err and "diffuse.albedo, lobe1.ks, lobe1.alpha, lobe1.f0" in err


def test_export_of_a_fit_json_to_every_renderer(plastic_csv, tmp_path, capsys):
    js = tmp_path / "fit.json"
    assert main(["fit", str(plastic_csv), "--model", "lambert+ggx", "--json", str(js)]) == 0
    capsys.readouterr()
    assert main(["export", str(js), "--format", "pbrt", "-o", str(tmp_path / "m.pbrt")]) == 2
    assert "pass --approx" in capsys.readouterr().err
    for fmt, name in (("pbrt", "m.pbrt"), ("gltf", "m.gltf"), ("mitsuba", "m.xml")):
        assert main(["export", str(js), "--format", fmt, "-o", str(tmp_path / name), "--approx"]) == 0
        assert "APPROXIMATION" in capsys.readouterr().out and (tmp_path / name).stat().st_size > 100
    assert main(["export", str(plastic_csv), "--format", "gltf", "-o", str(tmp_path / "x.gltf")]) == 2
    err = capsys.readouterr().err
    assert "exports a fit result (gonio fit --json FIT.json), and this is a gonio CSV export" in err
    assert err.count("\n") == 1


def test_models_without_a_counterpart_export_with_approx_as_a_fitted_lambert_ggx():
    model = make("gtr", kd=[0.07, 0.1, 0.04], ks=[0.22, 0.24, 0.16], alpha=0.4, gamma=1.2, f0=1.0)
    for to, target in ((to_pbrt, "pbrt"), (to_gltf, "glTF")):
        with pytest.raises(ConfigError, match="no counterpart to export.*pass --approx"):
            to(model)
        ex = to(model, approx=True)
        assert 0 < ex.error < 0.2 and f"gtr has no {target} counterpart" in ex.describe()
        assert "APPROXIMATION" in ex.describe()
