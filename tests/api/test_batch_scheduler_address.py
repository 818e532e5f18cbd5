"""A malformed ``--scheduler`` address (no port) is one line naming it, not Dask's traceback."""

from __future__ import annotations

import pytest

from gonio.cli.main import main


BAD = ["localhost", "tcp://localhost", "tcp://localhost:", "tcp://:8786", "tcp://localhost:abc",
       "tcp://localhost:70000", "tcp://localhost:0", "http://localhost:8786", "tcp://h:1/path", "", "tcp://a b:1",
       "inproc://", "inproc://host"]


@pytest.mark.parametrize("address", BAD)
def test_scheduler_without_port_is_one_line(tmp_path, address, capsys):
    """Refused by gonio's own check, before Dask is imported or starts its event loop (Dask's own refusal of
    "tcp://localhost" came from its loop thread: under load an assertion there, not its ValueError)."""
    (tmp_path / "a.binary").write_bytes(b"")  # never read: the address is refused first
    rc = main(["fit", str(tmp_path / "a.binary"), "--model", "lambert", "--scheduler", address,
               "--summary", str(tmp_path / "s.csv")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "--scheduler" in err[0] and address in err[0]
    assert "Traceback" not in err[0]


@pytest.mark.parametrize("address", ["localhost:8786", "tcp://127.0.0.1:8786", "tls://sched.lab:1", "tcp://[::1]:8786",
                                     "inproc://192.0.2.2/25965/1"])
def test_well_formed_addresses_pass_the_check(address):
    from gonio.batch import scheduler_address

    assert scheduler_address(address) == address


def test_the_check_needs_no_dask():
    import subprocess
    import sys

    code = ("import sys; from gonio.batch import scheduler_address\n"
            "try:\n    scheduler_address('tcp://localhost')\nexcept Exception as e: print(type(e).__name__)\n"
            "print('distributed' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert out == ["ConfigError", "False"]
