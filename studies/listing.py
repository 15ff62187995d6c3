"""What the registered case studies are, read from their source without importing them.

Importing a case file imports CasADi, python-control and the design toolbox
(seconds); listing names, titles, scenarios and declared controllers, sizing
a progress bar, or checking a command line needs none of that. This module
reads each ``studies/cases/<name>.py``'s ``CASE = CaseStudy(...)`` with
`ast`: the literal keyword values (or module-level constants they name), the
scenario builders called, and the declared controller labels (the case's
``controllers=`` or `studies.case.CONTROLLERS`). `tests/studies/test_registry.py`
checks it agrees with the imported registry on every case.

It knows only what is written literally; a case that computes its plant name
or numeral is not listed here (the imported registry, `studies.cases`, still is).
"""

from __future__ import annotations

import ast
import functools
from dataclasses import dataclass
from pathlib import Path

from . import SCENARIO_NAMES

HERE = Path(__file__).resolve().parent

#: Scenario builders of `studies.case` and the scenario names they make.
BUILDERS = {
    "step": ("step",),
    "series_of_steps": ("steps",),
    "input_disturbance": ("disturbance",),
    "measurement_noise": ("noise",),
    "parameter_monte_carlo": ("mc",),
    "standard_scenarios": SCENARIO_NAMES,
}

_ROMAN = {"I": 1, "V": 5, "X": 10, "L": 50, "C": 100}


@dataclass(frozen=True)
class Listed:
    """One case study as its file declares it: name, numeral, source, scenario names, declared controllers."""

    name: str
    numeral: str
    source: str
    scenarios: tuple
    controllers: tuple


def _constants(tree: ast.Module) -> dict:
    """Module-level NAME = <literal> assignments."""
    found = {}
    for node in tree.body:
        if isinstance(node, ast.Assign) and len(node.targets) == 1 and isinstance(node.targets[0], ast.Name):
            try:
                found[node.targets[0].id] = ast.literal_eval(node.value)
            except ValueError:
                continue
    return found


def _value(node: ast.AST, constants: dict):
    """A literal, a module-level constant, `studies.case.CONTROLLERS`, or a sum of those (tuples)."""
    if isinstance(node, ast.Name) and node.id in constants:
        return constants[node.id]
    if isinstance(node, ast.Name) and node.id == "CONTROLLERS":
        return default_controllers()
    if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Add):
        return _value(node.left, constants) + _value(node.right, constants)
    return ast.literal_eval(node)


def _scenarios(node: ast.AST) -> tuple:
    calls = node.elts if isinstance(node, (ast.Tuple, ast.List)) else [node]
    names: list = []
    for call in calls:
        if not (isinstance(call, ast.Call) and isinstance(call.func, ast.Name) and call.func.id in BUILDERS):
            raise ValueError(f"scenarios must call the studies.case builders, found {ast.dump(call)[:80]}")
        names += BUILDERS[call.func.id]
    return tuple(names)


@functools.lru_cache(maxsize=1)
def default_controllers() -> tuple:
    """`studies.case.CONTROLLERS`, read from its source."""
    return _constants(ast.parse((HERE / "case.py").read_text(encoding="utf-8")))["CONTROLLERS"]


def read(path: Path) -> Listed | None:
    """The case declared in the file at `path`, or None if it declares no ``CASE = CaseStudy(...)``."""
    tree = ast.parse(Path(path).read_text(encoding="utf-8"))
    constants = _constants(tree)
    for node in tree.body:
        if (
            isinstance(node, ast.Assign)
            and len(node.targets) == 1
            and isinstance(node.targets[0], ast.Name)
            and node.targets[0].id == "CASE"
            and isinstance(node.value, ast.Call)
            and getattr(node.value.func, "id", None) == "CaseStudy"
        ):
            keywords = {k.arg: k.value for k in node.value.keywords}
            return Listed(
                name=_value(keywords["plant"], constants),
                numeral=_value(keywords["numeral"], constants),
                source=_value(keywords["source"], constants) if "source" in keywords else "",
                scenarios=_scenarios(keywords["scenarios"]),
                controllers=tuple(_value(keywords["controllers"], constants))
                if "controllers" in keywords
                else default_controllers(),
            )
    return None


def _numeral(numeral: str) -> int:
    values = [_ROMAN[c] for c in numeral]
    return sum(-v if i + 1 < len(values) and v < values[i + 1] else v for i, v in enumerate(values))


@functools.lru_cache(maxsize=1)
def cases() -> tuple[Listed, ...]:
    """Every case file's declaration, in the registry's order (by numeral, then file name)."""
    found = [
        listed
        for path in sorted((HERE / "cases").glob("*.py"))
        if not path.name.startswith("_")
        if (listed := read(path)) is not None
    ]
    return tuple(sorted(found, key=lambda c: _numeral(c.numeral)))


def names() -> tuple[str, ...]:
    """The case studies' names, as `studies.names()` gives them for the shipped cases."""
    return tuple(c.name for c in cases())


def get(name: str) -> Listed:
    for listed in cases():
        if listed.name == name:
            return listed
    raise ValueError(f"unknown plant {name!r}; valid plants: {', '.join(names())}")
