"""Hostile entries beside a session's files, and a disk that fills up: a planted FIFO, directory or symbolic link
at ``quarantine.jsonl`` or at the store's temporary names (``.manifest.json.tmp``, ``.samples.jsonl.repair``),
and ENOSPC while a record or the manifest is written. Each is one line naming the file, never a hang or a
traceback, and every good record stays in ``samples.jsonl`` (README "What gonio guarantees")."""

from __future__ import annotations

import errno
import os
import shutil
import threading

import pytest

from gonio.cli.main import main
from gonio.errors import DataError
from gonio.session import store as store_mod
from gonio.session.store import SessionStore, scan_samples
from tests.session.test_untrusted_session_dir import one_line

@pytest.fixture
def damaged(measured, tmp_path):
    """A copy of the session with one flipped bit in its second record (a repair has something to move)."""
    d = tmp_path / "s"
    shutil.copytree(measured, d)
    data = bytearray((d / "samples.jsonl").read_bytes())
    data[data.index(b"\n") + 20] ^= 1
    (d / "samples.jsonl").write_bytes(bytes(data))
    return d


def run_with_timeout(argv, seconds=30):
    """``main(argv)`` in a thread; fails the test (instead of hanging it) if it does not return."""
    box = {}
    t = threading.Thread(target=lambda: box.setdefault("code", main(argv)), daemon=True)
    t.start()
    t.join(seconds)
    assert not t.is_alive(), f"gonio {' '.join(argv)} hangs"
    return box["code"]


def plant(d, name, kind, tmp_path):
    p = d / name
    if kind == "fifo":
        os.mkfifo(p)
    elif kind == "dir":
        p.mkdir()
    else:
        os.symlink(tmp_path / "outside.jsonl", p)


@pytest.mark.parametrize("kind", ["fifo", "dir", "symlink"])
@pytest.mark.parametrize("command", ["repair", "resume"])
def test_a_planted_quarantine_file_is_one_line_and_keeps_every_record(damaged, tmp_path, capsys, kind, command):
    before = (damaged / "samples.jsonl").read_bytes()
    plant(damaged, "quarantine.jsonl", kind, tmp_path)
    one_line(capsys, run_with_timeout([command, str(damaged)]), expect="quarantine.jsonl")
    assert (damaged / "samples.jsonl").read_bytes() == before
    assert not (tmp_path / "outside.jsonl").exists()


@pytest.mark.parametrize("name", [".manifest.json.tmp", ".samples.jsonl.repair"])
def test_a_directory_at_a_temporary_name_is_one_line(damaged, capsys, name):
    before = (damaged / "samples.jsonl").read_bytes()
    good = scan_samples(damaged / "samples.jsonl")
    (damaged / name).mkdir()
    one_line(capsys, run_with_timeout(["repair", str(damaged)]), expect=name)
    after = (damaged / "samples.jsonl").read_bytes()
    if after != before:  # the damaged record was moved before the manifest could not be rewritten: verbatim
        _ln, a, b, _why = good.damaged[0]
        assert (damaged / "quarantine.jsonl").read_bytes() == before[a:b]
        assert after == before[:a] + before[b:]
    assert not (damaged / name).is_file()


def test_a_full_disk_while_appending_cuts_the_partial_record_and_is_a_data_error(measured, tmp_path, monkeypatch):
    d = tmp_path / "s"
    shutil.copytree(measured, d)
    lines = (d / "samples.jsonl").read_bytes().splitlines(keepends=True)
    (d / "samples.jsonl").write_bytes(b"".join(lines[:-1]))
    scan = scan_samples(d / "samples.jsonl")
    pose, (samples, meta) = max(scan.records.items())
    store = SessionStore.open(d)
    real_write, calls = os.write, []

    def full_after_some_bytes(fd, data):  # the first write lands partly, then the disk is full
        calls.append(len(data))
        if len(calls) == 1:
            return real_write(fd, bytes(data[:100]))
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(store_mod.os, "write", full_after_some_bytes)
    with pytest.raises(DataError, match="samples.jsonl.*No space left on device"):
        store.append(pose + 1, samples, meta)
    monkeypatch.undo()
    store.close()
    assert (d / "samples.jsonl").read_bytes() == b"".join(lines[:-1])  # no torn bytes left behind


def test_a_full_disk_while_writing_the_manifest_is_a_data_error_and_leaves_no_temporary_file(measured, tmp_path,
                                                                                            monkeypatch):
    d = tmp_path / "s"
    shutil.copytree(measured, d)
    manifest = (d / "manifest.json").read_bytes()
    store = SessionStore.open(d, resume=False)

    def enospc(fd, data):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(store_mod.os, "write", enospc)
    with pytest.raises(DataError, match="manifest.json.*No space left on device"):
        store.update_manifest(note="x")
    monkeypatch.undo()
    store.close()
    assert (d / "manifest.json").read_bytes() == manifest
    assert not (d / ".manifest.json.tmp").exists()
