"""tests/debian.py: a test that needs a missing Debian package skips naming it (and the apt-get line);
under .ci/run (GONIO_REQUIRE_DEBIAN set) the same is a failure, so CI cannot skip itself green."""

import pytest

from tests import debian


def test_a_missing_package_is_named_in_the_skip_and_fails_under_ci(monkeypatch):
    monkeypatch.setitem(debian.PACKAGES, "gonio-test-absent", lambda: None)
    monkeypatch.delenv("GONIO_REQUIRE_DEBIAN", raising=False)
    with pytest.raises(pytest.skip.Exception, match=r"the widget needs Debian package gonio-test-absent "
                                                    r"\(apt-get install gonio-test-absent\) and pip install "
                                                    r"'gonio\[nothing\]'"):
        debian.require("the widget", "gonio-test-absent", python=("gonio_no_such_module", "gonio[nothing]"))
    monkeypatch.setenv("GONIO_REQUIRE_DEBIAN", "1")
    with pytest.raises(pytest.fail.Exception, match="gonio-test-absent.*GONIO_REQUIRE_DEBIAN is set"):
        debian.require("the widget", "gonio-test-absent")


def test_present_packages_do_not_skip(monkeypatch):
    monkeypatch.setitem(debian.PACKAGES, "gonio-test-present", lambda: "/usr/bin/true")
    assert debian.require("the widget", "gonio-test-present", python=("json", "x")) is None
    assert debian.missing("make", "gonio-test-present") == []  # make is how the suite builds the firmware
