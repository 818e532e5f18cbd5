"""``gonio measure --sim --rig RIG.toml`` with a servo model gonio has no control table for is one line naming the
rig file and the joint, and makes no session directory (it made one, left marked running and empty, whose status
read 'still running, or killed: resume') — found by QA (qa-hostile)."""

from __future__ import annotations

from importlib import resources

from gonio.cli.main import main


def test_an_unknown_servo_model_is_one_line_before_any_session(tmp_path, capsys):
    text = (resources.files("gonio.rig") / "rigs" / "default.toml").read_text(encoding="utf-8")
    rig = tmp_path / "rig.toml"
    rig.write_text(text.replace('model = "XM430-W350"', 'model = "XM999"', 1))
    out = tmp_path / "s"
    code = main(["measure", "--sim", "--quiet", "--rig", str(rig), "--out", str(out)])
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert code == 2 and len(err) == 1 and str(rig) in err[0] and "light_el" in err[0] and "XM999" in err[0], err
    assert not out.exists()
