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
