"""gonio plan sphere (issue 30): a fixed camera and the light swept, every pose reachable, the coverage of the MERL
table printed before anything moves."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gonio.cli.main import main
from gonio.plan.generators import make_plan
from gonio.rig.kinematics import load_rig
from gonio.sphere import Sphere
from gonio.session.sphere_coverage import cells_of_pose, plan_cells, plan_coverage, valid_cells


@pytest.fixture(scope="module")
def rig():
    return load_rig("default")


def test_the_camera_stays_and_every_planned_pose_is_reachable(rig):
    p = make_plan("sphere", rig=rig, theta_o=math.radians(50), theta_i_step=math.radians(15),
                  phi_i_step=math.radians(90))
    assert len(p) > 10 and np.allclose(p.poses[:, 2], math.radians(50)) and np.allclose(p.poses[:, 3], 0.0)
    j = np.asarray(p.joints)
    assert np.all((j >= rig.lower - 1e-9) & (j <= rig.upper + 1e-9))
    wi, wo = rig.directions(j)
    assert not np.any(rig.check_directions(wi, wo))  # no collision, no shadow
    assert p.n_dropped > 0  # the light near the camera collides with it: dropped, said


def test_coverage_counts_cells_the_pipeline_would_fill(rig):
    from gonio.pipeline.target import CameraCalibration

    calib = CameraCalibration.pinhole(320, 240, 380.0)
    sph = Sphere((0.0, 0.0, 0.02), 0.02)
    small = make_plan("sphere", rig=rig, theta_i_step=math.radians(30), phi_i_step=math.pi)
    more = make_plan("sphere", rig=rig, theta_i_step=math.radians(15), phi_i_step=math.pi)
    a, b = plan_cells(small, rig, calib, sph), plan_cells(more, rig, calib, sph)
    assert a.sum() > 200 * len(small) and b.sum() > a.sum()
    # a pose's cells are those its pixels' (θh, θd, φd) fall in: hundreds per pose, all valid ones
    cells = max((cells_of_pose(rig, j, calib, sph) for j in small.joints), key=len)
    assert len(cells) > 200 and valid_cells()[cells].mean() > 0.95
    cov = plan_coverage(small, rig, calib, sph, reach_step=15.0)
    assert 0 < cov.filled <= cov.reachable <= cov.valid and 0 < cov.of_reachable <= 1
    assert "coverage:" in cov.lines()[0] and len(cov.lines()) == 3


def test_plan_sphere_prints_its_coverage_and_refuses_what_does_not_fit(tmp_path, capsys):
    assert main(["plan", "sphere", "--theta-i-step", "30", "--phi-i-step", "180"]) == 0
    out = capsys.readouterr().out
    assert "coverage:" in out and "MERL cells filled" in out and "by θd band" in out
    flat = tmp_path / "flat.toml"
    flat.write_text('white_albedo = 0.9\n')
    assert main(["plan", "sphere", "--target", str(flat)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "declares no [sphere]" in err
    assert main(["plan", "in_plane", "--target", str(flat)]) == 2
    assert "only for plan sphere" in capsys.readouterr().err


def test_the_greedy_plan_fills_what_it_is_asked_in_fewer_poses_than_its_candidates(rig):
    """gonio.session.sphere_plan: the fraction asked of the cells its candidates reach, each pose taken for the most
    new cells per lab second — fewer poses than the candidates, and its own count of cells is the geometry's."""
    from gonio.pipeline.target import CameraCalibration
    from gonio.session.sphere_plan import greedy_sphere_plan

    calib = CameraCalibration.pinhole(320, 240, 380.0)
    sph = Sphere((0.0, 0.0, 0.02), 0.02)
    plan, info = greedy_sphere_plan(rig, calib, sph, theta_i_step=math.radians(10), phi_i_step=math.radians(45),
                                    coverage=0.8)
    assert info["filled"] >= 0.8 * info["reachable"] and 0 < len(plan) < info["candidates"]
    assert np.allclose(plan.poses[:, 2], math.radians(60)) and plan.order == "optimized"
    assert plan_cells(plan, rig, calib, sph)[valid_cells()].sum() == info["filled"]
    first, _ = greedy_sphere_plan(rig, calib, sph, theta_i_step=math.radians(10), phi_i_step=math.radians(45),
                                  coverage=0.8, budget=1.0)
    assert len(first) == 1  # a budget below two poses' lab time: the single best pose


@pytest.mark.parametrize("opts, field", [(["--fill", "1.5"], "--fill"), (["--fill", "0"], "--fill"),
                                         (["--fill", "0.5", "--fill-budget", "-3"], "--fill-budget")])
def test_plan_sphere_fill_refuses_bad_values_in_one_line(opts, field, capsys):
    assert main(["plan", "sphere", *opts]) != 0
    err = capsys.readouterr().err.strip()
    assert field in err and "\n" not in err


def test_fill_is_only_for_plan_sphere(capsys):
    assert main(["plan", "in_plane", "--fill", "0.5"]) != 0
    assert "only for plan sphere" in capsys.readouterr().err
