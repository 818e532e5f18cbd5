"""The suite's scheduling lists in tests/conftest.py name modules that exist: a module renamed or removed would
silently lose its lane, its group or its early start (the suite would still pass, only slower)."""

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture
def conftest(pytestconfig):
    """tests/conftest.py as pytest loaded it (not imported again: several directories have a conftest.py)."""
    mine = ROOT / "tests" / "conftest.py"
    return next(p for p in pytestconfig.pluginmanager.get_plugins() if getattr(p, "__file__", None) == str(mine))


def test_every_module_the_scheduling_names_exists(conftest):
    named = [*conftest.SLOW_FIRST, *conftest.SHARED_FIXTURE_MODULES, *conftest.SAME_WORKER,
             *conftest.SAME_WORKER.values(), *conftest.LANE_OF]
    missing = sorted({m for m in named if not (ROOT / m).is_file()})
    assert not missing, f"tests/conftest.py names modules that do not exist: {missing}"


def test_a_module_is_in_one_lane_at_most_and_not_also_first_among_the_rest(conftest):
    lanes = [m for lane in conftest.WAITING_LANES for m in lane]
    assert len(lanes) == len(set(lanes)), "a module is in two lanes"
    assert not set(lanes) & set(conftest.SLOW_FIRST), "a lane's module is also in SLOW_FIRST (lanes start first anyway)"
    # a module that joins another's group (SAME_WORKER) runs in that group's lane, so it is not listed itself
    assert not set(lanes) & set(conftest.SAME_WORKER)
