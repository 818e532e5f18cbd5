"""An output path that names a device or a FIFO is refused in one line, even with --force: outputs are written
to a temporary file renamed into place, so ``--force`` replaced the device node itself by a regular file (as
root, ``gonio export S --format merl -o /dev/full --force`` left a 35 MB file at /dev/full, and /dev/null would
go the same way) — found by QA (qa-hostile). Here a FIFO stands for the device."""

from __future__ import annotations

import os
import stat

import pytest

from gonio.cli.main import main


@pytest.mark.parametrize("argv", [
    ["export", "{s}", "--format", "merl", "-o", "{o}.binary", "--force"],
    ["export", "{s}", "--format", "csv", "-o", "{o}.csv", "--force"],
    ["fit", "{s}", "--model", "lambert", "--json", "{o}.json", "--force"],
    ["tabulate", "{s}", "-o", "{o}.binary", "--force"],
    ["plan", "in_plane", "--out", "{o}.json", "--force"],
])
def test_a_fifo_output_is_refused_and_kept(session, tmp_path, capsys, argv):
    argv = [a.format(s=session, o=tmp_path / "out") for a in argv]
    target = next(a for a in argv if a.startswith(str(tmp_path / "out")))
    os.mkfifo(target)
    code = main(argv)
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert code == 2 and len(err) == 1 and "not a regular file" in err[0], err
    assert stat.S_ISFIFO(os.lstat(target).st_mode)
    assert not os.path.exists(target + ".json") or target.endswith(".json")  # no sidecar written beside it
