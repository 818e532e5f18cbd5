"""Shared test configuration.

Tests that need real hardware are opt-in: ``pytest --port /dev/ttyUSB0`` (servo bus) and
``--controller-port`` (rig controller); without them those tests are deselected, not skipped green.
"""

from __future__ import annotations

import os
import shutil
import sys

# One BLAS/OpenMP thread per process, set before anything imports numpy (the xdist workers import this file
# first): the suite runs at least one worker per core (`-n 4` in addopts on 2 cores), so a second BLAS thread
# in each worker only contends for another worker's core; OpenBLAS's threads spin while they wait, which cost
# about a quarter of the CPU time of the fit- and session-heavy tests. OpenCV's own thread pool likewise (its board
# detection: the same corners; the calibrating and lab-time tests, three interleaved pairs, 11.3-11.7 -> 10.9-11.1
# CPU s, mostly the threads' system time). The `gonio` processes the tests start inherit it. A value set by the
# caller is kept.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENCV_FOR_THREADS_NUM"):
    os.environ.setdefault(_var, "1")

# Bytecode, kept out of the source tree: every process of a run (this one, the xdist workers, the `gonio` processes
# the tests start, all of which inherit the environment) reads and writes compiled modules, and pytest's rewritten
# test modules, under PYC_CACHE (in pytest's own cache directory, .pytest_cache/, which git ignores and
# `pytest --cache-clear` empties) instead of compiling gonio, sim and every test module from source again in each
# process. Where PYTHONDONTWRITEBYTECODE is set (as on the reference machine) nothing else would keep them: each of
# the workers each compiled and rewrote everything (collection: ~10 CPU s per worker, ~3 s from a warm cache) and
# each `gonio` subprocess compiled gonio again (~0.8 CPU s). Bytecode is never written beside the sources (that
# is what PYTHONDONTWRITEBYTECODE is usually set to prevent); a PYTHONPYCACHEPREFIX set by the caller is kept.
PYC_CACHE = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), ".pytest_cache", "pycache")
os.environ["PYTHONPYCACHEPREFIX"] = os.environ.get("PYTHONPYCACHEPREFIX") or PYC_CACHE
os.environ.pop("PYTHONDONTWRITEBYTECODE", None)
sys.pycache_prefix = os.environ["PYTHONPYCACHEPREFIX"]  # this process too: its imports from here on
sys.dont_write_bytecode = False


def link_installed_bytecode(prefix: str) -> int:
    """Hard-link the bytecode the installation already holds (the standard library's and site-packages'
    ``__pycache__/*.pyc``) into ``prefix``'s layout (where :func:`importlib.util.cache_from_source` looks under a
    prefix), once per cache; returns how many files were linked. Under a prefix Python reads no ``__pycache__``
    beside a source, so in a fresh clone every process compiled numpy, scipy, numba, pytest ... from source until
    one had written them, the workers all at once while collecting: measured on fresh clones, `pytest -n 4 -k` of
    no test took 26.5-34 CPU s, 22-23 after linking (~17,600 files, ~0.8 s once). Import still checks each file
    against its source (mtime, size) and writes a stale one anew (a new file: the installation's is untouched).
    Where linking fails (another filesystem, no permission) the libraries compile into the cache as before."""
    import hashlib
    import sysconfig

    paths = sysconfig.get_paths()
    roots = sorted({os.path.realpath(paths[k]) for k in ("stdlib", "platstdlib", "purelib", "platlib")})
    roots = [r for r in roots if not any(r.startswith(o + os.sep) for o in roots if o != r)]
    suffix = f".{sys.implementation.cache_tag}.pyc"  # the unoptimized bytecode, as imports ask for it
    marker = os.path.join(prefix, f".installed-bytecode-{hashlib.sha256(repr(roots).encode()).hexdigest()[:16]}")
    if os.path.exists(marker):
        return 0
    linked = 0
    try:
        for root in roots:
            for d, _, files in os.walk(root):
                if os.path.basename(d) != "__pycache__":
                    continue
                target = prefix + os.path.dirname(d)  # cache_from_source: the prefix + the source's directory
                for f in (f for f in files if f.endswith(suffix)):
                    os.makedirs(target, exist_ok=True)
                    try:
                        os.link(os.path.join(d, f), os.path.join(target, f))
                        linked += 1
                    except FileExistsError:
                        pass
    except OSError:  # not linkable here: leave it to the imports, and do not try again each run
        pass
    try:
        os.makedirs(prefix, exist_ok=True)
        open(marker, "w").close()
    except OSError:
        pass
    return linked


