"""session_lab_time's schedule (refreshes found in windows of the remaining poses) equals a plain
pose-by-pose walk of the runner's rule: refresh before a pose that starts more than dark_max_age
after the last refresh started."""

import numpy as np
import pytest

from gonio.plan import CaptureSettings, SessionTiming, session_lab_time


@pytest.mark.parametrize("age", [0.0, 20.0, 900.0, 5000.0])  # a refresh every pose, ~7, ~300, ~1700 poses apart
def test_schedule_matches_pose_by_pose_walk(age):
    moves = np.random.default_rng(7).uniform(0.0, 5.0, 3000)
    cap = CaptureSettings()
    for startup in (True, False):
        acc = session_lab_time(moves, cap, SessionTiming(dark_max_age=age), startup=startup)
        cost = moves + cap.settle + acc.capture / moves.size
        per_refresh = acc.refresh_time / max(acc.refreshes, 1)
        t, t_dark, refreshes, ends = acc.startup, 0.0, 0, []
        for c in cost:
            if t - t_dark > age:
                t_dark, t, refreshes = t, t + per_refresh, refreshes + 1
            t += c
            ends.append(t)
        assert acc.refreshes == refreshes > (0 if age < 5000 else -1)
        np.testing.assert_allclose(acc.ends, ends, rtol=1e-12)
        assert acc.total == acc.ends[-1]
