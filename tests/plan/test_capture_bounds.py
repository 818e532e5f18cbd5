"""A settle (or readout) time beyond an hour, or more than MAX_FRAMES frames an exposure, is refused in one line before a session exists: ``gonio measure --sim
--settle 1e308`` was an OverflowError traceback in the lab-time estimate (after the session directory was made)
and, with --quiet, a session that never ended (found by QA, qa-hostile)."""

from __future__ import annotations

import pytest

from gonio.cli.main import main
from gonio.errors import DataError
from gonio.plan.plan import MAX_WAIT_S, CaptureSettings


@pytest.mark.parametrize("field", ["settle", "readout"])
def test_a_wait_beyond_an_hour_is_refused(field):
    CaptureSettings(**{field: MAX_WAIT_S})
    with pytest.raises(DataError, match=f"capture.{field} = 1e\\+308: must be seconds in"):
        CaptureSettings(**{field: 1e308})


def test_settle_1e308_is_one_line_and_makes_no_session(tmp_path, capsys):
    out = tmp_path / "s"
    code = main(["measure", "--sim", "--settle", "1e308", "--out", str(out)])
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert code == 2 and len(err) == 1 and "capture.settle" in err[0], err
    assert not out.exists()


def test_frames_beyond_the_bound_are_refused_in_one_line_before_a_session(tmp_path, capsys):
    from gonio.plan.plan import MAX_FRAMES

    CaptureSettings(frames=MAX_FRAMES)
    with pytest.raises(DataError, match="capture.frames = 1001: must be an integer in"):
        CaptureSettings(frames=MAX_FRAMES + 1)
    out = tmp_path / "s"
    code = main(["measure", "--sim", "--frames", "100000000", "--out", str(out)])
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert code == 2 and len(err) == 1 and "frames" in err[0], err
    assert not out.exists()
