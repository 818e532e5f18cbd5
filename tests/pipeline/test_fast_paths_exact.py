"""The simulator's and the frame checks' fast paths give exactly what the plain formulas give (issue 17: faster,
same samples for the same seed): render caches on or off, the grey image for detection, the black and stale checks."""

from __future__ import annotations

import re

import numpy as np
import pytest

from gonio.pipeline.dark import DarkFrame
from gonio.pipeline.markers import to_gray8
from gonio.pipeline.signal import BLACK_SIGMAS, FrameSignalError, SignalCheck
from sim.camera import SensorModel, blurred_board_texture, board_texture


def _clear_render_caches(cam) -> None:
    cam._cache_key = cam._view_key = cam._sample_key = None
    cam._patch_scene = None
    cam._rays = None
    board_texture.cache_clear()  # the board textures are made once per process: made again here
    blurred_board_texture.cache_clear()


def test_frames_are_the_same_with_and_without_the_render_caches(bench_factory, lambert):
    """Same seed, same sequence of poses (the light moved alone, then back): every frame is bit for
    bit the same whether the camera reuses its per-pose caches or renders everything afresh."""
    poses = [(30, 20, 40, 200), (30, 20, 55, 150), (30, 20, 40, 200)]
    frames = {}
    for cached in (True, False):
        bench = bench_factory(lambert, seed=11)
        out = []
        for p in poses:
            bench.place(*p)
            if not cached:
                _clear_render_caches(bench.camera)
            out.append(bench.camera.capture(0.01).pixels)
        frames[cached] = out
    assert all(np.array_equal(a, b) for a, b in zip(frames[True], frames[False]))
    assert not np.array_equal(frames[True][0], frames[True][-1])  # same pose again: new noise, not a replay


@pytest.mark.parametrize("shape, dtype", [((48, 64, 3), np.uint16), ((48, 64, 3), np.uint8), ((48, 64), np.uint16),
                                          ((48, 64, 4), np.uint16)])
def test_gray_image_is_the_channel_mean_bit_for_bit(shape, dtype):
    rng = np.random.default_rng(3)
    px = rng.integers(0, np.iinfo(dtype).max, shape).astype(dtype)
    img = px.astype(np.float32)
    if img.ndim == 3:
        img = img.mean(axis=2)
    img = img - np.float32(64.0)
    scale = 230.0 / float(np.percentile(img[::4, ::4], 99.0))
    want = np.clip(img * np.float32(scale), 0, 255).astype(np.uint8)
    assert np.array_equal(to_gray8(px, 16, 64.0), want)


class _Frame:
    gain, black_level, saturation_level = 1.0, 64.0, 4095


def _dark(shape=(40, 60, 3)):
    rng = np.random.default_rng(7)
    mean = (64 + 3 * rng.random(shape)).astype(np.float32)
    var = (0.5 + rng.random(shape)).astype(np.float32)
    return DarkFrame(mean=mean, var=var, n=8, time=0.0, measured=True)


def test_black_check_against_a_dark_frame_decides_as_the_z_scores_do():
    """A frame whose brightest pixel sits just under BLACK_SIGMAS σ above its dark frame is black; one count more
    on that pixel is not; the refusal names the highest z-score computed as (x − mean)/σ."""
    noise = SensorModel().noise_model()
    check = SignalCheck(noise, lambda f: 4095.0)
    dark = _dark()
    sd = np.sqrt(dark.var[::2, ::2] + noise.variance(0.0, 1.0))
    base = np.floor(dark.mean).astype(np.uint16)  # at or below the dark level everywhere
    edge = dark.mean[::2, ::2][3, 5, 1] + BLACK_SIGMAS * sd[3, 5, 1]  # 6 σ above the dark level at one pixel
    below, above = base.copy(), base.copy()
    below[6, 10, 1] = np.floor(edge)
    above[6, 10, 1] = np.floor(edge) + 1
    z = (below[::2, ::2].astype(np.float64) - dark.mean[::2, ::2]) / sd
    with pytest.raises(FrameSignalError, match=re.escape(f"highest {z.max():+.1f} σ")):
        check(_Frame(), below, dark=dark)
    check(_Frame(), above, dark=dark)  # one count more: a signal
    other = DarkFrame(mean=dark.mean - 5, var=dark.var, n=8, time=0.0, measured=True)
    check(_Frame(), below + 1, dark=other)  # a new dark frame is not judged by the cached thresholds


