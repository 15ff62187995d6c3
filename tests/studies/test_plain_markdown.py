"""studies.plain_markdown: table.md's text is literal once rendered (checked with markdown-it's GFM
table parser) and carries no backslash a terminal reader would trip over where none is needed."""

import re

import pytest

from studies.plain_markdown import markdown_table, markdown_text

from .fault_providers import HOSTILE_LABELS

markdown_it = pytest.importorskip("markdown_it")

TEXTS = (
    *HOSTILE_LABELS,
    "settling time ∞ > 2 s; overshoot 22.7 % > 10 %",
    "peak |u| (N m)",
    "a|b || c",
    "&amp; &#35; & co",
    "**bold** __strong__ _em_ x_y a * b",
    "~~struck~~ ~5 %",
    "1. numbered",
    "> quoted",
    "# heading",
    "back\\slash \\* \\",
    "<http://x> <b>tag</b> a < b",
    "[ref]: http://x",
)


def _shown(text):
    """What `text` becomes for the reader: '|' around a word as ‖, any other '|' as '/'."""
    return re.sub(r"(?<![^\s(])\|([^|\s]+)\|(?=$|[\s,.;:)²])", "‖\\1‖", text).replace("|", "/")


def _rendered(markdown: str) -> list:
    """The inline tokens of `markdown` (GFM tables and strikethrough on): (type, content) of every child."""
    md = markdown_it.MarkdownIt("commonmark").enable(["table", "strikethrough"])
    return [t for t in md.parse(markdown) if t.type == "inline"]


@pytest.mark.parametrize("text", TEXTS)
def test_a_cell_shows_the_text_and_starts_no_syntax(text):
    cell = markdown_text(text)
    table = f"| a | b |\n|---|---|\n| {cell} | x |\n"
    inline = _rendered(table)
    assert [t.content for t in inline][-1] == "x"  # the row kept its two cells
    children = inline[-2].children
    assert {c.type for c in children} <= {"text"}, children
    assert "".join(c.content for c in children) == _shown(text)


@pytest.mark.parametrize("text", TEXTS)
def test_a_list_item_shows_the_text(text):
    (inline,) = _rendered(f"- {markdown_text(text)}\n")
    assert {c.type for c in inline.children} <= {"text"}
    assert "".join(c.content for c in inline.children) == _shown(text)


def test_plain_text_keeps_no_backslash():
    for text in ("settling time ∞ > 2 s; overshoot 22.7 % > 10 %", "mpc_typo: skipped", "a * b", "peak |u| (N m)"):
        assert "\\" not in markdown_text(text)


def test_a_table_has_no_escaped_bar():
    table = markdown_table([{"k": "a | b", "v": 1.0}], [("k", "peak |u|", str), ("v", "x > 1", str)])
    assert "\\" not in table and table.splitlines()[0] == "| peak ‖u‖ | x > 1 |"
