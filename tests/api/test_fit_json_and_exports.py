"""The data API (issue 31 item 4): a fit JSON reads back as the fit (``FitResult.from_json``, ``gonio.load``), and the
renderer exports have one shape on a fit — ``gonio.to_mitsuba / to_pbrt / to_gltf(fit, path=None, approx=, force=)``
— defined in gonio.io."""

from __future__ import annotations

import json

import numpy as np
import pytest

import gonio
from gonio.brdf import make
from gonio.errors import ConfigError, DataError
from gonio.geometry import from_spherical
from gonio.samples import SampleSet


@pytest.fixture(scope="module")
def samples():
    rng = np.random.default_rng(3)
    n = 400
    wi = from_spherical(rng.uniform(0, 1.2, n), rng.uniform(0, 2 * np.pi, n))
    wo = from_spherical(rng.uniform(0, 1.2, n), rng.uniform(0, 2 * np.pi, n))
    truth = make("lambert+ggx", **{"diffuse.albedo": [0.5, 0.3, 0.2], "lobe1.alpha": 0.3, "lobe1.f0": 0.9})
    f = truth.eval(wi, wo)
    sigma = 0.01 * f + 1e-4
    return SampleSet(wi, wo, f + sigma * rng.standard_normal(f.shape), sigma)


@pytest.fixture(scope="module")
def result(samples):
    return gonio.fit(samples, "lambert+ggx")


def test_a_fit_json_round_trips_and_evaluates_as_the_fit(result, tmp_path):
    again = gonio.FitResult.from_json(result.to_json())
    assert again.to_dict() == result.to_dict()  # every field the report has (a new one must be read back too)
    assert again.to_json() == result.to_json()
    path = tmp_path / "fit.json"
    result.to_json(path)
    loaded = gonio.load(path)
    assert isinstance(loaded, gonio.FitResult) and loaded.to_dict() == result.to_dict()
    wi, wo = from_spherical(np.array([0.3, 0.7]), np.array([0.1, 2.0])), from_spherical(np.array([0.2, 0.5]), np.array([3.0, 1.0]))
    np.testing.assert_allclose(loaded.eval(wi, wo), result.model.eval(wi, wo), rtol=1e-12)


def test_a_selection_json_reads_back_as_its_winner(samples, tmp_path):
    sel = gonio.select(samples, ["lambert", "lambert+ggx"])
    path = tmp_path / "sel.json"
    sel.to_json(path)
    loaded = gonio.load(path)
    assert loaded.model_name == sel.model_name and loaded.to_dict() == sel.winner.to_dict()


@pytest.mark.parametrize("text, named", [
    ('{"params": {}}', 'expected a JSON object with "model"'),
    ('{"model": "glitter", "params": {}}', "glitter"),
    ('{"model": "lambert", "params": {"albedo": "white"}}', "albedo"),
    ('{"model": "lambert", "params": {"albedo": 0.5}, "n_used": -3}', "n_used"),
    ('{"model": "lambert", "params": {"albedo": 0.5}, "uncertainty": {"albedo": "x"}}', "'x'"),
    ('{"model": "lambert", ', "not valid JSON"),
])
def test_a_malformed_fit_json_is_one_line_naming_the_file(tmp_path, text, named):
    path = tmp_path / "bad.json"
    path.write_text(text)
    with pytest.raises(DataError) as err:
        gonio.load(path)
    msg = str(err.value)
    assert "\n" not in msg and str(path) in msg and named in msg


def test_every_renderer_export_has_one_shape_on_a_fit(result, tmp_path):
    exports = {"mitsuba": (gonio.to_mitsuba, ".xml", dict), "pbrt": (gonio.to_pbrt, ".pbrt", str),
               "gltf": (gonio.to_gltf, ".gltf", dict)}
    for name, (to, suffix, kind) in exports.items():
        doc = to(result, approx=True)
        assert isinstance(doc, kind) and doc
        path = tmp_path / f"m{suffix}"
        written = to(result, path, approx=True)  # the material, also written (named for the file: pbrt, glTF)
        text = path.read_text()
        if name == "mitsuba":
            assert "<bsdf" in text and written == doc
        elif name == "pbrt":
            assert written == text and '"m"' in text
        else:
            assert written == json.loads(text)
        with pytest.raises(ConfigError, match="exists"):
            to(result, path, approx=True)  # an existing file only with force
        assert to(result, path, approx=True, force=True) == written
        with pytest.raises(ConfigError, match="must end in"):
            to(result, tmp_path / "m.txt", approx=True)
        assert to(result.model, approx=True) == doc  # a model exports as its fit does
    assert gonio.to_mitsuba(result, tmp_path / "m.json", approx=True) == json.loads((tmp_path / "m.json").read_text())


def test_a_refused_export_names_the_python_keyword_for_every_renderer():
    ward = make("ward", kd=0.3, ks=0.2, alpha_x=0.1, alpha_y=0.3)  # anisotropic: no renderer has it exactly
    for to in (gonio.to_mitsuba, gonio.to_pbrt, gonio.to_gltf):
        with pytest.raises(ConfigError, match="approx=True") as refused:
            to(ward)
        assert "--approx" not in str(refused.value)
