"""The session directory is untrusted input (issue: hardening): hand-edited or crafted manifests and
records, planted symlinks, damaged records, a kill during creation. Nothing outside the directory is
ever written; every bad field is one line; every good sample is kept."""

from __future__ import annotations

import base64
import json
import os
import signal
import subprocess
import sys
import zlib
from pathlib import Path

import numpy as np
import pytest

from gonio.cli.main import main
from gonio.session.records import encode_record
from gonio.session.store import load_session
from gonio.samples import SampleSet
from tests.conftest import SMALL_SESSION

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def pristine(tmp_path_factory, copy_small_session):
    """The small in-plane session (tests/conftest.py: ``measure --sim`` with SMALL_SESSION)."""
    return copy_small_session(tmp_path_factory.mktemp("u") / "s")


@pytest.fixture
def session(pristine, tmp_path):
    d = tmp_path / "s"
    d.mkdir()
    for f in pristine.iterdir():
        (d / f.name).write_bytes(f.read_bytes())
    return d


def _edit_manifest(d, **fields):
    m = json.loads((d / "manifest.json").read_text())
    m.update(fields)
    (d / "manifest.json").write_text(json.dumps(m))


def _one_line(capsys):
    out, err = capsys.readouterr()
    lines = err.strip().splitlines()
    assert "Traceback" not in out + err
    return lines


@pytest.mark.parametrize("name", ["../victim.txt", "/tmp/gonio-absolute-victim.txt"])
def test_samples_file_outside_the_directory_is_refused(session, tmp_path, capsys, name):
    victim = (session / name) if not name.startswith("/") else Path(name)
    victim.write_text("precious\n")
    _edit_manifest(session, samples_file=name, exit_status=None)
    for argv in (["status", str(session)], ["resume", str(session)], ["export", str(session), "--format", "csv",
                                                                       "-o", str(tmp_path / "x.csv")]):
        assert main(argv) != 0
        lines = _one_line(capsys)
        assert len(lines) == 1 and "samples_file" in lines[0], lines
    assert victim.read_text() == "precious\n"
    victim.unlink()


def test_symlinks_are_never_followed(session, tmp_path, capsys):
    victim = tmp_path / "victim.txt"
    victim.write_text("precious\n")
    # a planted temporary manifest link: finishing or resuming must not write through it
    os.symlink(victim, session / ".manifest.json.tmp")
    _edit_manifest(session, exit_status=None)
    main(["resume", str(session), "--quiet"])
    capsys.readouterr()
    assert victim.read_text() == "precious\n"
    # samples.jsonl replaced by a link: refused, not appended through
    real = session / "samples.jsonl"
    moved = tmp_path / "elsewhere.jsonl"
    real.rename(moved)
    os.symlink(moved, real)
    before = moved.read_bytes()
    assert main(["resume", str(session)]) != 0
    lines = _one_line(capsys)
    assert len(lines) == 1 and "symbolic link" in lines[0]
    assert main(["status", str(session)]) != 0 and "symbolic link" in _one_line(capsys)[0]
    assert moved.read_bytes() == before


def _crafted(pose=None, n=None, cols=None, meta=None, raw=None) -> bytes:
    s = SampleSet(np.array([[0, 0, 1.0]]), np.array([[0, 0, 1.0]]), np.ones((1, 3)), np.ones((1, 3)) * 0.01)
    good = json.loads(encode_record(3, s, {})[9:])
    if pose is not None:
        good["pose"] = pose
    if n is not None:
        good["n"] = n
    if cols is not None:
        good["cols"] = cols
    if meta is not None:
        good["meta"] = meta
    payload = raw if raw is not None else json.dumps(good).encode()
    return b"%08x " % zlib.crc32(payload) + payload + b"\n"


