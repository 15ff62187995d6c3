"""The one writer of files and tables: atomic files, JSON, CSV, Markdown and HTML tables.

Every file is written atomically: into a temporary file in the destination
folder, flushed, then renamed over the destination (`os.replace`), so an
interrupted run leaves either the previous file or the new one, never half
of one.

JSON conventions: SI units, angles in rad; a complex number is the pair
``[re, im]``; non-finite numbers are the strings ``"inf"``, ``"-inf"`` and
``"nan"`` (JSON has no infinity, and ``null`` would lose the sign); numpy
scalars and arrays become numbers and nested lists; a SISO transfer function
becomes ``{"num": [...], "den": [...]}`` in descending powers of s (or z) and a
state-space model ``{"A": ..., "B": ..., "C": ..., "D": ...}``.
"""

from __future__ import annotations

import contextlib
import html
import json
import math
import os
import re
import secrets
import shutil
import tempfile
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from . import deferred

control = deferred.module("control")

JSON_CONVENTIONS = (
    "SI units, angles in rad; complex numbers as [re, im]; non-finite numbers as the strings "
    "'inf', '-inf', 'nan'; transfer functions as {num, den} in descending powers"
)


# ---------------------------------------------------------------------------- atomic files
@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside `path`; rename it onto `path` when the block succeeds.

    For writers that want a file name (matplotlib's savefig, Pillow). The
    temporary file keeps the destination's suffix so format detection works.
    On an exception the temporary file is removed and `path` is untouched.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=f".tmp{path.suffix}", dir=path.parent)
    os.close(handle)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        with open(tmp_path, "rb+") as f:
            os.fsync(f.fileno())
        os.chmod(tmp_path, 0o644)
        os.replace(tmp_path, path)
    finally:
        if tmp_path.exists():
            tmp_path.unlink()


def write_text(path: str | os.PathLike, text: str) -> Path:
    """Write `text` (UTF-8) to `path` atomically; returns the path."""
    return write_bytes(path, text.encode("utf-8"))


def write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Write `data` to `path` atomically; returns the path."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)


def fresh_folder(parent: str | os.PathLike, prefix: str, suffix: str = "") -> Path:
    """A new, uniquely named folder in `parent` (created if needed), with the permissions a plain
    mkdir gives under the current umask (not the 0700 of `tempfile.mkdtemp`)."""
    parent = Path(parent)
    parent.mkdir(parents=True, exist_ok=True)
    folder = Path(tempfile.mkdtemp(prefix=prefix, suffix=suffix, dir=parent))
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(folder, 0o777 & ~umask)
    return folder


def replace_folder(source: str | os.PathLike, target: str | os.PathLike) -> Path:
    """Put the folder `source` in the place of `target`, replacing the folder there, by renames.

    `target` is renamed aside to a hidden sibling, `source` renamed onto `target`, and the old folder
    removed: `target` holds either every old file or every new one, never a mix (between the two
    renames it is briefly absent).

    A symbolic link `target` is followed: the folder it points to is the one replaced, and the link
    stays as it is (renaming the link aside would leave it hidden there, and the folder it points to
    untouched). When `source` is on another filesystem than the folder replaced, it is first copied
    into a hidden sibling of that folder (then renamed as above) and removed.

    Returns
    -------
    Path
        `target` as given (the link, for a link).

    Raises
    ------
    NotADirectoryError
        When `target` exists and is not a folder (it is left alone).
    """
    source, given = Path(source), Path(target)
    target = Path(os.path.realpath(given)) if given.is_symlink() else given
    if target.exists() and not target.is_dir():
        raise NotADirectoryError(f"cannot replace {str(given)!r} by a folder: it is a file")
    copied = None
    if os.stat(source).st_dev != os.stat(target.parent).st_dev:
        copied = fresh_folder(target.parent, f".{target.name}.", ".partial")
        try:
            shutil.copytree(source, copied, dirs_exist_ok=True)
        except BaseException:
            shutil.rmtree(copied, ignore_errors=True)
            raise
    old = None
    if target.exists():
        old = target.with_name(f".{target.name}.old-{secrets.token_hex(4)}")
        os.rename(target, old)
    try:
        os.rename(copied or source, target)
    except BaseException:
        if old is not None:
            os.rename(old, target)
        if copied is not None:
            shutil.rmtree(copied, ignore_errors=True)
        raise
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)
    if copied is not None:
        shutil.rmtree(source, ignore_errors=True)
    return given


def check_writable(folder: str | os.PathLike) -> Path:
    """Create `folder` if needed and prove a file can be written in it.

    Raises
    ------
    OSError
        With the folder named, when it cannot be created or written.
    """
    folder = Path(folder)
    try:
        folder.mkdir(parents=True, exist_ok=True)
        handle, probe = tempfile.mkstemp(prefix=".write-test.", dir=folder)
        os.close(handle)
        os.unlink(probe)
    except OSError as err:
        raise OSError(f"cannot write to the output folder {str(folder)!r}: {err.strerror or err}") from err
    return folder


# ---------------------------------------------------------------------------- JSON
def to_jsonable(value: Any, *, encode: bool = True) -> Any:
    """`value` as plain JSON types following the module's conventions.

    With ``encode=False`` only numpy goes: numpy scalars and arrays become Python
    numbers and nested lists, while complex numbers, non-finite floats and other
    objects stay as they are (homework records keep complex poles as complex).
    """
    if isinstance(value, Mapping):
        return {(str(k) if encode else k): to_jsonable(v, encode=encode) for k, v in value.items()}
    if isinstance(value, (str, bool)) or value is None:
        return value
    if isinstance(value, np.bool_):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        value = float(value)
        if encode and math.isnan(value):
            return "nan"
        if encode and math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return value
    if isinstance(value, (complex, np.complexfloating)):
        if not encode:
            return complex(value)
        return [to_jsonable(float(value.real)), to_jsonable(float(value.imag))]
    if isinstance(value, np.ndarray):
        if value.ndim == 0:
            return to_jsonable(value.item(), encode=encode)
        return [to_jsonable(v, encode=encode) for v in value.tolist()]
    if isinstance(value, (list, tuple)):
        return [to_jsonable(v, encode=encode) for v in value]
    if not encode:
        return value
    model = _lti_as_dict(value)
    if model is not None:
        return to_jsonable(model)
    raise TypeError(f"cannot write {type(value).__name__} to JSON: {value!r}")