def test_repeat_check_compares_the_frames_bytes():
    check = SignalCheck(SensorModel().noise_model(), lambda f: 4095.0)
    px = np.random.default_rng(1).integers(64, 3000, (40, 60, 3)).astype(np.uint16)
    check(_Frame(), px, levels=False)
    px2 = px.copy()
    px2[39, 59, 2] ^= 1  # one bit in the last value
    check(_Frame(), px2, levels=False)
    px2[39, 59, 2] ^= 1  # refilled in place: a new exposure that happens to differ from the last one
    check(_Frame(), px2, levels=False)
    with pytest.raises(FrameSignalError, match="identical to the previous frame"):
        check(_Frame(), px2.copy(), levels=False)  # the same bytes again, in another buffer
    check(_Frame(), px2[:, :, :2].copy(), levels=False)  # another shape is not a repeat


def test_black_check_alternating_dark_frames_decides_as_a_fresh_check():
    """A bracket alternates between its exposures' dark frames: the thresholds kept per dark frame decide every
    frame exactly as a check that never saw another frame does (same verdict, same message); a dark frame the
    session dropped is not kept alive by the check."""
    import gc
    import weakref

    noise = SensorModel().noise_model()
    darks = [_dark(), DarkFrame(mean=_dark().mean + 2, var=_dark().var * 2, n=8, time=0.0, measured=True)]
    rng = np.random.default_rng(5)
    check = SignalCheck(noise, lambda f: 4095.0)
    for i in range(8):
        dark = darks[i % 2]
        px = np.floor(dark.mean).astype(np.uint16)
        if i % 3:  # every other frame gets one pixel above the dark level somewhere
            px[rng.integers(0, 40), rng.integers(0, 60), rng.integers(0, 3)] += int(rng.integers(0, 40))
        verdicts = []
        for c in (check, SignalCheck(noise, lambda f: 4095.0)):
            c._last = None  # the repeat check is not what is compared here
            try:
                c(_Frame(), px, dark=dark)
                verdicts.append("ok")
            except FrameSignalError as exc:
                verdicts.append(str(exc))
        assert verdicts[0] == verdicts[1]
    ref = weakref.ref(darks[0])
    del darks[0], dark
    gc.collect()
    assert ref() is None


def test_normal_draws_from_raw_outputs_are_generator_integers_bit_for_bit(bench_factory, lambert):
    """The camera's noise indices drawn as raw 64-bit outputs' 16-bit fields are exactly what
    ``Generator.integers(0, 2**16, dtype=uint16)`` draws, and leave the generator where it leaves it: frame
    sizes that are a multiple of four and ones that are not (which leave a 32-bit half pending), in any order,
    followed by other draws (the Poisson part of the noise)."""
    cam = bench_factory(lambert, seed=9).camera
    ref = np.random.default_rng(9)
    for shape in [(240, 320, 3), (5, 7, 3), (4, 4, 3), (2, 3), (3, 1), (240, 320, 3), (8,)]:
        got = cam._normal_indices(shape)
        want = ref.integers(0, 1 << 16, size=shape, dtype=np.uint16)
        assert got.shape == want.shape and got.dtype == want.dtype and np.array_equal(got, want)
        a, b = cam._rng.bit_generator.state, ref.bit_generator.state
        assert a["state"] == b["state"] and a["has_uint32"] == b["has_uint32"]
        assert not a["has_uint32"] or a["uinteger"] == b["uinteger"]  # (the pending half, when there is one)
        assert np.array_equal(cam._rng.poisson(3.0, 5), ref.poisson(3.0, 5))


