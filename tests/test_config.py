"""Every TOML loader turns an unreadable, non-text or invalid file into a one-line ConfigError naming it."""

from __future__ import annotations

import pytest

from gonio.errors import ConfigError
from gonio.pipeline.target import load_target
from gonio.rig.calibration import load_camera_calibration
from gonio.rig.kinematics import load_rig
from gonio.session.material import load_material

LOADERS = [load_rig, load_material, load_target, load_camera_calibration]


@pytest.mark.parametrize("load", LOADERS, ids=lambda f: f.__name__)
@pytest.mark.parametrize("content, why", [(b"\xff\xfe\x00binary\x80", "not a text (TOML) file"),
                                          (b"a = [1,", "not valid TOML"), (None, "cannot read")])
def test_bad_files_are_one_line_errors_naming_the_file(tmp_path, load, content, why):
    p = tmp_path / "x.toml"
    if content is not None:
        p.write_bytes(content)
    with pytest.raises(ConfigError) as err:
        load(p)
    msg = str(err.value)
    assert str(p) in msg and why in msg and "\n" not in msg
