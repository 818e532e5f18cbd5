"""What a data file looks like, from its first bytes: so a file that is not what its name says is named
for what it is (a Git LFS pointer, an HTML error page, text, a truncated MERL binary, ...) in one line,
instead of being parsed as something it is not (``header dims (1936876918, …)``).

Signatures: MERL binary — int32 LE dims (90, 90, 180) (:mod:`gonio.io.merl`); gonio NPZ — a ZIP archive
(``PK\\x03\\x04``); gonio CSV — a text header starting ``theta_i_deg`` (:mod:`gonio.io.csv`); RGL
``.bsdf`` — ``tensor_file\\0`` (Dupuy & Jakob 2018, :mod:`gonio.io.powitacq`); Git LFS pointer —
``version https://git-lfs.github.com/spec/v1``; git-annex — a link/text naming ``.git/annex/objects``.
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["sniff", "describe", "KIND_NAMES"]

#: What each kind is called in messages.
KIND_NAMES = {
    "merl": "a MERL BRDF binary", "npz": "a gonio NPZ export", "csv": "a gonio CSV export",
    "bsdf": "an RGL material (.bsdf tensor file)",
}
_MERL_HEADER = (90).to_bytes(4, "little") + (90).to_bytes(4, "little") + (180).to_bytes(4, "little")


def sniff(path) -> tuple[str, str]:
    """``(kind, description)`` of the file at ``path``: kind is ``merl``, ``npz``, ``csv``, ``bsdf`` or
    ``other``; description is a short phrase for messages (``"a Git LFS pointer (run git lfs pull)"``)."""
    from gonio.io.merl import FILE_SIZE

    p = Path(path)
    size = p.stat().st_size
    with open(p, "rb") as fh:
        head = fh.read(512)
    if size == 0:
        return "other", "an empty file"
    if head.startswith(_MERL_HEADER):
        if size == FILE_SIZE:
            return "merl", KIND_NAMES["merl"]
        what = "truncated" if size < FILE_SIZE else "with trailing data"
        return "other", f"a MERL binary {what} ({size} bytes, expected {FILE_SIZE})"
    if head.startswith(b"tensor_file\0"):
        return "bsdf", KIND_NAMES["bsdf"]
    if head.startswith(b"PK\x03\x04") or head.startswith(b"PK\x05\x06"):
        return "npz", "a ZIP archive (an NPZ export?)"
    if head.startswith(b"version https://git-lfs.github.com/spec/"):
        return "other", "a Git LFS pointer, not the data (run 'git lfs pull')"
    if b".git/annex/objects" in head or head.startswith(b"/annex/objects/"):
        return "other", "a git-annex pointer, not the data (run 'git annex get')"
    if head.startswith(b"\x1f\x8b"):
        return "other", "a gzip-compressed file (decompress it first)"
    if head.startswith(b"\x89PNG"):
        return "other", "a PNG image"
    text = head.lstrip(b"\xef\xbb\xbf \t\r\n")
    low = text[:64].lower()
    if low.startswith(b"<!doctype html") or low.startswith(b"<html") or b"<html" in head.lower():
        return "other", "an HTML page (a download that saved an error or login page?)"
    if low.startswith(b"<?xml"):
        return "other", "an XML document"
    try:
        decoded = head.decode("utf-8")
    except UnicodeDecodeError as exc:
        if exc.start < len(head) - 4:  # not just a character cut at the 512-byte boundary
            return "other", f"binary data ({size} bytes) of no format gonio reads"
        decoded = head[:exc.start].decode("utf-8")
    first = decoded.splitlines()[0].strip() if decoded.strip() else ""
    if first.startswith("theta_i_deg"):
        return "csv", KIND_NAMES["csv"]
    if text[:1] in (b"{", b"["):
        return "other", "a JSON document"
    if all(c.isprintable() or c in "\r\n\t" for c in decoded):
        shown = first if len(first) <= 40 else first[:40] + "…"
        return "other", f"a text file (first line {shown!r})"
    return "other", f"binary data ({size} bytes) of no format gonio reads"


def describe(path) -> str:
    """The description part of :func:`sniff`."""
    return sniff(path)[1]
