"""Reading gonio's TOML files (rig, camera description, target, material, control tables).

One place turns a file that cannot be read, is not text, or is not valid TOML into a one-line
:class:`gonio.errors.ConfigError` naming the file (and the option that named it), so no loader lets an
``OSError``, ``UnicodeDecodeError`` or ``TOMLDecodeError`` traceback through.
"""

from __future__ import annotations


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


#: Largest configuration file read, bytes (a rig, camera, target or material file is a few kB).
MAX_CONFIG_BYTES = 1 << 20


def read_text(path, option: str | None = None) -> str:
    """The UTF-8 text of ``path``; ``option`` (e.g. ``--rig``) is the field the error names. Only a
    regular file of at most :data:`MAX_CONFIG_BYTES` is read: ``/dev/zero`` or a FIFO is a one-line
    error, not a MemoryError or a process waiting forever."""
    import os
    import stat

    field = option or "file"
    try:
        st = os.stat(path)
        if not stat.S_ISREG(st.st_mode):
            raise ConfigError.field(None, field, str(path), "is not a regular file")
        if st.st_size > MAX_CONFIG_BYTES:
            raise ConfigError.field(None, field, str(path), f"is {st.st_size} bytes, more than a configuration file "
                                    f"({MAX_CONFIG_BYTES})")
        with open(path, "rb") as fh:
            data = fh.read(MAX_CONFIG_BYTES + 1)
    except OSError as exc:
        raise ConfigError.field(None, field, str(path), f"cannot read: {exc.strerror or exc}") from None
    if len(data) > MAX_CONFIG_BYTES:
        raise ConfigError.field(None, field, str(path), "grew while it was read")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        raise ConfigError.field(None, field, str(path), "not a text (TOML) file") from None


def read_toml(path, option: str | None = None) -> dict:
    """:func:`read_text` then :func:`parse_toml`."""
    return parse_toml(read_text(path, option), str(path))
