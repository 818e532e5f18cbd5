"""Moved to :mod:`gonio.io.material_toml` (issue 31: the data formats read sessions without importing the session layer).

This name stays importable for scripts: it *is* that module (same object, so a patch of one patches the other).
"""

import sys

import gonio.io.material_toml as _moved

sys.modules[__name__] = _moved
