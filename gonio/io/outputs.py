"""Where outputs may be written (:mod:`gonio.outputs`, which every layer uses), with the data formats' own
rule: a MERL input's sidecar (:mod:`gonio.io.merl_sidecar`: which cells were filled, not measured) is an
input too, which an output never replaces."""

from __future__ import annotations

from pathlib import Path

from gonio import outputs as _core
from gonio.outputs import check_output_dir, session_root, write_text_atomically, written_atomically

__all__ = ["check_output", "check_output_dir", "session_root", "written_atomically", "write_text_atomically"]


def _input_files(inputs) -> list[Path]:
    """The files a command reads from ``inputs`` (paths): each file, and a MERL table's sidecar when it
    has one (:mod:`gonio.io.merl_sidecar`: which cells were filled, not measured)."""
    from gonio.errors import DataError
    from gonio.io.merl_sidecar import read_sidecar, sidecar_path

    files = []
    for i in inputs:
        q = Path(i).expanduser()
        files.append(q)
        if q.suffix.lower() == ".binary":
            side = sidecar_path(q)
            try:
                ours = read_sidecar(side) is not None
            except DataError:
                ours = True  # a damaged sidecar is still the table's: not ours to replace
            if ours:
                files.append(side)
    return files


def check_output(path, *, option: str, force: bool = False, suffixes: tuple[str, ...] | None = None,
                 inputs=()) -> Path:
    """:func:`gonio.outputs.check_output`, a MERL input's sidecar counted among the ``inputs``."""
    return _core.check_output(path, option=option, force=force, suffixes=suffixes, inputs=_input_files(inputs))
