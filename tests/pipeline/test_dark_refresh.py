"""DarkCache.refresh: the whole dark set in one light-off period, the same frames as one-by-one capture."""

from __future__ import annotations

import numpy as np

from gonio.pipeline.dark import DarkCache


class SwitchLog:
    """The bench's light, with every set_light call recorded."""

    def __init__(self, light):
        self.light, self.calls = light, []

    def set_light(self, on, level=1.0):
        self.calls.append(bool(on))
        self.light.set_light(on, level)


def test_refresh_switches_the_light_off_once_for_all_exposures(bench_factory, lambert):
    b = bench_factory(lambert)
    log = SwitchLog(b.light)
    cache = DarkCache(b.camera, b.calib, light=log, clock=b.clock, n_frames=2)
    exposures = (0.001, 0.004, 0.016, 0.064)
    cache.refresh(exposures)
    assert log.calls == [False, True] and cache.captures == 2 * len(exposures)
    one_by_one = DarkCache(b.camera, b.calib, light=log, clock=b.clock, n_frames=2)
    for t in exposures:
        d, e = cache.get(t), one_by_one.get(t)
        assert d.measured and d.n == 2
        # the same dark level (independent noise draws): means agree within a few standard deviations
        assert abs(float(d.mean.mean()) - float(e.mean.mean())) < 5 * float(np.sqrt(d.var.mean() + e.var.mean()))
    assert log.calls[2:] == [False, True] * len(exposures)  # get() alone switches per exposure
    assert b.light.output() > 0  # back on
