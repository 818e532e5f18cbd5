"""A batch job for tests/api/test_batch.py's interrupt test: spawned workers import it by name (the
test's folder is on ``sys.path``, which ``spawn`` passes to its children)."""

import time
from pathlib import Path


def slow_job(source: str, options: dict) -> dict:
    """Mark ``source`` as started in ``options['dir']``, then take ``options['seconds']``."""
    (Path(options["dir"]) / f"{Path(source).name}.started").touch()
    time.sleep(options["seconds"])
    return {"done": True}
