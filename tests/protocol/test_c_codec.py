"""The C99 codec (firmware_protocol/c), compiled with the system C compiler and run against the same
vectors as the Python codec, plus its seeded randomized robustness mode.

No compiler is a failure, not a skip: ``.ci/run`` installs gcc when none is present.
"""

import os
import shutil
import subprocess

import pytest

from firmware_protocol import C_DIR

CFLAGS = ["-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-O2"]
SANITIZE = ["-fsanitize=address,undefined", "-fno-sanitize-recover=all"]


def _compiler() -> str:
    for name in (os.environ.get("CC"), "cc", "gcc", "clang"):
        if name and shutil.which(name):
            return name
    pytest.fail("no C compiler found (tried $CC, cc, gcc, clang): the firmware_protocol C codec must be "
                "compiled and tested; install one (e.g. apt-get install gcc, as .ci/run does)")


def _build(out_dir, flags) -> subprocess.CompletedProcess:
    exe = out_dir / "fp_test"
    cmd = [_compiler(), *CFLAGS, *flags, "-o", str(exe), str(C_DIR / "fp_codec.c"), str(C_DIR / "fp_test.c")]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=120)


@pytest.fixture(scope="module")
def fp_test(tmp_path_factory):
    """Path of the compiled host test program; with ASan/UBSan when the toolchain supports them."""
    out = tmp_path_factory.mktemp("fp_c")
    res = _build(out, SANITIZE)
    if res.returncode != 0:  # toolchain without sanitizer runtimes: plain strict build must still work
        res = _build(out, [])
    assert res.returncode == 0, f"C codec does not compile with {' '.join(CFLAGS)}:\n{res.stderr}"
    return out / "fp_test"


def _run(exe, *args):
    env = dict(os.environ, ASAN_OPTIONS="detect_leaks=0", UBSAN_OPTIONS="print_stacktrace=1")
    return subprocess.run([str(exe), *args], capture_output=True, text=True, timeout=120, env=env)


def vectors_to_lines(v) -> list[str]:
    """Convert vectors.json into the host test program's line format (see fp_test.c)."""
    hx = lambda s: s or "-"  # noqa: E731
    lines = [f"C {hx(c['data'])} {c['crc']}" for c in v["crc"]]
    for m in v["messages"]:
        f = m["frame"]
        lines.append(f"E {f['type']} {f['seq']} {hx(f['payload'])} {m['bytes']}")
    for s in v["streams"]:
        events = []
        for e in s["events"]:
            if "frame" in e:
                f = e["frame"]
                events.append(f"F:{f['type']}:{f['seq']}:{hx(f['payload'])}")
            else:
                events.append(f"R:{e['reject']}")
        lines.append(f"S {s['bytes']} {len(events)} {' '.join(events)}".rstrip())
    return lines


def test_c_codec_matches_vectors(fp_test, vectors, tmp_path):
    lines = vectors_to_lines(vectors)
    path = tmp_path / "vectors.txt"
    path.write_text("\n".join(lines) + "\n")
    res = _run(fp_test, "vectors", str(path))
    assert res.returncode == 0, res.stdout + res.stderr
    assert res.stdout.strip() == f"PASS {len(lines)}"


def test_c_test_program_detects_a_wrong_vector(fp_test, vectors, tmp_path):
    """The checker itself can fail: a vector with one wrong byte and one wrong verdict is reported."""
    lines = vectors_to_lines(vectors)
    e = next(i for i, s in enumerate(lines) if s.startswith("E "))
    lines[e] = lines[e][:-4] + "ff00"
    s = next(i for i, s in enumerate(lines) if "R:crc" in s)
    lines[s] = lines[s].replace("R:crc", "R:cobs", 1)
    path = tmp_path / "bad.txt"
    path.write_text("\n".join(lines) + "\n")
    res = _run(fp_test, "vectors", str(path))
    assert res.returncode == 1
    assert res.stdout.count("FAIL") == 2, res.stdout


@pytest.mark.parametrize("seed", [1, 2])
def test_c_decoder_randomized_robustness(fp_test, seed):
    res = _run(fp_test, "fuzz", str(seed), "100000")
    assert res.returncode == 0, (res.stdout[-2000:] + res.stderr[-2000:])
    stats = dict(kv.split("=") for kv in res.stdout.splitlines()[-2].split()[1:])
    assert stats == {**stats, "iterations": "100000", "undetected": "0", "lost_resync": "0"}
