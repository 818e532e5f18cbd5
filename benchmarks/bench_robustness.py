"""Robustness: fuzzed Dynamixel status packets, mutated configuration files, servo-bus fault scenarios
through a simulated session, plus the sections other modules own (hooks below): fuzzed wire frames
(``benchmarks/robust_wire.py``) and kill -9 + resume, mutated session files, camera frame faults
(``benchmarks/robust_session.py``).

``python -m benchmarks robustness`` runs it at full scale (≥ 10⁶ frames per decoder, ≥ 10⁶ status
packets); ``--quick`` runs a small version (the suite runs a smaller one still,
tests/test_bench_robustness.py). Every table's goal column says what must hold: 0 crashes, 0 corrupt
frames or wrong values accepted, 0 tracebacks, 0 samples lost or duplicated.
"""

from __future__ import annotations

import importlib
import io
import random
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks.common import Table

REPO = Path(__file__).resolve().parents[1]


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


# -- configuration files --------------------------------------------------------------------------------
def config_fuzz(n_per_kind: int, seed: int = 3) -> dict:
    from benchmarks.robust_inputs import fuzz_configs

    with tempfile.TemporaryDirectory() as d:
        tried, bad = fuzz_configs(n_per_kind, seed, d)
    return {"files": tried, "tracebacks": len(bad), "example": bad[0] if bad else ""}


# -- servo-bus fault scenarios ---------------------------------------------------------------------------
#: (name, LinkFaults rates on every servo reply, event before a pose: None / "estop" / "alarm").
SCENARIOS = [("late replies 5 % (0.25 s)", dict(delay_rate=0.05), None),
             ("dropped replies 5 %", dict(drop_rate=0.05), None),
             ("corrupt replies 5 %", dict(corrupt_rate=0.05), None),
             ("short valid-CRC replies 5 %", dict(short_rate=0.05), None),
             ("all four at 3 % each", dict(delay_rate=0.03, drop_rate=0.03, corrupt_rate=0.03, short_rate=0.03), None),
             ("servo overload alarm after pose 1 moved", {}, "alarm"),
             ("E-stop pressed after pose 1 moved", {}, "estop")]


def fault_scenarios(quick: bool, scenarios=None) -> list[dict]:
    """Simulated sessions (real bytes over the servo pty) with faults on the servo link, a servo's hardware
    alarm and an E-stop between poses. Each must complete, or stop with one line naming the cause and the
    resume command; every pose the runner reported measured must be stored (``lost`` 0); after an E-stop or
    an alarm not one more goal packet reaches a servo (``goals after``)."""
    from gonio.errors import GonioError
    from gonio.plan.plan import CaptureSettings, Plan
    from gonio.session.runner import SessionRunner, open_devices
    from gonio.store.directory import SessionStore, load_session
    from sim.faults import LinkFaults
    from sim.rig import SimRig, SimRigConfig
    from sim.servo_bus import HW_OVERLOAD

    poses = np.radians([(30, 0, 30, 180), (45, 0, 20, 180), (20, 0, 50, 180), (60, 0, 40, 180), (10, 0, 30, 0),
                        (40, 0, 60, 180)])
    if quick:
        poses = poses[:4]
    rows = []
    for name, rates, event in (scenarios or SCENARIOS):
        with tempfile.TemporaryDirectory() as d:
            t0 = time.perf_counter()
            plan = Plan(poses=poses, capture=CaptureSettings(), generator="custom")
            with SimRig(config=SimRigConfig(seed=3, width=240, height=180, focal_px=285.0),
                        servo_faults=LinkFaults(seed=9, delay_s=0.25, **rates)) as sim:
                marks = {}

                def before(k, sim=sim, event=event, marks=marks):
                    sim.begin_pose(k)
                    if event and k == 1:
                        if event == "estop":
                            sim.controller.set_estop(True)
                        else:
                            sim.servo_bus.servo(min(sim.servo_bus.servos)).trip(HW_OVERLOAD)
                        marks["goals"] = len(sim.servo_bus.goal_log)
                try:
                    devices = open_devices(sim.rig, sim.servo_port, sim.controller_port, sim.camera, sim.clock)
                except GonioError as exc:  # refused at start: must be one line naming the servo and fault
                    msg = str(exc)
                    rows.append({"scenario": name, "status": "refused at start", "one_line": "\n" not in msg,
                                 "resume_hint": False, "ok": "\n" not in msg and "servo" in msg, "poses_stored": 0,
                                 "measured": 0, "lost": 0, "goals_after": 0, "ended": msg,
                                 "wall_s": time.perf_counter() - t0})
                    continue
                said = io.StringIO()
                try:
                    store = SessionStore.create(Path(d) / "s", {"plan": plan, "mode": "test"})
                    result = SessionRunner(plan, store, devices, sim.calibration, sim.layout, before_pose=before,
                                           resume_command="gonio resume DIR", stream=said).run()
                finally:
                    devices.close()
                goals_after = len(sim.servo_bus.goal_log) - marks["goals"] if marks else 0
            manifest, samples = load_session(Path(d) / "s")
            stored = len(set(samples.pose.tolist()))
            status = result.status
            hint = "gonio resume DIR" in said.getvalue()
            ok = status == "completed" or ("\n" not in status and hint)
            rows.append({"scenario": name, "status": status.split(":")[0], "one_line": "\n" not in status,
                         "resume_hint": hint, "ok": ok, "poses_stored": stored,
                         "measured": result.measured, "lost": result.measured - stored, "goals_after": goals_after,
                         "ended": manifest.get("exit_status", manifest.get("status", "")),
                         "wall_s": time.perf_counter() - t0})
    return rows


