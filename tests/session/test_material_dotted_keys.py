"""Material files: TOML dotted keys (nested tables) name lobe-sum parameters, like quoted keys do."""

from __future__ import annotations

import pytest

from gonio.errors import ConfigError
from gonio.session.material import load_material, material_from_dict

DOTTED = """model = "lambert+ggx"
[params]
diffuse.albedo = 0.3
lobe1.ks = 0.5
lobe1.alpha = 0.2
lobe1.f0 = 0.04
"""
QUOTED = """model = "lambert+ggx"
[params]
"diffuse.albedo" = 0.3
"lobe1.ks" = 0.5
"lobe1.alpha" = 0.2
"lobe1.f0" = 0.04
"""


def test_dotted_and_quoted_keys_give_the_same_material(tmp_path):
    a, b = tmp_path / "dotted.toml", tmp_path / "quoted.toml"
    a.write_text(DOTTED)
    b.write_text(QUOTED)
    ma, mb = load_material(a), load_material(b)
    assert dict(ma.params) == dict(mb.params) == {"diffuse.albedo": 0.3, "lobe1.ks": 0.5, "lobe1.alpha": 0.2,
                                                 "lobe1.f0": 0.04}
    assert ma.brdf().params == mb.brdf().params


def test_sub_tables_and_deeper_nesting_flatten_at_any_depth(tmp_path):
    p = tmp_path / "m.toml"
    p.write_text('model = "lambert+ggx"\n[params.diffuse]\nalbedo = [0.3, 0.2, 0.1]\n[params.lobe1]\n'
                 'ks = 0.5\nalpha = 0.2\nf0 = 0.04\n')
    assert load_material(p).params["diffuse.albedo"] == [0.3, 0.2, 0.1]
    with pytest.raises(ConfigError) as exc:
        material_from_dict({"model": "lambert+ggx", "params": {"lobe1": {"x": {"y": 1.0}}}}, source="deep.toml")
    msg = str(exc.value)
    assert "deep.toml" in msg and "lobe1.x.y" in msg and "\n" not in msg


def test_unknown_dotted_parameter_and_a_key_given_twice_are_one_line_errors(tmp_path):
    p = tmp_path / "m.toml"
    p.write_text(DOTTED.replace("lobe1.ks", "lobe3.ks"))
    with pytest.raises(ConfigError) as exc:
        load_material(p)
    msg = str(exc.value)
    assert str(p) in msg and "unknown parameter" in msg and "lobe3.ks" in msg and "\n" not in msg
    p.write_text(DOTTED + '"lobe1.ks" = 0.6\n')
    with pytest.raises(ConfigError) as exc:
        load_material(p)
    msg = str(exc.value)
    assert str(p) in msg and "params.lobe1.ks" in msg and "twice" in msg and "\n" not in msg