def _sensor_inputs(shape, seed):
    """Means spanning every branch of the sensor chain: 0, below 1, either side of the Poisson threshold, bright,
    past the full well."""
    from sim.camera import POISSON_EXACT_BELOW

    rng = np.random.default_rng(seed)
    levels = np.array([0.0, 0.05, 0.7, 3.0, 11.0, np.nextafter(np.float32(POISSON_EXACT_BELOW), 0), POISSON_EXACT_BELOW,
                       500.0, 19990.0, 40000.0], dtype=np.float32)
    return (levels[rng.integers(0, levels.size, shape)] * rng.uniform(0.5, 1.5, shape).astype(np.float32)).astype(
        np.float32)


@pytest.mark.parametrize("shape, bits, dsnu", [((48, 64, 3), 12, True), ((7, 9, 3), 12, False), ((48, 64, 3), 8, True),
                                                ((33, 5), 16, False)])
def test_sensor_chain_compiled_is_the_numpy_reference_bit_for_bit(shape, bits, dsnu):
    """sim.sensor_noise: the numba passes and the NumPy reference turn the same electron rates and seed into the
    same frame (every branch: Poisson by inversion, the normal approximation, the full well, the DN range; with and
    without a dark pattern)."""
    sn = SensorModel(bit_depth=bits)
    kw = dict(read_noise=sn.read_noise_e, full_well=sn.full_well, gain_k=sn.dn_per_electron * 1.7,
              black=sn.black_level, saturation=sn.saturation, dtype=np.uint8 if bits == 8 else np.uint16)
    for seed in range(5):
        rate = _sensor_inputs(shape, seed) / np.float32(0.01)
        pattern = np.random.default_rng(seed + 100).uniform(0.5, 1.5, shape).astype(np.float32) if dsnu else None
        _assert_chains_agree(rate, np.float32(0.01), pattern, np.float32(0.37), seed, kw)


def _assert_chains_agree(rate, scale, pattern, dark_e, seed, kw):
    """sim.sensor_noise's NumPy reference and compiled chain give the same frame from the same generator, and leave
    it in the same state."""
    from sim import sensor_noise
    from sim.camera import POISSON_EXACT_BELOW, normal_table

    frames = []
    for expose in (sensor_noise.expose_numpy, sensor_noise.expose_compiled):
        rng = np.random.default_rng(seed)
        frames.append(expose(rate, scale, pattern, dark_e, rng,
                             lambda s: rng.integers(0, 1 << 16, size=s, dtype=np.uint16), normal_table(),
                             POISSON_EXACT_BELOW, **kw))
        frames.append(rng.random())  # and the generator is left in the same state
    want, after_want, got, after_got = frames
    assert got.dtype == want.dtype and got.tobytes() == want.tobytes() and after_got == after_want


def test_sensor_chain_compiled_with_the_poisson_values_in_a_few_blocks_is_the_reference():
    """A bright frame with dark patches (as the board's black squares and the background make them): the compiled
    chain gathers the values below the Poisson threshold only from the blocks of its first pass that hold some
    (sim.sensor_noise.BLOCK), the frame not a multiple of the block; still the NumPy reference's frame, and the
    generator left in the same state."""
    from sim import sensor_noise

    sn = SensorModel()
    kw = dict(read_noise=sn.read_noise_e, full_well=sn.full_well, gain_k=sn.dn_per_electron, black=sn.black_level,
              saturation=sn.saturation)
    shape = (61, 47, 3)
    assert np.prod(shape) % sensor_noise.BLOCK and np.prod(shape) > 4 * sensor_noise.BLOCK
    rate = np.full(shape, 5000.0, dtype=np.float32)
    rate[3:5, 10:12] = 0.0  # a few values, inside one block
    rate[30:34] = np.linspace(0.0, 40.0, 34 * 47 * 3 - 30 * 47 * 3, dtype=np.float32).reshape(4, 47, 3)  # across blocks
    rate[-1, -1] = 3.0  # the last value, in the last (short) block
    for seed in range(3):
        _assert_chains_agree(rate, np.float32(1.0), None, np.float32(0.5), seed, kw)


