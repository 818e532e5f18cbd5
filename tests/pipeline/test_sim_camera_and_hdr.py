"""The simulated camera's radiometry and noise, the HDR merge, bracket planning and the real camera's error path."""

from __future__ import annotations

import numpy as np
import pytest

from gonio.brdf import make
from gonio.errors import ConfigError, HardwareError
from gonio.geometry import from_spherical
from gonio.pipeline.exposure import ExposureSettings, plan_bracket
from gonio.pipeline.hdr import ExposureStack, calibrate_response, linearize, merge_linear
from gonio.pipeline.target import NoiseModel


def centre_pixel(bench):
    uv = bench.camera._pose.project(np.zeros(3), bench.calib)
    return int(round(uv[1])), int(round(uv[0]))


def analytic_rate(bench, normal, albedo):
    """Independent computation: electrons/s at the sample centre, ρ/π · I (n·wi) / r² · responsivity."""
    S = bench.camera._light_pos
    r2 = S @ S
    cos = max(float(normal @ (S / np.sqrt(r2))), 0.0)
    return np.asarray(albedo) / np.pi * cos / r2 * np.asarray(bench.sensor.responsivity)


def test_rendered_radiance_matches_the_point_light_formula(bench_factory, lambert):
    bench = bench_factory(lambert)
    bench.place(30, 20, 40, 200)
    r, c = centre_pixel(bench)
    got = bench.camera.electron_rate()[r, c]
    np.testing.assert_allclose(got, analytic_rate(bench, np.array([0, 0, 1.0]), lambert.albedo), rtol=2e-3)


def test_tilted_sample_normals_use_the_inverse_transpose(bench_factory, lambert):
    # rotate by 15° about x, plus a shear of z into y: points of the plane z = 0 do not move under the
    # shear, so the true normal is R·z; transforming the normal like a point would tilt it further.
    a = np.radians(15)
    R = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    shear = np.array([[1, 0, 0], [0, 1, 0.7], [0, 0, 1.0]])
    M = np.eye(4)
    M[:3, :3] = R @ shear
    bench = bench_factory(lambert, transform=M)
    bench.place(30, 20, 40, 200)
    r, c = centre_pixel(bench)
    got = bench.camera.electron_rate()[r, c]
    np.testing.assert_allclose(got, analytic_rate(bench, R @ [0, 0, 1.0], lambert.albedo), rtol=2e-3)
    wrong = analytic_rate(bench, (R @ shear @ [0, 0, 1.0]) / np.linalg.norm(shear @ [0, 0, 1.0]), lambert.albedo)
    assert not np.allclose(got, wrong, rtol=2e-2)


def test_frames_are_reproducible_per_seed(bench_factory, lambert):
    frames = []
    for seed in (5, 5, 6):
        bench = bench_factory(lambert, seed=seed)
        bench.place(30, 20, 40, 200)
        frames.append(bench.camera.capture(0.01).pixels)
    assert np.array_equal(frames[0], frames[1])
    assert not np.array_equal(frames[0], frames[2])


@pytest.mark.parametrize("bits", [12, 16])
def test_noise_follows_the_sensor_model(bench_factory, lambert, bits):
    """Difference of two frames over the white patch: variance = 2 σ²(EMVA 1288) within 10 %."""
    from sim.camera import SensorModel

    bench = bench_factory(lambert, sensor=SensorModel(bit_depth=bits))
    bench.place(0, 0, 30, 180)
    a = bench.camera.capture(0.01)
    b = bench.camera.capture(0.01)
    mask = bench.layout.white.contains(*_plane_xy(bench), 0.004)
    da = a.pixels[mask].astype(float)
    db = b.pixels[mask].astype(float)
    signal = (da + db) / 2 - a.black_level
    model = bench.calib.noise.variance(signal)
    ratio = np.var(da - db) / (2 * model.mean())
    assert 0.9 < ratio < 1.1, ratio
    assert signal.mean() > 200  # the check ran at a meaningful signal


def _plane_xy(bench):
    cal, pose = bench.calib, bench.camera._pose
    v, u = np.mgrid[0:cal.height, 0:cal.width].astype(float)
    d = cal.rays(u, v) @ pose.R
    C = pose.centre
    t = -C[2] / d[..., 2]
    return C[0] + t * d[..., 0], C[1] + t * d[..., 1]


def test_capture_rejects_bad_settings(bench_factory, lambert):
    bench = bench_factory(lambert)
    with pytest.raises(ConfigError, match="exposure"):
        bench.camera.capture(-1.0)
    with pytest.raises(ConfigError, match="gain"):
        bench.camera.capture(0.01, gain=0.1)


def _stack(mean, maxv, t, n=1, limit=4000.0):
    return ExposureStack(exposure=t, gain=1.0, n=n, mean=mean, max=maxv, light=1.0, black_level=0.0, linear_limit=limit)