CRAFTED = {
    "pose Infinity": _crafted(raw=b'{"pose": Infinity, "n": 0, "cols": {}, "meta": {}}'),
    "pose 1e30": _crafted(pose=10 ** 30),
    "pose negative": _crafted(pose=-4),
    "cols a list": _crafted(cols=[1, 2]),
    "shape huge": _crafted(n=10 ** 12),
    "deeply nested": _crafted(raw=b'{"pose": 1, "meta": ' + b"[" * 100000 + b"]" * 100000 + b"}"),
    "column bytes short": _crafted(cols={"wi": ["<f8", [1, 3], base64.b64encode(b"x" * 8).decode()]}),
    "not JSON": _crafted(raw=b"\xff\xfe garbage"),
}


@pytest.mark.parametrize("kind", sorted(CRAFTED))
def test_crafted_records_with_valid_checksums_are_damaged_records_not_tracebacks(session, pristine, tmp_path, capsys,
                                                                                kind):
    data = (session / "samples.jsonl").read_bytes()
    first_end = data.index(b"\n") + 1
    (session / "samples.jsonl").write_bytes(data[:first_end] + CRAFTED[kind] + data[first_end:])
    n_good = len(load_session(session)[1])
    assert n_good == len(load_session(pristine)[1])  # every good sample still read
    assert main(["status", str(session)]) == 0
    out = capsys.readouterr().out
    assert "1 damaged record(s): line 2" in out
    assert main(["export", str(session), "--format", "csv", "-o", str(tmp_path / "x.csv")]) == 0
    capsys.readouterr()
    assert main(["repair", str(session)]) == 0
    assert "moved to quarantine.jsonl" in capsys.readouterr().out
    assert (session / "quarantine.jsonl").read_bytes() == CRAFTED[kind]
    assert len(load_session(session)[1]) == n_good


def test_damaged_records_are_remeasured_on_resume(session, capsys):
    manifest, before = load_session(session)
    data = bytearray((session / "samples.jsonl").read_bytes())
    start = data.index(b"\n") + 1
    data[start + 30] ^= 0x01  # one flipped bit in the second record
    data[data.index(b"\n", start) + 1: data.index(b"\n", start) + 1] = b"\n\n"  # and two stray newlines
    (session / "samples.jsonl").write_bytes(bytes(data))
    _edit_manifest(session, exit_status=None)
    assert main(["resume", str(session), "--quiet"]) == 0
    err = capsys.readouterr().err
    assert "repaired" in err and "3 damaged record(s)" in err
    after_manifest, after = load_session(session)
    assert after_manifest["exit_status"] == "completed"
    assert sorted(set(after.pose.tolist())) == sorted(set(before.pose.tolist()))  # the lost pose re-measured


@pytest.mark.parametrize("sim, message", [({"height": {}}, "sim.height = {}"),
                                          ({"width": 100000}, "sim.width = 100000"),
                                          ({"seed": -1}, "sim.seed = -1")])
def test_crafted_sim_settings_are_one_line(session, capsys, sim, message):
    m = json.loads((session / "manifest.json").read_text())
    m["sim"].update(sim)
    m["exit_status"] = None
    (session / "manifest.json").write_text(json.dumps(m))
    data = (session / "samples.jsonl").read_bytes()
    (session / "samples.jsonl").write_bytes(data[:data.index(b"\n") + 1])  # something left to measure
    assert main(["resume", str(session)]) != 0
    lines = _one_line(capsys)
    assert any(message in ln for ln in lines) and not any("Traceback" in ln for ln in lines)


def test_a_manifest_edit_cannot_widen_the_joint_limits(session, capsys):
    import hashlib

    from gonio.session.recording import manifest_rig as _manifest_rig
    from gonio.rig.kinematics import load_rig

    m = json.loads((session / "manifest.json").read_text())
    text = m["rig"]["toml"]
    import re

    wide = re.sub(r"min_deg = [-0-9.]+", "min_deg = -179.0", text)
    wide = re.sub(r"max_deg = [-0-9.]+", "max_deg = 179.0", wide)
    assert wide != text
    m["rig"].update(toml=wide, sha256=hashlib.sha256(wide.encode()).hexdigest())  # a consistent edit
    rig = _manifest_rig(m, "test")
    declared = load_rig("default")
    assert np.all(rig.lower >= declared.lower - 1e-12) and np.all(rig.upper <= declared.upper + 1e-12)


