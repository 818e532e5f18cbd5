"""A plan's size is checked before its poses are built: a step given in radians where degrees are
expected (0.17 for 10°) must be one line, not a plan of tens of millions of poses that exhausts memory."""

import math
import resource

import pytest

from gonio.errors import ConfigError
from gonio.plan import GENERATORS, make_plan
from gonio.plan.generators import MAX_PLAN_CANDIDATES, candidate_count

RAD = math.radians


@pytest.fixture
def memory_cap():
    """Cap this process's address space so a regression fails with MemoryError instead of taking the
    machine down (the unguarded grid below needs > 10 GB)."""
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    cap = 4 << 30 if hard == resource.RLIM_INFINITY else min(4 << 30, hard)
    resource.setrlimit(resource.RLIMIT_AS, (cap if soft == resource.RLIM_INFINITY else min(cap, soft), hard))
    yield
    resource.setrlimit(resource.RLIMIT_AS, (soft, hard))


@pytest.mark.parametrize("name, params", [
    # radians typed where the CLI expects degrees (0.17 rad ≈ 10°, 0.52 rad ≈ 30°)
    ("grid", dict(theta_step=RAD(0.17), phi_step=RAD(0.52), theta_max=RAD(1.22))),
    ("grid", dict(theta_step=RAD(1), phi_step=RAD(5))),
    ("isotropic", dict(theta_step=RAD(0.17), phi_step=RAD(0.26))),
    ("half_diff", dict(n_theta_h=90, theta_d_step=RAD(0.1), phi_d_step=RAD(0.1))),
])
def test_oversized_plan_is_one_line_naming_the_plan(name, params, memory_cap):
    with pytest.raises(ConfigError) as exc:
        make_plan(name, order="raster", **params)
    msg = str(exc.value)
    assert "\n" not in msg and name in msg and "poses" in msg and "degrees" in msg


@pytest.mark.parametrize("name", sorted(GENERATORS))
def test_candidate_count_is_what_the_generator_makes(name):
    for params in ({}, {k: s.default * 0.5 if s.kind == "angle" else 3 for k, s in GENERATORS[name].params.items()
                        if k != "theta_max"}):
        values = {k: params.get(k, s.default) for k, s in GENERATORS[name].params.items()}
        assert candidate_count(name, values) == len(GENERATORS[name].fn(**values))


def test_plans_of_the_docs_and_benchmarks_stay_allowed():
    # the densest grid of benchmarks/bench_plan.py (5°/20°) and the dense 10°/30° grid
    for ts, ps in ((5, 20), (10, 30)):
        values = dict(theta_step=RAD(ts), phi_step=RAD(ps), theta_max=GENERATORS["grid"].params["theta_max"].default)
        assert candidate_count("grid", values) <= MAX_PLAN_CANDIDATES
