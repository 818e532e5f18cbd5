"""Several outputs of one command, each standing alone (``gonio fit S --json f.json --mitsuba f.xml
--pbrt f.pbrt --gltf f.gltf``): every output is attempted, a refused or failed one is one line on stderr
naming its option, the others are still written, and the exit code says that some failed.

An output that fails never stops the ones after it: a renderer that cannot represent the model (a refused
``--pbrt`` without ``--approx``) is no reason to lose the glTF export the user also asked for.
"""

from __future__ import annotations

import sys
from typing import Callable, Sequence

from gonio.errors import GonioError

__all__ = ["write_each"]


def write_each(command: str, outputs: Sequence[tuple[str, Callable[[], str]]]) -> int:
    """Run each ``(option, write)`` of ``outputs`` in order; ``write()`` writes its output and returns the line
    to print (``wrote PATH (...)``). A :class:`GonioError` from one is printed as ``gonio COMMAND: error:
    MESSAGE`` and the next is attempted. Returns 0 when every output was written, else the largest exit code
    of the failures (ConfigError 2, HardwareError 3, DataError 4: :mod:`gonio.errors`), after a last line
    saying which were not written (when there were several)."""
    failed: list[tuple[str, GonioError]] = []
    for option, write in outputs:
        try:
            print(write())
        except GonioError as exc:
            print(f"gonio {command}: error: {exc}", file=sys.stderr)
            failed.append((option, exc))
    if not failed:
        return 0
    if len(outputs) == 1:
        return failed[0][1].exit_code
    written = len(outputs) - len(failed)
    print(f"gonio {command}: {len(failed)} of {len(outputs)} outputs not written ({', '.join(o for o, _ in failed)}); "
          f"{written} written", file=sys.stderr)
    return max(exc.exit_code for _, exc in failed)
