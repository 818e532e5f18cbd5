"""Shared fixtures of the protocol tests: the test vectors."""

import json

import pytest

from firmware_protocol import VECTORS_PATH


@pytest.fixture(scope="session")
def vectors():
    return json.loads(VECTORS_PATH.read_text())