def _lti_as_dict(value) -> dict | None:
    """A SISO python-control transfer function as {num, den[, dt]}, a state space as {A, B, C, D[, dt]},
    anything else None."""
    if isinstance(value, control.TransferFunction) and value.issiso():
        return {
            "num": np.ravel(value.num[0][0]),
            "den": np.ravel(value.den[0][0]),
            **({"dt": value.dt} if value.dt else {}),
        }
    if isinstance(value, control.StateSpace):
        return {"A": value.A, "B": value.B, "C": value.C, "D": value.D, **({"dt": value.dt} if value.dt else {})}
    return None


def dumps(value: Any) -> str:
    """JSON text of `value` (see `to_jsonable`), indented, keys in insertion order."""
    return json.dumps(to_jsonable(value), indent=2, allow_nan=False) + "\n"


def write_json(path: str | os.PathLike, value: Any) -> Path:
    """Write `value` as JSON (`dumps`) to `path` atomically; returns the path."""
    return write_text(path, dumps(value))


# ---------------------------------------------------------------------------- tables
def format_number(value: Any, digits: int = 4) -> str:
    """A table cell: 4 significant digits, '—' for NaN, '∞' for infinity, text as is."""
    if value is None:
        return "—"
    if isinstance(value, str):
        return value
    if isinstance(value, (bool, np.bool_)):
        return "yes" if value else "no"
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    value = float(value)
    if math.isnan(value):
        return "—"
    if math.isinf(value):
        return "∞" if value > 0 else "−∞"
    if value == 0:
        return "0"
    text = f"{value:.{digits}g}"
    return text.replace("e-0", "e-").replace("e+0", "e")


Column = tuple  # (source column, header, converter value -> cell text)


def markdown_table(rows: Sequence[Mapping], columns: Sequence[Column], literal: bool = True) -> str:
    """A GitHub Markdown table; `columns` are (key, header, format) with format value -> str.

    With `literal` (the default) every cell is shown as written (`escape_markdown`): labels and
    messages never become formatting, links or HTML. ``literal=False`` is for cells written as
    Markdown on purpose (code spans in a document's text): only '|' and line breaks are escaped.
    """
    escape = escape_markdown if literal else _escape_cell
    header = "| " + " | ".join(escape(h) for _, h, _ in columns) + " |"
    rule = "|" + "|".join("---" for _ in columns) + "|"
    body = ["| " + " | ".join(escape(fmt(row.get(key))) for key, _, fmt in columns) + " |" for row in rows]
    return "\n".join([header, rule, *body]) + "\n"


def _escape_cell(text: str) -> str:
    """A Markdown table cell kept on one line: '|' escaped, line breaks as spaces."""
    return text.replace("|", "\\|").replace("\n", " ")


def html_table(rows: Sequence[Mapping], columns: Sequence[Column]) -> str:
    """The same table as HTML."""
    head = "".join(f"<th>{html.escape(h)}</th>" for _, h, _ in columns)
    body = "".join(
        "<tr>" + "".join(f"<td>{html.escape(fmt(row.get(key)))}</td>" for key, _, fmt in columns) + "</tr>"
        for row in rows
    )
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


#: Characters that start Markdown syntax anywhere in a line (emphasis, code, links, inline HTML,
#: entities, strikethrough, table cells, headings); each is escaped with a backslash.
_MARKDOWN_SPECIAL = re.compile(r"([\\`*_\[\]<>|~&#])")
#: A list or block-quote marker at the start of a text (escaped too).
_MARKDOWN_LEADING = re.compile(r"^(\s*)([-+]|\d+[.)])(?=\s|$)")


def escape_markdown(text: str) -> str:
    """`text` shown literally in Markdown, on one line: what a label says is what the reader sees,
    never formatting, a link or HTML (the counterpart of `html.escape`)."""
    text = _MARKDOWN_SPECIAL.sub(r"\\\1", str(text).replace("\r", " ").replace("\n", " "))
    return _MARKDOWN_LEADING.sub(lambda m: m.group(1) + m.group(2)[:-1] + "\\" + m.group(2)[-1], text)


def fill_template(template: str, values: Mapping[str, str]) -> str:
    """`template` with every placeholder (a key of `values`) replaced by its value, in one pass:
    a value that contains a placeholder is inserted as it is, never substituted again."""
    if not values:
        return template
    pattern = re.compile("|".join(re.escape(key) for key in sorted(values, key=len, reverse=True)))
    return pattern.sub(lambda m: values[m.group(0)], template)


def scaled(scale: float = 1.0, digits: int = 4) -> Callable[[Any], str]:
    """A cell formatter multiplying numbers by `scale` (for example rad -> deg) first."""

    def fmt(value):
        if isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool):
            return format_number(float(value) * scale, digits)
        return format_number(value, digits)

    return fmt


def write_csv(path: str | os.PathLike, frame) -> Path:
    """Write a pandas DataFrame as CSV (full precision, 'inf' for infinity, empty for NaN)."""
    return write_text(path, frame.to_csv(index=False, float_format="%.10g"))
