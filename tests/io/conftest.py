"""Shared fixtures of the I/O tests."""

from __future__ import annotations

import pytest

from gonio.cli.main import main


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """A small simulated in-plane session (θi = 30°, θo every 20°), one per test module: the module's
    tests may damage or extend it."""
    d = tmp_path_factory.mktemp("sessions") / "s"
    assert main(["measure", "--sim", "--plan", "in_plane", "--theta-i", "30", "--theta-o-step", "20", "--quiet",
                 "--out", str(d)]) == 0
    return d
