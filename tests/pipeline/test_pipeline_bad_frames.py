"""Bad frames give flagged samples or a clear error — never a crash, never a silent wrong value."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from gonio import samples as S
from gonio.errors import HardwareError
from gonio.pipeline.acquire import BoardNotFound
from gonio.pipeline.hdr import BadFrame


class Corrupting:
    """Wraps the simulated camera and corrupts the first ``bad`` frames with ``how``."""

    def __init__(self, camera, how, bad=10**9):
        self.camera, self.how, self.bad = camera, how, bad

    def capture(self, exposure, gain=1.0, *, timeout=10.0):
        frame = self.camera.capture(exposure, gain)
        if self.bad > 0:
            self.bad -= 1
            return self.how(frame)
        return frame

    def close(self):
        self.camera.close()


def rewire(bench, camera):
    from gonio.pipeline.acquire import Pipeline

    bench.pipeline = Pipeline(camera, bench.calib, bench.layout, light=bench.light, clock=bench.clock)


def test_a_camera_of_another_size_is_a_config_error_naming_both_sizes(bench_factory, lambert):
    from gonio.errors import ConfigError

    bench = bench_factory(lambert)
    bench.place(30, 20, 20, 200)
    rewire(bench, Corrupting(bench.camera, lambda f: dataclasses.replace(f, pixels=f.pixels[:-1])))
    with pytest.raises(ConfigError, match="frame size 640x479 .* calibration's 640x480"):
        bench.pipeline.measure(bench.camera._light_pos)


def test_wrong_size_frames_after_good_ones_are_bad_frames(bench_factory, lambert):
    bench = bench_factory(lambert)
    pose, light = bench.place(30, 20, 20, 200)
    bench.pipeline.measure(light)  # frames of the calibrated size: the size check is done
    bench.pipeline.camera = Corrupting(bench.camera, lambda f: dataclasses.replace(f, pixels=f.pixels[:-1]))
    with pytest.raises(BadFrame, match=r"pixels\.shape"):
        bench.pipeline.measure(light)


@pytest.mark.parametrize("how, field", [
    (lambda f: dataclasses.replace(f, pixels=f.pixels.astype(np.float32)), "pixels.dtype"),
    (lambda f: dataclasses.replace(f, pixels=f.pixels[..., :2]), "pixels.shape"),
    (lambda f: dataclasses.replace(f, bit_depth=10), "bit_depth"),
    (lambda f: dataclasses.replace(f, exposure=float("nan")), "exposure"),
    (lambda f: dataclasses.replace(f, linear=False), "linear"),
])
def test_malformed_frames_raise_a_named_error(bench_factory, lambert, how, field):
    bench = bench_factory(lambert)
    bench.place(30, 20, 20, 200)
    rewire(bench, Corrupting(bench.camera, how))
    with pytest.raises(BadFrame, match=field.replace(".", r"\.")) as exc:
        bench.pipeline.measure(bench.camera._light_pos)
    assert isinstance(exc.value, HardwareError)


def test_a_transient_bad_frame_is_retried(bench_factory, lambert):
    bench = bench_factory(lambert)
    pose, light = bench.place(30, 20, 20, 200)
    rewire(bench, Corrupting(bench.camera, lambda f: dataclasses.replace(f, pixels=f.pixels[:10]), bad=1))
    res = bench.pipeline.measure(light)
    assert len(res.samples.good()) == len(res.samples) > 0


def test_board_not_found_without_hint_is_a_clear_error(bench_factory, lambert):
    bench = bench_factory(lambert)
    bench.place(30, 20, 20, 200)
    bench.camera.set_pose(dataclasses.replace(bench.camera._pose, t=bench.camera._pose.t + [0.0, 0.0, -1.0]))
    with pytest.raises(BoardNotFound, match="ChArUco board not found"):
        bench.pipeline.measure(bench.camera._light_pos)


def test_all_saturated_frames_give_flagged_samples(bench_factory, lambert):
    # a light so strong that even the shortest exposure saturates everything
    bench = bench_factory(lambert, intensity=1e7)
    pose, light = bench.place(30, 20, 20, 200)
    with pytest.raises(BoardNotFound):
        bench.pipeline.measure(light)
    res = bench.pipeline.measure(light, camera_pose_hint=pose)
    s = res.samples
    assert len(s) > 0
    assert np.all(s.flags & S.SATURATED) and np.all(s.flags & S.NO_BOARD)
    assert np.all(np.isnan(s.f))  # no usable pixel: no value, not a wrong one
    assert len(s.good()) == 0


def test_all_dark_frames_give_low_signal_samples(bench_factory, lambert):
    bench = bench_factory(lambert, intensity=1e-9)
    pose, light = bench.place(30, 20, 20, 200)
    res = bench.pipeline.measure(light, camera_pose_hint=pose)
    s = res.samples
    assert np.all(s.flags & S.LOW_SIGNAL) and np.all(s.flags & S.NO_BOARD)
    assert len(s.good()) == 0
    assert np.all(np.isfinite(s.sigma))


def test_light_off_is_an_error(bench_factory, lambert):
    bench = bench_factory(lambert)
    pose, light = bench.place(30, 20, 20, 200)
    bench.light.set_light(False)
    with pytest.raises(HardwareError, match="photodiode|board|black"):
        bench.pipeline.measure(light, camera_pose_hint=pose)


def test_partly_saturated_white_reference_is_flagged(bench_factory, lambert):
    from gonio.pipeline.exposure import CapturePlan

    bench = bench_factory(lambert)
    pose, light = bench.place(30, 20, 20, 200)
    res = bench.pipeline.measure(light, plan=CapturePlan((0.05,), (1,)))  # one long exposure: white clips
    assert np.all(res.samples.flags & S.SATURATED)


def test_dark_frames_are_cached_and_refreshed(bench_factory, lambert):
    from gonio.pipeline.exposure import CapturePlan

    bench = bench_factory(lambert)
    pose, light = bench.place(30, 20, 20, 200)
    plan = CapturePlan((0.004, 0.016), (1, 1))
    bench.pipeline.measure(light, plan=plan)
    n = bench.pipeline.darks.captures
    assert n == 2 * bench.pipeline.settings.dark_frames
    bench.pipeline.measure(light, plan=plan)
    assert bench.pipeline.darks.captures == n  # cached
    bench.clock.sleep(bench.pipeline.settings.dark_max_age + 1)
    bench.pipeline.measure(light, plan=plan)
    assert bench.pipeline.darks.captures == 2 * n  # refreshed on schedule
    assert bench.light.output() > 0  # the light is back on


def _uniform(value):
    def how(frame):
        v = frame.saturation_level if value == "max" else int(frame.black_level)
        return dataclasses.replace(frame, pixels=np.full_like(frame.pixels, v))
    return how


def _stale():
    first = []

    def how(frame):
        if not first:
            first.append(frame)
        return dataclasses.replace(first[0], timestamp=frame.timestamp)
    return how


@pytest.mark.parametrize("how, match", [(_uniform("black"), "black"), (_uniform("max"), "saturated everywhere"),
                                        (_stale(), "identical to the previous frame")])
def test_bracket_frames_without_signal_are_retaken_then_refused(bench_factory, lambert, how, match):
    """Black, all-saturated and repeated frames never become samples: retaken (bounded), then an error."""
    from gonio.pipeline.acquire import Pipeline
    from gonio.pipeline.exposure import CapturePlan
    from gonio.pipeline.signal import FrameSignalError

    bench = bench_factory(lambert)
    pose, light = bench.place(30, 20, 20, 200)
    plan = CapturePlan((0.004, 0.016), (1, 1), 1.0)
    good = bench.pipeline.measure(light, camera_pose_hint=pose, plan=plan)  # darks cached, board found
    assert len(good.samples.good()) > 0
    cam = Corrupting(bench.camera, how)
    p = Pipeline(cam, bench.calib, bench.layout, light=bench.light, clock=bench.clock)
    p.darks = bench.pipeline.darks
    calls = []
    orig = cam.capture
    cam.capture = lambda *a, **k: calls.append(1) or orig(*a, **k)
    with pytest.raises(FrameSignalError, match=match):
        p.measure(light, camera_pose_hint=pose, plan=plan)
    assert len(calls) <= 1 + p.settings.meter_tries + p.settings.retries + 1 + 8  # bounded retakes


def test_one_bad_frame_is_retaken_and_the_sample_is_right(bench_factory, lambert):
    from gonio.pipeline.acquire import Pipeline
    from gonio.pipeline.exposure import CapturePlan

    bench = bench_factory(lambert)
    pose, light = bench.place(30, 20, 20, 200)
    plan = CapturePlan((0.004, 0.016), (1, 1), 1.0)
    ref = bench.pipeline.measure(light, camera_pose_hint=pose, plan=plan)
    seq = iter([False, True, False, False])  # the first bracket frame black, then good ones

    class OneBlack(Corrupting):
        def capture(self, exposure, gain=1.0, *, timeout=10.0):
            frame = self.camera.capture(exposure, gain)
            return _uniform("black")(frame) if next(seq, False) else frame

    p = Pipeline(OneBlack(bench.camera, None), bench.calib, bench.layout, light=bench.light, clock=bench.clock)
    p.darks = bench.pipeline.darks
    res = p.measure(light, camera_pose_hint=pose, plan=plan)
    assert len(res.samples) == len(ref.samples)
    np.testing.assert_allclose(res.samples.f, ref.samples.f, rtol=0.05)
