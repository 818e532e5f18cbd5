"""The simulated camera's board texture and its prefiltered copies are made once per process for each board
(sim.camera.board_texture, blurred_board_texture): cameras of the same scene share them, a different board or
albedo gets its own, and they are the texture OpenCV draws and its Gaussian blur, read-only."""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np

from gonio.pipeline.target import CameraCalibration, TargetLayout
from gonio.brdf import make
from sim.camera import SensorModel, SimCamera, SimScene, blurred_board_texture, board_texture


def _camera(scene):
    return SimCamera(CameraCalibration.pinhole(64, 48, 80.0), SensorModel(), scene)


def test_cameras_share_the_board_texture_and_its_blur_and_they_are_the_drawn_board():
    scene = SimScene(TargetLayout(), make("lambert", albedo=0.5))
    a, b = _camera(scene), _camera(scene)
    assert a._board_texture() is b._board_texture()
    assert a._blurred_texture(1.5) is b._blurred_texture(1.5)
    spec = scene.layout.charuco
    w, h = spec.size
    img = spec.board().generateImage((int(round(w / scene.texel)), int(round(h / scene.texel))), marginSize=0,
                                     borderBits=1)
    want = (scene.board_black + (scene.board_white - scene.board_black) * (img / 255.0)).astype(np.float32)
    tex = a._board_texture()
    assert tex.tobytes() == want.tobytes() and not tex.flags.writeable
    assert a._blurred_texture(1.5).tobytes() == cv2.GaussianBlur(want, (0, 0), 1.5).tobytes()
    other = _camera(replace(scene, board_white=0.9))  # another albedo: its own texture
    assert other._board_texture() is not tex and other._board_texture().max() > tex.max()
    smaller = replace(scene.layout.charuco, squares=(5, 4))
    assert board_texture(smaller, scene.texel, scene.board_white, scene.board_black).shape != tex.shape
    assert blurred_board_texture(spec, scene.texel, scene.board_white, scene.board_black, 2.5) is not \
        a._blurred_texture(1.5)