KILL_SCRIPT = """
import os, signal, sys
import gonio.session.store as store
step = int(sys.argv[2])
count = {"n": 0}
real_replace, real_rename, real_fsync = os.replace, os.rename, os.fsync
def maybe_die():
    count["n"] += 1
    if count["n"] == step:
        os.kill(os.getpid(), signal.SIGKILL)
def fsync(fd):
    maybe_die(); real_fsync(fd)
def rename(a, b):
    maybe_die(); real_rename(a, b)
def replace(a, b):
    maybe_die(); real_replace(a, b)
os.fsync, os.rename, os.replace = fsync, rename, replace
store.SessionStore.create(sys.argv[1], {"plan": {"format": 1, "n_poses": 0}, "mode": "test"}).close()
"""


@pytest.mark.parametrize("step", range(1, 8))
def test_a_kill_during_creation_leaves_no_session_or_a_resumable_one(tmp_path, step):
    target = tmp_path / "s"
    proc = subprocess.run([sys.executable, "-c", KILL_SCRIPT, str(target), str(step)], cwd=REPO,
                          env={**os.environ, "PYTHONPATH": str(REPO)}, capture_output=True)
    assert proc.returncode in (0, -signal.SIGKILL), proc.stderr.decode()[-500:]
    if target.exists():  # complete: a manifest that reads, a samples file
        manifest, samples = load_session(target)
        assert manifest["format"] == 1 and len(samples) == 0
    else:  # nothing at the name: a new session can be created there
        from gonio.session.store import SessionStore

        SessionStore.create(target, {"mode": "test"}).close()


def test_the_lab_time_of_a_killed_run_survives_the_resume(tmp_path, capsys):
    import time

    from gonio.cli.status import session_status

    d = tmp_path / "s"
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.Popen([sys.executable, "-m", "gonio.cli.main", "measure", "--sim", *SMALL_SESSION, "--out", str(d)],
                            cwd=REPO, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 600  # a guard against a hung process only: a loaded machine may need minutes
    while proc.poll() is None and time.monotonic() < deadline:
        if (d / "samples.jsonl").exists() and (d / "samples.jsonl").read_bytes().count(b"\n") >= 5:
            break
        time.sleep(0.02)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    before = session_status(d)["lab_time"]
    assert before and before > 0
    assert main(["resume", str(d), "--quiet"]) == 0
    manifest = json.loads((d / "manifest.json").read_text())
    killed, resumed = manifest["runs"]
    assert killed["status"] == "killed" and killed["lab_time_s"] == pytest.approx(before, rel=1e-12)
    assert session_status(d)["lab_time"] == pytest.approx(before + resumed["lab_time_s"], rel=1e-12)


@pytest.mark.parametrize("timing, message", [({"warmup_min": 1e308}, "timing.warmup_min"),
                                             ({"warmup_min": True}, "timing.warmup_min"),
                                             ({"darks": "none"}, "timing.darks"),
                                             ({"warmup": "stable", "extra": 1}, "timing")])
def test_crafted_timing_is_one_line_naming_the_manifest_and_nothing_is_lost(session, capsys, timing, message):
    """The light/dark strategy a session recorded is read back as untrusted input: a wait of 1e308 s (or
    true) would hang resume; every bad value is one line naming manifest.json, and the samples stay."""
    _edit_manifest(session, timing=timing, exit_status=None)
    data = (session / "samples.jsonl").read_bytes()
    (session / "samples.jsonl").write_bytes(data[:data.index(b"\n") + 1])  # something left to measure
    kept = (session / "samples.jsonl").read_bytes()
    assert main(["resume", str(session)]) == 2
    errors = [ln for ln in _one_line(capsys) if "error:" in ln]
    assert len(errors) == 1 and "manifest.json" in errors[0] and message in errors[0], errors
    assert (session / "samples.jsonl").read_bytes() == kept
