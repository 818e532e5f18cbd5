"""A malformed ``--scheduler`` address (no port) is one line naming it, not Dask's traceback."""

from __future__ import annotations

import pytest

from gonio.cli.main import main


@pytest.mark.parametrize("address", ["localhost", "tcp://localhost"])
def test_scheduler_without_port_is_one_line(tmp_path, address, capsys):
    pytest.importorskip("distributed", reason="Dask is the optional 'dask' extra")
    (tmp_path / "a.binary").write_bytes(b"")  # never read: the address is refused first
    rc = main(["fit", str(tmp_path / "a.binary"), "--model", "lambert", "--scheduler", address,
               "--summary", str(tmp_path / "s.csv")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "--scheduler" in err[0] and address in err[0]
    assert "Traceback" not in err[0]
