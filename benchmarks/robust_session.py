"""Session robustness at scale: kill -9 at random instants, mutated session files, camera frame faults.

Functions for ``benchmarks/bench_robustness.py`` (each returns rows; :func:`tables` wraps them as
:class:`benchmarks.common.Table`); ``python -m benchmarks.robust_session [--quick] [--n N]`` prints them.
The test suite runs a small version (tests/session/test_robust_session.py).

* :func:`run_kill_resume` — ``gonio measure --sim`` killed with SIGKILL at a random instant of its run
  (session creation included), then ``gonio resume`` until completed: poses lost, duplicated, sessions that
  could not be resumed, tracebacks; against an uninterrupted reference with the same seed.
* :func:`run_mutated_session_files` — a measured session's manifest fields replaced with hostile values
  (wrong types, NaN/Infinity, 10³⁰, deep nesting, paths outside the directory) and its records damaged
  (bit flips, stray newlines, crafted records with a valid CRC); ``gonio status``, ``export``, ``repair`` and
  ``resume`` on each: tracebacks (must be 0) and good samples lost (must be 0).
* :func:`run_frame_faults` — sessions whose simulated camera returns black, stale, saturated, wrong-size
  and NaN frames or times out: sessions that completed, or stopped / ended incomplete with one line and a
  resume hint; samples stored that are wrong (more than 6 σ from a fault-free run with the same seed).
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import random
import shutil
import signal
import subprocess
from gonio import childproc  # children die with this process
import sys
import tempfile
import time
import zlib
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
ARGS = ["--quiet", "--plan", "in_plane", "--theta-i-step", "30", "--theta-o-step", "30", "--theta-max", "60",
        "--sim-resolution", "240x180", "--seed", "11"]
__all__ = ["run_kill_resume", "run_mutated_session_files", "run_frame_faults", "tables", "KILL_COLUMNS",
           "MUTATION_COLUMNS", "FRAME_COLUMNS"]

KILL_COLUMNS = ("what", "runs", "tracebacks", "not resumable", "poses lost", "poses duplicated")
MUTATION_COLUMNS = ("what", "mutations", "commands run", "tracebacks", "good samples lost")
FRAME_COLUMNS = ("fault", "sessions", "completed", "stopped/incomplete with one line + resume hint", "tracebacks",
                 "wrong samples stored")


def _env():
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}


def _gonio(*args, **kw):
    return childproc.popen([sys.executable, "-m", "gonio.cli.main", *args], cwd=REPO, env=_env(),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, **kw)


def _cli(*args) -> tuple[int, str, bool]:
    """``gonio ARGS`` in-process: (exit code, stderr, traceback?) — any exception escaping main is a traceback."""
    from gonio.cli.main import main

    out, err = io.StringIO(), io.StringIO()
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            code = main(list(args))
    except SystemExit as exc:  # argparse
        return int(exc.code or 0), err.getvalue(), False
    except BaseException:  # noqa: BLE001 - what the benchmark counts
        return -1, err.getvalue(), True
    return code, err.getvalue(), "Traceback" in err.getvalue()


def _poses(d: Path) -> dict:
    from gonio.store.directory import load_session

    manifest, samples = load_session(d)
    return {int(k): samples.subset(samples.pose == k) for k in np.unique(samples.pose)}


# -- kill -9 at random instants, then resume -------------------------------------------------------------
def run_kill_resume(n: int = 20, quick: bool = False, *, seed: int = 1) -> list[tuple]:
    """``n`` runs of ``gonio measure --sim`` killed with SIGKILL at a uniformly random instant of an
    uninterrupted run's wall time (from process start: imports, session creation, poses), then resumed:
    with ``gonio resume`` in a process of its own, or (``quick``) through :func:`gonio.cli.main.main` in this
    process (:func:`_cli`, which counts an escaping exception as a traceback): the resume reads only the killed
    run's directory, so the same check without an interpreter start-up (imports, numba cache) per resume."""
    from gonio.store.directory import scan_samples

    rng = random.Random(seed)
    tmp = Path(tempfile.mkdtemp(prefix="gonio-kill-"))
    tracebacks = not_resumable = lost = duplicated = 0
    try:
        ref = tmp / "ref"
        t0 = time.perf_counter()
        p = _gonio("measure", "--sim", *ARGS, "--out", str(ref))
        p.communicate(timeout=300)
        wall = time.perf_counter() - t0
        reference = set(_poses(ref))
        for i in range(n):
            d = tmp / f"k{i}"
            p = _gonio("measure", "--sim", *ARGS, "--out", str(d))
            time.sleep(rng.uniform(0.0, wall))
            p.send_signal(signal.SIGKILL)
            _, err = p.communicate(timeout=60)
            tracebacks += b"Traceback" in err
            if not (d / "manifest.json").exists():  # killed before the session existed: no session, none left
                if d.exists() and any(d.iterdir()):
                    not_resumable += 1
                continue
            for _attempt in range(3):
                if quick:
                    code, _, tb = _cli("resume", str(d), "--quiet")
                    tracebacks += tb
                else:
                    r = _gonio("resume", str(d), "--quiet")
                    _, err = r.communicate(timeout=300)
                    tracebacks += b"Traceback" in err
                    code = r.returncode
                if code == 0:
                    break
            else:
                not_resumable += 1
                continue
            got = set(_poses(d))
            lost += len(reference - got)
            duplicated += scan_samples(d / "samples.jsonl").n_duplicates
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return [("kill -9 at a random instant, then gonio resume", n, tracebacks, not_resumable, lost, duplicated)]


