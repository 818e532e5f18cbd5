"""The geometric calibration's error, shared by every pose, reaches a fit's σ (gonio.fit.geometry): the σ it adds
is the change of the fitted parameters when the light really is one principal σ off at every pose, as a refit of
data made with the light there shows; without the modes nothing is added."""

from __future__ import annotations

import numpy as np

from gonio.fit.fit import fit
from gonio.fit.geometry import CalibrationModes
from gonio.brdf import make
from gonio.samples import SampleSet

MAT = {"kd": [0.3, 0.12, 0.06], "ks": 0.8, "alpha": 0.1, "f0": 0.04, "distribution": "ggx"}


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _log_e(p, S):
    d = S - p
    return np.log(d[..., 2]) - 1.5 * np.log(np.sum(d * d, axis=-1))


def _poses():
    """Light and camera positions of 10 poses around the specular direction (metres)."""
    S, C = [], []
    for ti in np.radians([20, 35, 50]):
        for phi in np.radians([0, 120, 240]):
            w = np.array([np.sin(ti) * np.cos(phi), np.sin(ti) * np.sin(phi), np.cos(ti)])
            S.append(0.45 * w)
            C.append(0.4 * _unit(w * [-1, -1, 1] + [0.02, 0.03, 0]))
    return np.array(S), np.array(C)


def _session(dS):
    """Samples of a grid of tiles per pose as the host records them when the light really is at S + dS (m): wi from
    S, the value relative to a white reference at (−0.085, 0, 0) with the irradiances the host assumed."""
    model = make("microfacet", **MAT)
    S, C = _poses()
    g = np.linspace(-0.02, 0.02, 7)
    x = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    x = np.concatenate([x, np.zeros((len(x), 1))], axis=1)
    white = np.array([-0.085, 0.0, 0.0])
    wi, wo, f, pose = [], [], [], []
    for k in range(len(S)):
        true = S[k] + dS[k]
        w_true, w_host, w_o = _unit(true - x), _unit(S[k] - x), _unit(C[k] - x)
        ratio = np.exp(_log_e(x, true) - _log_e(x, S[k]) - (_log_e(white, true) - _log_e(white, S[k])))
        wi.append(w_host)
        wo.append(w_o)
        f.append(model.eval(w_true, w_o) * ratio[:, None])
        pose.append(np.full(len(x), k))
    wi, wo, f, pose = (np.concatenate(a) for a in (wi, wo, f, pose))
    sigma = 0.002 * f + 1e-4
    return SampleSet(wi, wo, f, sigma, pose=pose, sigma_pose=np.zeros_like(f))


def _modes(offset):
    S, _ = _poses()
    return CalibrationModes(np.arange(len(S)), S, offset[None], np.array([-0.085, 0.0, 0.0]), ("light.d_el_deg",))


def _offset():
    """One principal axis: the light 0.3° further from the zenith at every pose (an elevation zero error)."""
    S, _ = _poses()
    t = np.arctan2(np.hypot(S[:, 0], S[:, 1]), S[:, 2])
    phi = np.arctan2(S[:, 1], S[:, 0])
    d = np.radians(0.3)
    tn = t + d
    moved = 0.45 * np.stack([np.sin(tn) * np.cos(phi), np.sin(tn) * np.sin(phi), np.cos(tn)], -1)
    return moved - S


def test_the_calibration_sigma_is_the_fit_moved_by_a_one_sigma_geometry_error():
    dS = _offset()
    nominal = _session(np.zeros_like(dS))
    kw = dict(report=False, n_starts=1)
    plain = fit(nominal, "microfacet", **kw)
    with_geo = fit(nominal, "microfacet", geometry=_modes(dS), **kw)
    up, down = fit(_session(dS), "microfacet", **kw), fit(_session(-dS), "microfacet", **kw)
    assert not any("geometric calibration" in n for n in plain.notes)
    assert any("geometric calibration's error shared by all 9 poses" in n and "GUM" in n for n in with_geo.notes)
    u_geo = np.sqrt(with_geo.uncertainty["alpha"] ** 2 - plain.uncertainty["alpha"] ** 2)
    shift = abs(up.params["alpha"] - down.params["alpha"]) / 2  # the linear part of the refit's response
    assert shift > 3 * plain.uncertainty["alpha"]  # the geometry error matters here: it is not lost in the noise
    assert 0.9 < u_geo / shift < 1.1
    assert plain.params["alpha"] == with_geo.params["alpha"]  # the estimate itself is unchanged


