"""Text put into an HTML page: the one place that makes it safe (the viewer, `compare.pages.viewer`).

Data embedded in a page (run.json's command and descriptions, labels, pilot and vehicle names, anything a
run folder or a scenario file holds) is JSON in which no character can end the element it is in or start
markup: `<`, `>` and `&` are written as JSON escapes (`\\u003c`...), as are U+2028 and U+2029 (line
terminators in older JavaScript). The browser's `JSON.parse` gives the text back unchanged. This is safe by
construction, whatever the case or spelling of a closing tag; there is no list of dangerous strings to keep
up to date. Text outside a script goes through `html.escape` (quotes included).
"""
from __future__ import annotations

import html
import json
import re
from typing import Any

_JSON_UNSAFE = {"<": "\\u003c", ">": "\\u003e", "&": "\\u0026", "\u2028": "\\u2028", "\u2029": "\\u2029"}
_JSON_UNSAFE_RE = re.compile("[<>&\u2028\u2029]")
_SCRIPT_END_RE = re.compile(r"<(/script|!--)", re.IGNORECASE)


def json_for_script(data: Any) -> str:
    """`data` as JSON that can stand anywhere inside a `<script>` element (or an HTML attribute) of a page.

    Raises:
        ValueError: a NaN or an infinity in `data` (not JSON).
    """
    text = json.dumps(data, separators=(",", ":"), allow_nan=False, ensure_ascii=False)
    return _JSON_UNSAFE_RE.sub(lambda m: _JSON_UNSAFE[m.group(0)], text)


def text_for_html(text: str) -> str:
    """`text` as HTML text or a quoted attribute value: `<`, `>`, `&` and both quotes escaped."""
    return html.escape(text, quote=True)


def code_for_script(code: str) -> str:
    """JavaScript source of our own or of an installed package (plotly.js) put inline in a `<script>`: every
    `</script` and `<!--`, in any case, is written `<\\/script` / `<\\!--` (the same code to JavaScript).
    Data never goes this way: it goes through `json_for_script`."""
    return _SCRIPT_END_RE.sub(lambda m: "<\\" + m.group(1), code)
