"""sim.sensor_noise's compiled chain on frames whose Poisson values all have one mean (a dark frame: every value's
mean is the dark signal; sim.sensor_noise._pass2_one_mean tabulates that mean's partial sums once) is the NumPy
reference's frame bit for bit, and leaves the generator where the reference does — at means below, at and above
the tabulation's threshold and up to the Poisson threshold, with and without a bright part."""

from __future__ import annotations

import numpy as np
import pytest

from sim import sensor_noise
from sim.camera import POISSON_EXACT_BELOW, SensorModel, normal_table


def _frames(rate, scale, dark_e, seed):
    sn = SensorModel()
    kw = dict(read_noise=sn.read_noise_e, full_well=sn.full_well, gain_k=sn.dn_per_electron, black=sn.black_level,
              saturation=sn.saturation)
    out = []
    for expose in (sensor_noise.expose_numpy, sensor_noise.expose_compiled):
        rng = np.random.default_rng(seed)
        out.append((expose(rate, np.float32(scale), None, np.float32(dark_e), rng,
                           lambda s: rng.integers(0, 1 << 16, size=s, dtype=np.uint16), normal_table(),
                           POISSON_EXACT_BELOW, **kw).tobytes(), rng.random()))
    return out


@pytest.mark.parametrize("dark_e", [0.3, sensor_noise.ONE_MEAN_FROM, 1.28, 5.1, 20.5,
                                    float(np.nextafter(np.float32(POISSON_EXACT_BELOW), 0))])
def test_a_dark_frame_is_the_reference_bit_for_bit(dark_e):
    rate = np.random.default_rng(1).uniform(0.0, 5000.0, (40, 50, 3)).astype(np.float32)
    for seed in range(3):
        want, got = _frames(rate, 0.0, dark_e, seed)  # light off: every mean is the dark signal
        assert got == want, (dark_e, seed)


def test_one_mean_among_bright_values_and_runs_of_means_are_the_reference():
    """Poisson values of one mean next to bright values (the board's black squares at one exposure), and runs of
    different means: the same frames."""
    rate = np.full((30, 40, 3), 8000.0, dtype=np.float32)
    rate[5:20, 5:30] = 0.0  # dark patch: mean = dark signal
    mixed = np.repeat(np.array([0, 0, 2, 2, 2, 7, 0, 25], np.float32), 450).reshape(30, 40, 3)
    for seed in range(3):
        for r, scale in ((rate, 1.0), (mixed, 1.0), (mixed, 0.25)):
            want, got = _frames(r, scale, 3.5, seed)
            assert got == want, seed


@pytest.mark.parametrize("dark_e", [0.3, 1.28, 5.1, 20.5])
def test_a_dark_frame_with_a_dsnu_pattern_is_the_reference_bit_for_bit(dark_e):
    """Every value its own mean (the DSNU pattern times the dark signal): the searches side by side
    (sim.sensor_noise._pass2_lanes, means from LANES_FROM on) or one by one give the reference's frame."""
    from sim.camera import sensor_pattern

    sn = SensorModel()
    kw = dict(read_noise=sn.read_noise_e, full_well=sn.full_well, gain_k=sn.dn_per_electron, black=sn.black_level,
              saturation=sn.saturation)
    shape = (37, 41, 3)  # not a multiple of the lanes' block
    assert np.prod(shape) % sensor_noise.LANES
    pattern = sensor_pattern(0x5E750, shape, 0.3)
    rate = np.zeros(shape, dtype=np.float32)
    for seed in range(3):
        frames = []
        for expose in (sensor_noise.expose_numpy, sensor_noise.expose_compiled):
            rng = np.random.default_rng(seed)
            frames.append((expose(rate, np.float32(0.0), pattern, np.float32(dark_e), rng,
                                  lambda s: rng.integers(0, 1 << 16, size=s, dtype=np.uint16), normal_table(),
                                  POISSON_EXACT_BELOW, **kw).tobytes(), rng.random()))
        assert frames[0] == frames[1], (dark_e, seed)


def test_the_searches_side_by_side_find_the_one_by_one_searches_values():
    """sim.sensor_noise._pass2_lanes writes what _pass2 writes, value for value: means from 0 to just below the
    Poisson threshold mixed in each block (a block runs as long as its longest search), uniforms up to the largest
    below 1, a last block shorter than LANES."""
    pass1, pass2, pass2_one_mean, pass2_lanes = sensor_noise._compiled()
    rng = np.random.default_rng(7)
    n = 5 * sensor_noise.LANES + 17
    lam = rng.uniform(0.0, POISSON_EXACT_BELOW, n)
    lam[::7] = 0.0
    lam[1::11] = rng.uniform(0.0, 0.05, lam[1::11].size)
    p0 = np.exp(-lam)
    u = rng.random(n)
    u[::13] = np.nextafter(1.0, 0.0)
    idx = rng.integers(0, 1 << 16, n, dtype=np.uint16)
    pos = rng.permutation(n)
    sn = SensorModel(bit_depth=16)
    conv = (np.float32(sn.read_noise_e), np.float32(sn.full_well), np.float32(sn.dn_per_electron),
            np.float32(sn.black_level), np.float32(sn.saturation))
    want, got = np.zeros(n, np.uint16), np.zeros(n, np.uint16)
    pass2(pos, idx, normal_table(), lam, p0, u, sensor_noise.RECIPROCALS, *conv, want)
    pass2_lanes(pos, idx, normal_table(), lam, p0, u, sensor_noise.RECIPROCALS, *conv, got)
    assert got.tobytes() == want.tobytes()
    assert len(np.unique(want)) > 100  # the values vary: the comparison means something
