"""Measured materials on the simulated rig: a MERL ``.binary``, an RGL ``.bsdf``, a gonio NPZ export or a
fit JSON (``gonio fit --json``) as the sample the simulator renders, besides the TOML of an analytic model
(:mod:`gonio.io.material_toml`). :func:`open_material` (``--material``) and :func:`material_from_record` (a
manifest's ``material``) take either; the file's content decides.

What is rendered:

- a table (MERL binary, an NPZ export's table, or an NPZ export's samples tabulated on the MERL grid without
  filling): :class:`gonio.io.table_brdf.TableBRDF` — trilinear interpolation in the Rusinkiewicz
  (θh, θd, φd) parametrisation between the MERL grid's cell centres; cells the table does not hold are
  filled with the nearest held cell's value, said in one line (:attr:`MaterialFile.note`);
- an RGL material: its own evaluation (:meth:`gonio.io.powitacq.PowitacqBRDF.eval`, anisotropic ones too);
- a fit JSON: the fitted model (:meth:`gonio.fit.result.FitResult.from_json`).

The manifest records the file as ``{"label", "file", "kind", "sha256"}`` (absolute path, SHA-256 of its
bytes): ``gonio resume`` reads the same file again and refuses, in one line, a file that is gone or whose
content changed, since the samples already measured came from the old one.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

from gonio.errors import DataError

__all__ = ["MaterialFile", "open_material", "material_from_record", "load_material_file", "material_file_from_dict",
           "FILE_KINDS"]

#: What each kind of material file is, for labels and messages.
FILE_KINDS = {"merl": "MERL table", "bsdf": "RGL material", "npz": "gonio NPZ", "fit": "fitted model"}
_KEYS = {"label", "file", "kind", "sha256"}
#: The last file loaded (path, sha256) -> (evaluable BRDF, note): `gonio measure` checks the file before the
#: session exists and renders it after, a 35 MB table is read and filled once.
_LOADED: dict = {}


def file_sha256(path: Path) -> str:
    """SHA-256 (hex) of the file's bytes, read in 1 MiB blocks."""
    h = hashlib.sha256()
    try:
        with open(path, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                h.update(block)
    except OSError as exc:
        raise DataError(f"{path}: cannot read material file ({exc.strerror or exc})") from None
    return h.hexdigest()


@dataclass(frozen=True)
class MaterialFile:
    """A material that is a data file (module docstring); the same interface as
    :class:`gonio.io.material_toml.Material` (``brdf()``, ``to_dict()``, ``defaults_note()``, ``label``)."""

    path: str
    kind: str
    sha256: str
    label: str
    source: str = "<material>"
    defaulted: tuple[str, ...] = ()

    def brdf(self):
        """The evaluable BRDF (``eval(wi, wo)`` → 1/sr, RGB), loaded once per file content."""
        return _load(Path(self.path), self.kind, self.sha256)[0]

    @property
    def note(self) -> str:
        """One line about what the renderer fills in ('' when nothing): cells of a table not measured."""
        return _load(Path(self.path), self.kind, self.sha256)[1]

    def defaults_note(self) -> str:
        """'' (a data file has no defaulted parameters); see :attr:`note`."""
        return ""

    def to_dict(self) -> dict[str, Any]:
        """``{"label", "file", "kind", "sha256"}``: what the session manifest records."""
        return {"label": self.label, "file": self.path, "kind": self.kind, "sha256": self.sha256}


def _kind(path: Path) -> str:
    """``merl``, ``bsdf``, ``npz`` or ``fit`` from the file's content (:func:`gonio.io.sniff.sniff`)."""
    from gonio.io.sniff import sniff

    try:
        kind, looks = sniff(path)
    except OSError as exc:
        raise DataError(f"{path}: cannot read material file ({exc.strerror or exc})") from None
    if kind in ("merl", "bsdf", "npz"):
        return kind
    if looks == "a JSON document":
        return "fit"
    raise DataError(f"{path}: not a material gonio renders (a MERL .binary, an RGL .bsdf, a gonio NPZ, a fit "
                    f"JSON or a material TOML): it looks like {looks}")


def _load(path: Path, kind: str, sha256: str):
    """``(brdf, note)`` of the file, from :data:`_LOADED` when the same content was loaded last."""
    key = (str(path), sha256)
    hit = _LOADED.get(key)
    if hit is not None:
        return hit
    if kind == "fit":
        from gonio.fit.result import FitResult

        loaded = (FitResult.from_json(path).model, "")
    else:
        from gonio.io.source import load_source
        from gonio.io.table_brdf import TableBRDF

        measured = load_source(path)
        if measured.brdf is not None:  # an RGL material evaluates its own tensor
            loaded = (measured.brdf, "")
        else:
            table = TableBRDF(measured.tabulated(), source=str(path))
            loaded = (table, table.fill_note())
    _LOADED.clear()
    _LOADED[key] = loaded
    return loaded


def load_material_file(path, label: str | None = None) -> MaterialFile:
    """Check a material data file and load it once (a malformed file is one :class:`DataError` line
    naming it, before anything is measured)."""
    p = Path(path)
    if p.is_dir():
        raise DataError(f"{p}: a directory: a simulated material is a file (export a session first: "
                        "gonio export DIR --format npz -o M.npz)")
    if not p.exists():
        raise DataError(f"{p}: no such material file")
    p = p.resolve()
    kind = _kind(p)
    m = MaterialFile(path=str(p), kind=kind, sha256=file_sha256(p), label=label or f"{p.stem} ({FILE_KINDS[kind]})",
                     source=str(path))
    m.brdf()
    return m


def material_file_from_dict(data: Mapping[str, Any], source: str = "manifest material") -> MaterialFile:
    """The material a manifest recorded (:meth:`MaterialFile.to_dict`): the same file, unchanged."""
    unknown = sorted(set(data) - _KEYS)
    if unknown:
        raise DataError(f"{source}: {unknown[0]}: unknown field; a material file record has {', '.join(sorted(_KEYS))}")
    for key in ("file", "kind", "sha256"):
        if not isinstance(data.get(key), str) or not data[key]:
            raise DataError(f"{source}: {key} = {str(data.get(key))[:40]!r}: must be a non-empty string")
    if data["kind"] not in FILE_KINDS:
        raise DataError(f"{source}: kind = {data['kind']!r}: must be one of {', '.join(FILE_KINDS)}")
    p = Path(data["file"])
    if not p.is_file():
        raise DataError(f"{source}: file = {str(p)!r}: no such file (the session simulated this material; "
                        "put the file back to resume)")
    digest = file_sha256(p)
    if digest != data["sha256"]:
        raise DataError(f"{source}: file = {str(p)!r}: its content changed since the session started (sha256 "
                        f"{digest[:12]}…, recorded {data['sha256'][:12]}…): the samples measured came from the old one")
    label = data.get("label")
    return MaterialFile(path=str(p), kind=data["kind"], sha256=digest,
                        label=label if isinstance(label, str) and label else p.stem, source=source)


def open_material(path):
    """``--material PATH``: a TOML file of an analytic model (:func:`gonio.io.material_toml.load_material`), or
    a data file (:func:`load_material_file`); the content decides (a material TOML may have another suffix)."""
    from gonio.io.material_toml import load_material

    p = Path(path)
    if p.suffix.lower() == ".toml" or not p.exists():
        return load_material(path)  # read_toml names a missing file
    if p.is_file():
        try:
            if _kind_or_text(p) == "text":
                return load_material(path)
        except OSError:
            return load_material(path)
    return load_material_file(p)


def _kind_or_text(p: Path) -> str:
    from gonio.io.sniff import sniff

    kind, looks = sniff(p)
    return "text" if kind == "other" and looks.startswith("a text file") else kind


def material_from_record(data, source: str = "manifest material", *, complete: bool = False):
    """The material a session manifest recorded: a data file's record (``file``, ``kind``, ``sha256``: the same
    file, unchanged, :func:`material_file_from_dict`) or an analytic model's (``model``, ``params``:
    :func:`gonio.io.material_toml.material_from_dict`)."""
    from gonio.io.material_toml import material_from_dict

    if isinstance(data, Mapping) and "file" in data:
        return material_file_from_dict(data, source)
    return material_from_dict(data, source, complete=complete)