def test_camera_frames_are_the_same_with_and_without_numba(bench_factory, lambert, monkeypatch):
    """A seed gives the same frames whichever implementations of the sensor chain (sim.sensor_noise) and the board's
    rendering run (sim.compiled.use_compiled)."""
    from sim import compiled as paths

    frames = {}
    for compiled in (True, False):
        monkeypatch.setattr(paths, "use_compiled", lambda: compiled)
        monkeypatch.setattr(paths, "_compiling_elsewhere", lambda _f: False)  # even while another process compiles
        bench = bench_factory(lambert, seed=4)
        bench.place(30, 20, 40, 200)
        frames[compiled] = [bench.camera.capture(t).pixels for t in (1e-4, 0.01, 0.2)]
    assert all(a.tobytes() == b.tobytes() for a, b in zip(frames[True], frames[False]))


def test_frames_take_the_numpy_paths_until_they_have_cost_the_compiled_paths_price(bench_factory, lambert, monkeypatch):
    """sim.compiled: in a process without numba, a frame's sensor chain and board rendering take the NumPy paths, whose
    CPU time is counted; once it reaches COLD_SECONDS, or once numba is loaded, the compiled ones."""
    import sim.camera as camera
    from sim import compiled as paths
    from sim import sensor_noise

    ran = []
    for mod, name in ((sensor_noise, "expose_compiled"), (sensor_noise, "expose_numpy"),
                      (camera, "board_points_compiled"), (camera, "board_points_numpy"),
                      (camera, "shade_board_compiled"), (camera, "shade_board_numpy")):
        def recorded(*args, _f=getattr(mod, name), _name=name, **kw):
            ran.append(_name.rsplit("_", 1)[1])
            return _f(*args, **kw)

        monkeypatch.setattr(mod, name, recorded)
    monkeypatch.setattr(paths, "_NUMPY_SECONDS", [0.0])
    monkeypatch.setattr(paths, "_BOUGHT", [False])  # no session of this process forecast more
    bench = bench_factory(lambert, seed=4)
    for pose, spent, warm, want in (((30, 20, 40, 200), 0.0, False, "numpy"),
                                    ((20, 10, 30, 150), paths.COLD_SECONDS, False, "compiled"),
                                    ((30, 20, 40, 200), 0.0, True, "compiled")):
        paths._NUMPY_SECONDS[0] = spent
        monkeypatch.setattr(paths, "_warm", lambda warm=warm: warm)  # False: as if numba were not loaded
        ran.clear()
        bench.place(*pose)  # a new pose: the board is rendered again
        bench.camera.capture(0.01)
        assert ran == [want] * 3, (spent, warm)
        assert (paths._NUMPY_SECONDS[0] > spent) == (want == "numpy")


def test_a_session_forecast_to_cost_numpy_more_than_the_price_takes_the_compiled_paths_from_its_first_frame(
        monkeypatch):
    """sim.compiled.expect: a session whose NumPy frames would cost COLD_SECONDS or more (its dark set and poses,
    from the frame's size) takes the compiled paths at once; a smaller one keeps renting."""
    from sim import compiled as paths

    monkeypatch.setattr(paths, "_warm", lambda: False)  # as if numba were not loaded
    monkeypatch.setattr(paths, "_NUMPY_SECONDS", [0.0])
    monkeypatch.setattr(paths, "_BOUGHT", [False])
    for values, poses in ((240 * 180 * 3, 12), (0, 10 ** 6), (240 * 180 * 3, 60)):  # ~0.25 s, 0, ~0.38 s
        paths.expect(values, poses)
        assert not paths.use_compiled(), (values, poses)
    paths.expect(320 * 240 * 3, 38)  # the quick start's session: ~0.57 s
    assert paths.use_compiled()
    # several sessions in one process, a dark set each: `gonio bench --smoke`'s plan table, 12 + 38 poses (~0.58 s)
    monkeypatch.setattr(paths, "_BOUGHT", [False])
    paths.expect(240 * 180 * 3, 12 + 38)  # as one session: ~0.36 s
    assert not paths.use_compiled()
    paths.expect(240 * 180 * 3, 12 + 38, sessions=2)
    assert paths.use_compiled()


