"""The registry of case studies: the only list of plants the studies know.

Every module of this package that defines ``CASE = CaseStudy(...)`` is a
case study; `names()` lists them by their Roman numeral (the text's order).
`register` adds a user's case at run time. Adding a plant to the studies is
one new module here (and its plant declaration, if the plant is new).

The case files are imported at the first lookup. Everything that needs the
cases reads them here, ``python -m studies --list`` and the command line's
checks included: the heavy third-party modules their designs use are imported
at their first use (`models.deferred`), so importing every case stays quick.
"""

from __future__ import annotations

import importlib
import pkgutil

from ..case import CaseStudy, numeral_value

_REGISTRY: dict[str, CaseStudy] = {}
_DISCOVERED: list[bool] = []


def _discover() -> None:
    """Import every module of this package once and register the `CaseStudy` each one names ``CASE``."""
    if _DISCOVERED:
        return
    _DISCOVERED.append(True)
    for info in pkgutil.iter_modules(__path__):
        module = importlib.import_module(f"{__name__}.{info.name}")
        case = getattr(module, "CASE", None)
        if isinstance(case, CaseStudy):
            _REGISTRY.setdefault(case.plant, case)


def names() -> tuple[str, ...]:
    """Names of the registered case studies, by numeral (then by registration order)."""
    _discover()
    cases = list(_REGISTRY.values())
    order = sorted(range(len(cases)), key=lambda i: (numeral_value(cases[i].numeral), i))
    return tuple(cases[i].plant for i in order)


def get(name: str) -> CaseStudy:
    """The case study `name` (ValueError listing the registered ones otherwise)."""
    _discover()
    if name not in _REGISTRY:
        raise ValueError(f"unknown plant {name!r}; valid plants: {', '.join(names())}")
    return _REGISTRY[name]


def register(case: CaseStudy, replace: bool = False) -> CaseStudy:
    """Add `case` to the registry under its plant's name; returns it.

    Raises
    ------
    ValueError
        When a case of that name is registered already and `replace` is False.
    """
    if not isinstance(case, CaseStudy):
        raise TypeError(f"register needs a studies.CaseStudy, got {type(case).__name__}")
    numeral_value(case.numeral)
    _discover()
    if case.plant in _REGISTRY and not replace:
        raise ValueError(f"a case study named {case.plant!r} is registered already; pass replace=True to replace it")
    _REGISTRY[case.plant] = case
    return case


def unregister(name: str) -> None:
    """Remove the case `name` from the registry (ValueError if it is not registered)."""
    get(name)
    del _REGISTRY[name]
