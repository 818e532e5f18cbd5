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

