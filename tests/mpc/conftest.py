"""A recorded closed loop shared by the MPC tests that compare solvers on real instances."""

import pytest

import models
import mpc


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

    controller = mpc.linear_mpc("pendulum", models.perturbed(plant, 0.05), solver=Recorder)
    models.simulate_closed_loop(plant, controller, 2.0, 0.6, input_disturbance=0.5)
    return controller, recorded
