"""The Debian packages some tests exercise for real, and the skip that names a missing one.

``.ci/run`` installs every package and sets ``GONIO_REQUIRE_DEBIAN=1``: there a missing package is a
failure, so CI can never skip itself green. Elsewhere (a developer's machine without them) the tests
that need a package skip, with a reason naming it and the ``apt-get`` line.
"""

from __future__ import annotations

import glob
import importlib.util
import os
import shutil

import pytest

#: package -> how to tell it is installed (commands are looked up on PATH)
PACKAGES = {
    "chromium": lambda: shutil.which("chromium"),
    "aravis-tools": lambda: shutil.which("arv-fake-gv-camera-0.8"),
    "gir1.2-aravis-0.8": lambda: glob.glob("/usr/lib/*/girepository-1.0/Aravis-0.8.typelib"),
}


def missing(*packages: str) -> list[str]:
    """Those of ``packages`` that are not installed (names of :data:`PACKAGES` or of
    :data:`sim.simavr.DEBIAN_PACKAGES`)."""
    from sim.simavr import DEBIAN_PACKAGES

    checks = {**DEBIAN_PACKAGES, **PACKAGES}
    return [p for p in packages if not checks[p]()]


def require(what: str, *packages: str, python: tuple[str, ...] = ()) -> None:
    """Skip (or under ``GONIO_REQUIRE_DEBIAN``, fail) naming the missing Debian ``packages`` and Python
    modules (``python``: (module, pip requirement) pairs flattened, e.g. ``("gi", "gonio[genicam]")``)."""
    gone = missing(*packages)
    pip = [python[i + 1] for i in range(0, len(python), 2) if importlib.util.find_spec(python[i]) is None]
    if not gone and not pip:
        return
    parts = []
    if gone:
        parts.append(f"Debian package{'s' if len(gone) > 1 else ''} {' '.join(gone)} "
                     f"(apt-get install {' '.join(gone)})")
    if pip:
        parts.append(f"pip install '{' '.join(dict.fromkeys(pip))}'")
    msg = f"{what} needs {' and '.join(parts)}; .ci/run installs them"
    if os.environ.get("GONIO_REQUIRE_DEBIAN"):
        pytest.fail(f"{msg} (GONIO_REQUIRE_DEBIAN is set: nothing may be skipped)", pytrace=False)
    pytest.skip(msg)
