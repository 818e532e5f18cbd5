"""A cylinder target (issue 30): its geometry against closed forms, its frame along the axis (anisotropic slices),
the target file's [cylinder] refused in one line when malformed, and the simulated rig's render measured per pixel
(an anisotropic material included: the simulator and the pipeline agree on the frame)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gonio.brdf import make
from gonio.errors import ConfigError
from gonio.pipeline.target import TargetLayout
from gonio.sphere import sphere_frame_samples, sphere_hits
from gonio.sphere.cylinder import Cylinder
from tests.pipeline.test_sphere import _camera

CYL = Cylinder((0.0, 0.0, 0.015), (1.0, 0.0, 0.0), 0.015, 0.05)


def test_rays_meet_the_cylinder_where_the_closed_forms_say():
    eye = np.array([0.01, -0.3, 0.015])  # level with the axis, looking across it
    t, hit = CYL.intersect(eye, np.array([[0.0, 1.0, 0.0]]))
    assert hit[0] and t[0] == pytest.approx(0.3 - 0.015)
    # tangent to the surface (distance r from the axis) grazes; a hair further misses; along the axis: no hit
    d = np.array([[0.0, 1.0, 0.0]])
    _, hit = CYL.intersect(eye + [0.0, 0.0, 0.015 - 1e-9], d)
    _, miss = CYL.intersect(eye + [0.0, 0.0, 0.015 + 1e-6], d)
    _, along = CYL.intersect(np.array([-0.3, 0.0, 0.015]), np.array([[1.0, 0.0, 0.0]]))
    assert hit[0] and not miss[0] and not along[0]
    # beyond an end (|x| > length/2) the surface is not there
    _, beyond = CYL.intersect(np.array([0.03, -0.3, 0.015]), d)
    assert not beyond[0]


def test_normals_are_radial_across_the_axis_and_the_frame_runs_along_it():
    rng = np.random.default_rng(3)
    ang = rng.uniform(0, 2 * math.pi, 50)
    xs = rng.uniform(-0.02, 0.02, 50)
    pts = np.stack([xs, 0.015 * np.cos(ang), 0.015 + 0.015 * np.sin(ang)], axis=-1)
    n = CYL.normal(pts)
    assert np.allclose(n, np.stack([np.zeros(50), np.cos(ang), np.sin(ang)], axis=-1))
    F = CYL.frames(pts, n)
    assert np.allclose(F[:, 0], [1.0, 0.0, 0.0])  # t = the axis
    assert np.allclose(np.einsum("nij,nkj->nik", F, F), np.eye(3))  # orthonormal
    assert np.allclose(np.linalg.det(F), 1.0)  # right-handed
    # the light and the camera in the vertical plane through the axis, over its top line: the half vector there
    # lies in the (axis, normal) plane, φh = 0 or π (an anisotropic slice along the axis)
    eye, light = np.array([-0.2, 0.0, 0.3]), np.array([0.25, 0.0, 0.35])
    d = np.array([0.0, 0.0, 0.03]) - eye
    h, mask = sphere_hits(eye, (d / np.linalg.norm(d))[None], CYL, light)
    assert mask[0] and np.allclose(h.n[0], [0.0, 0.0, 1.0])
    assert min(abs(h.phi_h[0]), abs(abs(h.phi_h[0]) - math.pi)) < 1e-9


@pytest.mark.parametrize("table, field", [
    ({"length": 0.05}, "cylinder.radius"), ({"radius": 0.015}, "cylinder.length"),
    ({"radius": 0.015, "length": 0.05, "axis": [0, 0, 1]}, "cylinder.axis"),
    ({"radius": 0.015, "length": 0.05, "axis": [0, 0, 0]}, "cylinder.axis"),
    ({"radius": 0.015, "length": 0.05, "axis": [1, 0]}, "cylinder.axis"),
    ({"radius": 0.015, "length": 0.05, "centre": [0, 0, 0.02]}, "cylinder.centre"),
    ({"radius": 0.015, "length": 0.05, "centre": [-0.085, 0, 0.015]}, "cylinder.centre"),
    ({"radius": 0.015, "length": 0.05, "centre": [0.5, 0, 0.015]}, "cylinder.centre"),
    ({"radius": "wide", "length": 0.05}, "cylinder.radius"),
    ({"radius": 0.015, "length": 0.05, "colour": "red"}, "cylinder.colour"), ("0.015", "cylinder")])
def test_a_malformed_cylinder_in_the_target_file_is_refused_in_one_line(table, field):
    with pytest.raises(ConfigError) as e:
        TargetLayout.from_dict({"cylinder": table}, source="T.toml")
    msg = str(e.value)
    assert "\n" not in msg and field in msg and msg.startswith("T.toml")


def test_a_cylinder_is_read_defaulted_round_tripped_and_not_taken_with_a_sphere(tmp_path):
    lay = TargetLayout.from_dict({"cylinder": {"radius": 0.015, "length": 0.05}})
    assert lay.cylinder == CYL and lay.curved is lay.cylinder  # lying along x on the board's centre by default
    assert TargetLayout.from_dict(lay.to_dict()).cylinder == lay.cylinder
    with pytest.raises(ConfigError) as e:
        TargetLayout.from_dict({"cylinder": {"radius": 0.015, "length": 0.05}, "sphere": {"radius": 0.02}})
    assert "not both" in str(e.value)


@pytest.mark.parametrize("material", [
    make("lambert", albedo=[0.5, 0.35, 0.25]),
    make("ward", kd=[0.2, 0.1, 0.05], ks=0.4, alpha_x=0.1, alpha_y=0.4)])
def test_the_simulated_cylinder_is_measured_per_pixel_as_its_material(material):
    """The render (4×4 rays per pixel, the frame along the axis) and the pipeline's per-pixel samples agree away
    from the silhouette, for an anisotropic material too: both put t on the axis."""
    cam, calib = _camera(material, CYL, light=(0.02, 0.2, 0.3))  # the highlight runs along the cylinder
    rate = cam.electron_rate().astype(np.float64)
    out = sphere_frame_samples(rate, np.maximum(rate, 1.0) * 1e-6, calib, cam._pose, CYL, cam._light_pos,
                               TargetLayout(), grazing_deg=70)
    assert out.counts["used"] > 500 and out.counts["silhouette"] > 0
    truth = material.eval(out.wi_local, out.wo_local)
    rel = np.abs(out.f / truth - 1)
    assert np.median(rel) < 5e-3 and np.percentile(rel, 90) < 0.03
    if not material.isotropic:  # the same pixels with the frame turned a quarter about n: another material
        turn = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
        wrong = material.eval(out.wi_local @ turn.T, out.wo_local @ turn.T)
        lobe = truth[:, 0] > 2 * 0.2 / np.pi  # where the specular lobe is most of the value
        assert lobe.sum() > 20 and np.median(np.abs(out.f[lobe] / wrong[lobe] - 1)) > 0.1


def test_a_cylinder_session_on_the_simulated_rig_measures_the_material(tmp_path):
    """``gonio measure --target`` with a [cylinder]: the simulated rig renders it, the pipeline gives one sample per
    pixel (no silhouette refinement: the declared pose), and they match the default material."""
    from gonio.cli.main import main
    from gonio.store.directory import load_session

    target = tmp_path / "cylinder.toml"
    target.write_text("[cylinder]\nradius = 0.015\nlength = 0.05\n")
    d = tmp_path / "c"
    assert main(["measure", "--sim", "--target", str(target), "--plan", "in_plane", "--theta-i", "30",
                 "--theta-o-step", "60", "--out", str(d), "--quiet"]) == 0
    manifest, s = load_session(d)
    assert manifest["target"]["cylinder"]["length"] == 0.05 and len(s.f) > 300 * len(manifest["plan"]["poses"])
    m = make("microfacet", kd=[0.3, 0.12, 0.06], ks=0.8, alpha=0.25, f0=0.04, distribution="ggx")
    truth = m.eval(s.wi, s.wo)
    rel = np.abs(s.f / truth - 1)
    assert np.median(rel) < 0.01 and np.percentile(rel, 95) < 0.05
    assert np.mean(np.abs(s.f - truth) <= 2 * s.sigma) > 0.9
