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
