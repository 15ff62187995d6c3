"""A case study's own controllers and homework answers, by kind: the providers every case file lists.

Each receives the `studies.CaseStudy` it designs for (registered or not) and reads its record:
`classical` and `classical_answers` its ``classical`` design, `statespace` and `statespace_answers`
its ``statespace`` choices, `mpc` its ``mpc`` settings (and, from the same settings, the robust rows
of `studies.robust_rows`: the scenario-tree NMPC and the tube MPC), `tuned` its stored tuned gains
(`studies.tuner`). A case without that design has nothing to provide: `NotProvided`, which the run
notes. `STANDARD` and `STANDARD_ANSWERS` are the lists a case file gives as ``providers=`` and
``answer_providers=``. How providers are found and called is `studies.provider_calls`.
"""

from __future__ import annotations

import models
from mpc import linear_mpc, nonlinear_mpc

from . import cases, homework, robust_rows, tuned_rows, tuner
from .case import CaseStudy
from .provider_calls import AnswerProvider, Provider
from .provider_calls import NotProvided as NotProvided  # what these raise; callers catch it from here too


def _case(case: CaseStudy | str) -> CaseStudy:
    """`case`, or the registered case of that name (for callers that hold only the name)."""
    return cases.get(case) if isinstance(case, str) else case


def classical(case: CaseStudy | str, known: models.Plant | None = None) -> dict:
    """The case's classical controllers (the .8-.14 designs), designed from `known` (default: nominal)."""
    case = _case(case)
    if case.classical is None:
        raise NotProvided(f"the {case.plant} case has no classical design")
    return dict(homework.classical_design(case, known).controllers)


def statespace(case: CaseStudy | str, known: models.Plant | None = None) -> dict:
    """The case's state-space controllers (.15-.17 and LQR), designed from `known` (default: nominal)."""
    case = _case(case)
    if case.statespace is None:
        raise NotProvided(f"the {case.plant} case has no state-space design")
    return homework.statespace_controllers(case, known)


def mpc(case: CaseStudy | str, known: models.Plant | None = None) -> dict:
    """The case's linear and nonlinear MPC with its `mpc.MPCSettings`, designed from `known` (default: nominal)."""
    case = _case(case)
    if case.mpc is None:
        raise NotProvided(f"the {case.plant} case has no MPC settings")
    known = models.get(case.plant) if known is None else known
    return {
        "linear MPC": linear_mpc(known, case.mpc, tracked=case.tracked),
        "nonlinear MPC": nonlinear_mpc(known, case.mpc, tracked=case.tracked),
    }


def tuned(case: CaseStudy | str, known: models.Plant | None = None) -> dict:
    """The case's "tuned" design: its hand PID with the stored tuned gains (see `studies.tuner`)."""
    case = _case(case)
    if tuner.stored(case) is None:
        raise NotProvided(f"no tuned gains stored for {case.plant}; `python -m studies.tuner {case.plant}` tunes them")
    return tuner.controllers(case, known)


def classical_answers(case: CaseStudy | str) -> dict:
    """The classical homework answers of the case, designed on the nominal plant."""
    case = _case(case)
    if case.classical is None:
        raise NotProvided(f"the {case.plant} case has no classical design")
    return homework.classical_answers(case)


def statespace_answers(case: CaseStudy | str) -> dict:
    """The state-space homework answers of the case, designed on the nominal plant."""
    case = _case(case)
    if case.statespace is None:
        raise NotProvided(f"the {case.plant} case has no state-space design")
    return homework.statespace_answers(case)


#: A case's own controllers, by kind: each provides nothing (`NotProvided`) for a case without that design.
STANDARD: tuple[Provider, ...] = (
    classical,
    statespace,
    mpc,
    robust_rows.scenario_tree,
    robust_rows.tube,
    tuned,
    tuned_rows.tuned_weights,
)
#: A case's own homework answers, by kind.
STANDARD_ANSWERS: tuple[AnswerProvider, ...] = (classical_answers, statespace_answers)
