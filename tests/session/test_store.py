"""The session store: append/reopen, exact floats, torn and corrupted records, refusals, SIGKILL."""

import json
import math
import os
import random
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from gonio.errors import ConfigError, DataError
from gonio.samples import SampleSet
from gonio.session.store import MANIFEST, SAMPLES, SessionStore, load_session, scan_samples


def samples_for(pose: int, n: int = 2) -> SampleSet:
    """Deterministic samples of one pose, with awkward float64 values."""
    rng = np.random.default_rng(pose)
    f = rng.uniform(0, 3, (n, 3))
    f[0, 0] = 1 / 3
    sigma = rng.uniform(0, 0.1, (n, 3))
    sigma[-1, -1] = 5e-324  # subnormal
    return SampleSet(rng.normal(size=(n, 3)), rng.normal(size=(n, 3)), f, sigma,
                     n_pixels=rng.integers(1, 1000, n), flags=rng.integers(0, 64, n))


def same(a: SampleSet, b: SampleSet) -> bool:
    return all(a.to_dict()[k].tobytes() == b.to_dict()[k].tobytes() and a.to_dict()[k].dtype == b.to_dict()[k].dtype
               for k in SampleSet.columns())


def expected(poses) -> SampleSet:
    sets = []
    for p in sorted(poses):
        s = samples_for(p)
        sets.append(SampleSet(**{**s.to_dict(), "pose": np.full(len(s), p)}))
    return SampleSet.concat(sets)


def make(tmp_path, poses=(0, 1, 2), name="s"):
    d = tmp_path / name
    store = SessionStore.create(d, {"material": "test", "plan": {"n_poses": 6}})
    for p in poses:
        store.append(p, samples_for(p), {"joints": [0.1 * p, 0.2], "t_end": 1.5 * p, "exposures": [0.01, 0.04]})
    store.close()
    return d


def test_manifest_is_self_describing(tmp_path):
    d = make(tmp_path)
    m = json.loads((d / MANIFEST).read_text())
    assert m["values"] == "BRDF, not BRDF*cos" and m["units"]["angles"] == "rad"
    assert m["software"]["name"] == "gonio" and m["software"]["version"]
    assert m["material"] == "test" and m["exit_status"] is None and m["started"]


def test_append_reopen_resume_finish(tmp_path):
    d = make(tmp_path, poses=(0, 2))
    store = SessionStore.open(d)
    assert store.done_poses() == {0, 2} and store.torn is None
    assert store.remaining().tolist() == [1, 3, 4, 5]
    assert store.remaining(4).tolist() == [1, 3]
    store.append(1, samples_for(1), {"t_end": 9.0})
    store.finish("completed", lab_time=12.5)
    manifest, got = load_session(d)
    assert manifest["exit_status"] == "completed" and manifest["sample_count"] == 6 and manifest["lab_time"] == 12.5
    assert manifest["resumes"][0]["previous_exit_status"] is None
    assert same(got, expected([0, 1, 2]))


def test_float64_round_trip_is_bit_exact(tmp_path):
    rng = np.random.default_rng(7)
    bits = rng.integers(0, 2**63, (50, 3), dtype=np.int64).view(np.float64)  # NaN payloads, subnormals, huge
    special = np.array([[0.0, -0.0, np.inf], [-np.inf, np.nan, 5e-324], [1 / 3, 2.0**-1074, np.finfo(float).max]])
    vals = np.vstack([bits, special])
    s = SampleSet(vals, vals[::-1], vals * 1, vals[:, ::-1], pose=np.zeros(len(vals)))
    store = SessionStore.create(tmp_path / "s", {})
    store.append(0, s, {"photodiode": 0.1 + 0.2})
    store.close()
    _, got = load_session(tmp_path / "s")
    assert same(got, s)
    assert scan_samples(tmp_path / "s" / SAMPLES).records[0][1]["photodiode"] == 0.1 + 0.2


def test_duplicate_pose_keeps_last_record_once(tmp_path):
    d = make(tmp_path, poses=(0, 1))
    store = SessionStore.open(d)
    store.append(1, samples_for(1), {"t_end": 5.0})  # re-measured after a crash, same values
    store.append(0, samples_for(10), {})  # re-measured with new values: the new one wins
    assert store.sample_count == 4
    store.close()
    _, got = load_session(d)
    assert len(got) == 4 and got.pose.tolist() == [0, 0, 1, 1]
    assert got.f[:2].tobytes() == samples_for(10).f.tobytes()
    scan = scan_samples(d / SAMPLES)
    assert scan.n_records == 4 and scan.n_duplicates == 2


