"""Controller providers that inject faults into a study, for tests/studies/test_faults.py.

Each is a provider ``provider(case, known) -> {label: controller}`` (`studies.providers`), named
``fault_providers:function`` on the command line's ``--provider``.
"""

from __future__ import annotations

import sys

from example_providers import PythonStateFeedback, controllers

import models
from models.exported_loop import ExportedLoop
from mpc.controller import NonlinearMPC
from mpc.export_nmpc import ExportedNMPC


class SolverAlwaysFails(PythonStateFeedback):
    """The example state feedback, whose every step reports a failed solve and a fallback plan
    (as an MPC whose solver fails on every step while the shifted plan keeps it going)."""

    def step_info(self):
        return {"status": "Maximum_Iterations_Exceeded", "success": False, "fallback": True, "solve_time": 0.0}


def solver_always_fails(case, known: models.Plant | None = None) -> dict:
    """One 'MPC' whose solver fails on all of its steps."""
    lqr = controllers(case, known)["LQR"]
    plant = known or models.get(case.plant)
    return {"failing MPC": SolverAlwaysFails(lqr, float(plant.input_limit[0]))}


class InterruptInDisguise(PythonStateFeedback):
    """Raises what CasADi raises when Ctrl-C arrives inside one of its calls: a RuntimeError whose
    text mentions KeyboardInterrupt (the runner must stop, not note a failed row)."""

    def step(self, xc, y, r):
        if xc[0] >= 20:
            raise RuntimeError(
                "Error in Function::call for 'solver' [IpoptInterface] at .../casadi/core/"
                "function.cpp:1401:\nKeyboardInterrupt"
            )
        return super().step(xc, y, r)


def interrupt_in_disguise(case, known: models.Plant | None = None) -> dict:
    """The example LQR, and an 'MPC' whose CasADi call reports Ctrl-C as an error at its 20th step."""
    lqr = controllers(case, known)["LQR"]
    plant = known or models.get(case.plant)
    return {"interrupted MPC": InterruptInDisguise(lqr, float(plant.input_limit[0]))}


class RaisesMidRun(PythonStateFeedback):
    """Raises an ordinary error at its 30th step: the row fails, the others run."""

    def step(self, xc, y, r):
        if xc[0] >= 30:
            raise FloatingPointError("the solver's factorization broke down")
        return super().step(xc, y, r)


def raises_mid_run(case, known: models.Plant | None = None) -> dict:
    """The example LQR, and an 'MPC' that raises an ordinary error at its 30th step."""
    lqr = controllers(case, known)["LQR"]
    plant = known or models.get(case.plant)
    return {"LQR": lqr, "broken MPC": RaisesMidRun(lqr, float(plant.input_limit[0]))}


#: Labels a user may choose, with Markdown and HTML syntax and the animation page's placeholders.
HOSTILE_LABELS = ("<script>alert(1)</script> *bold* | pipe", "__DATA__ and __TITLE__", "- [link](http://x) `code`")


def hostile_labels(case, known: models.Plant | None = None) -> dict:
    """The example LQR (the fastest, so it is the animated 'best' one) under labels with markup."""
    found = controllers(case, known)
    return {HOSTILE_LABELS[0]: found["LQR fast"], HOSTILE_LABELS[1]: found["LQR"], HOSTILE_LABELS[2]: found["LQR slow"]}


def announce_nonlinear_mpc(case, known: models.Plant | None = None) -> dict:
    """No controller: makes every nonlinear MPC print 'NMPC RUN STARTED' on stderr as each of its runs
    starts, in Python or by its exported C (`models.exported_loop`), so a test can interrupt the command
    while the case's own nonlinear MPC is solving."""
    start = NonlinearMPC.initial_state
    if not getattr(start, "announces", False):

        def initial_state(self, y0, r0):
            state = start(self, y0, r0)
            print("NMPC RUN STARTED", file=sys.stderr, flush=True)
            return state

        initial_state.announces = True
        NonlinearMPC.initial_state = initial_state
    run = ExportedLoop.run
    if not getattr(run, "announces", False):

        def exported_run(self, *args, **kwargs):
            if isinstance(self.exported, ExportedNMPC):
                print("NMPC RUN STARTED", file=sys.stderr, flush=True)
            return run(self, *args, **kwargs)

        exported_run.announces = True
        ExportedLoop.run = exported_run
    return {}


def not_a_dict(case, known: models.Plant | None = None):
    """A provider with a bug: it returns a list."""
    return [1, 2, 3]