def rewrite_each_module_once(rewrite) -> bool:
    """Make pytest's assertion rewriting (``rewrite``: :mod:`_pytest.assertion.rewrite`) of a module that has no
    rewritten pyc in the cache yet take a lock beside that pyc (``flock``), look again for the pyc under it, and write
    its own before letting go; returns whether it could. The xdist workers all collect every test module in the same
    order at the same moment: in a fresh clone none found the others' pyc, and each rewrote all ~200 modules (~3.5 CPU
    s per worker, 2026-11-27 fresh-clone profile). Now the first to reach a module rewrites it while the others wait,
    without using the CPU, and then read it. One lock at a time, held only while one module is rewritten (which imports
    nothing): no deadlock; a killed process's flock is released by the kernel. Where pytest's internals are not as
    expected, or a lock file cannot be opened, each process rewrites as pytest does by itself."""
    try:
        import fcntl
        from pathlib import Path

        original, read_pyc, write_pyc = rewrite._rewrite_test, rewrite._read_pyc, rewrite._write_pyc
        cache_dir, tail, state_key = rewrite.get_cache_dir, rewrite.PYC_TAIL, rewrite.assertstate_key
    except (ImportError, AttributeError):
        return False
    if getattr(original, "once", False):
        return True

    def _rewrite_test(fn: Path, config):
        pyc = cache_dir(fn) / (fn.name[:-3] + tail)
        try:
            lock = open(f"{pyc}.lock", "a")
        except OSError:
            return original(fn, config)
        with lock:
            fcntl.flock(lock, fcntl.LOCK_EX)
            co = read_pyc(fn, pyc)  # another process rewrote it while this one waited
            if co is not None:
                return os.stat(fn), co
            stat, co = original(fn, config)
            if config is not None and not sys.dont_write_bytecode:
                write_pyc(config.stash[state_key], co, stat, pyc)  # before the others look again
            return stat, co

    _rewrite_test.once = True
    rewrite._rewrite_test = _rewrite_test
    return True


if "PYTEST_XDIST_WORKER" not in os.environ:  # the controller, before it starts the workers
    link_installed_bytecode(sys.pycache_prefix)
import _pytest.assertion.rewrite  # noqa: E402

rewrite_each_module_once(_pytest.assertion.rewrite)

import pytest  # noqa: E402
from hypothesis import HealthCheck, settings  # noqa: E402

