"""Self-describing NPZ archive of a session: samples, the MERL-grid table, and metadata (no pickle).

Keys: ``samples/<column>`` for every :class:`gonio.samples.SampleSet` column; ``table/values``,
``table/sigma``, ``table/count`` (the tabulation, when the data are isotropic); ``metadata``: a
one-element unicode array holding a JSON object (units, cosine convention "BRDF, not BRDF·cos",
detector solid angle, material label, rig, software version, ...). Loads with
``np.load(path)`` — ``allow_pickle`` is never needed.
"""

from __future__ import annotations

import json
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from gonio.errors import DataError
from gonio.io.merl import MerlTable
from gonio.samples import SampleSet

__all__ = ["COSINE_CONVENTION", "NpzContent", "build_metadata", "write_npz", "read_npz", "savez_deflated"]

#: What the stored values are.
COSINE_CONVENTION = "BRDF, not BRDF·cos"
UNITS = {
    "f": "1/sr", "sigma": "1/sr (standard uncertainty)", "wi": "unit vector, local frame",
    "sigma_pose": "1/sr (the part of sigma shared by every sample of the pose: docs/uncertainty.md)",
    "wo": "unit vector, local frame", "angles": "rad", "table/values": "1/sr",
    "table/sigma": "1/sr (standard uncertainty)", "table/count": "samples per cell",
}


def _find(d: Any, *names: str) -> Any:
    """First value stored under any of ``names`` anywhere in nested dicts (breadth first)."""
    queue = [d]
    while queue:
        cur = queue.pop(0)
        if isinstance(cur, Mapping):
            for n in names:
                if n in cur and cur[n] is not None:
                    return cur[n]
            queue.extend(v for v in cur.values() if isinstance(v, Mapping))
    return None


def build_metadata(manifest: Mapping[str, Any] | None, **extra: Any) -> dict[str, Any]:
    """Metadata of an export from a session manifest (whatever of it is known) plus ``extra``."""
    from gonio import __version__

    manifest = dict(manifest or {})
    material = manifest.get("material")
    label = _find(manifest, "material_label", "label")
    if label is None and isinstance(material, Mapping):
        label = material.get("name") or material.get("model")
    elif label is None and isinstance(material, str):
        label = material
    software = manifest.get("software")
    meta = {
        "format": "gonio-npz/1",
        "quantity": "BRDF",
        "cosine_convention": COSINE_CONVENTION,
        "session_cosine_convention": _find(manifest, "cosine_convention") or (
            manifest["values"] if isinstance(manifest.get("values"), str) else None),
        "units": UNITS,
        "frame": "z = surface normal, x = sample reference direction, y = z × x; wi toward the light, "
                 "wo toward the camera",
        # the session's definition and computation: gonio/session/detector.py (None + reason if unknown)
        "detector_solid_angle_sr": _find(manifest, "detector_solid_angle_sr", "detector_solid_angle"),
        "detector": manifest.get("detector"),
        "material_label": label,
        "rig": manifest.get("rig"),
        "software_version": _find(manifest, "software_version") or (
            software.get("version") if isinstance(software, Mapping) else software),
        "exported_by": f"gonio {__version__}",
        "table_grid": "MERL 90x90x180 (theta_h sqrt-mapped, theta_d, phi_d folded to [0, pi)); "
                      "axes (theta_h, theta_d, phi_d, rgb); NaN = not measured",
        "manifest": manifest,
    }
    meta.update(extra)
    return meta


@dataclass(frozen=True)
class NpzContent:
    """What :func:`read_npz` returns."""

    metadata: dict
    samples: SampleSet
    table: MerlTable | None
    #: (90, 90, 180) bool: table cells interpolated, not measured (``table/filled``, or where ``table/count``
    #: is 0 but a value is given), or None
    filled: np.ndarray | None = None