@pytest.mark.parametrize("lam", [0.02, 0.6, 3.7, 12.0, 29.9])
def test_poisson_by_inversion_follows_the_poisson_law(lam):
    """sim.sensor_noise.poisson_inversion draws Poisson(λ): χ² goodness of fit over the cells with ≥ 5 expected
    counts (200 000 draws; the 0.999 quantile of χ² bounds it, a fixed seed), mean and variance within 4 standard
    errors. Poisson's pmf exp(k·ln λ − ln k! − λ) and χ²'s quantile 2·P⁻¹(dof/2, q) (P the regularized lower incomplete
    gamma function) from scipy.special: what scipy.stats.poisson.pmf and chi2.ppf compute (their _pmf and _ppf), bit for
    bit, without importing scipy.stats (~0.4 CPU s in the worker that runs this)."""
    from scipy.special import gammaincinv, gammaln, xlogy

    from sim import sensor_noise

    n = 200_000
    lam_a = np.full(n, lam)
    u = np.random.default_rng(int(lam * 100)).random(n)
    k = sensor_noise.poisson_inversion(lam_a, np.exp(-lam_a), u)
    counts = np.bincount(k, minlength=int(lam + 10 * np.sqrt(lam) + 10))
    k_all = np.arange(counts.size)
    expected = np.exp(xlogy(k_all, lam) - gammaln(k_all + 1) - lam) * n
    cells = expected >= 5
    rest_obs, rest_exp = n - counts[cells].sum(), n - expected[cells].sum()
    chi2 = np.sum((counts[cells] - expected[cells]) ** 2 / expected[cells])
    dof = int(cells.sum()) - 1
    if rest_exp >= 5:
        chi2 += (rest_obs - rest_exp) ** 2 / rest_exp
        dof += 1
    assert chi2 < 2 * gammaincinv(max(dof, 1) / 2, 0.999)
    assert abs(k.mean() - lam) < 4 * np.sqrt(lam / n)
    assert abs(k.var() - lam) < 4 * lam * np.sqrt(2 / n) + 4 * np.sqrt(lam / n)


def test_poisson_inversion_gives_each_value_its_own_search_s_k():
    """sim.sensor_noise.poisson_inversion (the searches side by side, the ended ones dropped now and then) gives each
    value the k of its own sequential search (the module docstring's, one value after the other here), for means from
    0 to 30 mixed and uniforms equal to a partial sum of their search, just below and just above it, 0, the largest
    below 1 and random ones."""
    from sim import sensor_noise

    def search(lam, p0, u):  # one value: the smallest k with u ≤ its partial sum, or where a term stops changing it
        k, p, cdf = 0, p0, p0
        while u > cdf:
            k += 1
            p = p * (lam * (1.0 / k))
            if cdf + p == cdf:
                break
            cdf = cdf + p
        return k

    rng = np.random.default_rng(3)
    lams = np.concatenate([[0.0, 1e-300, 0.013, 0.77, 1.0, 3.3, 17.9, 29.999], rng.uniform(0.0, 30.0, 40)])
    lam, u = [], []
    for m in lams:
        p0 = np.exp(-np.array([m]))[0]
        sums, p, j = [p0], p0, 0  # the search's partial sums
        while True:
            j += 1
            p = p * (m * (1.0 / j))
            if sums[-1] + p == sums[-1]:
                break
            sums.append(sums[-1] + p)
        s = np.array(sums)
        us = np.concatenate([s, np.nextafter(s, 0.0), np.nextafter(s, 1.0), [0.0, np.nextafter(1.0, 0.0)],
                             rng.random(50)])
        u.append(us[us < 1.0])
        lam.append(np.full(u[-1].size, m))
    lam, u = np.concatenate(lam), np.concatenate(u)
    order = rng.permutation(lam.size)  # the means mixed, as a frame's are
    lam, u = lam[order], u[order]
    p0 = np.exp(-lam)
    k = sensor_noise.poisson_inversion(lam, p0, u)
    assert k.dtype == np.int64 and k.tolist() == [search(*v) for v in zip(lam, p0, u)]