# -- mutated manifests and records -----------------------------------------------------------------------
HOSTILE = [None, {}, [], [1, 2], "x", -1, 0, 10 ** 30, 1e308, True, "../victim.txt", "/etc/passwd",
           "NaN", "Infinity", {"a": {"b": {"c": []}}}, "A" * 10000]


def _raw_nasty(rng: random.Random) -> str:
    return rng.choice(["NaN", "Infinity", "-Infinity", "[" * 100000 + "]" * 100000, "1" + "0" * 400,
                       '{"' + "k" * 50 + '": ' * 0 + "1}"])


def _mutate_manifest(text: str, rng: random.Random) -> str:
    m = json.loads(text)
    paths = []

    def walk(o, path):
        if isinstance(o, dict):
            for k, v in o.items():
                paths.append(path + (k,))
                if len(path) < 3:
                    walk(v, path + (k,))
        elif isinstance(o, list) and o and len(path) < 3:
            paths.append(path + (0,))
            walk(o[0], path + (0,))

    walk(m, ())
    path = rng.choice(paths)
    holder = m
    for key in path[:-1]:
        holder = holder[key]
    marker = "__GONIO_RAW__"
    if rng.random() < 0.2:
        holder[path[-1]] = marker
        return json.dumps(m).replace(json.dumps(marker), _raw_nasty(rng))
    holder[path[-1]] = rng.choice(HOSTILE)
    return json.dumps(m)


def _record(payload) -> bytes:
    body = (payload if isinstance(payload, str) else json.dumps(payload)).encode()
    return b"%08x " % zlib.crc32(body) + body + b"\n"


CRAFTED = ['{"pose": Infinity, "n": 0, "cols": {}}', {"pose": 10 ** 30, "n": 0, "cols": {}},
           {"pose": 1, "n": 0, "cols": [1, 2]}, {"pose": 1, "n": 10 ** 12, "cols": {}},
           {"pose": 1, "n": 2, "cols": {"f": ["<f8", [10 ** 9, 3], ""]}}, "[" * 100000 + "]" * 100000,
           {"pose": 1, "n": 1, "cols": {"f": ["|O", [1, 3], ""]}}, {"pose": True, "n": 0, "cols": {}}]


def _mutate_samples(data: bytes, rng: random.Random) -> tuple[bytes, int]:
    """Damage one record in the middle (returns the new bytes and how many good records it destroyed)."""
    lines = data.splitlines(keepends=True)
    i = rng.randrange(1, max(len(lines) - 1, 2))
    how = rng.choice(("flip", "newlines", "crafted"))
    if how == "flip":
        b = bytearray(lines[i])
        j = rng.randrange(len(b) - 1)
        b[j] ^= 1 << rng.randrange(8)
        if b[j] == 0x0A:
            b[j] ^= 0x01
        lines[i] = bytes(b)
        return b"".join(lines), 1
    if how == "newlines":
        cut = rng.randrange(10, len(lines[i]) - 10)
        lines[i] = lines[i][:cut] + b"\n\n" + lines[i][cut:]
        return b"".join(lines), 1
    lines.insert(i, _record(rng.choice(CRAFTED)))
    return b"".join(lines), 0


