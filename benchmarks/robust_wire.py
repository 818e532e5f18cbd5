"""Wire frames fuzzed through both decoders (the robustness benchmark's wire section).

``run_wire_fuzz(n_frames, quick)`` damages valid frames — 1 to 5 flipped bits, a deleted or inserted
byte, truncation plus noise, pure noise — and feeds every resulting segment to the Python decoder
(:func:`firmware_protocol.codec.decode_segment`) and to the C decoder (``fp_decode_segment`` of
``firmware_protocol/c``, through the firmware's host library), checking that they agree segment for
segment (verdict and frame) and counting crashes and corrupt frames accepted. A second row runs the C
codec's own fuzzer (``fp_test fuzz``, its own mutations and the streaming decoder with a resync check).
The guarantee under test is SPEC.md §2.5 (CRC-32C over the wire bytes: Hamming distance 6 at these
lengths, Koopman DSN 2002). ``tables(quick)`` is the hook ``benchmarks/bench_robustness.py`` calls.
"""

from __future__ import annotations

import ctypes
import random
import shutil
import subprocess
from gonio import childproc  # children die with this process
import tempfile
import time
from pathlib import Path

from benchmarks.common import Table
from firmware_protocol import C_DIR
from firmware_protocol import codec as fp

#: fp_result of fp_codec.h -> the Python verdicts
_C_VERDICT = {1: "frame", 2: "overflow", 3: "cobs", 4: "length", 5: "crc"}


class _CFrame(ctypes.Structure):
    _fields_ = [("type", ctypes.c_uint8), ("seq", ctypes.c_uint8), ("len", ctypes.c_uint8),
                ("payload", ctypes.c_uint8 * fp.MAX_PAYLOAD)]


def _c_decoder():
    from sim.firmware import library  # the firmware's host library links fp_codec.c

    lib = library()
    lib.fp_decode_segment.restype = ctypes.c_int
    lib.fp_decode_segment.argtypes = [ctypes.c_char_p, ctypes.c_size_t, ctypes.POINTER(_CFrame)]
    out = _CFrame()

    def decode(seg: bytes):
        r = lib.fp_decode_segment(seg, len(seg), ctypes.byref(out))
        v = _C_VERDICT.get(r, f"?{r}")
        return (v, fp.Frame(out.type, out.seq, bytes(out.payload[:out.len]))) if v == "frame" else (v, None)

    return decode