def write_npz(path, samples: SampleSet, metadata: Mapping[str, Any], table: MerlTable | None = None,
              filled: np.ndarray | None = None) -> Path:
    """Write samples, an optional table and JSON metadata to a compressed NPZ; returns the path.
    ``filled`` ((90, 90, 180) bool): the table's cells that were interpolated, not measured (a MERL
    export's sidecar), kept as ``table/filled`` so no reader takes them for measurements."""
    path = Path(path)
    arrays = {f"samples/{k}": v for k, v in samples.to_dict().items()}
    if table is not None:
        arrays["table/values"] = table.values
        for name in ("sigma", "count"):
            if getattr(table, name) is not None:
                arrays[f"table/{name}"] = getattr(table, name)
        if filled is not None and np.any(filled):
            arrays["table/filled"] = np.asarray(filled, dtype=bool)
    try:
        text = json.dumps(dict(metadata), default=_json_default, ensure_ascii=False)
    except (TypeError, ValueError) as exc:
        raise DataError(f"{path}: metadata cannot be written as JSON ({exc})") from None
    arrays["metadata"] = np.array([text])
    try:
        from gonio.io.outputs import written_atomically

        with written_atomically(path, "wb") as fh:
            savez_deflated(fh, arrays)
    except OSError as exc:
        raise DataError(f"{path}: cannot write NPZ ({exc.strerror or exc})") from None
    return path


#: zlib level of :func:`savez_deflated`: 1, the fastest. Measured on the exports of tests/io (32 archives, 621 MB
#: of arrays, mostly float64 samples and tables): level 6 (np.savez_compressed's) 2.87 CPU s and 56 MB, level 1
#: 1.56 CPU s and 59 MB; the arrays read back are the same either way (DEFLATE is lossless).
NPZ_LEVEL = 1


def savez_deflated(fh, arrays: Mapping[str, Any], level: int = NPZ_LEVEL) -> None:
    """``np.savez_compressed(fh, **arrays)`` with the DEFLATE level ``level``: the same archive layout (each
    array as ``<key>.npy`` in NumPy's format, ZIP64 entries, no pickle), which ``np.load`` reads as it reads
    np.savez_compressed's, only faster to write (:data:`NPZ_LEVEL`)."""
    with zipfile.ZipFile(fh, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=level, allowZip64=True) as zf:
        for key, value in arrays.items():
            with zf.open(key + ".npy", "w", force_zip64=True) as out:
                np.lib.format.write_array(out, np.asanyarray(value), allow_pickle=False)


def _json_default(o):
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serializable: {type(o).__name__}")


def read_npz(path) -> NpzContent:
    """Read an archive written by :func:`write_npz` (without pickle); :class:`DataError` on bad files."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            files = set(z.files)
            if "metadata" not in files:
                raise DataError(f"{path}: not a gonio NPZ export (no 'metadata' entry)")
            metadata = json.loads(str(z["metadata"][0]))
            samples = SampleSet.from_dict(
                {k.split("/", 1)[1]: z[k] for k in files if k.startswith("samples/")}, source=str(path))
            table, filled = None, None
            if "table/values" in files:
                table = MerlTable(z["table/values"], z["table/sigma"] if "table/sigma" in files else None,
                                  z["table/count"] if "table/count" in files else None)
                if "table/filled" in files:
                    filled = np.asarray(z["table/filled"])
                    if filled.dtype != bool or filled.shape != table.values.shape[:3]:
                        raise DataError(f"{path}: table/filled must be bool of shape {table.values.shape[:3]}, "
                                        f"not {filled.dtype} {filled.shape}")
                elif table.count is not None:  # a tabulation's filled cells: a value, no sample
                    filled = (table.count == 0) & np.isfinite(table.values).any(axis=-1)
                if filled is not None and not filled.any():
                    filled = None
    except DataError:
        raise
    except (OSError, ValueError, KeyError, IndexError, zipfile.BadZipFile) as exc:
        raise DataError(f"{path}: cannot read NPZ ({exc})") from None
    return NpzContent(metadata, samples, table, filled)
