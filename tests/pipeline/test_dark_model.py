"""Modelled dark frames (gonio.pipeline.dark.DarkModel): one dark set, fitted per pixel, predicts the dark
frame of another exposure after the sensor has warmed up, once a check frame has measured the drift."""

from __future__ import annotations

import numpy as np
import pytest

from gonio.pipeline.dark import DarkCache
from sim.camera import SensorModel

#: a warm, leaky sensor whose dark current doubles every 8 K (not the model's 6.5 K prior) and heats by 10 K
SENSOR = dict(dark_current_e=300.0, dark_doubling_c=8.0, dsnu=0.3, heating_c=10.0, thermal_tau=300.0)
SET = (0.01, 0.1, 0.4, 1.0)


def _measured(bench, exposure, n=8):
    """A freshly measured dark frame (the truth the model must predict) and the sensor temperature it saw."""
    ref = DarkCache(bench.camera, bench.calib, light=bench.light, clock=bench.clock, n_frames=n)
    return ref.get(exposure), ref.temperature


@pytest.mark.parametrize("reports_temperature", [True, False])
def test_model_predicts_the_dark_frame_after_the_sensor_warmed(bench_factory, lambert, reports_temperature):
    b = bench_factory(lambert, sensor=SensorModel(**SENSOR, reports_temperature=reports_temperature))
    cache = DarkCache(b.camera, b.calib, light=b.light, clock=b.clock, n_frames=4)
    cache.refresh(SET)
    model = cache.fit_model()
    assert (model.temperature is not None) == reports_temperature
    b.clock.sleep(400.0)
    cache.check(1.0)  # one light-off frame measures how far the dark current moved
    b.clock.sleep(800.0 if reports_temperature else 0.0)  # without a temperature: predicted at the check's k
    truth, temp = _measured(b, 0.5)
    cache.temperature = temp
    pred = cache.get(0.5)
    assert pred.modelled and cache.captures == 4 * len(SET) + 1  # predicted, not captured
    diff = pred.mean.astype(np.float64) - truth.mean
    sd = np.sqrt(pred.var.astype(np.float64) + truth.var)
    # the drift is large: the start set's prediction (k = 1) is off by many standard deviations
    stale = model.offset + 0.5 * model.rate - truth.mean
    assert abs(float(stale.mean())) > 20 * float(sd.mean()) / np.sqrt(stale.size) and abs(float(stale.mean())) > 10
    # the model's prediction: its mean error is a small part of the drift it corrects (without a temperature,
    # the few seconds between the check and the reference frames add ~0.5 %), its per-pixel errors as its
    # variance says
    assert abs(float(diff.mean())) < 0.02 * abs(float(stale.mean())), (float(diff.mean()), float(stale.mean()))
    z = diff / sd
    assert 0.7 < float(z.std()) < 1.3, float(z.std())
    # the fixed pattern (DSNU) is predicted pixel by pixel
    assert np.corrcoef(pred.mean.ravel(), truth.mean.ravel())[0, 1] > 0.95
    if reports_temperature:
        assert model.doubling_fitted and 6.0 < model.doubling_c < 10.0  # 8 K measured, not the 6.5 K prior


def test_pipeline_notes_the_sensor_temperature(bench_factory, lambert):
    b = bench_factory(lambert, sensor=SensorModel(**SENSOR))
    b.pipeline.darks.refresh(SET)
    b.pipeline.darks.fit_model()
    b.clock.sleep(600.0)
    b.measure(30, 20, 20, 200)
    assert b.pipeline.darks.temperature == pytest.approx(b.camera.sensor_temperature(), abs=0.1)
    assert b.pipeline.darks.temperature > SensorModel().ambient_c + 5
