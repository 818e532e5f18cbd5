"""A dark set's frames (light off, several frames per exposure) from sim.camera.SimCamera are the sensor chain's NumPy
reference on the rendered scene's electron rates times the zero light output, bit for bit: the camera renders nothing
for a light-off frame, and sim.sensor_noise.expose_compiled gathers the values below the Poisson threshold once per
exposure (sim.sensor_noise.LowValues) — with and without a dark-signal pattern (DSNU), at exposures whose dark signal
is below the threshold everywhere and where part of it is above."""

from __future__ import annotations

import numpy as np
import pytest

from gonio.brdf import make
from gonio.pipeline.target import CameraCalibration, CameraPose, TargetLayout
from sim import compiled, sensor_noise
from sim.camera import POISSON_EXACT_BELOW, SensorModel, SimCamera, SimScene, normal_table

#: a dark signal from 0.001 to ~41 electrons (20 e/s): with DSNU 0.3 the 1.6 s frames' means straddle the threshold
EXPOSURES = (5e-5, 0.004, 0.3, 1.6, 0.004)


def _camera(dsnu, seed):
    sensor = SensorModel(dsnu=dsnu)
    calib = CameraCalibration.pinhole(64, 48, 80.0, noise=sensor.noise_model())
    cam = SimCamera(calib, sensor, SimScene(TargetLayout(), make("lambert", albedo=[0.6, 0.45, 0.3])), seed=seed)
    cam.set_pose(CameraPose.look_at([0.05, 0.02, 0.6]))
    cam.set_light([0.1, 0.2, 0.5], on=False)
    return cam


@pytest.mark.parametrize("dsnu", [0.0, 0.3])
def test_light_off_frames_are_the_reference_chain_on_the_rendered_rates(dsnu, monkeypatch):
    monkeypatch.setattr(compiled, "use_compiled", sensor_noise.compiled_available)  # the compiled path from frame 1
    monkeypatch.setattr(compiled, "_compiling_elsewhere", lambda _f: False)  # even while another process compiles
    cam, ref = _camera(dsnu, 11), _camera(dsnu, 11)
    rate = ref.electron_rate()  # the scene as the light would show it: times the light's zero output
    assert rate.max() > 1e3
    sn = ref.sensor
    kw = dict(read_noise=sn.read_noise_e, full_well=sn.full_well, gain_k=sn.dn_per_electron, black=sn.black_level,
              saturation=sn.saturation)
    every = []
    for t in EXPOSURES:
        for _ in range(3):
            got = cam.capture(t).pixels
            dark_e = np.float32(sn.dark_rate(ref.sensor_temperature()) * t)
            want = sensor_noise.expose_numpy(rate, np.float32(0.0), ref._dark_pattern(rate.shape), dark_e, ref._rng,
                                             ref._normal_indices, normal_table(), POISSON_EXACT_BELOW, **kw)
            assert got.dtype == want.dtype and got.tobytes() == want.tobytes(), (dsnu, t)
            every.append(cam._low.every if sensor_noise.compiled_available() else None)
        assert cam._rng.random() == ref._rng.random()  # and the generators are left in the same state
    if sensor_noise.compiled_available():  # both branches ran: the first pass skipped, and kept
        assert every.count(True) >= 9 and (every.count(False) >= 3) == (dsnu > 0)
    assert cam._rate is None  # nothing rendered


def test_frames_under_one_key_are_the_reference_whatever_came_between():
    """expose_compiled with a LowValues memo: frames under one key (the same means), under alternating keys and after a
    lit frame, each the NumPy reference's from the same generator, which is left where the reference leaves it."""
    sn = SensorModel()
    kw = dict(read_noise=sn.read_noise_e, full_well=sn.full_well, gain_k=sn.dn_per_electron, black=sn.black_level,
              saturation=sn.saturation)
    shape = (37, 29, 3)
    zero = np.zeros(shape, np.float32)
    lit = np.random.default_rng(2).uniform(0.0, 4000.0, shape).astype(np.float32)
    pattern = np.maximum(1.0 + 0.3 * np.random.default_rng(3).standard_normal(shape), 0.0).astype(np.float32)
    memo = sensor_noise.LowValues()
    steps = [(zero, 0.0, 2.5, "a"), (zero, 0.0, 2.5, "a"), (zero, 0.0, 28.0, "b"), (zero, 0.0, 28.0, "b"),
             (zero, 0.0, 2.5, "a"), (lit, 0.01, 2.5, None), (zero, 0.0, 28.0, "b"), (zero, 0.0, 28.0, "b")]
    rng_a, rng_b = np.random.default_rng(5), np.random.default_rng(5)
    for rate, scale, dark_e, key in steps:
        args = (rate, np.float32(scale), pattern, np.float32(dark_e))
        want = sensor_noise.expose_numpy(*args, rng_a, lambda s: rng_a.integers(0, 1 << 16, size=s, dtype=np.uint16),
                                         normal_table(), POISSON_EXACT_BELOW, **kw)
        got = sensor_noise.expose_compiled(*args, rng_b, lambda s: rng_b.integers(0, 1 << 16, size=s, dtype=np.uint16),
                                           normal_table(), POISSON_EXACT_BELOW, memo=memo,
                                           key=None if key is None else (key, dark_e), **kw)
        assert got.tobytes() == want.tobytes(), (dark_e, key)
    assert rng_a.random() == rng_b.random()
    assert memo.key == ("b", 28.0) and not memo.every  # 28 e × DSNU: some means above the threshold


