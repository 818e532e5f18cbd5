"""The suite's scheduling lists in tests/conftest.py name modules that exist: a module renamed or removed would
silently lose its lane, its group or its early start (the suite would still pass, only slower)."""

from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def test_every_module_the_scheduling_names_exists(suite_conftest):
    named = [*suite_conftest.SLOW_FIRST, *suite_conftest.SHARED_FIXTURE_MODULES, *suite_conftest.SAME_WORKER,
             *suite_conftest.SAME_WORKER.values(), *suite_conftest.LANE_OF]
    missing = sorted({m for m in named if not (ROOT / m).is_file()})
    assert not missing, f"tests/conftest.py names modules that do not exist: {missing}"


def test_a_module_is_in_one_lane_at_most_and_not_also_first_among_the_rest(suite_conftest):
    lanes = [m for lane in suite_conftest.WAITING_LANES for m in lane]
    assert len(lanes) == len(set(lanes)), "a module is in two lanes"
    assert not set(lanes) & set(suite_conftest.SLOW_FIRST), "a lane's module is in SLOW_FIRST (lanes start first)"
    # a module that joins another's group (SAME_WORKER) runs in that group's lane, so it is not listed itself
    assert not set(lanes) & set(suite_conftest.SAME_WORKER)