def test_modes_of_poses_the_data_do_not_have_add_nothing():
    dS = _offset()
    nominal = _session(np.zeros_like(dS))
    S, _ = _poses()
    other = CalibrationModes(np.arange(len(S)) + 100, S, dS[None], None)
    r = fit(nominal, "microfacet", geometry=other, report=False, n_starts=1)
    assert not any("geometric calibration" in n for n in r.notes)


def test_select_propagates_it_into_the_winner_not_into_each_fold(monkeypatch):
    import sys

    from gonio.fit.select import select

    fit_module = sys.modules["gonio.fit.fit"]
    dS = _offset()
    propagated = []
    real = fit_module.calibration_covariance

    def spy(*a, **k):
        out = real(*a, **k)
        propagated.append(out is not None)
        return out

    monkeypatch.setattr(fit_module, "calibration_covariance", spy)
    sel = select(_session(np.zeros_like(dS)), ("microfacet",), criterion="cv", folds=3, geometry=_modes(dS), n_starts=1)
    assert any("geometric calibration's error" in n for n in sel.winner.notes)
    assert 1 <= sum(propagated) <= 2  # the candidate's fit (and a refit of the winner), never the 3 folds


def _turned_session(angle_deg):
    """The samples of :func:`_session` (no light error) when the sample's surface really is turned by ``angle_deg``
    about y against the board's frame the host uses: the true directions ``D wi``, ``D wo``, the host's value
    ``f(D wi, D wo) · cos θi' / cos θi`` (its irradiance assumed the board's normal)."""
    from scipy.spatial.transform import Rotation

    base = _session(np.zeros((9, 3)))
    D = Rotation.from_rotvec([0.0, np.radians(angle_deg), 0.0]).as_matrix()
    wi_t, wo_t = base.wi @ D.T, base.wo @ D.T
    f = make("microfacet", **MAT).eval(wi_t, wo_t) * (wi_t[:, 2] / base.wi[:, 2])[:, None]
    return SampleSet(base.wi, base.wo, f, 0.002 * f + 1e-4, pose=base.pose, sigma_pose=np.zeros_like(f))


def test_a_turn_of_the_board_frame_is_propagated_like_the_light():
    """The frame's turn (CalibrationModes.frame_turns: the board's orientation against the sample, shared by every
    pose) adds the σ a refit of data made with the surface turned ±0.3° about y moves α by, within 10 %."""
    S, _ = _poses()
    modes = CalibrationModes(np.arange(len(S)), S, np.zeros((0, len(S), 3)), np.array([-0.085, 0.0, 0.0]),
                             frame_turns=np.array([[0.0, np.radians(0.3), 0.0]]))
    kw = dict(report=False, n_starts=1)
    nominal = _session(np.zeros((9, 3)))
    plain = fit(nominal, "microfacet", **kw)
    with_turn = fit(nominal, "microfacet", geometry=modes, **kw)
    up, down = fit(_turned_session(0.3), "microfacet", **kw), fit(_turned_session(-0.3), "microfacet", **kw)
    assert any("1 turns of the board's frame" in n for n in with_turn.notes)
    u_turn = np.sqrt(with_turn.uncertainty["alpha"] ** 2 - plain.uncertainty["alpha"] ** 2)
    shift = abs(up.params["alpha"] - down.params["alpha"]) / 2
    assert shift > 3 * plain.uncertainty["alpha"]
    assert 0.9 < u_turn / shift < 1.1
