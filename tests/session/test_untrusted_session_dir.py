"""A session directory is untrusted input: fixed file names, no symbolic link followed, every field read back
checked, sizes bounded, atomic creation; a manifest edit never widens the joint limits. Through the CLI
(`gonio.cli.main`) on the simulated rig: one line, no traceback, nothing outside the directory touched."""

from __future__ import annotations

import json
import os
import zlib

import pytest

from gonio.cli.main import main
from gonio.errors import DataError
from gonio.session.store import SessionStore, load_session, scan_samples

@pytest.fixture
def session(measured, tmp_path):
    import shutil

    d = tmp_path / "s"
    shutil.copytree(measured, d)
    return d


def edit_manifest(d, **fields):
    m = json.loads((d / "manifest.json").read_text())
    m.update(fields)
    (d / "manifest.json").write_text(json.dumps(m))


def one_line(capsys, code, *, expect):
    out = capsys.readouterr()
    assert code not in (0, None), out
    err = [line for line in out.err.splitlines() if line.strip()]
    assert len(err) == 1 and "Traceback" not in out.err, out.err
    assert expect in err[0], err[0]
    return err[0]


def record(payload: dict | str) -> bytes:
    body = (payload if isinstance(payload, str) else json.dumps(payload)).encode()
    return b"%08x " % zlib.crc32(body) + body + b"\n"


@pytest.mark.parametrize("name", ["../victim.txt", "/tmp/victim-abs.txt", "samples.jsonl/../../victim.txt", 5])
def test_samples_file_outside_the_directory_is_refused_in_one_line(session, tmp_path, capsys, name):
    victim = tmp_path / "victim.txt"
    victim.write_text("precious\n")
    edit_manifest(session, samples_file=name, exit_status=None)
    for cmd in (["resume", str(session), "--quiet"], ["status", str(session)], ["export", str(session), "--format",
                "csv", "-o", str(tmp_path / "x.csv")], ["repair", str(session)]):
        one_line(capsys, main(cmd), expect="samples_file")
    assert victim.read_text() == "precious\n"


def test_symlinked_samples_file_is_never_followed_for_read_or_write(session, tmp_path, capsys):
    outside = tmp_path / "outside.jsonl"
    os.replace(session / "samples.jsonl", outside)
    before = outside.read_bytes()
    os.symlink(outside, session / "samples.jsonl")
    edit_manifest(session, exit_status=None)
    one_line(capsys, main(["resume", str(session), "--quiet"]), expect="symbolic link")
    one_line(capsys, main(["status", str(session)]), expect="symbolic link")
    assert outside.read_bytes() == before


def test_planted_manifest_tmp_link_is_replaced_not_written_through(session, tmp_path):
    outside = tmp_path / "outside.txt"
    outside.write_text("keep me")
    os.symlink(outside, session / ".manifest.json.tmp")
    SessionStore.open(session, resume=False).finish("completed")  # rewrites the manifest through .manifest.json.tmp
    assert outside.read_text() == "keep me"
    assert not os.path.lexists(session / ".manifest.json.tmp")
    assert load_session(session)[0]["exit_status"] == "completed"


def test_symlinked_manifest_is_refused(session, tmp_path, capsys):
    outside = tmp_path / "m.json"
    os.replace(session / "manifest.json", outside)
    os.symlink(outside, session / "manifest.json")
    one_line(capsys, main(["status", str(session)]), expect="symbolic link")


def test_a_fifo_as_samples_file_does_not_hang(session, capsys):
    os.unlink(session / "samples.jsonl")
    os.mkfifo(session / "samples.jsonl")
    one_line(capsys, main(["status", str(session)]), expect="not a regular file")


GOOD = None


@pytest.mark.parametrize("crafted", [
    '{"pose": Infinity, "n": 0, "cols": {}}',
    '{"pose": NaN, "n": 0, "cols": {}}',
    {"pose": 10 ** 30, "n": 0, "cols": {}},
    {"pose": 1, "n": 0, "cols": [1, 2]},
    {"pose": 1, "n": 10 ** 12, "cols": {}},
    {"pose": 1, "n": 2, "cols": {"f": ["<f8", [2, 3], "AAAA"]}},
    {"pose": 1, "n": 2, "cols": {"f": ["<f8", [10 ** 9, 3], ""]}},
    {"pose": 1, "n": 1, "cols": {"f": ["|O", [1, 3], ""]}},
    {"pose": 1, "n": 1, "cols": {"nope": ["<f8", [1], "AAAAAAAAAAA="]}},
    {"pose": True, "n": 0, "cols": {}},
    {"pose": 1, "n": 0, "cols": {}, "meta": [1]},
    "[" * 100000 + "]" * 100000,  # deep nesting
    '{"pose": 1, "n": 0, "cols": {"x": ' + "[" * 5000 + "]" * 5000 + "}}",
    [1, 2],
])
def test_crafted_records_with_valid_crc_are_damaged_records_not_tracebacks(session, tmp_path, capsys, crafted):
    lines = (session / "samples.jsonl").read_bytes().splitlines(keepends=True)
    n_good = len(lines)
    (session / "samples.jsonl").write_bytes(b"".join(lines[:2]) + record(crafted) + b"".join(lines[2:]))
    scan = scan_samples(session / "samples.jsonl")
    assert len(scan.damaged) == 1 and scan.damaged[0][0] == 3 and len(scan.records) == n_good
    assert main(["status", str(session)]) == 0
    out = capsys.readouterr()
    assert "damaged" in out.out and "line 3" in out.out and "Traceback" not in out.err
    assert main(["export", str(session), "--format", "csv", "-o", str(tmp_path / "x.csv")]) == 0
    assert "damaged" in capsys.readouterr().err
    assert main(["repair", str(session)]) == 0
    assert "quarantine.jsonl" in capsys.readouterr().out
    assert len(scan_samples(session / "samples.jsonl").records) == n_good