# -- hooks: sections owned by other modules -------------------------------------------------------------
def _hook_tables(module: str, title: str, quick: bool) -> list[Table]:
    """``benchmarks.<module>.tables(quick)`` when that module exists; otherwise one table saying the
    section is not available (never a silent gap)."""
    try:
        mod = importlib.import_module(f"benchmarks.{module}")
    except ModuleNotFoundError as exc:
        if exc.name != f"benchmarks.{module}":
            raise
        mod = None
    if mod is None or not hasattr(mod, "tables"):
        t = Table(title, ["section"])
        t.add(f"not available (benchmarks/{module}.py with tables(quick) not present)")
        return [t]
    return list(mod.tables(quick=quick))


def wire_tables(quick: bool) -> list[Table]:
    """HOOK (protocol engineer): wire frames fuzzed per decoder / crashes / corrupt accepted —
    ``benchmarks/robust_wire.py``, ``tables(quick) -> list[Table]``."""
    return _hook_tables("robust_wire", "Wire frames fuzzed per decoder", quick)


def session_tables(quick: bool) -> list[Table]:
    """HOOK (session engineer): kill -9 + resume, mutated manifests and records, black/stale frames,
    camera timeout — ``benchmarks/robust_session.py``, ``tables(quick) -> list[Table]``."""
    return _hook_tables("robust_session", "Session robustness (kill -9, session files, camera frames)", quick)


def run(quick: bool = False) -> list[Table]:
    tables = wire_tables(quick)
    n_dxl = 20_000 if quick else 1_000_000
    d = dxl_status_fuzz(n_dxl)
    t = Table("Dynamixel status packets fuzzed through gonio's checked packet handler (the real SDK's receive path)",
              ["packets", "crashes", "wrong values", "accepted (right values)", "goal"])
    t.add(d["packets"], d["crashes"], d["wrong_values"], d["accepted"], "0 / 0")
    tables.append(t)
    cf = config_fuzz(60 if quick else 400)
    t = Table("Mutated configuration files (rig, turntable rig, camera, target, material)",
              ["files", "tracebacks", "goal"])
    t.add(cf["files"], cf["tracebacks"], "0")
    if cf["example"]:
        t.notes.append(f"first traceback: {cf['example']}")
    tables.append(t)
    t = Table("Servo-bus fault scenarios through a simulated session (real bytes over the servo pty)",
              ["scenario", "ended", "one line + resume hint", "poses stored", "lost", "goal packets after",
               "wall s"])
    for r in fault_scenarios(quick):
        t.add(r["scenario"], r["status"], "yes" if r["ok"] else "NO", r["poses_stored"], r["lost"],
              r["goals_after"], r["wall_s"])
    t.notes.append("Goal: every session completed, or stopped with one line and `gonio resume DIR`; lost 0; "
                   "0 goal packets after an alarm or E-stop.")
    tables.append(t)
    tables.extend(session_tables(quick))
    return tables