def test_merge_is_unbiased_and_its_variance_matches_the_scatter():
    rng = np.random.default_rng(0)
    noise = NoiseModel(dn_per_electron=0.2, read_noise_e=3.0, full_well_e=20000)
    rate = np.full((200, 200, 1), 30000.0)  # DN/s
    stacks, darks = [], []
    for t in (0.01, 0.04, 0.16):
        mean = rate * t
        y = mean + np.sqrt(noise.variance(mean)) * rng.standard_normal(mean.shape)
        y = np.minimum(y, 4000.0)
        stacks.append(_stack(y, y, t))
        darks.append((np.zeros_like(y), np.zeros_like(y)))
    hdr = merge_linear(stacks, darks, noise)
    assert not hdr.saturated.any()
    assert np.all(hdr.used == 2)  # the 0.16 s frame (4800 DN) is saturated and excluded
    assert abs(hdr.rate.mean() / 30000.0 - 1) < 1e-3
    assert 0.9 < hdr.rate.var() / hdr.var.mean() < 1.1


def test_merge_marks_pixels_saturated_everywhere():
    noise = NoiseModel()
    y = np.full((2, 2, 3), 4000.0)
    y[0, 0] = 100.0
    hdr = merge_linear([_stack(y, y, 0.01)], [(np.zeros_like(y), np.zeros_like(y))], noise)
    assert hdr.saturated[0, 0].sum() == 0 and hdr.saturated[1, 1].all()
    assert np.isnan(hdr.rate[1, 1]).all() and np.isfinite(hdr.rate[0, 0]).all()


def test_bracket_spans_bright_and_dim_within_limits():
    s = ExposureSettings(max_brackets=4, step=4.0)
    plan = plan_bracket(rate_bright=1e6, rate_dim=1e3, range_dn=4000, n_pixels=100, noise=NoiseModel(), settings=s)
    assert plan.exposures[0] == pytest.approx(0.75 * 4000 / 1e6)
    assert len(plan.exposures) == 4 and np.allclose(np.diff(np.log(plan.exposures)), np.log(4))
    one = plan_bracket(1e6, 9e5, 4000, 100, NoiseModel(), s)
    assert len(one.exposures) == 1
    more = plan_bracket(1e6, 9e5, 4000, 1, NoiseModel(), ExposureSettings(target_snr=1000, max_frames=50))
    assert more.frames[0] > one.frames[0]


def test_8_bit_response_recovery_with_opencv(bench_factory, lambert):
    """8-bit gamma camera: Debevec response (float32 times) linearizes ratios of radiance."""
    from sim.camera import SensorModel

    bench = bench_factory(lambert, sensor=SensorModel(bit_depth=8, linear=False, read_noise_e=1.0))
    bench.place(0, 0, 30, 180)
    times = [0.0025, 0.005, 0.01, 0.02, 0.04]
    imgs = [bench.camera.capture(t).pixels for t in times]
    resp = calibrate_response(imgs, times)
    assert np.isfinite(resp).all() and np.all(np.diff(resp[20:240, 0, 1]) > 0)
    # the recovered curve is the inverse gamma: value y maps to ∝ (y/255)^2.2
    y = np.array([60, 120, 200])
    ratio = resp[y, 0, 1] / resp[120, 0, 1]
    np.testing.assert_allclose(ratio, (y / 120.0) ** 2.2, rtol=0.15)
    lin = linearize(imgs[2], resp)
    assert lin.shape == imgs[2].shape and np.isfinite(lin).all()


def test_real_camera_without_a_device_is_a_clear_error():
    from gonio.rig.camera import OpenCVCamera
    from sim.clock import SimClock

    with pytest.raises(HardwareError, match="cannot open"):
        OpenCVCamera(17, SimClock())
    with pytest.raises(HardwareError, match="/dev/video-none"):
        OpenCVCamera("/dev/video-none", SimClock())
    with pytest.raises(ConfigError, match="camera.device"):
        OpenCVCamera(2.5, SimClock())


def test_reseed_restarts_the_noise(bench_factory, lambert):
    bench = bench_factory(lambert, seed=1)
    bench.place(30, 20, 40, 200)
    cam = bench.camera
    cam.reseed([7, 3])
    a = cam.capture(0.01).pixels
    b = cam.capture(0.01).pixels  # the generator moved on: new noise
    cam.reseed([7, 3])
    c = cam.capture(0.01).pixels
    assert not np.array_equal(a, b)
    assert np.array_equal(a, c)


def test_a_new_scene_is_rendered_not_the_old_ones_cache(bench_factory, lambert):
    import dataclasses

    from sim.camera import SimCamera

    b = bench_factory(lambert)
    b.place(30, 40, 20, 180)
    before = b.camera.electron_rate().copy()
    scene = dataclasses.replace(b.scene, material=make("lambert", albedo=[0.1, 0.2, 0.3]), board_white=0.5)
    b.camera.scene = scene  # the same pose and light: only the scene changed
    fresh = SimCamera(b.calib, b.sensor, scene)
    fresh.set_pose(b.camera._pose)
    fresh.set_light(b.camera._light_pos)
    after = b.camera.electron_rate()
    assert not np.array_equal(after, before)
    assert np.array_equal(after, fresh.electron_rate())