@pytest.fixture
def fast_dir(tmp_path):
    """A directory on tmpfs when there is one: the torn-record test reopens (and fsyncs) ~1000 times,
    which is about logic, not disk durability."""
    import shutil
    import tempfile

    if os.path.isdir("/dev/shm") and os.access("/dev/shm", os.W_OK):
        d = tempfile.mkdtemp(prefix="gonio-test-", dir="/dev/shm")
        yield __import__("pathlib").Path(d)
        shutil.rmtree(d, ignore_errors=True)
    else:
        yield tmp_path


def test_torn_last_record_at_every_byte_offset(fast_dir):
    d = make(fast_dir, poses=(0, 1, 2))
    path = d / SAMPLES
    full = path.read_bytes()
    start = full.rstrip(b"\n").rfind(b"\n") + 1  # first byte of the last record
    manifest = (d / MANIFEST).read_bytes()
    for cut in range(start, len(full)):
        path.write_bytes(full[:cut])
        (d / MANIFEST).write_bytes(manifest)
        _, got = load_session(d)  # read-only: ignores the torn record
        assert same(got, expected([0, 1]))
        store = SessionStore.open(d)
        assert store.done_poses() == {0, 1}
        assert (store.torn is None) == (cut == start), cut
        assert path.stat().st_size == start  # cut back to the last good record
        store.close()
    store = SessionStore.open(d)
    store.append(2, samples_for(2), {"joints": [0.1 * 2, 0.2], "t_end": 1.5 * 2, "exposures": [0.01, 0.04]})
    store.close()
    assert path.read_bytes() == full
    assert same(load_session(d)[1], expected([0, 1, 2]))


def test_corrupted_last_record_is_quarantined(tmp_path):
    d = make(tmp_path, poses=(0, 1, 2))
    data = bytearray((d / SAMPLES).read_bytes())
    data[-40] ^= 0x04
    (d / SAMPLES).write_bytes(bytes(data))
    store = SessionStore.open(d)
    assert store.done_poses() == {0, 1} and store.torn is None
    assert [q["line"] for q in store.repaired["quarantined"]] == [3]
    store.close()
    assert (d / "quarantine.jsonl").read_bytes() == bytes(data[data.rindex(b"\n", 0, len(data) - 1) + 1:])


@pytest.mark.parametrize("offset", [0, 5, 9, 60, -30])
def test_bit_flip_in_the_middle_keeps_every_good_record_and_quarantines_the_bad_one(tmp_path, offset):
    d = make(tmp_path, poses=(0, 1, 2))
    data = bytearray((d / SAMPLES).read_bytes())
    line2 = data.index(b"\n") + 1
    end2 = data.index(b"\n", line2)
    data[(line2 + offset) if offset >= 0 else (end2 + offset)] ^= 0x10
    (d / SAMPLES).write_bytes(bytes(data))
    manifest, samples = load_session(d)  # read-only: the good records, nothing changed
    assert sorted(set(samples.pose.tolist())) == [0, 2] and (d / SAMPLES).read_bytes() == bytes(data)
    store = SessionStore.open(d)
    assert store.done_poses() == {0, 2} and [q["line"] for q in store.repaired["quarantined"]] == [2]
    store.close()
    assert (d / "quarantine.jsonl").read_bytes() == bytes(data[line2:end2 + 1])  # kept, not deleted
    assert (d / SAMPLES).read_bytes() == bytes(data[:line2] + data[end2 + 1:])


def test_refuses_a_directory_holding_a_session(tmp_path):
    d = make(tmp_path)
    before = {p.name: p.read_bytes() for p in d.iterdir()}
    with pytest.raises(ConfigError, match="holds another session"):
        SessionStore.create(d, {"material": "other"})
    assert {p.name: p.read_bytes() for p in d.iterdir()} == before


def test_refuses_unwritable_and_file_paths(tmp_path):
    f = tmp_path / "file"
    f.write_text("x")
    with pytest.raises(ConfigError, match="not a directory"):
        SessionStore.create(f, {})
    with pytest.raises(ConfigError, match="not writable"):
        SessionStore.create(f / "sub", {})
    assert f.read_text() == "x"
    if os.geteuid() != 0:
        ro = tmp_path / "ro"
        ro.mkdir(mode=0o500)
        with pytest.raises(ConfigError, match="not writable"):
            SessionStore.create(ro, {})
        assert list(ro.iterdir()) == []


