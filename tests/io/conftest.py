"""Shared fixtures of the I/O tests."""

from __future__ import annotations

import pytest


@pytest.fixture(scope="module")
def session(tmp_path_factory, copy_small_session):
    """A small simulated in-plane session (θi = 30°, θo every 20°), one copy per test module of the one
    measured per run (tests/conftest.py): the module's tests may damage or extend it."""
    return copy_small_session(tmp_path_factory.mktemp("sessions") / "s")
