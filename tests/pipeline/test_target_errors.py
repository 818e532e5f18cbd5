"""TARGET.toml errors name the file, the field as written in the file, and the value, in one line."""

from __future__ import annotations

import pytest

from gonio.errors import ConfigError
from gonio.pipeline.target import TargetLayout, load_target


@pytest.mark.parametrize("text, expect", [
    ("sample = [0.02, -0.025, -0.02, 0.025]\n", "sample.x1 = -0.02: must exceed sample.x0 = 0.02"),
    ("sample = [-0.02, 0.03, 0.02, 0.025]\n", "sample.y1 = 0.025: must exceed sample.y0 = 0.03"),
    ('sample = [-0.02, "a", 0.02, 0.025]\n', "sample.y0 = 'a': needs a finite number"),
    ("white = [-0.1, -0.02, -0.06]\n", "white = [-0.1, -0.02, -0.06]: needs [x0, y0, x1, y1]"),
    ("sample = [-0.5, -0.025, 0.025, 0.025]\n", "sample = "),  # off the board
    ("[charuco]\nsquares = [2, 7]\n", "charuco.squares = (2, 7): needs at least 3"),
    ("[charuco]\nsquares = 9\n", "charuco.squares = 9: needs [columns, rows]"),
    ("[charuco]\nmarker_length = 0.05\n", "charuco.marker_length = 0.05"),
    ("[charuco]\nsquare_lenght = 0.03\n", "charuco.square_lenght = 0.03: unknown key"),
    ("white_albedo = 1.5\n", "white_albedo = 1.5: needs 3 values"),
    ("white_albedo = [0.9, 0.9]\n", "white_albedo = [0.9, 0.9]: needs 3 values"),
    ("[mount]\nheight = 0.5\n", "mount.height = 0.5"),
])
def test_each_error_names_the_file_the_real_field_and_the_value(tmp_path, text, expect):
    p = tmp_path / "TARGET.toml"
    p.write_text(text)
    with pytest.raises(ConfigError) as exc:
        load_target(p)
    msg = str(exc.value)
    assert msg.startswith(f"{p}: ") and expect in msg and "\n" not in msg, msg
    assert "target." not in msg.replace(str(p), "")


def test_a_grey_white_albedo_and_a_full_table_round_trip(tmp_path):
    p = tmp_path / "TARGET.toml"
    p.write_text("white_albedo = 0.95\nsample = [-0.02, -0.02, 0.02, 0.02]\n[charuco]\nsquares = [9, 7]\n")
    t = load_target(p)
    assert t.white_albedo == (0.95, 0.95, 0.95) and t.sample.x1 == 0.02
    assert TargetLayout.from_dict(t.to_dict(), source="manifest") == t