def test_unjsonable_manifest_leaves_nothing(tmp_path):
    with pytest.raises(ConfigError, match="JSON"):
        SessionStore.create(tmp_path / "s", {"bad": object()})
    assert list(tmp_path.iterdir()) == []  # no session, no half-built directory beside it


def test_one_writer_at_a_time(tmp_path):
    d = make(tmp_path)
    first = SessionStore.open(d)
    with pytest.raises(ConfigError, match="in use"):
        SessionStore.open(d)
    first.close()
    SessionStore.open(d).close()


def test_load_errors_name_the_file(tmp_path):
    with pytest.raises(DataError, match=r"nothere: no such session directory"):
        load_session(tmp_path / "nothere")
    d = make(tmp_path)
    (d / MANIFEST).write_text("{not json")
    with pytest.raises(DataError, match="manifest.json: unreadable"):
        load_session(d)
    d2 = make(tmp_path, name="t")
    (d2 / SAMPLES).unlink()
    with pytest.raises(DataError, match="samples.jsonl: samples file is missing"):
        load_session(d2)


WRITER = textwrap.dedent("""
    import sys
    sys.path.insert(0, {tests!r})
    from test_store import samples_for
    from gonio.session.store import SessionStore
    store = SessionStore.create(sys.argv[1], {{"material": "kill"}})
    for pose in range(10_000):
        store.append(pose, samples_for(pose, n=int(sys.argv[2])), {{"t_end": float(pose)}})
        print(pose, flush=True)
""")


@pytest.mark.parametrize("seed", range(4))
def test_sigkill_keeps_exactly_the_completed_records(tmp_path, seed):
    rng = random.Random(seed)
    script = tmp_path / "writer.py"
    script.write_text(WRITER.format(tests=os.path.dirname(__file__)))
    d = tmp_path / "s"
    n_rows = rng.choice([1, 3000])  # small records, and ~400 kB records (kills land mid-write)
    proc = subprocess.Popen([sys.executable, str(script), str(d), str(n_rows)], stdout=subprocess.PIPE, text=True)
    try:
        target = rng.randint(1, 12)
        acked = -1
        while acked < target:
            line = proc.stdout.readline()
            assert line, "writer died early"
            acked = int(line)
        for _ in range(rng.randint(0, 3)):  # let it get somewhere inside the next write/fsync
            proc.stdout.readline()
            acked += 1
        proc.kill()
    finally:
        proc.kill()
        proc.wait(timeout=10)
        proc.stdout.close()
    store = SessionStore.open(d)
    done = store.done_poses()
    store.close()
    # Every acknowledged record survives, and what survives is a contiguous prefix: the writer may
    # have completed more records between the last line we read and the kill, never half of one.
    assert done == set(range(max(done) + 1)) and max(done) >= acked
    _, got = load_session(d)
    want = SampleSet.concat([SampleSet(**{**samples_for(p, n_rows).to_dict(), "pose": np.full(n_rows, p)})
                             for p in sorted(done)])
    assert same(got, want)


def test_pose_without_samples_still_counts_as_done(tmp_path):
    store = SessionStore.create(tmp_path / "s", {})
    store.append(3, SampleSet.empty(), {"photodiode": float("nan")})  # e.g. every pixel flagged out
    store.close()
    store = SessionStore.open(tmp_path / "s")
    assert store.done_poses() == {3} and store.sample_count == 0 and store.remaining(5).tolist() == [0, 1, 2, 4]
    store.close()
    assert len(load_session(tmp_path / "s")[1]) == 0
    assert scan_samples(tmp_path / "s" / SAMPLES).records[3][1] == {"photodiode": "nan"}  # standard JSON


