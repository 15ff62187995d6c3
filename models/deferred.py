"""Third-party modules imported on their first use, not when ours are.

python-control, SciPy, pandas, Matplotlib, SymPy, cvxpy and OSQP take from
0.1 to 3 s each to import, and every case file imports the toolbox that uses
them. With ``control = deferred.module("control")`` at the top of a module,
``control.tf(...)`` imports python-control at that first call; so
``python -m studies --list``, ``--help`` and a command line refused for a bad
argument answer without loading any of them.

Where an annotation names the module's types, import it for the type checker
only (``if TYPE_CHECKING: import pandas as pd`` ``else: pd = deferred.module("pandas")``).
"""

from __future__ import annotations

import importlib
from typing import Any


class Deferred:
    """A stand-in for the module `name`: its first attribute access imports it."""

    __slots__ = ("_name", "_module")

    def __init__(self, name: str):
        self._name = name
        self._module: Any = None

    def __getattr__(self, attribute: str) -> Any:
        """The real module's attribute, importing the module the first time."""
        if self._module is None:
            self._module = importlib.import_module(self._name)
        return getattr(self._module, attribute)

    def __repr__(self) -> str:
        state = "imported" if self._module is not None else "not imported yet"
        return f"<deferred module {self._name!r}, {state}>"


def module(name: str) -> Any:
    """The module `name`, imported when one of its attributes is first used."""
    return Deferred(name)