def test_a_dark_cache_mean_is_the_frames_float32_sum_over_n():
    """gonio.pipeline.dark.DarkCache accumulates its frames in place: the mean is (((f1 + f2) + f3) + f4) / 4 in
    float32 of the same frames (a second camera with the same seed gives them), bit for bit."""
    from gonio.pipeline.dark import DarkCache
    from sim.camera import SceneLight
    from sim.clock import SimClock

    cam, ref = _camera(0.3, 4), _camera(0.3, 4)
    light = SceneLight(SimClock())
    cam._light_output = ref._light_output = light.output
    darks = DarkCache(cam, cam.calibration, light=light, n_frames=4)
    for t in (0.004, 1.6):
        got = darks.get(t)  # the light switched off for its frames, and on again
        light.set_light(False)
        frames = [ref.capture(t).pixels.astype(np.float32) for _ in range(4)]
        want = (((frames[0] + frames[1]) + frames[2]) + frames[3]) / np.float32(4)
        assert got.mean.dtype == np.float32 and got.mean.tobytes() == want.tobytes()
        assert got.n == 4 and darks.captures == (4 if t == 0.004 else 8)


def test_the_normal_table_is_the_scipy_quantiles_one_bit_for_bit():
    """sim.camera.normal_table from Wichura's AS 241 is the float32 table made from scipy.special.ndtri (every
    simulated frame's noise draws from it: sessions stay the same), and inverse_normal is ndtri within 2e-15
    relative from 1e-300 to 1 − 1e-16."""
    from scipy.special import ndtri

    from sim.camera import inverse_normal

    p = (np.arange(1 << 16, dtype=np.float64) + 0.5) / (1 << 16)
    q = ndtri(p)
    want = (q / np.sqrt(np.mean(q * q))).astype(np.float32)
    assert normal_table().tobytes() == want.tobytes()
    p = np.concatenate([np.logspace(-300, -1, 2000), np.linspace(0.01, 0.99, 2001), 1 - np.logspace(-16, -1, 500)])
    assert (np.abs(inverse_normal(p) - ndtri(p)) <= 2e-15 * np.abs(ndtri(p))).all()  # p = ½: both 0


@pytest.mark.parametrize("dsnu", [0.0, 0.3])
def test_a_zero_rate_frame_s_means_from_numpy_are_the_first_pass_s(dsnu):
    """expose_compiled(dark=True): the means of a light-off frame made by one NumPy product (pattern · dark signal,
    float32, then float64) are the first pass's gathered means bit for bit, and so are their e^-mean and the frame."""
    sn = SensorModel()
    kw = dict(read_noise=sn.read_noise_e, full_well=sn.full_well, gain_k=sn.dn_per_electron, black=sn.black_level,
              saturation=sn.saturation)
    shape = (31, 23, 3)
    zero = np.zeros(shape, np.float32)
    pattern = (np.maximum(1.0 + dsnu * np.random.default_rng(8).standard_normal(shape), 0.0).astype(np.float32)
               if dsnu else None)
    for dark_e in (0.013, 0.77, 3.3, 17.9):
        got = []
        for dark in (False, True):
            memo, rng = sensor_noise.LowValues(), np.random.default_rng(2)
            frame = sensor_noise.expose_compiled(
                zero, np.float32(0.0), pattern, np.float32(dark_e), rng,
                lambda s: rng.integers(0, 1 << 16, size=s, dtype=np.uint16), normal_table(), POISSON_EXACT_BELOW,
                memo=memo, key=1, dark=dark, **kw)
            got.append((memo.lam.tobytes(), memo.p0.tobytes(), memo.pos.tobytes(), memo.every, frame.tobytes()))
        assert got[0] == got[1], dark_e  # (at 17.9 e with DSNU some means are above the threshold: pass1 runs)
