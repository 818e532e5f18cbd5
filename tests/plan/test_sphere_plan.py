"""gonio plan sphere (issue 30): a fixed camera and the light swept, every pose reachable, the coverage of the MERL
table printed before anything moves."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gonio.cli.main import main
from gonio.errors import ConfigError
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


def test_the_greedy_plan_fills_what_it_is_asked_in_fewer_poses_than_its_candidates(rig, monkeypatch):
    """gonio.session.sphere_plan: the fraction asked of the reachable cells, each pose taken for the most new cells
    per lab second — fewer poses than the candidates, and its own count of cells is the geometry's. Asked for more
    than its candidates can fill, it takes every candidate that adds a cell, and says how many it reaches."""
    from gonio.pipeline.target import CameraCalibration
    from gonio.session import sphere_plan
    from gonio.session.sphere_plan import greedy_sphere_plan, sweep_cells

    calib = CameraCalibration.pinhole(320, 240, 380.0)
    sph = Sphere((0.0, 0.0, 0.02), 0.02)

    kw = dict(theta_i_step=math.radians(10), phi_i_step=math.radians(45))
    kw["sweep"] = sweep_cells(rig, calib, sph, theta_o=math.radians(60), theta_max=math.radians(89), **kw)
    plan, info = greedy_sphere_plan(rig, calib, sph, coverage=0.03, **kw)
    assert info["filled"] >= 0.03 * info["reachable"] and 0 < len(plan) < info["candidates"]
    assert np.allclose(plan.poses[:, 2], math.radians(60)) and plan.order == "optimized"
    assert plan_cells(plan, rig, calib, sph)[valid_cells()].sum() == info["filled"]
    every, more = greedy_sphere_plan(rig, calib, sph, coverage=0.9, **kw)
    assert more["filled"] == more["candidates_reach"] < 0.9 * more["reachable"] and len(every) > len(plan)
    tr = more["trace"]  # the coverage against lab time, pose by pose: both grow, and end at what it says
    assert tr.shape == (len(every), 2) and np.all(np.diff(tr, axis=0) > 0)
    assert tr[-1, 1] == more["filled"] and more["lab_s"] <= tr[-1, 0] + 1e-9  # the ordered tour moves less
    from gonio.plan.labtime import session_lab_time
    from gonio.plan.plan import CaptureSettings

    one = session_lab_time(np.zeros(1), CaptureSettings()).total  # the session's start-up and one pose
    first, f1 = greedy_sphere_plan(rig, calib, sph, coverage=0.8, budget=one + 0.2, **kw)
    assert len(first) == 1 and f1["lab_s"] == pytest.approx(one)  # below two poses: the single best one
    # a budget the greedy's own count of moves would exhaust: the ordered tour's savings go back to it, and the
    # plan, ordered, still fits the budget
    some, s = greedy_sphere_plan(rig, calib, sph, coverage=0.9, budget=60.0, **kw)
    monkeypatch.setattr(sphere_plan, "REFILLS", 0)
    fewer, f = greedy_sphere_plan(rig, calib, sph, coverage=0.9, budget=60.0, **kw)
    assert 60.0 >= s["lab_s"] > f["lab_s"] and len(some) == len(s["trace"]) > len(fewer) and s["filled"] > f["filled"]
    from gonio.plan import estimate_plan

    assert estimate_plan(some, rig).optimized == pytest.approx(s["lab_s"])  # the session's lab time, as estimated
    with pytest.raises(ConfigError, match="start-up and one pose"):
        greedy_sphere_plan(rig, calib, sph, coverage=0.8, budget=one - 0.1, **kw)


def test_reachable_cells_are_the_limit_of_finer_sweeps_not_a_sweep_s_sample(rig):
    """gonio.session.sphere_coverage.reachable_cells: a cell is reachable when the pipeline keeps its configuration
    (θi, θo in the normal's frame within 80°) and its θd is within the rig's range — closed form; every cell a sweep
    fills is reachable, and finer sweeps fill more of them (a sampled count is not the rig's reach)."""
    from gonio.geometry import dirs_from_half_diff
    from gonio.io.merl import cell_centres
    from gonio.pipeline.target import CameraCalibration
    from gonio.session.sphere_coverage import reachable_cells

    reach = reachable_cells((4, 77))
    th, td, pd = cell_centres()

    def cell(i, j, k):
        return (i * 90 + j) * 180 + k

    for i, j, k in ((10, 30, 90), (40, 20, 10), (60, 60, 45), (5, 50, 170)):
        wi, wo = dirs_from_half_diff(np.array([th[i]]), 0.0, np.array([td[j]]), np.array([pd[k]]))
        keep = min(wi[0, 2], wo[0, 2]) >= math.cos(math.radians(80))
        assert reach[cell(i, j, k)] == keep
    assert not reach[cell(10, 3, 90)] and not reach[cell(10, 78, 90)] and reach[cell(10, 4, 90)]
    calib = CameraCalibration.pinhole(320, 240, 380.0)
    sph = Sphere((0.0, 0.0, 0.02), 0.02)
    counts = []
    for step in (20.0, 10.0):
        sweep = make_plan("sphere", rig=rig, theta_i_step=math.radians(step), phi_i_step=math.radians(2 * step))
        swept = plan_cells(sweep, rig, calib, sph, stride=2) & valid_cells()
        counts.append(int(swept.sum()))
    assert counts[1] > 1.5 * counts[0] > 0
    inside = reachable_cells((0, 89))[swept].mean()
    assert inside > 0.98  # the rest: cells at the grazing limit whose centre is just past it


@pytest.mark.parametrize("opts, field", [(["--fill", "1.5"], "--fill"), (["--fill", "0"], "--fill"),
                                         (["--fill", "0.5", "--fill-budget", "-3"], "--fill-budget")])
def test_plan_sphere_fill_refuses_bad_values_in_one_line(opts, field, capsys):
    assert main(["plan", "sphere", *opts]) != 0
    err = capsys.readouterr().err.strip()
    assert field in err and "\n" not in err


def test_fill_is_only_for_plan_sphere(capsys):
    assert main(["plan", "in_plane", "--fill", "0.5"]) != 0
    assert "only for plan sphere" in capsys.readouterr().err


def test_reachable_cells_match_a_brute_force_over_the_sphere_s_normals():
    """reachable_cells' closed form against the geometry itself: light and camera far away at 2·θd apart (θd the
    row's centre, here 62.5°), the sphere's normals every 0.2° of azimuth around the half vector at every θh row's centre; a
    normal is kept when the pipeline would keep its pixel (θi, θo in its frame ≤ 80°), and its (θh, θd, φd) cell
    counted. Every closed-form cell of the row is hit (θd 54–72° is reachable: those rows stay empty for want of
    pixels, not of geometry), and the few hit cells the closed form leaves out are at the grazing limit (a cell's
    centre past 80°, part of it inside)."""
    from gonio.geometry import frame_from_normal, half_diff_from_dirs
    from gonio.io.merl import SHAPE, cell_centres
    from gonio.io.merl_index import half_diff_index
    from gonio.session.sphere_coverage import reachable_cells

    j = 62
    th, td, _ = cell_centres()
    wi = np.array([math.sin(td[j]), 0.0, math.cos(td[j])])
    wo = np.array([-math.sin(td[j]), 0.0, math.cos(td[j])])  # the half vector: +z
    TH, PS = np.meshgrid(th, np.radians(np.arange(0.0, 360.0, 0.2)), indexing="ij")
    n = np.stack([np.sin(TH) * np.cos(PS), np.sin(TH) * np.sin(PS), np.cos(TH)], axis=-1).reshape(-1, 3)
    F = frame_from_normal(n)
    li, lo = F @ wi, F @ wo
    c = math.cos(math.radians(80))
    ok = (li[:, 2] >= c) & (lo[:, 2] >= c)
    a, _, b, p = half_diff_from_dirs(li[ok], lo[ok])
    ih, idd, ip = half_diff_index(a, b, p)
    assert np.all(idd == j)
    hit = np.zeros(SHAPE[0] * SHAPE[2], dtype=bool)
    hit[ih * SHAPE[2] + ip] = True
    closed = reachable_cells((0, 89)).reshape(SHAPE)[:, j, :].ravel()
    assert closed.sum() > 5000 and not np.any(closed & ~hit)
    extra = np.flatnonzero(hit & ~closed)
    assert len(extra) < 0.005 * closed.sum()
    # the extra cells are at the grazing limit: their centre's θi or θo is within a cell of 80°
    from gonio.geometry import dirs_from_half_diff

    _, _, pd = cell_centres()
    ewi, ewo = dirs_from_half_diff(th[extra // SHAPE[2]], 0.0, np.full(len(extra), td[j]), pd[extra % SHAPE[2]])
    assert np.all(np.minimum(ewi[:, 2], ewo[:, 2]) > math.cos(math.radians(83)))


def test_theta_d_reach_is_remembered_by_value_and_is_the_computation(rig):
    """theta_d_reach answers a repeated question from memory (the greedy plan and the coverage of the plan it made
    ask the same): the remembered answer is the computed one, and a question that differs (the sphere, the camera's
    elevation) is computed afresh — its own answer, not another's."""
    from gonio.pipeline.target import CameraCalibration
    from gonio.session import sphere_coverage as sc

    calib, step = CameraCalibration.pinhole(320, 240, 380.0), math.radians(30)
    args = [(Sphere((0.0, 0.0, 0.02), 0.02), 60), (Sphere((0.0, 0.0, 0.01), 0.01), 60),
            (Sphere((0.0, 0.0, 0.02), 0.02), 40)]
    computed = [sc._theta_d_reach(rig, calib, s, theta_o=math.radians(t), step=step, layout=None, stride=4)
                for s, t in args]
    assert len(set(computed)) == 3  # the three questions have different answers
    for _ in range(2):  # computed (or remembered) the first time, remembered the second
        assert [sc.theta_d_reach(rig, calib, s, theta_o=math.radians(t), step=step) for s, t in args] == computed


def test_cell_centre_cosines_are_those_of_dirs_from_half_diff():
    """sphere_coverage takes the cell centres' cosines from gonio.io.merl.cell_directions: cos θi to the bit, cos θo
    within 4.4e-16 of gonio.geometry.dirs_from_half_diff's, and the valid and reachable cells the same."""
    from gonio.geometry import dirs_from_half_diff
    from gonio.io.merl import cell_centres
    from gonio.session.sphere_coverage import _cell_centre_cosines, reachable_cells

    th, td, pd = cell_centres()
    TH, TD, PD = np.meshgrid(th, td, pd, indexing="ij")
    wi, wo = dirs_from_half_diff(TH.ravel(), 0.0, TD.ravel(), PD.ravel())
    cos_i, cos_o = _cell_centre_cosines()
    assert np.array_equal(cos_i, wi[:, 2]) and np.max(np.abs(cos_o - wo[:, 2])) <= 4.5e-16
    assert np.array_equal(valid_cells(), (wi[:, 2] > 0) & (wo[:, 2] > 0))
    c = math.cos(math.radians(80.0))
    assert np.array_equal(reachable_cells((0, 89)), (wi[:, 2] > 0) & (wo[:, 2] > 0) & (wi[:, 2] >= c) & (wo[:, 2] >= c))
