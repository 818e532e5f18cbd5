"""The highlight detector's grey image (gonio.pipeline.highlight._gray): the channels' mean as np.mean(axis=2)
computes it, bit for bit, for raw integer frames and for the float mean of several frames, 3 or 4 channels."""

from __future__ import annotations

import numpy as np
import pytest

from gonio.pipeline.highlight import _gray


@pytest.mark.parametrize("channels", [1, 3, 4])
def test_the_grey_image_is_numpys_channel_mean(channels):
    rng = np.random.default_rng(channels)
    raw = rng.integers(0, 4096, (48, 64, channels)).astype(np.uint16)
    frames = np.mean([rng.integers(0, 4096, (48, 64, channels)) for _ in range(3)], axis=0) / 7.0  # not integers
    for px in (raw, frames):
        want = np.asarray(px, dtype=np.float64).mean(axis=2) - 64.0
        np.testing.assert_array_equal(_gray(px, 64.0), want)
    np.testing.assert_array_equal(_gray(raw[..., 0], 64.0), raw[..., 0] - 64.0)  # a grey frame as it is
