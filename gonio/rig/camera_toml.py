"""Writing the camera description (``CAMERA.toml``, :mod:`gonio.rig.calibration`) from what ``gonio camera
calibrate`` and ``gonio camera noise`` measured.

:func:`write_camera_toml` merges the measured keys into the file: a new file is written whole; an existing
one only with ``force`` (the measured keys replaced, every other key kept, the previous text kept beside it
as ``CAMERA.toml.prev``). The result is read back through :func:`gonio.rig.calibration.load_camera_calibration`
before it replaces anything (an invalid description is never written), and renamed into place atomically.
TOML (v1.0.0) is written by :func:`dumps`: numbers, booleans, strings, arrays and one or two levels of tables,
all gonio's camera description uses.
"""

from __future__ import annotations

import json
import math
import time
from typing import Any, Mapping

from gonio.errors import ConfigError

__all__ = ["dumps", "write_camera_toml"]


def _value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if not math.isfinite(v):
            raise ValueError(f"{v} is not a finite number")
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v, ensure_ascii=False)  # a TOML basic string: JSON's escapes are TOML's
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    if hasattr(v, "tolist"):  # numpy scalars and arrays
        return _value(v.tolist())
    raise ValueError(f"cannot write {type(v).__name__} to TOML")


def dumps(data: Mapping[str, Any], header: str = "") -> str:
    """TOML text of ``data`` (plain values first, then ``[tables]`` and ``[table.subtables]``); keys whose value
    is not finite are left out (the loader takes no NaN)."""
    def plain(d):
        out = []
        for k, v in d.items():
            if isinstance(v, Mapping):
                continue
            try:
                out.append(f"{k} = {_value(v)}")
            except ValueError:
                continue
        return out

    lines = [f"# {line}" for line in header.splitlines()] + plain(data)
    for k, v in data.items():
        if isinstance(v, Mapping):
            lines += ["", f"[{k}]"] + plain(v)
            for k2, v2 in v.items():
                if isinstance(v2, Mapping):
                    lines += ["", f"[{k}.{k2}]"] + plain(v2)
    return "\n".join(lines) + "\n"


def write_camera_toml(path, updates: Mapping[str, Any], *, force: bool, command: str, remove=(),
                      option: str = "-o") -> list[str]:
    """Merge ``updates`` (top-level keys and tables) into the camera description at ``path`` (module docstring).
    ``remove``: top-level keys to drop (``focal_px`` when ``K`` is written). Returns the keys written that
    replaced a value the file had."""
    from gonio.config import read_toml
    from gonio.outputs import check_output, written_atomically
    from gonio.rig.calibration import load_camera_calibration

    p = check_output(path, option=option, force=force, suffixes=(".toml",))
    data: dict = {}
    old_text = None
    if p.exists():
        old_text = p.read_text(encoding="utf-8")
        data = read_toml(p, option)
    replaced = []
    for k, v in updates.items():
        if isinstance(v, Mapping):
            table = data.setdefault(k, {})
            if not isinstance(table, dict):
                raise ConfigError.field(str(p), k, table, "must be a table")
            replaced += [f"{k}.{k2}" for k2 in v if k2 in table and table[k2] != v[k2]]
            if k in ("intrinsics", "emva1288"):  # a measurement's record is replaced whole, never mixed
                table.clear()
            table.update(v)
        else:
            if k in data and data[k] != v:
                replaced.append(k)
            data[k] = v
    for k in remove:
        data.pop(k, None)
    text = dumps(data, header=f"Camera description (gonio/rig/calibration.py), written by `{command}` on "
                              f"{time.strftime('%Y-%m-%d %H:%M:%S')}.")
    check = dict(data) if ("K" in data or "focal_px" in data) else {**data, "focal_px": 1.0}
    probe = p.with_name(f".{p.name}.check.toml")
    try:
        probe.write_text(dumps(check), encoding="utf-8")  # beside the file: a relative response path resolves alike
        load_camera_calibration(probe, for_session=False)
    except ConfigError as exc:
        raise ConfigError(f"{p}: the description would not be valid ({str(exc).replace(str(probe), str(p))}); "
                          "nothing was written") from None
    finally:
        probe.unlink(missing_ok=True)
    if old_text is not None:
        p.with_name(p.name + ".prev").write_text(old_text, encoding="utf-8")
    with written_atomically(p) as fh:
        fh.write(text)
    return replaced
