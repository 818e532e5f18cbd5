"""A rig file's unknown key is refused in one line naming it (a typo of a key that has a default, such as
``direction`` or ``model``, was silently ignored: the joint kept the default), and ``bus.protocol`` must be 2.0;
the rig text a session recorded stays loadable (``strict=False``), so an older session remains resumable."""

from __future__ import annotations

from importlib import resources

import pytest

from gonio.errors import ConfigError
from gonio.rig.kinematics import load_rig


def shipped(name="default"):
    return (resources.files("gonio.rig") / "rigs" / f"{name}.toml").read_text(encoding="utf-8")


@pytest.mark.parametrize("edit, message", [
    (lambda t: t.replace("direction = 1", "directon = -1", 1), "joints[0].directon = -1: unknown key (did you mean 'direction'?)"),
    (lambda t: t.replace('model = "XM540-W270"', 'modle = "XM540-W270"', 1), "joints[0].modle"),
    (lambda t: t.replace("min_arm_separation_deg", "min_arm_seperation_deg"), "geometry.min_arm_seperation_deg"),
    (lambda t: t.replace("baud = ", "buad = "), "bus.buad"),
    (lambda t: "lay_out = \"arms\"\n" + t, "lay_out"),
    (lambda t: t.replace("protocol = 2.0", "protocol = 1.0"), "bus.protocol = 1.0: must be 2.0"),
])
def test_an_unknown_key_or_protocol_is_one_line_naming_it(edit, message):
    with pytest.raises(ConfigError) as exc:
        load_rig(text=edit(shipped()), source="rig.toml")
    assert message in str(exc.value) and "\n" not in str(exc.value)


@pytest.mark.parametrize("name", ["default", "turntable"])
def test_the_shipped_rigs_load_and_a_recorded_rig_text_with_an_unknown_key_still_does(name):
    assert load_rig(name).name == name
    rig = load_rig(text=shipped(name).replace("direction = 1", "directon = -1", 1), source="manifest rig", strict=False)
    assert rig.joints[0].direction == 1