def run_mutated_session_files(n: int = 200, quick: bool = False, *, seed: int = 2) -> list[tuple]:
    """``n`` mutated manifests and ``n`` damaged samples files of one measured session; each is read by
    ``gonio status``, ``export``, ``repair`` and ``resume`` (in-process through ``gonio.cli.main``)."""
    import warnings

    from gonio.store.directory import scan_samples

    rng = random.Random(seed)
    tmp = Path(tempfile.mkdtemp(prefix="gonio-mutate-"))
    rows = []
    try:
        base = tmp / "base"
        code, err, tb = _cli("measure", "--sim", *ARGS, "--out", str(base))
        assert code == 0, err
        n_records = len(scan_samples(base / "samples.jsonl").records)
        text = (base / "manifest.json").read_text()
        data = (base / "samples.jsonl").read_bytes()
        for what in ("manifest fields", "samples records"):
            tracebacks = commands = lost = 0
            for i in range(n):
                d = tmp / f"m{i}"
                shutil.rmtree(d, ignore_errors=True)
                shutil.copytree(base, d)
                destroyed = 0
                if what == "manifest fields":
                    (d / "manifest.json").write_text(_mutate_manifest(text, rng))
                else:
                    new, destroyed = _mutate_samples(data, rng)
                    (d / "samples.jsonl").write_bytes(new)
                    m = json.loads(text)
                    m["exit_status"] = None  # so resume has to open and repair it
                    (d / "manifest.json").write_text(json.dumps(m))
                cmds = [("status", str(d)), ("export", str(d), "--format", "csv", "-o", str(tmp / f"x{i}.csv")),
                        ("repair", str(d))]
                if what == "samples records" or i % 10 == 0:  # resume runs the rig: a sample of the manifests
                    cmds.append(("resume", str(d), "--quiet"))
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    for cmd in cmds:
                        code, err, tb = _cli(*cmd)
                        commands += 1
                        tracebacks += tb
                if what == "samples records":
                    try:
                        got = len(scan_samples(d / "samples.jsonl").records)
                    except Exception:  # noqa: BLE001
                        got = 0
                    lost += max(0, n_records - destroyed - got)
                shutil.rmtree(d, ignore_errors=True)
            rows.append((what, n, commands, tracebacks, lost))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return rows


# -- camera frame faults ---------------------------------------------------------------------------------
FRAME_FAULTS = ["black=0.05", "stale=0.05", "saturated=0.05", "wrong_size=0.05,nan=0.05", "timeout=0.02",
                "black=0.05,stale=0.05,saturated=0.05,wrong_size=0.02,nan=0.02", "black=1"]


def run_frame_faults(n: int = 2, quick: bool = False, *, seed: int = 3) -> list[tuple]:
    """``n`` sessions (different seeds) per fault spec of :data:`FRAME_FAULTS` through ``gonio measure --sim
    --sim-frame-faults``; a session must complete, or stop / end incomplete with one line naming
    ``gonio resume``; no stored sample may differ from the fault-free run by more than 6 σ."""
    import warnings

    specs = FRAME_FAULTS[-2:] if quick else FRAME_FAULTS
    tmp = Path(tempfile.mkdtemp(prefix="gonio-frames-"))
    rows = []
    try:
        clean = {}
        for s in range(n):
            d = tmp / f"clean{s}"
            args = [*ARGS[:-1], str(seed + s)]
            assert _cli("measure", "--sim", *args, "--out", str(d))[0] == 0
            clean[s] = _poses(d)
        for spec in specs:
            completed = stopped = tracebacks = wrong = 0
            for s in range(n):
                d = tmp / f"f{s}-{spec}"
                args = [*ARGS[:-1], str(seed + s)]
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    code, err, tb = _cli("measure", "--sim", *args, "--sim-frame-faults", spec, "--out", str(d))
                tracebacks += tb
                lines = [x for x in err.splitlines() if x.strip()]
                if code == 0:
                    completed += 1
                elif lines and len(lines) <= 2 and "gonio resume" in err and not tb:
                    stopped += 1
                for k, got in _poses(d).items():
                    ref = clean[s].get(k)
                    ok = (got.flags == 0) & (ref.flags == 0) if ref is not None and len(ref) == len(got) else None
                    if ok is None:
                        continue
                    z = np.abs(got.f - ref.f)[ok] / np.sqrt(got.sigma ** 2 + ref.sigma ** 2)[ok]
                    wrong += int(np.count_nonzero(np.any(z > 6, axis=-1)))
            rows.append((spec, n, completed, stopped, tracebacks, wrong))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return rows


def tables(quick: bool = False) -> list:
    """The three tables (small sizes with ``quick``)."""
    from benchmarks.common import Table

    kill = Table("Session kill -9 + resume (gonio measure --sim, SIGKILL at a random instant)", KILL_COLUMNS)
    for r in run_kill_resume(2 if quick else 34, quick):
        kill.add(*r)
    mut = Table("Mutated session files (status, export, repair, resume through gonio.cli.main)", MUTATION_COLUMNS)
    for r in run_mutated_session_files(8 if quick else 500, quick):
        mut.add(*r)
    frames = Table("Camera frame faults (gonio measure --sim --sim-frame-faults)", FRAME_COLUMNS)
    for r in run_frame_faults(1 if quick else 3, quick):
        frames.add(*r)
    return [kill, mut, frames]


if __name__ == "__main__":
    for t in tables(quick="--quick" in sys.argv):
        print(t.to_markdown())
