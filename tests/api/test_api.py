"""The public API at the top of the package: gonio.load / gonio.fit / gonio.select and their results."""

from __future__ import annotations

import json

import numpy as np
import pytest

import gonio
from gonio.brdf import make
from gonio.errors import ConfigError, DataError
from gonio.io.merl import MerlTable, cell_directions, write_merl


@pytest.fixture(scope="module")
def merl_file(tmp_path_factory):
    """A MERL table of a known Lambert + GGX material (every cell with both directions above the horizon)."""
    truth = make("lambert+ggx", **{"diffuse.albedo": [0.5, 0.3, 0.2], "lobe1.alpha": 0.2, "lobe1.f0": [0.9, 0.8, 0.7]})
    wi, wo, *_ = cell_directions()
    values = truth.eval(wi, wo)
    values[(wi[..., 2] <= 0) | (wo[..., 2] <= 0)] = np.nan
    path = tmp_path_factory.mktemp("api") / "known.binary"
    write_merl(path, MerlTable(values))
    return path, truth


def test_import_is_cheap_and_lists_the_api():
    for name in ("load", "fit", "select", "Measured", "FitResult", "Selection", "make"):
        assert name in dir(gonio)
    with pytest.raises(AttributeError):
        gonio.no_such_thing


def test_load_fit_select_round_trip(merl_file, tmp_path):
    path, truth = merl_file
    data = gonio.load(path)
    assert isinstance(data, gonio.Measured) and data.kind == "merl"
    assert "merl" in repr(data) and "cells measured" in repr(data)
    wi, wo = np.array([[0.3, 0.1, 0.95]]), np.array([[-0.2, 0.0, 0.98]])
    wi, wo = wi / np.linalg.norm(wi), wo / np.linalg.norm(wo)
    np.testing.assert_allclose(data.eval(wi, wo), truth.eval(wi, wo), rtol=0.05)
    result = gonio.fit(data, "lambert+ggx", max_theta_deg=80)
    assert result.model_name == "lambert+ggx"
    np.testing.assert_allclose(result.model.eval(wi, wo), truth.eval(wi, wo), rtol=0.02)
    assert result.model is result.model  # built once
    assert result.errors["rms_rel"] == pytest.approx(result.rms_rel)
    text = repr(result)
    assert text.startswith("FitResult: lambert+ggx") and "lobe1.alpha" in text and "{" not in text
    out = tmp_path / "fit.json"
    report = json.loads(result.to_json(out))
    assert report["model"] == "lambert+ggx" and json.loads(out.read_text()) == report
    with pytest.raises(ConfigError, match="exists"):
        result.to_json(out)
    result.to_json(out, force=True)
    # the same result from a path and from the samples
    again = gonio.fit(str(path), "lambert+ggx", max_theta_deg=80)
    assert again.params == result.params


def test_select_result_reads_like_its_winner(merl_file):
    path, _ = merl_file
    choice = gonio.select(gonio.load(path), ["lambert", "microfacet"], criterion="bic")
    assert choice.model_name == choice.winner.model_name and choice.params is choice.winner.params
    assert choice.model_name != "lambert"  # a specular table is not diffuse
    text = repr(choice)
    assert "Selection by bic" in text and "lambert" in text and "microfacet" in text


def test_fit_package_is_still_a_package_and_callable():
    import gonio.fit
    from gonio.fit.select import select  # the function, by its module path

    assert callable(gonio.fit) and callable(select)
    assert gonio.fit.fit.__module__ == "gonio.fit.fit"


def test_bad_inputs_are_one_line(tmp_path):
    with pytest.raises(DataError, match="no such"):
        gonio.load(tmp_path / "missing.binary")
    with pytest.raises(TypeError, match="expected a path"):
        gonio.fit(42, "lambert")


def test_a_mitsuba_refusal_names_the_python_keyword_not_the_cli_option(merl_file):
    """A notebook user told to "pass --approx" has no such thing to pass (found by QA, qa-user)."""
    path, _ = merl_file
    samples = gonio.load(path).to_samples()
    result = gonio.fit(samples.subset(np.arange(0, len(samples), 100)), "ward")  # no exact Mitsuba 3 counterpart
    with pytest.raises(ConfigError, match="approx=True") as refused:
        gonio.to_mitsuba(result)
    assert "--approx" not in str(refused.value)
