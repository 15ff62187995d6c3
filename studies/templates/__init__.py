"""The pages' Jinja2 templates (the ``*.html.j2`` files beside this module, shipped as package data)
and the one environment that renders them.

Every page a study writes (``index.html``, ``animation.html``) and every HTML fragment of the
designer's page comes from a template here; the code prepares the data, the template says where it
goes. Escaping is the engine's: autoescape is on for every template, so every ``{{ value }}`` is
escaped unless the template marks it ``|safe`` (an SVG drawn by matplotlib, a fragment rendered by
another template) or it is already markup (a macro's result, ``|tojson``).

The escaping rule is the standard library's `html.escape` (``&``, ``<``, ``>``, ``"`` and ``'``;
quotes written ``&quot;`` and ``&#x27;``), where MarkupSafe, Jinja2's default, writes ``&#34;`` and
``&#39;``: the same meaning in HTML, and the pages keep the bytes they had when they were written
with `html.escape` (tests compare titles with ``html.escape``).

Jinja2 is imported at the first render (`models.deferred`), not with the writers.
"""

from __future__ import annotations

import functools
import html
from typing import TYPE_CHECKING, Any

from models import deferred

if TYPE_CHECKING:
    import jinja2
else:
    jinja2 = deferred.module("jinja2")

#: ``|tojson`` writes compact JSON in the key order given, non-ASCII characters as they are (Jinja2's
#: default sorts the keys); it always replaces ``<``, ``>``, ``&`` and ``'`` by ``\\u`` escapes, so no
#: string in the data can close a ``<script>``.
JSON_OPTIONS = {"separators": (",", ":"), "ensure_ascii": False}


class Escaped(str):
    """Text already escaped for HTML: the engine inserts it as it is (MarkupSafe's ``__html__`` protocol)."""

    __slots__ = ()

    def __html__(self) -> str:
        return str(self)


def escape(value: Any) -> Any:
    """The environment's ``finalize``: `value` escaped with `html.escape`, markup (a macro's result,
    ``|safe``, ``|tojson``) left as it is."""
    if hasattr(value, "__html__"):
        return value
    return Escaped(html.escape(str(value)))


@functools.cache
def environment() -> jinja2.Environment:
    """The environment of the package's templates: autoescape on, `escape` as the escaping rule,
    lines holding only a block tag removed (``trim_blocks``, ``lstrip_blocks``), a template's last
    newline kept, and an undefined name an error (never an empty string in a page)."""
    env = jinja2.Environment(
        loader=jinja2.PackageLoader("studies", "templates"),
        autoescape=True,
        finalize=escape,
        trim_blocks=True,
        lstrip_blocks=True,
        keep_trailing_newline=True,
        undefined=jinja2.StrictUndefined,
    )
    env.policies["json.dumps_kwargs"] = dict(JSON_OPTIONS)
    return env


def render(name: str, /, **context: Any) -> str:
    """The template `name` (such as "index.html.j2") rendered with `context`."""
    return environment().get_template(name).render(**context)


def macro(name: str, macro_name: str):
    """The macro `macro_name` of template `name`, as a function returning markup (a `str`)."""
    return getattr(environment().get_template(name).module, macro_name)