def test_manifest_json_reads_back_as_the_indented_json_module_output_and_refuses_nan():
    """write_json_atomic's encoder (lists of numbers and rows of them on one line, by the C encoder) gives the
    document json.dumps(indent=1) gives, read back: nested dicts and lists, empty ones, escapes, big ints."""
    from gonio.store.directory import _encode

    rng = random.Random(0)

    def value(depth=0):
        r = rng.random()
        if depth > 4 or r < 0.4:
            return rng.choice([1, -2.5, 1e-300, 0.1 + 0.2, "é\"x\n\u2028", True, False, None, 10**20, ""])
        if r < 0.7:
            return [value(depth + 1) for _ in range(rng.randint(0, 4))]
        return {rng.choice("abé\"\\"): value(depth + 1) for _ in range(rng.randint(0, 4))}

    for _ in range(2000):
        doc = {"x": value(), "poses": [[rng.random() for _ in range(4)] for _ in range(rng.randint(0, 3))]}
        assert json.loads(_encode(doc)) == json.loads(json.dumps(doc, indent=1))
    assert _encode({"a": {"b": [[1, 2], [3, 4]], "c": [{"d": []}]}}) == \
        '{\n "a": {\n  "b": [[1, 2], [3, 4]],\n  "c": [\n   {\n    "d": []\n   }\n  ]\n }\n}'
    for bad in ({"a": [float("nan")]}, {"a": float("inf")}, {"a": [[1.0, float("nan")]]}, {"a": [{"b": [-math.inf]}]}):
        with pytest.raises(ValueError):
            _encode(bad)


def test_manifest_rewrites_reuse_unchanged_entries_and_write_what_a_fresh_encoding_writes(tmp_path):
    """update_manifest keeps the text of entries passed back unchanged (manifest_entry's, e.g. an adaptive session's
    candidate poses) instead of encoding them again; the file is always what encoding the whole manifest gives,
    and an entry changed or replaced by an equal new value is written as it now is."""
    from gonio.store.directory import _encode
    from gonio.store.records import _jsonable

    store = SessionStore.create(tmp_path / "s", {"adaptive": {"candidates": {"poses": np.arange(12.0).reshape(4, 3)},
                                                              "rounds": []}, "rig": {"name": "x"}})
    path = tmp_path / "s" / MANIFEST
    for k in range(4):
        base = store.manifest_entry("adaptive")
        store.update_manifest(adaptive={**base, "rounds": [*base["rounds"], {"round": k, "index": np.array([k])}],
                                        "stop": None if k < 3 else "budget"}, plan={"n_poses": k})
        assert path.read_text() == _encode(_jsonable(store.manifest)) + "\n"
        assert json.loads(path.read_text()) == store.manifest
    assert store.manifest_entry("adaptive")["candidates"] is base["candidates"]  # kept, not converted again
    assert [r["round"] for r in store.manifest["adaptive"]["rounds"]] == [0, 1, 2, 3]
    # a new value for the entry (equal or not) is converted and written, never the old text
    store.update_manifest(adaptive={**store.manifest_entry("adaptive"), "candidates": {"poses": [[-1.0, 2, 3]]}})
    assert json.loads(path.read_text())["adaptive"]["candidates"] == {"poses": [[-1.0, 2, 3]]}
    assert path.read_text() == _encode(_jsonable(store.manifest)) + "\n"
    store.close()


def test_a_record_without_samples_is_not_taken_for_a_lost_pose(tmp_path):
    """A pose may be stored with no sample (a sphere pose whose pixels were all rejected: a chrome highlight off the
    sphere): loading the session counts records, not the samples' poses, so it does not warn that the manifest
    counted a pose samples.jsonl lacks (benchmarks sphere's chrome session did); a record really lost still warns."""
    import warnings

    import gonio

    d = tmp_path / "s"
    store = SessionStore.create(d, {"plan": {"n_poses": 3}})
    v = np.full((4, 3), 0.5)
    store.append(0, SampleSet(v, v, v, v * 0.01, pose=np.zeros(4)), {"k": 0})
    store.append(1, SampleSet(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3)),
                              pose=np.zeros(0)), {"k": 1})
    store.append(2, SampleSet(v, v, v, v * 0.01, pose=np.full(4, 2)), {"k": 2})
    store.finish("completed")
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        gonio.load(d)
    assert not [x for x in w if "manifest counted" in str(x.message)]
    lines = (d / SAMPLES).read_bytes().splitlines(keepends=True)
    (d / SAMPLES).write_bytes(b"".join(lines[:-1]))  # the last record lost
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        gonio.load(d)
    assert [x for x in w if "1 pose(s) the manifest counted" in str(x.message)]


