"""Robustness: fuzzed wire frames and servo status packets, mutated configuration and session files,
kill -9 at random instants then resume, and fault scenarios through the simulated rig.

``python -m benchmarks robustness`` runs it at full scale (≥ 10⁶ frames per decoder, ≥ 10⁶ status
packets); ``--quick`` runs a small version (the suite runs a smaller one still,
tests/test_bench_robustness.py). Every table's goal column says what must hold: 0 crashes, 0 corrupt
frames or wrong values accepted, 0 tracebacks, 0 samples lost or duplicated.
"""

from __future__ import annotations

import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks.common import Table

REPO = Path(__file__).resolve().parents[1]


# -- wire frames ---------------------------------------------------------------------------------------
def _mutate_frame(wire: bytes, rng: random.Random) -> tuple[bytes, bool]:
    """``(damaged bytes, True if the damage must be detected)``: 1-5 flipped bits (must), or random
    corruption / truncation / insertion (must not yield a *different* valid frame)."""
    w = bytearray(wire)
    mode = rng.random()
    if mode < 0.6:
        for k in rng.sample(range(8 * len(w)), rng.randint(1, 5)):
            w[k // 8] ^= 1 << (k % 8)
        return bytes(w), True
    if mode < 0.8:
        for _ in range(rng.randint(1, 8)):
            w[rng.randrange(len(w))] = rng.randrange(256)
        return bytes(w), False
    if mode < 0.9:
        return bytes(w[: rng.randrange(1, len(w))]) + bytes(rng.randrange(256) for _ in range(rng.randint(0, 20))), False
    i = rng.randrange(len(w))
    return bytes(w[:i]) + bytes([rng.randrange(256)]) + bytes(w[i:]), False


def python_wire_fuzz(n: int, seed: int = 1) -> dict:
    from firmware_protocol import codec as c

    rng = random.Random(seed)
    crashes = accepted_corrupt = 0
    sentinel = c.encode_frame(c.STATUS, 200, b"")
    lost_resync = 0
    for _ in range(n):
        f = c.Frame(rng.randrange(256), rng.randrange(256), bytes(rng.randrange(256) for _ in range(rng.randint(0, 64))))
        wire = c.encode_frame(f.type, f.seq, f.payload)
        bad, must = _mutate_frame(wire, rng)
        try:
            events = c.Decoder().feed(bad + sentinel)
        except Exception:  # noqa: BLE001 - what is counted
            crashes += 1
            continue
        frames = [e for e in events if isinstance(e, c.Frame)]
        if not frames or frames[-1] != c.Frame(c.STATUS, 200, b""):
            lost_resync += 1
        others = frames[:-1]
        accepted_corrupt += sum(1 for g in others if must or g != f)
    return {"decoder": "Python", "frames": n, "crashes": crashes, "corrupt_accepted": accepted_corrupt,
            "lost_resync": lost_resync}


def c_wire_fuzz(n: int, seed: int = 1) -> dict:
    from firmware_protocol import C_DIR

    cc = shutil.which(os.environ.get("CC", "cc")) or shutil.which("gcc")
    if cc is None:
        return {"decoder": "C", "frames": 0, "crashes": "no C compiler", "corrupt_accepted": "-", "lost_resync": "-"}
    with tempfile.TemporaryDirectory() as d:
        exe = Path(d) / "fp_test"
        subprocess.run([cc, "-std=c99", "-O2", "-o", str(exe), str(C_DIR / "fp_codec.c"), str(C_DIR / "fp_test.c")],
                       check=True, capture_output=True)
        res = subprocess.run([str(exe), "fuzz", str(seed), str(n)], capture_output=True, text=True)
    stats = dict(kv.split("=") for kv in res.stdout.strip().splitlines()[-2 if res.returncode == 0 else -1].split()[1:]
                 if "=" in kv)
    return {"decoder": "C (fp_test fuzz)", "frames": n, "crashes": 0 if res.returncode in (0, 1) else res.returncode,
            "corrupt_accepted": int(stats.get("undetected", -1)), "lost_resync": int(stats.get("lost_resync", -1))}


# -- Dynamixel status packets ---------------------------------------------------------------------------
class _BytesPort:
    """The few PortHandler methods the SDK's receive path uses, over a byte string (the serial link's
    stand-in: the code under test is the SDK plus gonio's checks, not this)."""

    def __init__(self, data: bytes):
        self.data, self.pos, self.is_using = data, 0, True

    def readPort(self, n):  # noqa: N802 - SDK name
        out = list(self.data[self.pos:self.pos + n])
        self.pos += len(out)
        return out

    def isPacketTimeout(self):  # noqa: N802 - SDK name
        return self.pos >= len(self.data)


def dxl_status_fuzz(n: int, seed: int = 2) -> dict:
    """Status packets of a 4-byte read, damaged: short with a valid CRC, another ID or instruction with a
    valid CRC, 1-3 flipped bits, truncated, garbage before. A value is *wrong* if the handler returns
    success with bytes other than the ones sent."""
    from gonio.rig.dynamixel import _CheckedPacketHandler
    from sim import dxl_packet as P

    rng = random.Random(seed)
    ph = _CheckedPacketHandler()
    crashes = wrong = accepted = 0
    for _ in range(n):
        value = bytes(rng.randrange(256) for _ in range(4))
        dxl_id = rng.randint(1, 20)
        kind = rng.randrange(6)
        if kind == 0:
            pkt = P.status(dxl_id, 0, value[: rng.randrange(4)])
        elif kind == 1:
            pkt = P.status(dxl_id + 1, 0, value)
        elif kind == 2:
            pkt = P.encode(dxl_id, rng.choice([0x01, 0x02, 0x03, 0x56]), bytes([0]) + value)
        elif kind == 3:
            b = bytearray(P.status(dxl_id, 0, value))
            for k in rng.sample(range(8 * len(b)), rng.randint(1, 3)):
                b[k // 8] ^= 1 << (k % 8)
            pkt = bytes(b)
        elif kind == 4:
            full = P.status(dxl_id, 0, value)
            pkt = full[: rng.randrange(len(full))]
        else:
            pkt = bytes(rng.randrange(1, 256) for _ in range(rng.randint(1, 8))) + P.status(dxl_id, 0, value)
        try:
            data, result, _err = ph.readRx(_BytesPort(pkt), dxl_id, 4)
        except Exception:  # noqa: BLE001 - what is counted
            crashes += 1
            continue
        if result == 0:
            accepted += 1
            # only the garbage-prefixed packet holds a genuine reply; anything else accepted is wrong
            wrong += kind != 5 or bytes(data) != value
    return {"packets": n, "crashes": crashes, "wrong_values": wrong, "accepted": accepted}


# -- configuration and session files --------------------------------------------------------------------
def config_fuzz(n_per_kind: int, seed: int = 3) -> dict:
    from benchmarks.robust_inputs import fuzz_configs

    with tempfile.TemporaryDirectory() as d:
        tried, bad = fuzz_configs(n_per_kind, seed, d)
    return {"files": tried, "tracebacks": len(bad), "example": bad[0] if bad else ""}


def record_fuzz(session: Path, n: int, seed: int = 4) -> dict:
    """Records and manifests mutated *with valid checksums* (a crafted file), read by the scanner and the
    manifest reader: every outcome must be a kept record, a damaged record, or a one-line DataError."""
    import json
    import zlib

    from gonio.errors import GonioError
    from gonio.session.records import scan_bytes

    rng = random.Random(seed)
    lines = (session / "samples.jsonl").read_bytes().splitlines()
    payloads = [ln[9:] for ln in lines if len(ln) > 9]
    crashes = 0
    for _ in range(n):
        p = bytearray(rng.choice(payloads))
        for _ in range(rng.randint(1, 6)):
            i = rng.randrange(len(p))
            p[i] = rng.choice(b'0123456789-+.eE"[]{}:,9e999Infinity' + bytes([rng.randrange(256)]))
        line = b"%08x " % zlib.crc32(bytes(p)) + bytes(p) + b"\n"
        try:
            scan_bytes(line)
        except Exception:  # noqa: BLE001
            crashes += 1
    manifest = json.loads((session / "manifest.json").read_text())
    from gonio.cli.status import session_status

    with tempfile.TemporaryDirectory() as d:
        dd = Path(d) / "s"
        shutil.copytree(session, dd)
        fields = ["samples_file", "plan", "sim", "runs", "rig", "calibration", "running", "exit_status"]
        crafted = [None, {}, [], "../x", 10 ** 30, -1, float("inf"), {"n_poses": 10 ** 30}, [[[]]], "x" * 1000]
        for _ in range(max(1, n // 50)):
            m = dict(manifest)
            m[rng.choice(fields)] = rng.choice(crafted)
            (dd / "manifest.json").write_text(json.dumps(m, allow_nan=True))
            try:
                session_status(dd)
            except GonioError:
                pass
            except Exception:  # noqa: BLE001
                crashes += 1
    return {"records": n, "manifests": max(1, n // 50), "tracebacks": crashes}


# -- kill -9 and resume ---------------------------------------------------------------------------------
SESSION_ARGS = ["--plan", "in_plane", "--theta-i", "30", "--theta-o-step", "20", "--quiet", "--seed", "5"]


def _gonio(*args, **kw):
    env = {**os.environ, "PYTHONPATH": str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    return subprocess.Popen([sys.executable, "-m", "gonio.cli.main", *args], cwd=REPO, env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, **kw)


def kill_resume(n: int, seed: int = 6) -> dict:
    """Sessions killed at random instants (creation included), resumed until complete, compared per pose
    with an uninterrupted session of the same seed: records lost or duplicated, samples that differ."""
    from gonio.session.store import load_session, scan_samples

    rng = random.Random(seed)
    with tempfile.TemporaryDirectory() as d:
        ref = Path(d) / "ref"
        assert _gonio("measure", "--sim", *SESSION_ARGS, "--out", str(ref)).wait() == 0
        _, ref_samples = load_session(ref)
        lost = duplicated = differ = unresumable = 0
        for k in range(n):
            out = Path(d) / f"s{k}"
            proc = _gonio("measure", "--sim", *SESSION_ARGS, "--out", str(out))
            time.sleep(rng.uniform(0.0, 1.5))
            proc.send_signal(signal.SIGKILL)
            proc.wait()
            for _attempt in range(3):
                if not out.exists():  # killed before the session existed: start it again
                    code = _gonio("measure", "--sim", *SESSION_ARGS, "--out", str(out)).wait()
                else:
                    code = _gonio("resume", str(out), "--quiet").wait()
                if code == 0:
                    break
            else:
                unresumable += 1
                continue
            scan = scan_samples(out / "samples.jsonl")
            duplicated += scan.n_duplicates
            _, got = load_session(out)
            for pose in np.unique(ref_samples.pose):
                a, b = ref_samples.subset(ref_samples.pose == pose), got.subset(got.pose == pose)
                if len(b) == 0:
                    lost += 1
                elif len(a) != len(b) or not np.array_equal(a.f, b.f):
                    differ += 1
    return {"kills": n, "unresumable": unresumable, "poses_lost": lost, "records_duplicated": duplicated,
            "poses_not_bit_identical": differ}


# -- fault scenarios ------------------------------------------------------------------------------------
def fault_scenarios(quick: bool) -> list[dict]:
    """Simulated sessions with faults on the servo link and an E-stop: each must complete, or stop with
    one line and the resume command; nothing stored may be lost."""
    from gonio.plan.plan import CaptureSettings, Plan
    from gonio.session.runner import SessionRunner, open_devices
    from gonio.session.store import SessionStore, load_session
    from sim.faults import LinkFaults
    from sim.rig import SimRig, SimRigConfig

    poses = np.radians([(30, 0, 30, 180), (45, 0, 20, 180), (20, 0, 50, 180), (60, 0, 40, 180), (10, 0, 30, 0),
                        (40, 0, 60, 180)])

    rows = []
    scenarios = [("late replies 5 %", dict(delay_rate=0.05)), ("dropped replies 5 %", dict(drop_rate=0.05)),
                 ("corrupt replies 5 %", dict(corrupt_rate=0.05)), ("short valid-CRC replies 5 %", dict(short_rate=0.05)),
                 ("E-stop at pose 3", None)]
    if quick:
        scenarios = scenarios[3:]
    for name, faults in scenarios:
        with tempfile.TemporaryDirectory() as d:
            t0 = time.perf_counter()
            plan = Plan(poses=poses, capture=CaptureSettings(), generator="custom")
            with SimRig(config=SimRigConfig(seed=3, width=240, height=180, focal_px=285.0),
                        servo_faults=LinkFaults(seed=9, delay_s=0.25, **(faults or {}))) as sim:
                def before(k, sim=sim, estop=faults is None):
                    sim.begin_pose(k)
                    if estop and k == 3:
                        sim.controller.set_estop(True)
                devices = open_devices(sim.rig, sim.servo_port, sim.controller_port, sim.camera, sim.clock)
                try:
                    store = SessionStore.create(Path(d) / "s", {"plan": plan, "mode": "test"})
                    result = SessionRunner(plan, store, devices, sim.calibration, sim.layout, before_pose=before,
                                           resume_command="gonio resume DIR", stream=None).run()
                finally:
                    devices.close()
            one_line = "\n" not in result.status
            manifest, samples = load_session(Path(d) / "s")
            stored = len(set(samples.pose.tolist()))
            rows.append({"scenario": name, "status": result.status.split(":")[0], "one_line": one_line,
                         "poses_stored": stored, "measured": result.measured, "lost": result.measured - stored,
                         "wall_s": time.perf_counter() - t0})
    return rows


def run(quick: bool = False) -> list[Table]:
    n_wire = 20_000 if quick else 1_000_000
    n_dxl = 20_000 if quick else 1_000_000
    t = Table("Wire frames fuzzed (1-5 flipped bits, random corruption, truncation, insertion), then a valid frame",
              ["decoder", "frames", "crashes", "corrupt accepted", "resync lost", "goal"])
    for row in (python_wire_fuzz(n_wire // (5 if not quick else 1)), c_wire_fuzz(n_wire)):
        t.add(row["decoder"], row["frames"], row["crashes"], row["corrupt_accepted"], row["lost_resync"], "0 / 0 / 0")
    t.notes.append("Python decoder: a fifth of the C count at full scale (it runs ~30x slower); both see the same "
                   "mutation kinds.")
    tables = [t]
    d = dxl_status_fuzz(n_dxl)
    t = Table("Dynamixel status packets fuzzed through gonio's checked packet handler (the real SDK's receive path)",
              ["packets", "crashes", "wrong values", "accepted (right values)", "goal"])
    t.add(d["packets"], d["crashes"], d["wrong_values"], d["accepted"], "0 / 0")
    tables.append(t)
    cf = config_fuzz(60 if quick else 400)
    t = Table("Mutated configuration files (rig, turntable rig, camera, target, material)",
              ["files", "tracebacks", "goal"])
    t.add(cf["files"], cf["tracebacks"], "0")
    tables.append(t)
    with tempfile.TemporaryDirectory() as d:
        s = Path(d) / "s"
        assert _gonio("measure", "--sim", *SESSION_ARGS, "--out", str(s)).wait() == 0
        rf = record_fuzz(s, 2_000 if quick else 50_000)
    t = Table("Crafted session files (records with valid checksums, manifest fields)",
              ["records", "manifests", "tracebacks", "goal"])
    t.add(rf["records"], rf["manifests"], rf["tracebacks"], "0")
    tables.append(t)
    kr = kill_resume(3 if quick else 20)
    t = Table("kill -9 at random instants (creation included), then resume, against an uninterrupted session",
              ["kills", "unresumable", "poses lost", "records duplicated", "poses not bit-identical", "goal"])
    t.add(kr["kills"], kr["unresumable"], kr["poses_lost"], kr["records_duplicated"], kr["poses_not_bit_identical"],
          "0 / 0 / 0 / 0")
    tables.append(t)
    t = Table("Fault scenarios (simulated rig; servo link faults on every reply)",
              ["scenario", "ended", "one line", "poses stored", "lost", "wall s"])
    for r in fault_scenarios(quick):
        t.add(r["scenario"], r["status"], "yes" if r["one_line"] else "NO", r["poses_stored"], r["lost"], r["wall_s"])
    tables.append(t)
    return tables
