"""The default controller and answer providers of a case study: its own designs, by kind.

Each provider is called by the runner as ``function(case_name, known=Plant)``
(answers: ``function(case_name)``) and reads the registered case. A case
without a design of that kind has nothing to provide: `NotProvided`, which
the runner notes instead of failing.
"""

from __future__ import annotations

import models

from . import cases, homework
from .runner import NotProvided


def classical(name: str, known: models.Plant | None = None) -> dict:
    """The case's classical controllers (the .8-.14 designs), designed from `known`."""
    case = cases.get(name)
    if case.classical is None:
        raise NotProvided(f"the {name} case has no classical design")
    return dict(homework.classical_design(case, known).controllers)


def statespace(name: str, known: models.Plant | None = None) -> dict:
    """The case's state-space controllers (.15-.17 and LQR), designed from `known`."""
    case = cases.get(name)
    if case.statespace is None:
        raise NotProvided(f"the {name} case has no state-space design")
    return homework.statespace_controllers(case, known)


def mpc(name: str, known: models.Plant | None = None) -> dict:
    """The case's linear and nonlinear MPC with its `mpc.MPCSettings`, designed from `known`."""
    import mpc as mpc_package

    case = cases.get(name)
    if case.mpc is None:
        raise NotProvided(f"the {name} case has no MPC settings")
    known = models.get(name) if known is None else known
    return {
        "linear MPC": mpc_package.linear_mpc(known, case.mpc, tracked=case.tracked),
        "nonlinear MPC": mpc_package.nonlinear_mpc(known, case.mpc, tracked=case.tracked),
    }


def tuned(name: str, known: models.Plant | None = None) -> dict:
    """The case's "tuned" design: its hand PID with the stored tuned gains (see `studies.tuner`)."""
    from . import tuner

    case = cases.get(name)
    if tuner.stored(case) is None:
        raise NotProvided(f"no tuned gains stored for {name}; `python -m studies.tuner {name}` tunes them")
    return tuner.controllers(case, known)


def classical_answers(name: str) -> dict:
    """The classical homework answers of the case, designed on the nominal plant."""
    case = cases.get(name)
    if case.classical is None:
        raise NotProvided(f"the {name} case has no classical design")
    return homework.classical_answers(case)


def statespace_answers(name: str) -> dict:
    """The state-space homework answers of the case, designed on the nominal plant."""
    case = cases.get(name)
    if case.statespace is None:
        raise NotProvided(f"the {name} case has no state-space design")
    return homework.statespace_answers(case)