def test_sensor_chain_rounds_half_to_even_and_clips_as_numpy_does():
    """The compiled loop's rounding ((x + 2²³) − 2²³ in float32) is np.rint's, ties to even included, and its
    clipping is np.clip's, from below zero to past the range (a zero noise table: the values are the means; the
    read noise keeps the square roots of the negative means real)."""
    from sim import sensor_noise

    mean = np.concatenate([np.arange(-4.0, 70000.0, 0.5), np.arange(0.0, 3.0, 0.125), [1e9, 3.4e38]]).astype(np.float32)
    table = np.zeros(1 << 16, dtype=np.float32)
    for bits, dtype in ((12, np.uint16), (16, np.uint16), (8, np.uint8)):
        kw = dict(read_noise=3.0, full_well=1e30, gain_k=1.0, black=0.0, saturation=(1 << bits) - 1, dtype=dtype)
        frames = [expose(mean, np.float32(1.0), None, np.float32(0.0), np.random.default_rng(0),
                         lambda s: np.zeros(s, dtype=np.uint16), table, -np.inf, **kw)
                  for expose in (sensor_noise.expose_numpy, sensor_noise.expose_compiled)]
        assert frames[1].tobytes() == frames[0].tobytes()
        want = frames[0]
        assert want[np.flatnonzero(mean == 2.5)[0]] == 2 and want[np.flatnonzero(mean == 3.5)[0]] == 4


def test_board_shading_compiled_is_the_numpy_reference_bit_for_bit(bench_factory, lambert):
    """sim.camera: the board's irradiance and electron rates from the numba pass equal the NumPy reference's, for
    camera and light positions around the sample (grazing ones included)."""
    from sim.camera import shade_board_compiled, shade_board_numpy

    f32 = np.float32
    bench = bench_factory(lambert, seed=1)
    k = np.asarray(bench.sensor.responsivity, dtype=np.float32) / f32(np.pi)
    for pose in [(0, 0, 30, 90), (60, 45, 75, 200), (85, 10, 5, 300), (30, 200, 88, 20)]:
        bench.place(*pose)
        px, py, hit, albedo = bench.camera._board_view()
        S = bench.camera._light_pos
        args = (px, py, hit, albedo, f32(S[0]), f32(S[1]), f32(S[2] ** 2), f32(max(S[2], 0.0)), k)
        for a, b in zip(shade_board_numpy(*args), shade_board_compiled(*args)):
            assert a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


@pytest.mark.parametrize("distorted", [False, True])
def test_board_points_compiled_are_the_numpy_reference_bit_for_bit(bench_factory, lambert, distorted):
    """sim.camera: where the pixels' rays meet the board, whether they do and the texture coordinates there, from the
    numba pass and from the NumPy reference, for cameras around the sample (grazing, and below the board plane: no
    hits), with an ideal pinhole (ray maps of one row and one column, broadcast) and with lens distortion (full
    maps)."""
    from dataclasses import replace

    from gonio.pipeline.target import CameraPose
    from sim.camera import board_points_compiled, board_points_numpy

    bench = bench_factory(lambert, seed=1)
    cam = bench.camera
    if distorted:
        cam.calibration = replace(cam.calibration, dist=np.array([-0.12, 0.03, 0.001, -0.002, 0.0]))
    x, y = (a.astype(np.float32) for a in cam._ray_maps())
    assert (x.ndim, x.shape[0] > 1) == (2, distorted)
    for pose in [(0, 0, 30, 90), (60, 45, 75, 200), (89, 10, 5, 300), (30, 200, 88, 20)]:
        bench.place(*pose)
        poses = [cam._pose, CameraPose.look_at(cam._pose.centre * [1.0, 1.0, -1.0])]  # and from below the board
        for p in poses:
            args = (x, y, p.R, p.centre, 1.0 / 0.25e-3, (123.5, 87.25))
            want, got = board_points_numpy(*args), board_points_compiled(*args)
            for a, b in zip(want, got):
                assert a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()
            assert want[2].any() == (p.centre[2] > 0)


