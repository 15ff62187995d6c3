"""Homework answers of a case study, keyed by item, and the errata that concern it.

The model items (.5 equilibria, .6 transfer functions, .7 state space) come from
the plant declared in `models`; the design items (.8, .10, .13, .14 and
.15-.17) from the providers' ``answers(plant)`` functions; the errata are read
from ``docs/errata.md``, never copied here.
"""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path
from typing import Mapping

import control
import numpy as np

import models
from models.linear import tf_string

from .runner import Study, call_providers

ERRATA_PATH = Path(__file__).resolve().parent.parent / "docs" / "errata.md"


def _coordinate_tf(lin: models.LinearModel, coordinate: str, input_name: str) -> control.TransferFunction:
    """Transfer function from `input_name` to the state `coordinate` (cleaned as `LinearModel.tf` does)."""
    i = lin.state_names.index(coordinate)
    row = np.eye(lin.nx)[i:i + 1]
    single = dataclasses.replace(lin, C=row, D=np.zeros((1, lin.nu)), ye=lin.xe[i:i + 1],
                                 output_names=(coordinate,))
    return control.minreal(single.tf(coordinate, input_name), verbose=False)


def _chop(G: control.TransferFunction, rel: float = 1e-9) -> control.TransferFunction:
    def clean(coeffs):
        coeffs = np.ravel(coeffs).astype(float)
        return np.where(np.abs(coeffs) <= rel * np.max(np.abs(coeffs)), 0.0, coeffs)
    return control.tf(clean(G.num[0][0]), clean(G.den[0][0]), G.dt)


def model_answers(study: Study) -> dict:
    """The .5, .6 and .7 answers from the plant's model (SI units, angles in rad).

    Returns
    -------
    dict item -> dict: ".5" the standard equilibrium and its linearization,
    ".6" the transfer functions from the input to each output (and the
    cascade of the successive-loop designs), ".7" the state-space matrices.
    """
    case = study.case
    n = case.numeral
    plant = models.get(study.plant)
    xe, ue = plant.equilibrium()
    lin = plant.linearize(xe, ue)
    u_name = plant.input_names[0]
    out = {
        f"{n}.5": {"x_e": dict(zip(plant.state_names, xe)), "u_e": dict(zip(plant.input_names, ue)),
                   "A": lin.A, "B": lin.B},
        f"{n}.6": {f"{o}/{u_name}": lin.tf(o, u_name) for o in plant.output_names},
        f"{n}.7": {"states": list(plant.state_names), "outputs": list(plant.output_names),
                   "A": lin.A, "B": lin.B, "C": lin.C, "D": lin.D},
    }
    if study.cascade:
        inner, outer = study.cascade
        name, overrides = study.cascade_model or (study.plant, {})
        model = models.get(name, **dict(overrides))
        mlin = model.linearize()
        g_inner = _coordinate_tf(mlin, inner, model.input_names[0])
        g_outer = _chop(control.minreal(_coordinate_tf(mlin, outer, model.input_names[0]) / g_inner,
                                        verbose=False))
        where = "" if name == study.plant else f" ({name}" + "".join(f", {k} = {v:g}" for k, v in
                                                                      dict(overrides).items()) + ")"
        out[f"{n}.6"] |= {f"cascade inner {inner}/{model.input_names[0]}{where}": g_inner,
                          f"cascade outer {outer}/{inner}{where}": g_outer}
    return out


def provider_answers(study: Study, strict: bool = False) -> tuple[dict, list]:
    """The design answers from the study's answer providers, merged by item, and notes."""
    found, notes = call_providers(study.answer_providers, study.plant, strict=strict)
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


def errata(study: Study, path: Path = ERRATA_PATH) -> list[dict]:
    """Rows of the errata tables in ``docs/errata.md`` that concern the study's case.

    A row concerns the case when its first cell names one of the case's items
    (numeral followed by a dot, e.g. "III.15", or the bare numeral) or the plant.

    Returns
    -------
    list of dicts {section, <table headers>: cell text}; empty when the file is missing
    """
    if not path.exists():
        return []
    numeral = study.case.numeral
    item = re.compile(rf"(?<![A-Z]){numeral}(?![A-Z])")
    plant_word = re.compile(rf"\b{re.escape(study.plant)}\b")
    rows, section, header = [], "", None
    for line in path.read_text(encoding="utf-8").splitlines():
        if line.startswith("#"):
            section, header = line.lstrip("#").strip(), None
            continue
        if not line.startswith("|"):
            header = None
            continue
        cells = [c.strip().replace("\\|", "|") for c in re.split(r"(?<!\\)\|", line.strip()[1:-1])]
        if header is None:
            header = cells
        elif all(set(c) <= set("-: ") for c in cells):
            continue
        elif item.search(cells[0]) or plant_word.search(cells[0]):
            rows.append({"section": section, **dict(zip(header, cells))})
    return rows


def collect(study: Study, strict: bool = False) -> tuple[dict, list]:
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
    match = re.match(r"([IVX]+)\.(\d+)(.*)", item)
    return (int(match.group(2)), match.group(3)) if match else (10**6, item)


def _number(v) -> str:
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


def format_answers(study: Study, answers: Mapping, title: str) -> str:
    """The answers and errata as Markdown text, items in homework order."""
    lines = [f"# Homework answers: {title}", "",
             "SI units, angles in rad. .5-.7 from the model declared in `models`; design items from the "
             "providers' answers.", ""]
    for item, values in answers.items():
        if item == "errata":
            continue
        lines.append(f"- **{item}**" + format_value(values).replace("\n", "\n  "))
    lines += ["", "## Errata found (from docs/errata.md)", ""]
    found = answers.get("errata") or []
    if not found:
        lines.append("none for this case study")
    for row in found:
        cells = [v for k, v in row.items() if k != "section"]
        lines.append(f"- {cells[0]}: " + " → ".join(c for c in cells[1:] if c and c != "—"))
    return "\n".join(lines) + "\n"
