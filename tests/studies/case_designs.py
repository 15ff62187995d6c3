"""The case studies' designs by plant name, for the tests: crane1 is the crane case's one-load design model.

These design through `studies.homework` directly; the studies ask the same designs through the
case's providers (`studies.providers.STANDARD`), which receive the case itself."""

from __future__ import annotations

import models
import studies
from studies import homework
from studies.cases import crane

#: Every plant a case study designs: the registered cases' and crane1, the crane case's one-load model.
DESIGNED = (*studies.names(), "crane1")


def case_of(name: str):
    """The case study designing plant `name` (crane1's is the crane case)."""
    return studies.get("crane" if name == "crane1" else name)


def _known(name: str, known):
    return models.get(name) if known is None else known


def _choices(name: str):
    """The state-space choices of `name` where they are not its case's own (crane1's one-load ones)."""
    return crane.STATESPACE_ONE_LOAD if name == "crane1" else None


def classical_answers(name: str, known=None) -> dict:
    return homework.classical_answers(case_of(name), _known(name, known))


def classical_controllers(name: str, known=None) -> dict:
    return dict(homework.classical_design(case_of(name), _known(name, known)).controllers)


def statespace_design(name: str, known=None, **overrides):
    return homework.statespace_design(case_of(name), _known(name, known), _choices(name), **overrides)


def statespace_answers(name: str, known=None, **overrides) -> dict:
    return homework.statespace_answers(case_of(name), _known(name, known), _choices(name), **overrides)


def statespace_controllers(name: str, known=None, **overrides) -> dict:
    return homework.statespace_controllers(case_of(name), _known(name, known), _choices(name), **overrides)
