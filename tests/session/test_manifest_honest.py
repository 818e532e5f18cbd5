"""The session manifest describes the rig, calibration and detector actually used; material files are
complete; plan errors are one clean line."""

from __future__ import annotations

import hashlib
import json
import math

import pytest

from gonio.cli.main import main
from gonio.errors import ConfigError, DataError
from gonio.pipeline.target import TargetLayout
from gonio.rig.kinematics import load_rig, read_rig_text
from gonio.session.detector import aperture_solid_angle, detector_solid_angle
from gonio.session.material import material_from_dict
from sim.rig import SimRigConfig

SMALL = ["--quiet", "--plan", "in_plane", "--theta-i-step", "30", "--theta-o-step", "30", "--theta-max", "60",
         "--sim-resolution", "240x180"]


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    """``measure --sim`` with SMALL, measured once per test run (tests/session/conftest.py): read-only."""
    from tests.session.conftest import measured_shared

    return measured_shared(tmp_path_factory, ["measure", "--sim", *SMALL])


def test_sim_manifest_records_rig_text_calibration_and_detector(small):
    d = small
    m = json.loads((d / "manifest.json").read_text())
    text, _ = read_rig_text("default")
    assert m["rig"]["toml"] == text and m["rig"]["sha256"] == hashlib.sha256(text.encode()).hexdigest()
    calib = SimRigConfig(width=240, height=180, focal_px=380.0 * 240 / 320).calibration()
    assert m["calibration"]["K"] == calib.K.tolist() and m["calibration"]["width"] == 240
    assert m["detector_solid_angle_sr"] == m["detector"]["solid_angle_sr"] > 0
    assert m["detector"]["aperture_sr"] == 0.0  # the simulated camera is an ideal pinhole


def test_resume_uses_the_manifest_rig_not_the_file(tmp_path, capsys):
    from gonio.session.recording import manifest_rig as _manifest_rig

    text, _ = read_rig_text("default")
    changed = text.replace("camera_arm_radius_m = 0.40", "camera_arm_radius_m = 0.35")
    assert changed != text
    rec = {"rig": {"name": "default", "source": "default", "toml": changed,
                   "sha256": hashlib.sha256(changed.encode()).hexdigest()}}
    assert _manifest_rig(rec, "m.json").camera_radius == pytest.approx(0.35)
    rec["rig"]["sha256"] = "0" * 64
    with pytest.raises(DataError, match="m.json: rig.toml does not match"):
        _manifest_rig(rec, "m.json")
    capsys.readouterr()
    old = _manifest_rig({"rig": {"name": "default", "source": "default"}}, "old.json")  # older manifest
    assert old.camera_radius == load_rig().camera_radius
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("gonio: warning: old.json: rig has no recorded description")


def test_detector_bin_matches_the_tile_area_at_the_reference_view():
    """Independent check: at normal view an interior tile of side w/n at distance R subtends ≈ (w/n)²/R²."""
    rig, layout = load_rig(), TargetLayout()
    calib = SimRigConfig().calibration()
    det = detector_solid_angle(calib, layout, rig, aperture_diameter_m=None, pinhole=True)
    n = math.isqrt(det["tiles"])
    s = layout.sample
    expected = ((s.x1 - s.x0) / n) * ((s.y1 - s.y0) / n) / rig.camera_radius ** 2
    assert det["bin_sr"] == pytest.approx(expected, rel=0.05)
    hw = detector_solid_angle(calib, layout, rig, aperture_diameter_m=None)
    assert hw["solid_angle_sr"] is None and "aperture" in hw["reason"] and hw["bin_sr"] == det["bin_sr"]
    ap = detector_solid_angle(calib, layout, rig, aperture_diameter_m=0.01)
    assert ap["aperture_sr"] == pytest.approx(math.pi * 0.005 ** 2 / rig.camera_radius ** 2, rel=1e-3)
    assert ap["solid_angle_sr"] > det["bin_sr"] + ap["aperture_sr"]
    assert aperture_solid_angle(2.0, 0.0) == pytest.approx(2 * math.pi)  # hemisphere at contact


def test_npz_export_carries_the_detector_solid_angle(tmp_path, capsys, small):
    from gonio.io.npz import read_npz

    d = small
    assert main(["export", str(d), "--format", "npz", "-o", str(tmp_path / "x.npz")]) == 0
    meta = read_npz(tmp_path / "x.npz").metadata
    m = json.loads((d / "manifest.json").read_text())
    assert meta["detector_solid_angle_sr"] == m["detector_solid_angle_sr"] > 0
    assert meta["detector"]["bin_sr"] == m["detector"]["bin_sr"]


@pytest.mark.parametrize("params, message", [
    ({"kd": [0.3, 0.1, 0.1], "ks": 1, "alpha": 0.1, "f0": 0.04, "distribution": "ggx", "foo": 1, "bar": 2},
     "mat.toml: params: unknown parameters foo, bar (model 'microfacet' takes kd, ks, alpha, f0, distribution)"),
    ({"kd": "red", "ks": 1, "alpha": 0.1, "f0": 0.04, "distribution": "ggx"}, "mat.toml: microfacet.kd = 'red'"),
])
def test_material_must_be_complete_and_known(params, message):
    with pytest.raises(ConfigError) as exc:
        material_from_dict({"model": "microfacet", "params": params}, "mat.toml")
    assert str(exc.value).startswith(message) and "\n" not in str(exc.value)


def test_material_from_an_old_manifest_may_be_partial():
    m = material_from_dict({"model": "microfacet", "params": {"kd": [0.3, 0.1, 0.1]}}, "manifest", complete=False)
    assert m.brdf().params["ks"] is not None


def test_material_file_with_missing_parameters_uses_and_states_the_defaults(tmp_path, capsys):
    f = tmp_path / "m.toml"
    f.write_text('model = "microfacet"\n[params]\nkd = [0.3, 0.1, 0.05]\n')
    assert main(["measure", "--sim", *SMALL, "--material", str(f), "--out", str(tmp_path / "s")]) == 0
    out = capsys.readouterr().out
    assert f"material {f}: not given, the model's defaults are used: ks = 1.0, alpha = 0.1, f0 = 1.0, " \
           "distribution = ggx" in out
    recorded = json.loads((tmp_path / "s" / "manifest.json").read_text())["material"]["params"]
    assert recorded == {"kd": [0.3, 0.1, 0.05], "ks": 1.0, "alpha": 0.1, "f0": 1.0, "distribution": "ggx"}


def test_plan_parameter_error_has_one_prefix(capsys):
    assert main(["plan", "in_plane", "--theta-i-step", "-5"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["gonio plan: error: in_plane.theta_i_step = -5.0: must be in [0.1, 90] deg"]
