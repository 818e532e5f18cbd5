"""The query parameters of ``gonio view``'s endpoints, validated: a value is used only if it is a plain
decimal number of the right type, finite and in its range; otherwise the request is refused with one line
naming the parameter and the value (HTTP 400) — never answered with a default.

A parameter that is absent takes its default; one the endpoint does not know, one given twice, or a
query that is not ``name=value&…`` (RFC 3986 §3.4, HTML's application/x-www-form-urlencoded) is refused.
"""

from __future__ import annotations

import math
import re
import urllib.parse
from dataclasses import dataclass

__all__ = ["Param", "BadRequest", "parse_query", "MAX_FIELDS"]

#: More fields than this in one query is refused before any is read.
MAX_FIELDS = 16
_INT = re.compile(r"[+-]?[0-9]{1,9}")
_FLOAT = re.compile(r"[+-]?([0-9]{1,12}(\.[0-9]{0,12})?|\.[0-9]{1,12})([eE][+-]?[0-9]{1,3})?")


class BadRequest(ValueError):
    """A request the server refuses: the message is the one line the client gets."""


@dataclass(frozen=True)
class Param:
    """One parameter: ``kind`` (int or float), inclusive range [lo, hi] (``hi`` None: no upper bound
    here; the endpoint checks it), and the value used when the parameter is absent."""

    kind: type
    lo: float
    hi: float | None
    default: float

    def describe(self) -> str:
        what = "an integer" if self.kind is int else "a number"
        return f"{what} in [{self.lo:g}, {self.hi:g}]" if self.hi is not None else f"{what} ≥ {self.lo:g}"

    def parse(self, name: str, raw: str):
        """The value of ``raw``, or :class:`BadRequest` naming ``name`` and ``raw``."""
        shown = raw if len(raw) <= 40 else raw[:40] + "…"
        pattern = _INT if self.kind is int else _FLOAT
        if not pattern.fullmatch(raw):
            raise BadRequest(f"{name} = {shown!r}: not {self.describe()}")
        value = self.kind(raw)
        if not math.isfinite(value) or value < self.lo or (self.hi is not None and value > self.hi):
            raise BadRequest(f"{name} = {shown!r}: out of range: {self.describe()}")
        return value


def parse_query(query: str, spec: dict[str, Param]) -> dict:
    """``{name: value}`` for every parameter of ``spec`` (absent: its default) from a URL's query string."""
    if query.count("&") >= MAX_FIELDS:
        raise BadRequest(f"too many parameters (at most {MAX_FIELDS})")
    try:
        pairs = urllib.parse.parse_qsl(query, keep_blank_values=True, strict_parsing=bool(query),
                                       encoding="utf-8", errors="strict", max_num_fields=MAX_FIELDS)
    except (ValueError, UnicodeDecodeError):
        raise BadRequest(f"malformed query {query[:60]!r}: expected name=value&…") from None
    seen: dict[str, str] = {}
    for name, raw in pairs:
        if name not in spec:
            known = ", ".join(spec) or "none"
            raise BadRequest(f"unknown parameter {name[:40]!r} (this page takes: {known})")
        if name in seen:
            raise BadRequest(f"{name} is given twice")
        seen[name] = raw
    return {name: (p.parse(name, seen[name]) if name in seen else p.default) for name, p in spec.items()}
