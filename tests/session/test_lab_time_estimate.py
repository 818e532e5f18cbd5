"""The printed lab-time estimate tells the truth: a simulated session's lab time lies between the lower
bound and the estimate × (1 + TOL) (gonio.plan.labtime is the runner's own cost model)."""

import math

import pytest

from gonio.plan import estimate_plan, make_plan
from gonio.session.runner import SessionRunner, open_devices
from gonio.session.store import SessionStore

TOL = 0.10


def _run(plan, out):
    from sim.rig import SimRig, SimRigConfig

    with SimRig(config=SimRigConfig(width=240, height=180, focal_px=285.0)) as sim:
        dev = open_devices(sim.rig, sim.servo_port, sim.controller_port, sim.camera, sim.clock)
        try:
            store = SessionStore.create(out, {"plan": plan, "mode": "test"})
            return SessionRunner(plan, store, dev, sim.calibration, sim.layout, before_pose=sim.begin_pose,
                                 stream=None).run()
        finally:
            dev.close()


@pytest.mark.parametrize("name,params", [
    ("in_plane", {}),  # gonio measure's default plan
    ("grid", {"theta_step": math.radians(30), "phi_step": math.radians(120), "theta_max": math.radians(60)}),
])
def test_session_lab_time_between_lower_bound_and_estimate(tmp_path, name, params):
    plan = make_plan(name, seed=0, **params)
    est = estimate_plan(plan)
    result = _run(plan, tmp_path / "s")
    assert result.ok and result.measured == len(plan)
    assert est.lower_bound <= result.lab_time <= est.optimized * (1 + TOL), (est.to_dict(), result.lab_time)
    # the runner's recorded estimate is the same model
    assert result.estimated_lab_time == pytest.approx(est.optimized, rel=0.05)
