"""Markdown that reads cleanly as plain text: table.md is read in a terminal as often as rendered.

`markdown_text(text)` shows `text` literally once rendered (GitHub Flavored Markdown: no
formatting, link, HTML or entity comes out of it) with as few backslashes as that needs: a
character is escaped only where it would start syntax (a ``<`` before a letter, an ``&`` that
spells an entity, a ``*`` or ``_`` that could open or close emphasis, a list marker at the start),
so "settling time ∞ > 2 s" is written as it is. GFM splits a table row at every ``|``, even inside
a code span, and ``\\|`` is what a terminal would show: a pair around a word (``|u|``) becomes
``‖u‖`` and any other ``|`` a ``/``. `markdown_table` is `models.files.markdown_table` with every
header and cell written so.
"""

from __future__ import annotations

import re
import string

from models.files import markdown_table as _markdown_table

__all__ = ["markdown_text", "markdown_table"]

#: |x| around one word: an absolute value or norm, shown as ‖x‖.
_BARS = re.compile(r"(?<![^\s(])\|([^|\s]+)\|(?=$|[\s,.;:)²])")
_ENTITY = re.compile(r"&(#\d+|#[xX][0-9A-Fa-f]+|[A-Za-z][A-Za-z0-9]*);")
_LEADING = re.compile(r"^(\s*)([-+*>#]|\d+[.)])(?=\s|$)")
_PUNCTUATION = set(string.punctuation)


def _escaped(text: str, i: int, brackets: bool) -> bool:
    """Whether character i of `text` would start Markdown syntax where it stands."""
    ch = text[i]
    before = text[i - 1] if i else " "
    after = text[i + 1] if i + 1 < len(text) else " "
    if ch == "\\":
        return after in _PUNCTUATION or after == " " and i + 1 == len(text)
    if ch == "`":
        return True
    if ch in "*~":
        return not (before.isspace() and after.isspace())
    if ch == "_":
        return not (before.isspace() and after.isspace()) and not (before.isalnum() and after.isalnum())
    if ch == "<":
        return after.isalpha() or after in "/!?"
    if ch == "&":
        return bool(_ENTITY.match(text, i))
    if ch in "[]":
        return brackets
    return False


def markdown_text(text) -> str:
    """`text` on one line, shown literally in GFM (inline or in a table cell), escaped only where needed."""
    text = str(text).replace("\r", " ").replace("\n", " ")
    text = _BARS.sub("‖\\1‖", text).replace("|", "/")
    brackets = "[" in text and "]" in text
    out = "".join("\\" + ch if _escaped(text, i, brackets) else ch for i, ch in enumerate(text))
    return _LEADING.sub(lambda m: m.group(1) + m.group(2)[:-1] + "\\" + m.group(2)[-1], out)


def markdown_table(rows, columns) -> str:
    """`models.files.markdown_table` of these (key, header, format) columns, headers and cells by `markdown_text`."""
    written = [(key, markdown_text(header), lambda v, f=fmt: markdown_text(f(v))) for key, header, fmt in columns]
    return _markdown_table(rows, written, literal=False)
