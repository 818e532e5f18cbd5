"""Where every random number of the simulator comes from: one generator per (session seed, pose, stream).

A simulated session is reproducible *per pose*: the noise a pose sees (camera shot and read noise,
servo encoder noise, photodiode noise, link faults) depends only on the session's seed, the pose and
the noise source, never on what was simulated before it. So a session killed with SIGKILL and resumed
measures, pose by pose, bit for bit what an uninterrupted session with the same seed measures — which
is how the tests check that "nothing is lost" exactly instead of within a few σ.

:func:`pose_rng` is the one place that derives those generators (NumPy ``SeedSequence`` spawning keys,
so streams are statistically independent: NumPy, "Parallel random number generation"). Add a stream
name to :data:`STREAMS` for a new noise source; do not build ``default_rng(seed + k)`` by hand.
"""

from __future__ import annotations

import zlib

import numpy as np

__all__ = ["pose_rng", "STREAMS", "SETUP"]

#: Noise sources of the simulator, each its own stream (a name's position is never reused).
STREAMS = ("camera", "photodiode", "encoder", "servo_faults", "controller_faults", "dark", "frame_faults")
# (index 0, the camera, takes no stream word; every other index is >= 1, so no key is a prefix + zeros of another)
#: Pseudo pose index of what happens outside any pose (start-up, dark sets): ``pose_rng(seed, SETUP, ...)``.
SETUP = -1


def _key(value) -> int:
    if isinstance(value, str):
        if value not in STREAMS:
            raise ValueError(f"unknown noise stream {value!r}; known: {', '.join(STREAMS)}")
        return STREAMS.index(value)
    v = int(value)
    return v if v >= 0 else (1 << 64) + v  # SeedSequence takes non-negative integers only


def pose_rng(seed: int, pose_index: int, stream: str, *extra) -> np.random.Generator:
    """A fresh generator for noise source ``stream`` at plan pose ``pose_index`` of a session seeded
    ``seed`` (``extra`` integers split a stream further, e.g. per servo ID or per exposure).

    ``SeedSequence([seed, pose])`` for the camera, ``SeedSequence([seed, pose, k, *extra])`` for the k-th
    other stream (k ≥ 1: the camera's and the photodiode's streams are the ones ``SimRig.begin_pose`` used
    before this module existed, so earlier sessions' noise is unchanged): the same arguments always give
    the same numbers; different arguments give independent streams (O'Neill's PCG64 seeded through
    SeedSequence's entropy hashing, numpy.random documentation, "Seeding and entropy")."""
    k = _key(stream)
    words = [_key(seed), _key(pose_index)] + ([k, *(_key(e) for e in extra)] if k or extra else [])
    return np.random.default_rng(np.random.SeedSequence(words))


def position_key(ticks: float) -> int:
    """An integer key of a servo position (ticks, 1/1024 tick resolution) for :func:`pose_rng`'s ``extra``."""
    return zlib.crc32(np.float64(round(float(ticks) * 1024.0) / 1024.0).tobytes())