settings.register_profile(
    "ci", max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow], derandomize=True
)
settings.register_profile("dev", max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.load_profile("ci" if os.environ.get("CI") else os.environ.get("HYPOTHESIS_PROFILE", "dev"))


#: `gonio measure --sim` arguments of the small in-plane session (θi = 30°, θo every 20°) that the I/O,
#: report and untrusted-session tests start from.
SMALL_SESSION = ["--plan", "in_plane", "--theta-i", "30", "--theta-o-step", "20", "--quiet"]


def measured_once(tmp_path_factory, name: str, argv: list[str]):
    """``gonio ARGV --out DIR`` (gonio's main, which must exit 0) measured once per test run, shared by the xdist
    workers of the run (a directory under their common base, made by the first worker that asks, under a file
    lock; the others wait for it): ``DIR``. Read-only to every test."""
    import fcntl

    from gonio.cli.main import main

    root = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        root = root.parent  # this run's base, shared by its workers (pytest-of-USER/pytest-N)
    done, d = root / f"{name}.done", root / name / "s"
    with open(root / f"{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not done.exists():
            shutil.rmtree(d.parent, ignore_errors=True)
            d.parent.mkdir()
            assert main([*argv, "--out", str(d)]) == 0
            done.touch()
    return d


@pytest.fixture(scope="session")
def small_session_measured(tmp_path_factory):
    """The small in-plane session, measured once per test run (:func:`measured_once`: once for all xdist
    workers). Read-only: a test that damages or extends a session takes :func:`copy_small_session`'s copy."""
    return measured_once(tmp_path_factory, "small-session", ["measure", "--sim", *SMALL_SESSION])


@pytest.fixture(scope="session")
def copy_small_session(small_session_measured):
    """``copy_small_session(dest)``: a private copy of the small session at ``dest`` (returned): the samples
    and manifest of measuring it again with the same arguments (the simulator is seeded), except that the
    manifest's recorded command names the directory it was measured in."""

    def copy(dest):
        shutil.copytree(small_session_measured, dest)
        return dest

    return copy


#: This module, taken while it runs: pytest imports every directory's conftest.py under the one name ``conftest``,
#: so sys.modules["conftest"] is another directory's later on.
_THIS_MODULE = sys.modules[__name__]


@pytest.fixture(scope="session")
def suite_conftest():
    """This module as pytest loaded it, for the tests of its own machinery (importing it again as ``tests.conftest``
    would run its set-up a second time, and ``conftest`` names whichever directory's conftest.py was loaded last)."""
    return _THIS_MODULE


@pytest.fixture(scope="session", autouse=True)
def _never_reads_realdata():
    """Tests never depend on the real materials (the folder benchmarks find beside the repository or in
    $GONIO_REALDATA; benchmarks may use them): in every test process the one lookup of that folder
    (:func:`gonio.prior.build_default.find_realdata`, which ``benchmarks.bench_realdata`` and every benchmark go
    through) fails the test that reaches it, and $GONIO_REALDATA is unset for the run (the processes the tests
    start inherit that)."""
    import gonio.prior.build_default

    def refuse(*_a, **_k):
        raise AssertionError("a test looked for the real materials (find_realdata; tests never depend on them)")

    with pytest.MonkeyPatch.context() as mp:
        mp.delenv("GONIO_REALDATA", raising=False)
        mp.setattr(gonio.prior.build_default, "find_realdata", refuse)
        yield


@pytest.fixture(autouse=True)
def _writes_nothing_into_the_working_directory():
    """Tests write under ``tmp_path`` only: a file or directory that appears in the working directory (the
    checkout, where pytest runs) during a test fails it, naming what appeared, and is removed — e.g. a batch
    command run without ``--summary`` writes ``./gonio-COMMAND-summary-DATE.csv``, which was committed by
    mistake twice. Dot files (pytest's and tools' caches) are not counted. Under xdist a stray written by a test
    on another worker at the same moment fails this test too: either way the run is red and names the file."""
    cwd = os.getcwd()
    before = set(os.listdir(cwd))
    yield
    new = sorted(n for n in set(os.listdir(cwd)) - before if not n.startswith("."))
    for name in new:
        path = os.path.join(cwd, name)
        if os.path.isdir(path):
            shutil.rmtree(path, ignore_errors=True)
        elif os.path.lexists(path):
            try:
                os.remove(path)
            except FileNotFoundError:  # removed by the same check on another worker
                pass
    if new:
        pytest.fail(f"the test wrote into the working directory {cwd} (removed): {', '.join(new)}; write under tmp_path")


@pytest.fixture(scope="session")
def default_session_measured(tmp_path_factory):
    """The quick start's session (`gonio measure --sim` with every default: the default plan, material and
    camera), measured once per test run (:func:`measured_once`; the modules that use it share a group,
    :data:`SAME_WORKER`). Read-only: copy it (shutil.copytree) to change it."""
    return measured_once(tmp_path_factory, "default-session", ["measure", "--sim", "--quiet"])


def pytest_addoption(parser):
    parser.addoption("--port", default=None, help="serial port of a real Dynamixel bus (enables hardware tests)")
    parser.addoption("--controller-port", default=None, help="serial port of a real rig controller")


# -- scheduling on the cores (pytest-xdist, `-n 4 --dist loadgroup` in addopts) -------------------------
#: Modules whose module-scoped fixture is most of their cost (a whole `gonio bench --quick`, a simulated
#: session, a browser): all their tests run on one worker (an ``xdist_group``), so the fixture runs once
#: instead of once per worker that happens to receive one of them. Every other module whose tests use a
#: module-scoped fixture (a simulated session, MERL tables, a compiled codec, ...) is grouped the same way
#: (:func:`_uses_a_module_fixture`); this list names the ones that must stay grouped whatever their fixtures.
SHARED_FIXTURE_MODULES = (
    "tests/test_bench_cli.py",
    "tests/rig/test_rig_kinematics_turntable_session.py",
    "tests/report/test_render_and_report.py",
    "tests/test_end_to_end.py",
    "tests/rig/test_camera_cli.py",
    # not a fixture: its tests share each gonio file's parsed imports (an lru_cache, ~1.3-1.6 CPU s to fill), which a
    # second worker receiving one of them parsed again (2026-11-27 18:45 run: 1.60 s on gw1 and 1.29 s on gw2)
    "tests/test_layering.py",
)


#: Modules that share a session-scoped fixture with a grouped module run in that module's group (on the same
#: worker), so the fixture is made once: module -> the module whose group it joins.
SAME_WORKER = {
    "tests/api/test_readme.py": "tests/fit/test_session.py",  # default_session_measured
    # tests/report/conftest.py's session fixtures: one Chromium, the report inputs, `gonio fit` and `gonio report` of
    # them (~3 CPU s and a browser start on every worker that receives one of these modules' tests)
    **{f"tests/report/{m}.py": "tests/report/test_hostile_names.py"
       for m in ("test_render_and_report", "test_report_layout", "test_report_fit_and_model",
                 "test_report_given_fit_errors", "test_viewer_server")},
}


#: Modules whose tests mostly wait rather than compute: on a serial line's timeouts and retries (servo bus, rig
#: controller), on a GigE camera process (Aravis), on a browser (the report and viewer, with the modules SAME_WORKER
#: puts in their group), on a child process that is killed. Each lane is one xdist group that a worker takes first and
#: runs alone, beside the workers that run everything else: their waits then overlap the other tests' computation.
#: Spread over all workers, several of them waited at once and left the cores idle (2026-11-27, 1,781 tests, CI=true,
#: the idle machine: -n 3 without lanes 161 s with 75 of 322 core-seconds idle; -n 4 with the waiting tests interleaved
#: among the others 146 s, 45 idle; -n 4 with these two lanes 127 s, 10 idle). Two lanes of about the same wall time;
#: the other two workers keep both cores busy. Only where a test runs changes; every test still runs.
WAITING_LANES = (
    (  # the browser, the servo bus and the rig controller on ptys
        "tests/report/test_hostile_names.py",
        "tests/rig/test_servo_hardening.py",
        "tests/rig/test_servo_setup.py",
        "tests/protocol/test_controller_pty.py",
        "tests/rig/test_rig_wire.py",
        "tests/rig/test_rig_cli_controller.py",
        "tests/rig/test_servo_waits.py",
        "tests/protocol/test_emulator_spec.py",
        "tests/rig/test_rig_cli_servo.py",
        "tests/test_sim_pty.py",
        "tests/rig/test_servo_move_guarded.py",
        "tests/protocol/test_exchange.py",
        "tests/protocol/test_exchanges.py",
    ),
    (  # GenICam cameras through Aravis, late servo replies, killed children
        "tests/rig/test_aravis.py",
        "tests/rig/test_aravis_frames.py",
        "tests/rig/test_aravis_pixel_format.py",
        "tests/rig/test_camera_characterise.py",
        "tests/rig/test_camera.py",
        "tests/session/test_bit_identical_resume.py",
        "tests/rig/test_rig_dynamixel.py",
        "tests/test_bench_robustness.py",
        "tests/test_childproc.py",
    ),
)
LANE_OF = {m: f"waiting-lane-{k}" for k, lane in enumerate(WAITING_LANES, 1) for m in lane}


def _uses_a_module_fixture(item) -> bool:
    """Whether ``item`` uses a module-scoped fixture (its own module's or a conftest's, e.g. tests/io's
    session): a module-scoped fixture runs once per worker that receives one of the module's tests."""
    info = getattr(item, "_fixtureinfo", None)
    if info is None:
        return False
    return any(defs and defs[-1].scope == "module" for defs in info.name2fixturedefs.values())


#: The most expensive modules (seconds of wall time each on a 2-core machine: a grouped module's whole group,
#: or single tests of several seconds), most expensive first. They are handed out first (longest processing
#: time first: Graham, "Bounds on multiprocessing timing anomalies", 1969): started last, one of them keeps
#: a worker busy while the other has nothing left to do. Measured with one BLAS thread per worker; only the
#: order changes, every test still runs.
SLOW_FIRST = (
    # the largest groups and single tests of a --durations run (2026-11-27, third session: the bench smoke group is
    # the longest single item, so it starts first)
    "tests/test_bench_cli.py",
    "tests/fit/test_session.py",
    "tests/api/test_readme.py",  # in tests/fit/test_session.py's group (SAME_WORKER)
    "tests/session/test_adaptive_session.py",
    "tests/prior/test_sparse_adaptive.py",
    "tests/api/test_api.py",
    "tests/fit/test_select.py",
    "tests/test_end_to_end.py",
    "tests/io/test_tabulate.py",
    "tests/api/test_batch.py",
    "tests/rig/test_geocal.py",
    "tests/session/test_session_api.py",
    "tests/io/test_table_npz.py",
    "tests/protocol/test_simavr.py",
    "tests/pipeline/test_sphere.py",
    "tests/session/test_measured_material.py",
    "tests/session/test_reliability.py",
    "tests/session/test_robust_session.py",
    "tests/session/test_lab_time_estimate.py",
    "tests/io/test_exports_and_plots.py",
    "tests/session/test_frame_faults.py",
    "tests/fit/test_real_data.py",
    "tests/pipeline/test_tilted_sample.py",
    "tests/io/test_read_back_and_sniff.py",
    "tests/rig/test_rig_kinematics_turntable_session.py",
)


@pytest.hookimpl(tryfirst=True)  # before pytest-xdist reads the groups
def pytest_collection_modifyitems(config, items):
    if not (config.getoption("--port") or config.getoption("--controller-port")):
        selected, deselected = [], []
        for item in items:
            (deselected if "hardware" in item.keywords else selected).append(item)
        if deselected:
            config.hook.pytest_deselected(items=deselected)
            items[:] = selected
    rank = {m: k for k, m in enumerate(SLOW_FIRST)}

    def module(item) -> str:
        return item.nodeid.split("::", 1)[0]

    grouped = {module(item) for item in items if module(item) in SHARED_FIXTURE_MODULES or _uses_a_module_fixture(item)}
    grouped |= set(SAME_WORKER.values())
    def lane(item) -> str | None:
        return LANE_OF.get(module(item)) or LANE_OF.get(SAME_WORKER.get(module(item), ""))

    for item in items:
        group = lane(item) or SAME_WORKER.get(module(item), module(item))
        if group in grouped or group in LANE_OF.values():
            item.add_marker(pytest.mark.xdist_group(group))
    # the lanes first (each is one work unit: a worker takes it and nothing else until it is nearly done), then the
    # most expensive of the rest; stable: the rest keeps its order
    items.sort(key=lambda item: (lane(item) is None, rank.get(module(item), len(SLOW_FIRST))))
