"""Fixtures of the MPC tests: the case studies' MPC designs, and a recorded closed loop shared by the
tests that compare solvers on real instances."""

import pytest

import models
import mpc
import studies


def case_mpc(name: str):
    """(MPCSettings, tracked coordinate) of the MPC of plant `name`, from its case study.

    crane1 is the crane case's one-load design model, with its own settings.
    """
    if name == "crane1":
        from studies.cases import crane

        return crane.MPC_ONE_LOAD, crane.CASE.tracked
    case = studies.get(name)
    return case.mpc, case.tracked


def build(kind: str, name: str, known=None, **overrides):
    """The case study's linear or nonlinear MPC of plant `name`, designed on `known` (default nominal)."""
    settings, tracked = case_mpc(name)
    known = models.get(name) if known is None else known
    builder = mpc.linear_mpc if kind == "linear" else mpc.nonlinear_mpc
    return builder(known, settings, tracked=tracked, **overrides)


@pytest.fixture(scope="session")
def build_mpc():
    """build(kind, name, known=None, **overrides): a case study's MPC ("linear" or "nonlinear")."""
    return build


@pytest.fixture(scope="session")
def mpc_settings():
    """case_mpc(name): (MPCSettings, tracked coordinate) of a case study's MPC."""
    return case_mpc


@pytest.fixture(scope="session")
def pendulum_qp_records():
    """(controller, [(QPParameters, QPSolution)]) of DAQP's solves along a 2 s pendulum step
    (0.6 m, 0.5 N input disturbance, +5 % model), where |theta| rides on its soft bound."""
    plant = models.get("pendulum")
    recorded = []

    class Recorder(mpc.CondensedDaqpSolver):
        def solve(self, params):
            solution = super().solve(params)
            recorded.append((params, solution))
            return solution

    controller = build("linear", "pendulum", models.perturbed(plant, 0.05), solver=Recorder)
    models.simulate_closed_loop(plant, controller, 2.0, 0.6, input_disturbance=0.5)
    return controller, recorded
