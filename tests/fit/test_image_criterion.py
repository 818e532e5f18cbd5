"""Selection by what a rendering shows: the rendered-sphere error and its CIELAB colour difference (issue 29)."""

from __future__ import annotations

import numpy as np
import pytest

from gonio.brdf import make
from gonio.errors import ConfigError
from gonio.fit.data import prepare
from gonio.fit.metrics import delta_e, image_error
from gonio.fit.select import select
from gonio.io.merl import cell_directions


@pytest.fixture(scope="module")
def dense():
    """6,000 MERL cell centres (dense enough to render spheres from) of a glossy red material, 1 % noise."""
    wi, wo, above = cell_directions()
    ok = above & (wi[..., 2] > 0.2) & (wo[..., 2] > 0.2)
    idx = np.random.default_rng(3).choice(np.flatnonzero(ok), 6000, replace=False)
    wi, wo = wi.reshape(-1, 3)[idx], wo.reshape(-1, 3)[idx]
    truth = make("microfacet", kd=[0.4, 0.1, 0.05], ks=0.3, alpha=0.15, f0=0.04)
    y = truth.eval(wi, wo) * (1 + 0.01 * np.random.default_rng(4).standard_normal((len(wi), 3)))
    return prepare((wi, wo, y)), truth


def test_delta_e_is_zero_for_the_measurement_itself_and_grows_with_a_colour_change(dense):
    d, truth = dense
    assert delta_e(truth, d) < 1.0  # 1 % noise and nearest-sample lookup: below a just-noticeable difference
    greener = make("microfacet", kd=[0.3, 0.2, 0.05], ks=0.3, alpha=0.15, f0=0.04)
    assert delta_e(greener, d) > 5 * delta_e(truth, d)


@pytest.mark.parametrize("criterion", ["image", "delta-e"])
def test_the_image_criteria_choose_the_model_whose_spheres_look_like_the_measurement(dense, criterion):
    d, truth = dense
    sel = select(d, ("lambert", "microfacet"), criterion=criterion)
    rows = {r["model"]: r for r in sel.candidates}
    assert sel.criterion == criterion and sel.model_name == "microfacet"
    assert rows["microfacet"][criterion] < rows["lambert"][criterion]
    measure = image_error if criterion == "image" else delta_e
    assert rows["lambert"][criterion] == pytest.approx(measure(sel.fits["lambert"].model, d))


def test_image_criterion_on_data_too_sparse_to_render_is_refused_in_one_line():
    # every sample 120° between light and view: no sphere pixel (0, 30 or 60° between them) has one near it
    rng = np.random.default_rng(1)
    phi = rng.uniform(0, 2 * np.pi, 60)
    t = np.radians(rng.uniform(58, 62, 60))
    wi = np.stack([np.sin(t) * np.cos(phi), np.sin(t) * np.sin(phi), np.cos(t)], axis=-1)
    wo = wi * np.array([-1.0, -1.0, 1.0])
    y = make("lambert", albedo=0.4).eval(wi, wo)
    with pytest.raises(ConfigError, match="too sparse") as exc:
        select((wi, wo, y), ("lambert",), criterion="image")
    assert "\n" not in str(exc.value)


def test_a_large_table_s_held_out_score_adds_what_the_rendered_spheres_show(dense):
    # issue 29: the data-driven fits minimize loss + image, and were scored on the loss alone
    from gonio.fit.fit import fit, resolve_loss
    from gonio.fit.select import HeldOut

    d, _ = dense
    loss = resolve_loss("auto", d)
    flat = fit(d, "lambert", report=False)  # misses the highlight the spheres show
    plain, both = HeldOut(d, loss, 0.0), HeldOut(d, loss, 4.0)
    assert both.cover.any() and both.image == 4.0
    s0, se0, share0 = plain(flat)
    s4, se4, share4 = both(flat)
    res = loss.residual(flat.build().eval(d.wi, d.wo), d.y, d.cos_i, d.sigma)
    res0 = loss.residual(np.zeros_like(d.y), d.y, d.cos_i, d.sigma)
    assert s0 == pytest.approx(np.mean(res ** 2) / np.mean(res0 ** 2), rel=1e-9) and share0 == 0.0
    assert 0.0 < share4 < 1.0 and s4 == pytest.approx(s0 / (1.0 - share4), rel=1e-9) and se4 > se0 > 0