def _mutate(wire: bytes, rng: random.Random) -> tuple[bytes, str]:
    w = bytearray(wire)
    mode = rng.randrange(5)
    if mode == 0:  # 1..5 flipped bits between the delimiters: never accepted (SPEC.md §2.5)
        k = rng.randint(1, 5)
        for bit in rng.sample(range(8, 8 * (len(w) - 1)), k):
            w[bit // 8] ^= 1 << (bit % 8)
        return bytes(w), f"{k}-bit"
    if mode == 1:
        del w[rng.randrange(1, len(w) - 1)]
        return bytes(w), "deleted byte"
    if mode == 2:
        w.insert(rng.randrange(1, len(w) - 1), rng.randrange(256))
        return bytes(w), "inserted byte"
    if mode == 3:
        return bytes(rng.randrange(256) for _ in range(rng.randrange(1, 120))), "noise"
    cut = rng.randrange(1, len(w) - 1)
    return bytes(w[:cut]) + bytes(rng.randrange(256) for _ in range(rng.randrange(100))), "truncated+noise"


def run_wire_fuzz(n_frames: int, quick: bool = False, seed: int = 11) -> list[dict]:
    """Fuzz ``n_frames`` damaged frames through both decoders; one row per decoder (see module doc)."""
    rng = random.Random(seed)
    c_decode = _c_decoder()
    crashes = {"python": 0, "c": 0}
    accepted_corrupt = {"python": 0, "c": 0}
    disagree = segments = 0
    t0 = time.perf_counter()
    for _ in range(n_frames):
        payload = bytes(rng.randrange(256) for _ in range(rng.choice((0, 1, 2, 3, 4, 8, 11, 14, 64))))
        orig = fp.Frame(rng.randrange(256), rng.randrange(256), payload)
        bad, _kind = _mutate(fp.encode_frame(orig.type, orig.seq, orig.payload), rng)
        for seg in bad.split(b"\x00"):
            if not seg:
                continue
            segments += 1
            try:
                p = fp.decode_segment(seg)
                pv = ("frame", p) if isinstance(p, fp.Frame) else (p.verdict, None)
            except Exception:  # noqa: BLE001 - what is counted
                crashes["python"] += 1
                pv = ("crash", None)
            try:
                cv = c_decode(seg)
            except Exception:  # noqa: BLE001
                crashes["c"] += 1
                cv = ("crash", None)
            disagree += pv != cv
            for name, v in (("python", pv), ("c", cv)):
                # the damaged bytes are never the original frame's wire bytes, so any frame is corrupt,
                # except the rare mutation that left the original segment intact (an insertion or
                # deletion outside it is impossible: positions are inside), counted only if different
                if v[0] == "frame" and v[1] != orig:
                    accepted_corrupt[name] += 1
    secs = time.perf_counter() - t0
    rows = [{"decoder": "Python codec.py vs C fp_codec.c, segment by segment", "frames": n_frames,
             "segments": segments, "crashes": crashes["python"] + crashes["c"],
             "corrupt_accepted": accepted_corrupt["python"] + accepted_corrupt["c"],
             "disagreements": disagree, "seconds": secs}]
    rows.append(_c_fuzz(max(n_frames, 20_000 if quick else 1_000_000), seed))
    return rows


def _c_fuzz(n: int, seed: int) -> dict:
    """``fp_test fuzz SEED N``: the C codec's own fuzzer (streaming decoder, resync on a sentinel)."""
    cc = shutil.which("cc") or shutil.which("gcc")
    row = {"decoder": "C fp_codec.c streaming (fp_test fuzz)", "frames": n, "segments": "", "crashes": 0,
           "corrupt_accepted": 0, "disagreements": "", "seconds": 0.0}
    if cc is None:
        row["decoder"] += " - no C compiler"
        return row
    with tempfile.TemporaryDirectory() as tmp:
        exe = Path(tmp) / "fp_test"
        childproc.run([cc, "-std=c99", "-O2", "-o", str(exe), str(C_DIR / "fp_codec.c"), str(C_DIR / "fp_test.c")],
                       check=True, capture_output=True, timeout=120)
        t0 = time.perf_counter()
        r = childproc.run([str(exe), "fuzz", str(seed), str(n)], capture_output=True, text=True, timeout=1800)
        row["seconds"] = time.perf_counter() - t0
    last = [x for x in r.stdout.splitlines() if x.startswith("fuzz iterations=")]
    if r.returncode < 0 or not last:
        row["crashes"] = 1
        return row
    kv = dict(x.split("=") for x in last[-1].split()[1:])
    row["corrupt_accepted"] = int(kv["undetected"])
    row["disagreements"] = f"lost resync {kv['lost_resync']}"
    return row


def tables(quick: bool = False) -> list[Table]:
    """The robustness benchmark's wire section: >= 1e6 frames per decoder at full scale (goal 0 / 0)."""
    rows = run_wire_fuzz(20_000 if quick else 1_000_000, quick)
    t = Table("Wire frames fuzzed per decoder (1-5 bit flips, byte deleted/inserted, truncation, noise)",
              ["decoder", "frames", "segments", "crashes", "corrupt accepted", "Python≠C", "seconds"],
              baseline=None, notes=["goal: 0 crashes, 0 corrupt frames accepted, 0 disagreements (SPEC.md §2.5)"])
    for r in rows:
        t.add(r["decoder"], r["frames"], r["segments"], r["crashes"], r["corrupt_accepted"], r["disagreements"],
              r["seconds"])
    return [t]
