"""The study's controllers: designed by its providers, the caller's own added, the ones asked to be left out removed.

`studies.runner.run_study` makes its controllers here before it simulates
them: each provider (``provider(case, known) -> {label: controller}``) is
called through `studies.provider_calls`, what it returns is checked, the
case's declared labels come first, and ``without`` labels (``python -m studies
--without LABEL``) are taken out, each with a note, so that a run can skip a
controller it does not need (the scenario-tree NMPC's Monte Carlo is most of a
default run).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import models

from .case import CaseStudy
from .provider_calls import call_all, resolve


def design_controllers(
    study: CaseStudy, known: models.Plant, providers: Sequence | None = None, strict: bool = False
) -> tuple[dict, list]:
    """The study's controllers designed from `known`, in table order, and notes on what is missing.

    Parameters
    ----------
    providers : replace the study's own (`CaseStudy.providers`): callables ``provider(case, known)``,
        or ``module:function`` strings naming them (`studies.provider_calls.resolve`)

    Returns
    -------
    {label: controller}: the study's declared labels first, in its order, then the others as provided;
    notes: list of str
    """
    chosen = resolve(study.providers if providers is None else providers, strict=strict)
    found, notes = call_all(chosen, study, known, strict=strict)
    collected: dict = {}
    for name, returned in found:
        if not isinstance(returned, Mapping):
            notes.append(f"{name}: returned {type(returned).__name__}, not a dict of controllers; skipped")
            continue
        for label, controller in returned.items():
            if label in collected:
                notes.append(f"{name}: controller {label!r} already provided; the first one is kept")
            elif not isinstance(controller, models.Controller):
                notes.append(f"{name}: {label!r} is a {type(controller).__name__}, not a controller; skipped")
            elif controller.n_reference != 1:
                notes.append(
                    f"{name}: {label!r} takes {controller.n_reference} references; the studies "
                    "command the tracked coordinate only; skipped"
                )
            else:
                collected[str(label)] = controller
    ordered = {label: collected[label] for label in study.controllers if label in collected}
    ordered |= {label: c for label, c in collected.items() if label not in ordered}
    missing = [label for label in study.controllers if label not in collected]
    if missing and found:
        notes.append("not provided yet: " + ", ".join(missing))
    return ordered, notes


def add_controllers(designed: dict, extra: Mapping) -> list:
    """Add the caller's `extra` {label: controller} to `designed` (in place), replacing a provider's
    controller of the same label; returns a note per label replaced."""
    notes = []
    for label, controller in extra.items():
        if label in designed:
            notes.append(f"controller {label!r} given twice; the provider's is replaced")
        designed[label] = controller
    return notes


def without_labels(value, what: str = "without") -> tuple:
    """`value` (a label, or a list or tuple of labels) as a tuple of distinct non-empty labels.

    Raises
    ------
    TypeError
        Naming `what`, for anything but a str or a list or tuple of str.
    ValueError
        Naming `what`, for an empty label.
    """
    labels = (value,) if isinstance(value, str) else value
    if not isinstance(labels, (list, tuple)) or not all(isinstance(label, str) for label in labels):
        raise TypeError(f"{what} must be a controller label or a list of them, got {value!r}")
    if any(not label.strip() for label in labels):
        raise ValueError(f"{what} names an empty controller label: {value!r}")
    return tuple(dict.fromkeys(labels))


def leave_out(designed: dict, labels: Sequence[str]) -> tuple[list, list]:
    """Remove the controllers `labels` from `designed` (in place).

    Returns
    -------
    the labels removed, in the order given;  notes: one per label removed, and one per label that names
    no controller of this study
    """
    removed, notes = [], []
    for label in labels:
        if label in designed:
            del designed[label]
            removed.append(label)
            notes.append(f"{label}: left out, as asked (without)")
        else:
            notes.append(f"without {label!r}: no controller of that label here")
    return removed, notes
