"""The suite's bytecode cache (tests/conftest.py, :data:`conftest.PYC_CACHE`): the processes the tests start
compile a module once into the cache, never beside its source, even where PYTHONDONTWRITEBYTECODE is set."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path


def test_a_child_process_writes_bytecode_into_the_cache_not_beside_the_source(tmp_path):
    (tmp_path / "cached_once.py").write_text("VALUE = 42\n")
    child = [sys.executable, "-c",
             "import sys, importlib.util, cached_once; "
             "print(sys.pycache_prefix); print(sys.dont_write_bytecode); "
             "print(importlib.util.cache_from_source(cached_once.__file__))"]
    out = subprocess.run(child, cwd=tmp_path, env={**os.environ, "PYTHONPATH": str(tmp_path)}, capture_output=True,
                         text=True, check=True).stdout.splitlines()
    prefix, dont_write, pyc = out[0], out[1], Path(out[2])
    assert prefix == os.environ["PYTHONPYCACHEPREFIX"] == sys.pycache_prefix
    assert dont_write == "False"
    assert pyc.is_file() and pyc.is_relative_to(prefix), pyc  # compiled once, into the cache
    assert not (tmp_path / "__pycache__").exists()  # nothing beside the source


def test_the_installed_bytecode_is_linked_into_a_new_cache_once(tmp_path, suite_conftest):
    """conftest.link_installed_bytecode: a new cache gets the installation's own compiled modules (the same files,
    linked), which a process importing under that prefix reads instead of compiling the sources again; a second call
    links nothing. Where the cache is on another filesystem than the installation nothing is linked."""
    import importlib.util
    import json
    import sysconfig

    import numpy

    link_installed_bytecode = suite_conftest.link_installed_bytecode
    prefix = str(tmp_path / "pyc")
    linked = link_installed_bytecode(prefix)
    same_fs = os.stat(tmp_path).st_dev == os.stat(sysconfig.get_paths()["purelib"]).st_dev
    suffix = f".{sys.implementation.cache_tag}.pyc"

    def installed(module) -> str:
        d, name = os.path.split(module.__file__)
        return os.path.join(d, "__pycache__", name[:-3] + suffix)

    def in_cache(module) -> str:
        d, name = os.path.split(module.__file__)
        return os.path.join(prefix + d, name[:-3] + suffix)

    if not same_fs:
        assert linked == 0
        return
    assert linked > 1000
    for module in (json, numpy):
        assert os.path.samefile(installed(module), in_cache(module)), module
    child = [sys.executable, "-c",
             "import numpy, importlib.util; print(importlib.util.cache_from_source(numpy.__file__))"]
    out = subprocess.run(child, env={**os.environ, "PYTHONPYCACHEPREFIX": prefix}, capture_output=True, text=True,
                         check=True).stdout.strip()
    assert out == in_cache(numpy) and os.path.samefile(out, installed(numpy))  # read, not compiled anew
    assert importlib.util.cache_from_source(numpy.__file__) != out  # (this process: the suite's own cache)
    assert link_installed_bytecode(prefix) == 0


def test_a_test_module_is_rewritten_by_the_first_process_while_the_others_wait_and_read_it(tmp_path, suite_conftest):
    """conftest.rewrite_each_module_once: pytest's assertion rewriting of a module with no rewritten pyc yet takes a
    lock beside that pyc; a process that finds it held (another rewriting the module) waits, then reads the pyc the
    other wrote instead of rewriting; one that gets the lock first rewrites and writes the pyc before letting go. A
    lock left by a killed process stops nobody."""
    import threading

    import _pytest.assertion.rewrite as rewrite

    assert suite_conftest.rewrite_each_module_once(rewrite) and rewrite._rewrite_test.once  # installed, and once
    fn = tmp_path / "test_rewritten_once.py"
    fn.write_text("def test_x():\n    assert 1 + 1 == 2\n")
    pyc = rewrite.get_cache_dir(fn) / (fn.name[:-3] + rewrite.PYC_TAIL)
    pyc.parent.mkdir(parents=True, exist_ok=True)
    holder = subprocess.Popen([sys.executable, "-c", "import fcntl, sys, time; f = open(sys.argv[1], 'a'); "
                               "fcntl.flock(f, fcntl.LOCK_EX); print('held', flush=True); time.sleep(120)",
                               f"{pyc}.lock"], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        got = []
        waiter = threading.Thread(target=lambda: got.append(rewrite._rewrite_test(fn, None)))
        waiter.start()
        waiter.join(0.3)
        assert waiter.is_alive()  # waits while the other process rewrites
        # what the other process writes: a code object that rewriting this source would not give
        marker = compile("WRITTEN_BY_THE_OTHER = True\n", str(fn), "exec")
        with open(pyc, "wb") as f:
            rewrite._write_pyc_fp(f, os.stat(fn), marker)
    finally:
        holder.kill()  # its lock goes with it
        holder.wait()
    waiter.join(30)
    assert got and got[0][1].co_names == marker.co_names  # read, not rewritten again
    pyc.unlink()
    stat, co = rewrite._rewrite_test(fn, None)  # nobody holds the lock: rewritten here
    test_x = next(c for c in co.co_consts if getattr(c, "co_name", None) == "test_x")
    assert any(v.startswith("@py_assert") for v in test_x.co_varnames) and stat.st_size == fn.stat().st_size
