"""Homework answers of a case study, keyed by item, and the errata that concern it.

The model items (.1 kinetic energy and .3 equations of motion as printed
expressions, .5 equilibria, .6 transfer functions, .7 state space) come from
the plant declared in `models`; the design items (.8, .10, .13, .14 and
.15-.17) from the case's answer providers (``provider(case)``, called
through `studies.provider_calls`); the errata from the case files' data (`studies.errata`).
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import re
from collections.abc import Mapping
from typing import TYPE_CHECKING

import numpy as np

import models
from models import deferred, symbolic
from models.linear import clean_tf, tf_string

from . import cases
from .case import CaseStudy
from .errata import errata_of
from .provider_calls import call_all, resolve

if TYPE_CHECKING:
    import control
else:
    control = deferred.module("control")


def _coordinate_tf(lin: models.LinearModel, coordinate: str, input_name: str) -> control.TransferFunction:
    """Transfer function from `input_name` to the state `coordinate` (cleaned as `LinearModel.tf` does)."""
    i = lin.state_names.index(coordinate)
    row = np.eye(lin.nx)[i : i + 1]
    single = dataclasses.replace(lin, C=row, D=np.zeros((1, lin.nu)), ye=lin.xe[i : i + 1], output_names=(coordinate,))
    return control.minreal(single.tf(coordinate, input_name), verbose=False)


def printed_model(plant: models.Plant, numeral: str) -> dict:
    """The .1 and .3 answers: kinetic energy and equations of motion derived from the declaration.

    Each as sympy text and as LaTeX (dots for time derivatives); the equations
    read M(q) q̈ = Q − C(q, q̇) q̇ − ∂V/∂q, one per coordinate. Computed once per
    declaration (simplifying takes a second or two).
    """
    return copy.deepcopy(_printed(plant.declaration, numeral))


@functools.lru_cache(maxsize=16)
def _printed(declaration, numeral: str) -> dict:
    """The .1 and .3 answers of `declaration` (cached: `printed_model` hands out copies)."""
    T = symbolic.kinetic_energy(declaration)
    equations = symbolic.equations_of_motion(declaration)
    return {
        f"{numeral}.1": {"T": str(T), "latex": f"$T = {symbolic.latex(T, declaration)}$"},
        f"{numeral}.3": {
            "equations": [f"{e.lhs} = {e.rhs}" for e in equations],
            "latex": [f"${symbolic.latex(e, declaration)}$" for e in equations],
        },
    }


def model_answers(study: CaseStudy) -> dict:
    """The .1, .3, .5, .6 and .7 answers from the plant's model (SI units, angles in rad).

    Returns
    -------
    dict item -> dict: ".1"/".3" the printed kinetic energy and equations of
    motion, ".5" the standard equilibrium and its linearization, ".6" the
    transfer functions from the input to each output (and the cascade of the
    successive-loop designs), ".7" the state-space matrices.
    """
    n = study.numeral
    plant = models.get(study.plant)
    xe, ue = plant.equilibrium()
    lin = plant.linearize(xe, ue)
    u_name = plant.input_names[0]
    out = printed_model(plant, n) | {
        f"{n}.5": {
            "x_e": dict(zip(plant.state_names, xe)),
            "u_e": dict(zip(plant.input_names, ue)),
            "A": lin.A,
            "B": lin.B,
        },
        f"{n}.6": {f"{o}/{u_name}": lin.tf(o, u_name) for o in plant.output_names},
        f"{n}.7": {
            "states": list(plant.state_names),
            "outputs": list(plant.output_names),
            "A": lin.A,
            "B": lin.B,
            "C": lin.C,
            "D": lin.D,
        },
    }
    if study.cascade:
        inner, outer = study.cascade
        name, overrides = study.cascade_model or (study.plant, {})
        model = models.get(name, **dict(overrides))
        mlin = model.linearize()
        g_inner = _coordinate_tf(mlin, inner, model.input_names[0])
        g_outer = clean_tf(control.minreal(_coordinate_tf(mlin, outer, model.input_names[0]) / g_inner, verbose=False))
        where = (
            ""
            if name == study.plant
            else f" ({name}" + "".join(f", {k} = {v:g}" for k, v in dict(overrides).items()) + ")"
        )
        out[f"{n}.6"] |= {
            f"cascade inner {inner}/{model.input_names[0]}{where}": g_inner,
            f"cascade outer {outer}/{inner}{where}": g_outer,
        }
    return out


def provider_answers(study: CaseStudy, strict: bool = False) -> tuple[dict, list]:
    """The design answers from the study's answer providers (each called as ``provider(study)``),
    merged by item (the first provider's value of a name is kept), and notes on what was skipped."""
    found, notes = call_all(resolve(study.answer_providers, "answer_providers", strict), study, strict=strict)
    merged: dict = {}
    for spec, answers in found:
        if not isinstance(answers, Mapping):
            notes.append(f"{spec}: returned {type(answers).__name__}, not a dict of answers; skipped")
            continue
        for item, values in answers.items():
            if item in merged and isinstance(merged[item], dict) and isinstance(values, Mapping):
                clash = set(merged[item]) & set(values)
                if clash:
                    notes.append(f"{spec}: {item} {sorted(clash)} already answered; the first is kept")
                merged[item] = dict(values) | merged[item]
            elif item in merged:
                notes.append(f"{spec}: {item} already answered; the first is kept")
            else:
                merged[item] = dict(values) if isinstance(values, Mapping) else values
    return merged, notes


def errata(study: CaseStudy) -> list[dict]:
    """Rows of the errata (declared in the case files) that concern the study's case, in document order.

    Returns
    -------
    list of dicts {section, item, <table headers>: cell text}
    """
    registered = [cases.get(n) for n in cases.names()]
    if all(c is not study for c in registered):
        registered.append(study)
    return errata_of(study, registered)


def collect(study: CaseStudy, strict: bool = False) -> tuple[dict, list]:
    """All answers of the study keyed by item (model items first), the errata and notes."""
    answers = model_answers(study)
    designed, notes = provider_answers(study, strict)
    for item, values in designed.items():
        if item in answers and isinstance(values, Mapping):
            answers[item] = dict(answers[item]) | dict(values)
        else:
            answers[item] = values
    ordered = dict(sorted(answers.items(), key=lambda kv: _item_key(kv[0])))
    ordered["errata"] = errata(study)
    return ordered, notes


def _item_key(item: str):
    """Sort key of a homework item: its number, then its letter ("I.8(c)" -> (8, "(c)")); others last."""
    match = re.match(r"([IVX]+)\.(\d+)(.*)", item)
    return (int(match.group(2)), match.group(3)) if match else (10**6, item)


def _number(v) -> str:
    """A number to 4 significant digits (complex as a±bj; -0 as 0)."""
    if isinstance(v, (complex, np.complexfloating)):
        return f"{v.real + 0.0:.4g}{v.imag + 0.0:+.4g}j"
    return f"{float(v) + 0.0:.4g}"


def format_value(value, indent: str = "    ") -> str:
    """Readable text of one answer value (numbers to 4 significant digits, complex as a±bj)."""
    if isinstance(value, control.TransferFunction):
        return tf_string(value)
    if isinstance(value, Mapping):
        if value and all(isinstance(v, (int, float, np.number)) and not isinstance(v, bool) for v in value.values()):
            return ", ".join(f"{k} = {format_value(v)}" for k, v in value.items())
        lines = []
        for k, v in value.items():
            text = format_value(v, indent + "    ")
            lines.append(f"{indent}{k}:{text}" if text.startswith("\n") else f"{indent}{k}: {text}")
        return "\n" + "\n".join(lines)
    if isinstance(value, (list, tuple, np.ndarray)):
        arr = np.asarray(value)
        if arr.dtype.kind in "fciu" and arr.ndim == 2:
            rows = ["[" + ", ".join(_number(v) for v in row) + "]" for row in arr]
            return "\n" + "\n".join(f"{indent}  {row}" for row in rows)
        if arr.dtype.kind in "fciu" and arr.ndim == 1:
            return "[" + ", ".join(_number(v) for v in arr) + "]"
        return ", ".join(str(v) for v in value)
    if isinstance(value, (float, np.floating, complex, np.complexfloating)):
        return _number(value)
    return str(value)


def format_answers(study: CaseStudy, answers: Mapping, title: str) -> str:
    """The answers and errata as Markdown text, items in homework order."""
    lines = [
        f"# Homework answers: {title}",
        "",
        "SI units, angles in rad. .1-.7 from the model declared in `models`; design items from the case's designs.",
        "",
    ]
    for item, values in answers.items():
        if item == "errata":
            continue
        lines.append(f"- **{item}**" + format_value(values).replace("\n", "\n  "))
    lines += ["", "## Errata found (from the case files; all of them in docs/errata.md)", ""]
    found = answers.get("errata") or []
    if not found:
        lines.append("none for this case study")
    for row in found:
        cells = [v for k, v in row.items() if k != "section"]
        lines.append(f"- {cells[0]}: " + " → ".join(c for c in cells[1:] if c and c != "—"))
    return "\n".join(lines) + "\n"