def _depth_by_node(obj, limit):
    """The nesting depth node by node (every value pushed with its depth; the store's check before it went level by
    level over containers only)."""
    deepest, stack = 0, [(obj, 1)]
    while stack:
        cur, d = stack.pop()
        deepest = max(deepest, d)
        if deepest > limit:
            return deepest
        if isinstance(cur, dict):
            stack.extend((v, d + 1) for v in cur.values())
        elif isinstance(cur, list):
            stack.extend((v, d + 1) for v in cur)
    return deepest


def test_record_depth_check_is_the_depth_of_every_node():
    """gonio.store.records._depth (the check that refuses records nested deeper than MAX_DEPTH) gives the depth a
    node-by-node walk gives, and the first depth past the limit, on random JSON values."""
    import random

    from gonio.store.records import _depth

    rnd = random.Random(0)

    def value(d):
        if d <= 0 or rnd.random() < 0.3:
            return rnd.choice([1, 2.5, "x", None, True, [], {}])
        if rnd.random() < 0.5:
            return [value(d - 1) for _ in range(rnd.randrange(0, 4))]
        return {str(i): value(d - 1) for i in range(rnd.randrange(0, 4))}

    values = [value(rnd.randrange(0, 40)) for _ in range(600)]
    assert len({_depth_by_node(v, 99) for v in values}) > 20  # depths 1 to 40
    for limit in (1, 10, 32):
        assert [_depth(v, limit) for v in values] == [_depth_by_node(v, limit) for v in values], limit


def test_an_open_store_reads_its_samples_as_load_session_does(tmp_path):
    """SessionStore.samples (an adaptive session reads its rounds' samples with it, with the manifest it holds
    instead of the file's parsed again) gives load_session's samples bit for bit, with the same warnings: as
    appended, a pose stored again, records beyond the plan left out, a damaged record, a torn last line; the
    store's manifest is not changed by it. has_manifest_entry and store_timing read what a copy would have."""
    import warnings

    from gonio.session.recording import manifest_timing, store_timing

    def read(f):
        with warnings.catch_warnings(record=True) as w:
            warnings.simplefilter("always")
            return f(), [str(x.message) for x in w]

    def check(n, n_warnings):
        (got, w_store), (want, w_load) = read(store.samples), read(lambda: load_session(tmp_path / "s")[1])
        assert same(got, want) and len(got) == n and w_store == w_load and len(w_store) == n_warnings

    store = SessionStore.create(tmp_path / "s", {"plan": {"n_poses": 4}, "geocal": None, "timing": {"darks": "model"}})
    for p in (2, 0, 1, 2):
        store.append(p, samples_for(p + 10 * (p == 2)))
    check(6, 0)
    store.update_manifest(plan={"n_poses": 2})  # pose 2 now lies beyond the plan
    check(4, 1)
    with open(tmp_path / "s" / SAMPLES, "ab") as f:  # a damaged record, then a torn last line
        f.write(b'{"pose": 1, "damaged\n{"pose": 1, "torn')
    check(4, 2)
    assert store.manifest == json.loads((tmp_path / "s" / MANIFEST).read_text())  # no damaged_records added
    assert store.has_manifest_entry("geocal") and "geocal" in store.manifest and not store.has_manifest_entry("adaptive")
    assert store_timing(store) == manifest_timing(store.manifest)
    store.close()


def test_open_takes_over_an_earlier_read_of_the_same_manifest_and_parses_a_changed_one(tmp_path):
    """SessionStore.open(known=read_manifest_bytes(d)) (a resume's checks read the manifest before the lock) reads
    the file again under its lock: the same bytes, and the earlier parse is the store's manifest, not parsed again;
    other bytes (a write in between) are parsed. Either way the store's manifest is the file's as a fresh open reads it."""
    from gonio.store.directory import read_manifest_bytes

    d = make(tmp_path)
    known = read_manifest_bytes(d)
    assert known[0] == (d / MANIFEST).read_bytes() and known[1] == json.loads(known[0])
    store = SessionStore.open(d, known=known)
    assert store._manifest is known[1] and store.manifest["resumes"][-1]["previous_exit_status"] is None
    store.update_manifest(material="changed")
    store.close()
    on_disk = json.loads((d / MANIFEST).read_text())
    store = SessionStore.open(d, known=known)  # stale: the file changed since
    assert store._manifest is not known[1] and store.manifest["material"] == "changed"
    assert len(store.manifest["resumes"]) == len(on_disk["resumes"]) + 1
    store.close()
