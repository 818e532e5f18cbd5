"""An exposure out of the simulated camera's range — typed in milliseconds, ``--exposures 4,16,64`` — is refused in
one line before the session directory is made; it was accepted, the session created, and its first pose failed on
every resume (``camera.exposure = 4.0: must be in [1e-05, 2] s``; found by QA, qa-user)."""

from __future__ import annotations

from gonio.cli.main import main


def test_exposures_in_milliseconds_are_refused_before_a_session_exists(tmp_path, capsys):
    out = tmp_path / "s"
    code = main(["measure", "--sim", "--quiet", "--exposures", "4,16,64", "--out", str(out)])
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert code == 2 and len(err) == 1, err
    assert "capture.exposures = 4.0" in err[0] and "seconds" in err[0], err
    assert not out.exists()


def test_exposures_in_range_measure(tmp_path, capsys):
    out = tmp_path / "s"
    argv = ["measure", "--sim", "--quiet", "--plan", "in_plane", "--theta-i-step", "30", "--theta-o-step", "30",
            "--theta-max", "60", "--sim-resolution", "320x240", "--exposures", "0.004,0.016", "--out", str(out)]
    assert main(argv) == 0
    assert (out / "samples.jsonl").stat().st_size > 0
