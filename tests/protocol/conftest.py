"""Shared fixtures of the protocol tests: the test vectors."""

import json

import pytest

from firmware_protocol import VECTORS_PATH


@pytest.fixture(scope="session")
def vectors():
    return json.loads(VECTORS_PATH.read_text())


@pytest.fixture(params=["python", "firmware"])
def Emulator(request):
    """The controller emulator class: the Python one (sim.controller) or the compiled reference
    firmware's host build (sim.firmware); the same tests run against both over a real pty."""
    if request.param == "python":
        from sim.controller import ControllerEmulator
        return ControllerEmulator
    from sim.firmware import FirmwareController
    return FirmwareController
