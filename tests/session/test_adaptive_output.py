"""What `gonio measure --plan adaptive` prints: darks only when measured, the session's lab time on the
progress line across rounds, and the fitted model as a table (5 significant digits, a tied f0 once)."""

from __future__ import annotations

import re

from gonio.cli.main import main
from gonio.session.adaptive import model_table

ARGS = ["measure", "--sim", "--seed", "5", "--sim-resolution", "240x180", "--plan", "adaptive",
        "--theta-step", "15", "--phi-step", "45", "--theta-max", "60", "--coarse", "6", "--batch", "4",
        "--max-rounds", "3", "--target-error", "0"]


def _seconds(text: str) -> int:
    parts = [int(x) for x in text.split(":")]
    return sum(p * 60 ** i for i, p in enumerate(reversed(parts)))


def test_adaptive_output_is_honest_and_formatted(tmp_path, capsys):
    assert main([*ARGS, "--out", str(tmp_path / "D")]) == 0
    out, err = capsys.readouterr()
    assert err.count("adaptive round") >= 4  # 3 rounds measured (and assessed)
    assert err.count("darks measured") == 1, err  # later rounds reuse the fresh darks: no "after 0:00 lab"
    labs = [_seconds(m) for m in re.findall(r"\] +\d+%  lab (\d+:\d{2}(?::\d{2})?)", err)]
    assert len(labs) >= 10 and labs == sorted(labs), labs  # the session's clock, not restarting each round
    assert labs[0] >= 6  # the start-up dark set (6.9 s of lab time) is part of the session's lab time
    lines = out.splitlines()
    start = lines.index("fitted on every sample: model microfacet")
    table = dict(re.match(r"  (\S+) +(.*)$", ln).groups() for ln in lines[start + 1:start + 6])
    assert set(table) == {"kd", "ks", "alpha", "f0", "distribution"}
    for k in ("kd", "ks", "alpha", "f0"):
        for v in table[k].split(", "):
            assert len(re.sub(r"[^0-9]", "", v).lstrip("0")) <= 5, (k, v)  # 5 significant digits
    assert "," not in table["f0"] and "[" not in out  # a tied f0 once, no Python lists


def test_model_table_keeps_distinct_channels_and_names_non_numbers():
    class M:
        name = "lambert+ggx"
        params = {"diffuse.albedo": [0.123456789, 0.2, 0.3], "lobe1.alpha": 0.1, "lobe1.f0": [0.04] * 3}

    assert model_table(M()) == ["fitted on every sample: model lambert+ggx",
                                "  diffuse.albedo     0.12346, 0.2, 0.3",
                                "  lobe1.alpha        0.1",
                                "  lobe1.f0           0.04"]
