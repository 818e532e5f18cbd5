"""A board pose found once is checked in a later frame by finding its corners again where it puts them
(:func:`gonio.pipeline.markers.refine_board_pose`): the same camera agrees whatever the light does, a camera
moved by a millimetre (the board or sample holder bumped) does not, and the pipeline then searches the frame."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from gonio.geometry import from_spherical
from gonio.pipeline.markers import BoardPose, board_poses_agree, detect_board_pose, refine_board_pose, to_gray8
from gonio.pipeline.target import CameraPose

CAMERA = (30.0, 40.0)  # θo, φo degrees


def _gray(bench, frame):
    return to_gray8(frame.pixels, frame.bit_depth, frame.black_level)


def _view(bench, light=(20.0, 180.0), shift_m=(0.0, 0.0, 0.0)):
    """A metering-like frame with the camera at CAMERA (moved by ``shift_m`` in the sample frame)."""
    eye = 0.6 * from_spherical(np.radians(CAMERA[0]), np.radians(CAMERA[1])) + np.asarray(shift_m)
    bench.camera.set_pose(CameraPose.look_at(eye, target=np.asarray(shift_m)))
    bench.camera.set_light(0.8 * from_spherical(np.radians(light[0]), np.radians(light[1])))
    return bench.camera.capture(2e-3)


@pytest.fixture
def found(bench_factory, lambert):
    bench = bench_factory(lambert)
    bp = detect_board_pose(_gray(bench, _view(bench)), bench.calib, bench.layout.charuco)
    assert bp is not None and bp.corner_ids is not None and len(bp.corner_ids) == bp.n_corners
    return bench, bp


def test_the_corners_found_again_in_another_light_agree_with_the_pose(found):
    bench, bp = found
    for light in [(20.0, 180.0), (60.0, 90.0), (5.0, 0.0)]:
        again = refine_board_pose(_gray(bench, _view(bench, light)), bp, bench.calib, bench.layout.charuco)
        assert again is not None and board_poses_agree(bp, again), light


@pytest.mark.parametrize("shift_m", [(1e-3, 0, 0), (0, 1e-3, 0), (0, 0, 3e-3)])
def test_a_board_moved_by_a_millimetre_is_told_apart(found, shift_m):
    bench, bp = found
    # the camera and the point it looks at moved together: in the camera's frame, the board was bumped
    again = refine_board_pose(_gray(bench, _view(bench, shift_m=shift_m)), bp, bench.calib, bench.layout.charuco)
    assert again is None or not board_poses_agree(bp, again)


def test_a_pose_without_its_corners_or_with_foreign_ones_is_not_refined(found):
    bench, bp = found
    gray = _gray(bench, _view(bench))
    spec = bench.layout.charuco
    bare = BoardPose(bp.pose, bp.n_corners, bp.rms_px, rvec=bp.rvec, tvec=bp.tvec, cov=bp.cov, board_size=bp.board_size)
    assert refine_board_pose(gray, bare, bench.calib, spec) is None
    n = (spec.squares[0] - 1) * (spec.squares[1] - 1)
    foreign = BoardPose(bp.pose, bp.n_corners, bp.rms_px, rvec=bp.rvec, tvec=bp.tvec, cov=bp.cov,
                        board_size=bp.board_size, corner_ids=np.arange(n, n + bp.n_corners))
    assert refine_board_pose(gray, foreign, bench.calib, spec) is None


def test_corner_ids_survive_the_record_and_bad_ones_void_it(found):
    _, bp = found
    rec = bp.to_record()
    back = BoardPose.from_record(rec)
    assert back is not None and np.array_equal(back.corner_ids, bp.corner_ids)
    ids = rec["corner_ids"]
    for bad in ([*ids[:-1], ids[0]], ids[:-1], [*ids[:-1], True], [*ids[:-1], 1.5], [*ids[:-1], -1], "0 1 2"):
        assert BoardPose.from_record({**rec, "corner_ids": bad}) is None, bad
    old = {k: v for k, v in rec.items() if k != "corner_ids"}  # a session written before corner_ids
    assert BoardPose.from_record(old) is not None and BoardPose.from_record(old).corner_ids is None


@pytest.mark.parametrize("case, source", [("still", "reused"), ("bumped", "replaced"), ("blank", "unverified")])
def test_the_pipeline_reuses_a_checked_pose_and_searches_when_the_check_fails(found, case, source):
    bench, bp = found
    shift = (1.5e-3, 0.0, 0.0) if case == "bumped" else (0.0, 0.0, 0.0)
    eye = 0.6 * from_spherical(np.radians(CAMERA[0]), np.radians(CAMERA[1])) + np.asarray(shift)
    bench.camera.set_pose(CameraPose.look_at(eye, target=np.asarray(shift)))
    light = 0.8 * from_spherical(np.radians(40.0), np.radians(200.0))
    bench.camera.set_light(light)
    if case == "blank":  # a board the camera cannot see (no contrast): neither the check nor a search finds it
        bench.camera.scene = dataclasses.replace(bench.scene, board_white=0.3, board_black=0.3)
    res = bench.pipeline.measure(light, board=bp)
    assert res.board_source == source
    if source == "replaced":
        assert res.board is not bp and not board_poses_agree(bp, res.board)
    else:
        assert res.board is bp
    assert len(res.samples) > 0
