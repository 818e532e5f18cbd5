"""A simulated rig + session runner, in-process (the same path `gonio measure --sim` takes)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gonio.plan.plan import CaptureSettings, Plan
from gonio.session.runner import SessionRunner
from gonio.session.store import SessionStore, scan_samples
from sim.rig import SimRig, SimRigConfig

#: ``gonio measure --sim`` options of a small session (in-plane, 30° steps, 320×240 camera: a few seconds; at
#: 160×120 the board is never found, every sample NO_BOARD: a session that ends `unusable`)
SMALL = ["--quiet", "--plan", "in_plane", "--theta-i-step", "30", "--theta-o-step", "30", "--theta-max", "60",
         "--sim-resolution", "320x240"]


@pytest.fixture(scope="session")
def measured(tmp_path_factory):
    """A small completed ``gonio measure --sim`` session, made once per test run (for all xdist workers): tests copy
    it before they change it."""
    from tests.conftest import measured_once

    return measured_once(tmp_path_factory, "session-measured", ["measure", "--sim", *SMALL])


def measured_shared(tmp_path_factory, argv: list[str]):
    """``gonio ARGV --out DIR`` measured once per test run for every test module that asks for the same ``argv``
    (tests/conftest.py ``measured_once``, named by a digest of ``argv``): ``DIR``, read-only."""
    import hashlib

    from tests.conftest import measured_once

    return measured_once(tmp_path_factory, "sim-" + hashlib.sha1("\0".join(argv).encode()).hexdigest()[:12], argv)


#: A small in-plane plan (degrees: θi, φi, θo, φo), all reachable on the default rig.
POSES_DEG = [(30, 0, 30, 180), (45, 0, 20, 180), (20, 0, 50, 180), (60, 0, 40, 180), (10, 0, 30, 0),
             (40, 0, 60, 180), (0, 0, 45, 180), (50, 0, 10, 180)]


def small_plan(poses_deg=POSES_DEG) -> Plan:
    return Plan(poses=np.radians(np.asarray(poses_deg, dtype=float)), capture=CaptureSettings(), generator="custom")


class Session:
    """SimRig + devices + store + runner; ``hooks`` maps pose index -> callable run before that pose."""

    def __init__(self, directory, plan=None, *, seed=0, servo_faults=None, controller_faults=None, hooks=None,
                 store=None):
        self.plan = plan or small_plan()
        self.sim = SimRig(config=SimRigConfig(seed=seed, width=240, height=180, focal_px=285.0),
                          servo_faults=servo_faults, controller_faults=controller_faults).start()
        self.devices = None
        try:
            self.devices = self.sim.open_devices()
        except BaseException:
            self.sim.stop()
            raise
        self.store = store or SessionStore.create(directory, {"plan": self.plan, "mode": "test"})
        self.hooks = dict(hooks or {})
        self.runner = SessionRunner(self.plan, self.store, self.devices, self.sim.calibration, self.sim.layout,
                                    before_pose=self._before, resume_command=f"gonio resume {directory}", stream=None)

    def _before(self, index):
        self.sim.begin_pose(index)
        hook = self.hooks.pop(index, None)
        if hook is not None:
            hook(self)

    def run(self):
        try:
            return self.runner.run()
        finally:
            self.close()

    def close(self):
        if self.devices is not None:
            self.devices.close()
            self.devices = None
        self.sim.stop()


@pytest.fixture
def session_factory():
    made = []

    def factory(*a, **kw):
        s = Session(*a, **kw)
        made.append(s)
        return s

    yield factory
    for s in made:
        s.close()


def assert_one_record_per_pose(directory, n_poses):
    scan = scan_samples(directory / "samples.jsonl")
    assert scan.torn is None
    assert scan.n_duplicates == 0, "a pose was stored twice"
    assert sorted(scan.records) == list(range(n_poses)), "a pose is missing"
    return scan


def joint_tolerance_rad(deg=0.5):
    return math.radians(deg)
