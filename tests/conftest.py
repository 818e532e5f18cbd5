"""Shared test configuration.

Tests that need real hardware are opt-in: ``pytest --port /dev/ttyUSB0`` (servo bus) and
``--controller-port`` (rig controller); without them those tests are deselected, not skipped green.
"""

from __future__ import annotations

import os

import pytest
from hypothesis import HealthCheck, settings

settings.register_profile(
    "ci", max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow], derandomize=True
)
settings.register_profile("dev", max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.load_profile("ci" if os.environ.get("CI") else os.environ.get("HYPOTHESIS_PROFILE", "dev"))


def pytest_addoption(parser):
    parser.addoption("--port", default=None, help="serial port of a real Dynamixel bus (enables hardware tests)")
    parser.addoption("--controller-port", default=None, help="serial port of a real rig controller")


def pytest_collection_modifyitems(config, items):
    if config.getoption("--port") or config.getoption("--controller-port"):
        return
    selected, deselected = [], []
    for item in items:
        (deselected if "hardware" in item.keywords else selected).append(item)
    if deselected:
        config.hook.pytest_deselected(items=deselected)
        items[:] = selected