@pytest.mark.parametrize("field, value, expect", [
    ("sim", {"width": 100000, "height": 120}, "sim.width"),
    ("sim", {"height": {}}, "sim.height"),
    ("sim", {"width": 100, "height": 100, "focal_px": float("nan")}, "focal_px"),
    ("sim", [1], "sim ="),
    ("material", 5, "material"),
    ("plan", {"n_poses": 10 ** 30}, "n_poses"),
    ("rig", "x", "rig"),
])
def test_crafted_manifest_fields_are_one_line(session, capsys, field, value, expect):
    m = json.loads((session / "manifest.json").read_text())
    if field in ("sim", "plan") and isinstance(value, dict):
        value = {**m[field], **value}
    m[field] = value
    m["exit_status"] = None
    text = json.dumps(m)  # NaN is written as NaN: not JSON, refused when read
    (session / "manifest.json").write_text(text)
    # the completed session has nothing left: make one pose missing so resume starts the rig
    lines = (session / "samples.jsonl").read_bytes().splitlines(keepends=True)
    (session / "samples.jsonl").write_bytes(b"".join(lines[:-1]))
    one_line(capsys, main(["resume", str(session), "--quiet"]), expect=expect)


def test_deeply_nested_manifest_is_one_line(session, capsys):
    (session / "manifest.json").write_text('{"format": 1, "x": ' + "[" * 200000 + "]" * 200000 + "}")
    one_line(capsys, main(["status", str(session)]), expect="nested")


def test_a_manifest_edit_cannot_widen_the_joint_limits(session, tmp_path):
    import hashlib

    from gonio.session.recording import manifest_rig as _manifest_rig
    from gonio.rig.kinematics import load_rig

    m = json.loads((session / "manifest.json").read_text())
    text = m["rig"]["toml"]
    wide = text.replace("max_deg", "max_deg_was").replace("max_deg_was", "max_deg", 0)
    import re

    wide = re.sub(r"(max_deg\s*=\s*)[-0-9.]+", r"\g<1>350", text)
    wide = re.sub(r"(min_deg\s*=\s*)[-0-9.]+", r"\g<1>-350", wide)
    assert wide != text
    m["rig"]["toml"] = wide
    m["rig"]["sha256"] = hashlib.sha256(wide.encode()).hexdigest()  # a checksum is not authentication
    rig = _manifest_rig(m, "m.json")
    ref = load_rig("default")
    assert (rig.lower >= ref.lower).all() and (rig.upper <= ref.upper).all()
    assert (rig.lower == ref.lower).all() and (rig.upper == ref.upper).all()
    # the manifest may narrow them
    narrow = re.sub(r"(max_deg\s*=\s*)([-0-9.]+)", lambda mm: f"{mm.group(1)}{float(mm.group(2)) - 5}", text)
    m["rig"]["toml"] = narrow
    m["rig"]["sha256"] = hashlib.sha256(narrow.encode()).hexdigest()
    assert (_manifest_rig(m, "m.json").upper < ref.upper).all()
    # the angle-to-tick mapping (which sets the servos' own limits) must be the rig file's
    shifted = re.sub(r"(zero_offset_deg\s*=\s*)([-0-9.]+)", lambda mm: f"{mm.group(1)}{float(mm.group(2)) + 40}",
                     text, count=1)
    m["rig"]["toml"] = shifted
    m["rig"]["sha256"] = hashlib.sha256(shifted.encode()).hexdigest()
    with pytest.raises(DataError, match="zero_offset_deg"):
        _manifest_rig(m, "m.json")
    # without the rig file, nothing can bound them: refused
    m["rig"]["toml"], m["rig"]["sha256"], m["rig"]["source"] = text, hashlib.sha256(text.encode()).hexdigest(), \
        str(tmp_path / "gone.toml")
    with pytest.raises(DataError, match="--rig"):
        _manifest_rig(m, "m.json")
