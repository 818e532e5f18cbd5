"""Pages that carry untrusted text safely: the HTML of ``gonio report`` and ``gonio view``.

Every string that comes from outside — a file or directory name, a manifest's material or notes, a fit
JSON's model label, an exception's message, a URL parameter — is escaped *where it lands*, by the one
function for that context:

- :func:`text`: HTML text and quoted attribute values (``& < > " '`` as character references,
  HTML Living Standard §13.1.2.6 and §13.5);
- :func:`plotly_text`: the labels Plotly draws (titles, legend, axis titles), which Plotly parses as
  a small HTML subset (``<b>``, ``<a href>``, ``<br>``) and whose entities it decodes
  (plotly.js ``svg_text_utils.convertToTspans``): ``& < >`` escaped, so a name is shown as written;
- :func:`json_data`: JSON inside a ``<script type="application/json">`` data block: ``<``, ``>``,
  ``&``, U+2028 and U+2029 as ``\\uXXXX`` escapes (RFC 8259 §7), so no ``</script>`` or ``<!--`` can
  end or change the block (HTML Living Standard §4.12.1.3, "Restrictions for contents of script
  elements").

As a second line of defence, every page states a Content-Security-Policy (W3C CSP Level 3) that lets
only the page's own scripts run: each inline script is allowed by its SHA-256 hash (CSP3 §8.3,
"hash-source"), so an injected ``<script>`` or ``onerror=`` handler is refused by the browser even if
an escape were missed. Plotly sets inline styles as it draws, so styles are ``'unsafe-inline'``; no
resource may come from another origin.
"""

from __future__ import annotations

import base64
import functools
import hashlib
import html
import json
import re

__all__ = ["text", "plotly_text", "json_data", "script_hash", "content_security_policy", "Page"]

#: What an inline script must not hold: ``</script`` in any ASCII letter case (what an HTML parser ends the element at;
#: the same test as ``"</script" in source.lower()``, without a lowered copy of the text) or ``<!--``.
_SCRIPT_END = re.compile(r"</script|<!--", re.IGNORECASE | re.ASCII)
_JSON_ESCAPES = {"<": "\\u003c", ">": "\\u003e", "&": "\\u0026", "\u2028": "\\u2028", "\u2029": "\\u2029"}


def text(value) -> str:
    """``str(value)`` for HTML text or a quoted attribute value: ``& < > " '`` as character references."""
    return html.escape(str(value), quote=True)


def plotly_text(value) -> str:
    """``str(value)`` for a label Plotly draws (title, trace name, axis title): ``& < >`` escaped, which
    Plotly decodes back, so the label is shown as written and never parsed as markup."""
    return html.escape(str(value), quote=False)


def json_data(value) -> str:
    """``value`` as JSON text safe inside a ``<script type="application/json">`` block: ``< > &`` U+2028
    U+2029 written as ``\\uXXXX`` escapes — the same JSON for ``JSON.parse``, and no ``</script>`` or
    ``<!--`` inside. NaN and infinities are refused (JSON has none: write ``null``)."""
    s = json.dumps(value, ensure_ascii=False, allow_nan=False)
    for ch, esc in _JSON_ESCAPES.items():
        s = s.replace(ch, esc)
    return s


@functools.lru_cache(maxsize=16)  # a page's scripts are the same few texts (Plotly's 4.8 MB among them)
def script_hash(source: str) -> str:
    """The CSP hash-source of an inline script: ``'sha256-BASE64'`` of its UTF-8 text (CSP3 §8.3)."""
    return "'sha256-" + base64.b64encode(hashlib.sha256(source.encode("utf-8")).digest()).decode("ascii") + "'"


def content_security_policy(scripts, *, same_origin: bool = False, header: bool = False) -> str:
    """The policy of a page whose only scripts are ``scripts`` (their text): nothing else runs, nothing is
    loaded from elsewhere. ``same_origin``: images and ``fetch`` from the page's own server (the viewer);
    ``header``: the directives only an HTTP header may carry (``frame-ancestors``: no other site frames it)."""
    own = " 'self'" if same_origin else ""
    directives = ["default-src 'none'", "script-src " + " ".join(sorted({script_hash(s) for s in scripts})),
                  "style-src 'unsafe-inline'", f"img-src data:{own}", "connect-src " + ("'self'" if same_origin else "'none'"),
                  "base-uri 'none'", "form-action 'none'", "object-src 'none'"]
    if header:
        directives.append("frame-ancestors 'none'")
    return "; ".join(directives)


class Page:
    """An HTML page assembled from escaped parts: ``add(markup)`` for body markup already escaped (built
    with :func:`text`), ``script(js)`` for the page's own inline scripts (fixed code: data go in
    :meth:`data` blocks), ``data(id, value)`` for JSON the scripts read. :meth:`render` writes the page
    with its Content-Security-Policy."""

    def __init__(self, title: str, style: str = "", *, same_origin: bool = False):
        self.title, self.style, self.same_origin = title, style, same_origin
        self.head_scripts: list[str] = []
        self.body: list[str] = []
        self.scripts: list[str] = []

    def add(self, markup: str) -> "Page":
        self.body.append(markup)
        return self

    def data(self, element_id: str, value, **attrs: str) -> "Page":
        """A JSON data block (not executed: no policy needed); ``attrs``: more attributes (``css_class``
        → ``class``, ``data_target`` → ``data-target``), escaped."""
        more = "".join(f' {"class" if k == "css_class" else k.replace("_", "-")}="{text(v)}"' for k, v in attrs.items())
        return self.add(f'<script type="application/json" id="{text(element_id)}"{more}>{json_data(value)}</script>')

    def script(self, source: str, *, head: bool = False) -> "Page":
        if _SCRIPT_END.search(source):
            raise ValueError("an inline script must not contain '</script' or '<!--' (it would end or change the element)")
        (self.head_scripts if head else self.scripts).append(source)
        return self

    def csp(self, *, header: bool = False) -> str:
        return content_security_policy([*self.head_scripts, *self.scripts], same_origin=self.same_origin, header=header)

    def render(self) -> str:
        head = "".join(f"<script>{s}</script>" for s in self.head_scripts)
        return (f'<!DOCTYPE html><html lang="en"><head><meta charset="utf-8">'
                f'<meta http-equiv="Content-Security-Policy" content="{text(self.csp())}">'
                f"<title>{text(self.title)}</title><style>{self.style}</style>{head}</head><body>"
                + "".join(self.body) + "".join(f"<script>{s}</script>" for s in self.scripts) + "</body></html>")
