"""Reading gonio's TOML files (rig, camera description, target, material, control tables).

One place turns a file that cannot be read, is not text, or is not valid TOML into a one-line
:class:`gonio.errors.ConfigError` naming the file (and the option that named it), so no loader lets an
``OSError``, ``UnicodeDecodeError`` or ``TOMLDecodeError`` traceback through.
"""

from __future__ import annotations

from pathlib import Path

from gonio.errors import ConfigError

try:  # Python >= 3.11
    import tomllib
except ModuleNotFoundError:  # pragma: no cover - Python 3.10
    import tomli as tomllib

__all__ = ["parse_toml", "read_text", "read_toml"]


def parse_toml(text: str, source: str) -> dict:
    """The TOML document ``text``; ``source`` names it in the error."""
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{source}: not valid TOML: {exc}") from None


def read_text(path, option: str | None = None) -> str:
    """The UTF-8 text of ``path``; ``option`` (e.g. ``--rig``) is the field the error names."""
    try:
        return Path(path).read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError.field(None, option or "file", str(path), f"cannot read: {exc.strerror or exc}") from None
    except UnicodeDecodeError:
        raise ConfigError.field(None, option or "file", str(path), "not a text (TOML) file") from None


def read_toml(path, option: str | None = None) -> dict:
    """:func:`read_text` then :func:`parse_toml`."""
    return parse_toml(read_text(path, option), str(path))
