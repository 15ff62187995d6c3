"""The newer MPC APIs' arguments: a one-line error naming the argument, its value and what it must be."""

from __future__ import annotations

import numpy as np
import pytest

import models
import mpc


@pytest.mark.parametrize("args", [("a", 2), (1, "b"), (True, 2), (1, 2, "c")])
def test_free_time_names_the_argument_that_is_not_a_number(args):
    # before: "could not convert string to float", naming no argument; True was taken as 1 s
    with pytest.raises(TypeError, match=r"FreeTime (lower|upper|guess) must be a real number of seconds, got"):
        mpc.FreeTime(*args)


def test_free_time_takes_numbers():
    assert mpc.FreeTime(1, 3).guess == 2.0


@pytest.mark.parametrize("final_time", ["abc", True, None])
def test_a_final_time_that_is_not_a_number_is_named(final_time):
    # before: "could not convert string to float" for "abc", and True taken as 1 s
    with pytest.raises(TypeError, match=r"final_time must be a real number of seconds or a FreeTime, got"):
        mpc.OptimalControlProblem(models.get("arm"), final_time)


def test_a_soft_bound_with_equal_sides_does_not_speak_of_a_scale_not_given():
    # before: "scale must be finite and > 0, got 0.0", a scale the caller never gave
    with pytest.raises(ValueError, match=r"lower = upper = 0.5; need lower < upper") as refused:
        mpc.SoftBound.on(models.get("arm"), {"theta": 1.0}, 0.5, 0.5, linear_weight=1.0, quadratic_weight=1.0)
    assert "scale must" not in str(refused.value)


def test_a_nonlinear_mpc_on_a_plant_it_cannot_hold_is_refused_as_the_linear_one_is():
    # before: the nonlinear MPC built without a word and reported "solved" at every step while the arm fell
    arm = models.get("arm", m=5.0)
    x_rest, _ = arm.equilibrium()
    needed = arm.equilibrium_input(x_rest[: arm.nq])  # the static balance, solved on its own
    assert abs(needed[0]) > arm.input_limit[0]
    message = rf"arm: holding the operating point needs the input \[{needed[0]:g}\], beyond the actuator limit \[1\.\]"
    settings = dict(sample_period=0.02, horizon=10, state_weight=1.0, input_weight=1.0, tracked="theta")
    with pytest.raises(ValueError, match=message):
        mpc.NonlinearMPC(arm, **settings)
    with pytest.raises(ValueError, match=message):
        mpc.NonlinearMPCProblem(arm, 0.02, 10, 1.0, 1.0)
    with pytest.raises(ValueError, match=message):
        mpc.LinearMPC(arm, **settings)


@pytest.mark.parametrize(
    "constraint",
    [
        lambda ocp: ocp.u.tau <= np.nan,
        lambda ocp: np.nan <= ocp.u.tau,
        lambda ocp: ocp.bounded(np.nan, ocp.u.tau, 1.0),
        lambda ocp: ocp.at_end(ocp.state) == [0.0, np.nan],
    ],
)
def test_a_nan_bound_in_subject_to_is_refused_naming_the_constraint(constraint):
    # before: accepted, and the solve then reported IPOPT's internals
    ocp = mpc.OptimalControlProblem(models.get("arm"), 1.0)
    with pytest.raises(ValueError, match=r"subject_to\(.+\): its (lower|upper) bound is NaN"):
        ocp.subject_to(constraint(ocp))
    assert ocp.constraints == []  # nothing of a refused constraint is kept
    ocp.subject_to([ocp.u.tau <= 1.0, ocp.u.tau >= -np.inf])  # numbers and infinities are bounds
    assert len(ocp.constraints) == 2


def test_a_nan_guess_or_a_bound_that_is_not_a_number_in_choose_is_named():
    # before: a NaN guess was accepted (np.clip keeps NaN) and the solve reported IPOPT's internals
    ocp = mpc.OptimalControlProblem(models.get("arm"), 1.0)
    with pytest.raises(ValueError, match=r"choose\('m'\) guess \(kg\) must be finite, got nan"):
        ocp.choose("m", 0.1, 2.0, np.nan)
    with pytest.raises(TypeError, match=r"choose\('m'\) upper must be a real number, got str 'x'"):
        ocp.choose("m", 0.1, "x")
    assert ocp.chosen == {}
    ocp.choose("m", 0.1, 2.0, 5.0)
    assert ocp.chosen["m"].guess == 2.0  # clipped into the range, as documented


class NamelessSolver:
    """A custom QP solver written as LinearMPC's docstring describes: solve and reset only."""

    def __init__(self, problem):
        self._inner = mpc.CondensedDaqpSolver(problem)

    def solve(self, params):
        return self._inner.solve(params)

    def reset(self):
        self._inner.reset()


def test_a_custom_qp_solver_without_a_name_runs_and_is_named_by_its_class():
    # before: AttributeError 'NamelessSolver' object has no attribute 'name' at its first step
    arm = models.get("arm")
    settings = dict(sample_period=0.02, horizon=10, state_weight=1.0, input_weight=1.0, tracked="theta")
    custom, daqp = mpc.LinearMPC(arm, solver=NamelessSolver, **settings), mpc.LinearMPC(arm, solver="daqp", **settings)
    y0, r = np.zeros(arm.ny), np.array([0.3])
    states = [controller.initial_state(y0, r) for controller in (custom, daqp)]
    for _ in range(3):
        (states[0], u_custom), (states[1], u_daqp) = custom.step(states[0], y0, r), daqp.step(states[1], y0, r)
        np.testing.assert_array_equal(u_custom, u_daqp)  # the same QPs, so the same commands
    assert custom.step_info()["solver"] == "NamelessSolver" and daqp.step_info()["solver"] == "daqp"