def test_geometry_variance_all_cases_at_once_is_one_case_at_a_time_bit_for_bit():
    """gonio.pipeline.uncertainty: the perturbation cases evaluated as one stack give, bit for bit, the sum of the
    cases evaluated one at a time (the formulation it replaced), and the stacked homographies are those solved one
    pose at a time."""
    from gonio.pipeline.target import CameraPose
    from gonio.pipeline.uncertainty import (_half, _log_irradiance, geometry_variance, local_h_gradient,
                                            plane_transfer, plane_transfer_many)
    from gonio.geometry import normalize

    rng = np.random.default_rng(5)
    n = 4
    p_tile = np.column_stack([rng.uniform(-0.01, 0.01, (n * n, 2)), np.zeros(n * n)])
    p_white = np.array([0.03, -0.01, 0.0])
    f = rng.uniform(0.1, 0.5, (n * n, 3))
    pose = CameraPose.look_at([0.2, -0.3, 0.5])
    perturbed = [CameraPose.look_at([0.2 + d, -0.3, 0.5 - d]) for d in (1e-3, -2e-3, 5e-4)]
    S = np.array([-0.3, 0.2, 0.6])
    def one_homography(points, src, dst):  # the plane-to-plane homography of one pose, solved alone
        Hs = np.column_stack([src.R[:, 0], src.R[:, 1], src.t])
        Hd = np.column_stack([dst.R[:, 0], dst.R[:, 1], dst.t])
        q = np.concatenate([points[..., :2], np.ones(points.shape[:-1] + (1,))], axis=-1) @ np.linalg.solve(Hd, Hs).T
        out = np.zeros_like(points)
        out[..., :2] = q[..., :2] / q[..., 2:3]
        return out

    many = plane_transfer_many(p_tile, pose, perturbed)
    for k, q in enumerate(perturbed):
        assert many[k].tobytes() == one_homography(p_tile, pose, q).tobytes()
        assert plane_transfer(p_tile, pose, q).tobytes() == many[k].tobytes()
    for white in (p_white, None):
        got = geometry_variance(f, p_tile, white, pose, S, n, pose_perturbations=perturbed, light_sigma=4e-4)
        h0 = _half(normalize(S - p_tile), normalize(pose.centre - p_tile))
        G = local_h_gradient(f, h0, n)
        want = np.zeros_like(f)
        for q, S_q in [(q, S) for q in perturbed] + [(pose, S + 4e-4 * e) for e in np.eye(3)]:
            pt = plane_transfer(p_tile, pose, q) if q is not pose else p_tile
            h = _half(normalize(S_q - pt), normalize(q.centre - pt))
            dlnE = _log_irradiance(pt, S_q) - _log_irradiance(p_tile, S)
            if white is not None:
                pw = plane_transfer(white, pose, q) if q is not pose else white
                dlnE = dlnE - (_log_irradiance(pw, S_q) - _log_irradiance(white, S))
            want += (np.einsum("tci,ti->tc", G, (h - h0)[:, :2]) + f * dlnE[:, None]) ** 2
        assert got.tobytes() == np.where(np.isfinite(want), want, 0.0).tobytes()
