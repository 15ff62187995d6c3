"""The MPC controllers in the common closed-loop simulator: exact input limits, failure
handling, infeasible soft bounds, the exact penalty, errors, reruns, and the nonlinear MPC
against the linear one on the (linear) satellite."""

import cvxpy as cp
import numpy as np
import pytest

import models
import mpc
from mpc.linear import QPSolution
from mpc.reference_cvxpy import mpc_problem


class FailingSolver(mpc.CondensedDaqpSolver):
    """DAQP that reports failure (with a NaN plan) on the chosen calls."""

    def __init__(self, problem, fail_on=()):
        super().__init__(problem)
        self.fail_on, self.calls = set(fail_on), 0

    def solve(self, params):
        solution = super().solve(params)
        self.calls += 1
        if self.calls - 1 in self.fail_on:
            n = self.problem.horizon
            return QPSolution(
                np.full((n, self.problem.nu), np.nan),
                np.full((n, self.problem.n_soft), np.nan),
                False,
                "injected failure",
                0,
                0.0,
            )
        return solution


class OvershootingSolver(mpc.CondensedDaqpSolver):
    """DAQP whose plan is 1.5 times the upper input bound (in deviation), as a sloppy solver might return."""

    def solve(self, params):
        solution = super().solve(params)
        solution.inputs = np.full_like(solution.inputs, 1.5 * self.problem.input_upper)
        return solution


def test_controllers_entry_point_returns_both_designs_following_the_protocol(build_mpc):
    designs = {
        label: build_mpc(kind, "pendulum", models.perturbed(models.get("pendulum"), 0.05))
        for label, kind in (("linear MPC", "linear"), ("nonlinear MPC", "nonlinear"))
    }
    assert set(designs) == {"linear MPC", "nonlinear MPC"}
    for controller in designs.values():
        assert isinstance(controller, models.Controller)
        assert controller.measures == "outputs" and controller.n_reference == 1
        assert controller.sample_period == 0.01


def test_linear_mpc_command_never_exceeds_the_limit_and_does_saturate(build_mpc):
    plant = models.get("pendulum")
    controller = build_mpc("linear", "pendulum", models.perturbed(plant, 0.05))
    result = models.simulate_closed_loop(plant, controller, 2.0, 1.0, input_disturbance=0.5)
    limit = plant.input_limit[0]
    assert np.all(np.abs(result.u) <= limit)
    assert np.max(np.abs(result.u)) == limit
    record = result.status[0]
    assert {
        "solver",
        "status",
        "success",
        "iterations",
        "solve_time",
        "fallback",
        "input_excess",
        "soft_violation",
        "soft_violation_now",
    } <= set(record)
    assert all(s["success"] for s in result.status)


def test_nonlinear_mpc_command_never_exceeds_the_limit_and_does_saturate(build_mpc):
    plant = models.get("arm")
    controller = build_mpc("nonlinear", "arm", models.perturbed(plant, 0.05, -1))
    result = models.simulate_closed_loop(plant, controller, np.deg2rad(50), 0.4, input_disturbance=0.2)
    assert np.all(np.abs(result.u) <= plant.input_limit[0])
    assert np.max(np.abs(result.u)) == plant.input_limit[0]
    assert all(s["success"] for s in result.status)


@pytest.mark.parametrize("kind", ["linear", "nonlinear"])
def test_rate_limit_holds_on_the_command(kind, build_mpc):
    plant = models.get("pendulum")
    controller = build_mpc(kind, "pendulum", rate_limit=[50.0])
    result = models.simulate_closed_loop(plant, controller, 1.0, 0.6)
    steps = np.abs(np.diff(np.concatenate([[0.0], result.u[:, 0]])))
    assert np.max(steps) <= 50.0 * 0.01 * (1 + 1e-12)
    assert np.max(steps) == pytest.approx(0.5, rel=1e-9)  # the limit is reached
    assert all(s["success"] for s in result.status)


def test_solver_answer_beyond_the_limit_is_clipped_exactly_and_the_excess_reported(build_mpc):
    plant = models.get("arm")
    controller = build_mpc("linear", "arm", solver=OvershootingSolver)
    result = models.simulate_closed_loop(plant, controller, 0.3, 0.05)
    assert np.all(result.u == plant.input_limit[0])
    # The solver's plan is 1.5 (limit − ue) + ue in total input; the excess is what clipping removed.
    excess = 1.5 * (plant.input_limit[0] - controller.model.ue[0]) + controller.model.ue[0] - plant.input_limit[0]
    assert result.status[0]["input_excess"] == pytest.approx(excess, rel=1e-12)


def test_failed_solve_applies_the_shifted_previous_plan_clipped(build_mpc):
    plant = models.get("pendulum")
    failures = {3, 4, 9}
    controller = build_mpc("linear", "pendulum", solver=lambda problem: FailingSolver(problem, failures))
    x = plant.equilibrium()[0]
    y, r = plant.output(x), np.array([2.0])
    xc = controller.initial_state(y, r)
    n, nu = controller.horizon, plant.nu
    for k in range(12):
        previous_plan = xc[plant.nx + nu :].reshape(n, nu)
        xc, u = controller.step(xc, y, r)
        info = controller.step_info()
        if k in failures:
            assert not info["success"] and info["fallback"] and info["status"] == "injected failure"
            np.testing.assert_array_equal(u, np.clip(previous_plan[1], -5, 5))
            assert np.all(u != 0)
        else:
            assert info["success"] and not info["fallback"]
        assert np.all(np.abs(u) <= plant.input_limit)


def test_failures_in_a_run_are_recorded_and_the_run_completes(build_mpc):
    plant = models.get("pendulum")
    controller = build_mpc("linear", "pendulum", solver=lambda problem: FailingSolver(problem, range(5, 40, 3)))
    result = models.simulate_closed_loop(plant, controller, 2.0, 1.0)
    failed = [k for k, s in enumerate(result.status) if s["fallback"]]
    assert failed == list(range(5, 40, 3))
    assert np.all(np.abs(result.u) <= plant.input_limit[0]) and np.all(result.u[failed] != 0)


def test_iteration_limits_are_reported_and_handled(build_mpc):
    plant = models.get("pendulum")
    linear = build_mpc("linear", "pendulum", solver=lambda problem: mpc.CondensedDaqpSolver(problem, iteration_limit=1))
    result = models.simulate_closed_loop(plant, linear, 2.0, 0.5)
    hit = [s for s in result.status if s["status"] == "iteration limit"]
    assert hit and all(s["fallback"] and not s["success"] for s in hit)
    assert np.all(np.abs(result.u) <= plant.input_limit[0])

    # The nonlinear MPC iterates to convergence where it has no previous solution (the first
    # sample): with one iteration allowed, that sample fails and falls back to the start's plan.
    arm = models.get("arm")
    nonlinear = build_mpc("nonlinear", "arm", max_iterations=1)
    result = models.simulate_closed_loop(arm, nonlinear, 0.8, 0.3)
    hit = [s for s in result.status if s["status"].startswith("not converged in 1 iterations")]
    assert hit and all(s["fallback"] and not s["success"] for s in hit)
    assert np.all(np.abs(result.u) <= arm.input_limit[0])


def ball_rolling_off():
    """The ball beyond the MPC's (backed-off) end bound, rolling outwards at 0.8 m/s."""
    plant = models.get("ballbeam")
    return plant, np.array([0.49, 0.0, 0.8, 0.0])


def test_ball_rolling_off_makes_the_hard_state_constraint_infeasible(build_mpc):
    plant, x = ball_rolling_off()
    controller = build_mpc("linear", "ballbeam")
    problem = controller.problem
    cvx, _, _ = mpc_problem(problem, x - controller.model.xe, np.zeros(1), np.zeros(4), np.zeros(1), np.zeros(1))
    g = cvx.variables()
    states = next(v for v in g if v.name() == "x")
    hard = cp.Problem(cvx.objective, cvx.constraints + [states[1:] @ problem.soft_rows.T <= problem.soft_upper])
    hard.solve(solver="CLARABEL", canon_backend=cp.SCIPY_CANON_BACKEND)
    assert hard.status == cp.INFEASIBLE


@pytest.mark.parametrize("kind", ["linear", "nonlinear"])
def test_infeasible_state_constraint_still_gives_an_input_within_limits_and_reports_it(kind, build_mpc):
    plant, x = ball_rolling_off()
    controller = build_mpc(kind, "ballbeam")
    y = plant.output(x)
    xc = controller.initial_state(y, np.array([0.25]))
    offset = controller.model.xe if kind == "linear" else np.zeros(4)
    xc[:4] = x - offset  # the estimator knows the state: the infeasibility is the plant's
    xc, u = controller.step(xc, y, np.array([0.25]))
    info = controller.step_info()
    assert info["success"] and np.all(np.isfinite(u)) and np.all(np.abs(u) <= plant.input_limit)
    assert info["soft_violation"] > 0.01 and info["soft_violation_now"] > 0.01


def test_soft_bound_equals_the_hard_one_when_that_is_feasible(pendulum_qp_records):
    """The exact penalty: where theta rides on its bound with zero slack along a closed loop,
    the hard-constrained problem is feasible and has the same first input."""
    controller, recorded = pendulum_qp_records
    problem = controller.problem
    bound = problem.soft_upper[0]
    compared = 0
    for params, soft in recorded:
        theta = problem.simulate(params.x0, soft.inputs, params.disturbance)[1:, 1]
        if np.sum(np.isclose(np.abs(theta), bound, atol=1e-7)) < 3 or np.max(soft.slacks) > 1e-9:
            continue
        cvx, u, s = mpc_problem(problem, *params)
        hard = cp.Problem(cvx.objective, cvx.constraints + [s == 0])
        hard.solve(
            solver="CLARABEL",
            canon_backend=cp.SCIPY_CANON_BACKEND,
            tol_gap_abs=1e-12,
            tol_gap_rel=1e-12,
            tol_feas=1e-12,
        )
        assert hard.status == cp.OPTIMAL
        np.testing.assert_allclose(soft.inputs[0], u.value[0], atol=1e-5)
        compared += 1
    assert compared >= 5


def test_rerun_after_initial_state_gives_the_same_run(build_mpc):
    plant = models.get("arm")
    for controller in (build_mpc("linear", "arm"), build_mpc("nonlinear", "arm")):
        first = models.simulate_closed_loop(plant, controller, 0.6, 0.3, input_disturbance=0.2)
        second = models.simulate_closed_loop(plant, controller, 0.6, 0.3, input_disturbance=0.2)
        np.testing.assert_allclose(first.u, second.u, atol=1e-12, rtol=0)


@pytest.mark.parametrize("x", [[0.0, 0.19, 0.0, 0.0], [0.3, 0.0, 0.0, -0.3], [0.0, -0.1, 0.0, -0.3]])
def test_nonlinear_and_linear_mpc_plan_the_same_on_the_linear_satellite(x, build_mpc):
    """The satellite is linear: the NMPC's RK4 multiple shooting and the exact-ZOH QP are the
    same problem up to integration error. Whole plans are compared, from states that
    violate the panel-deflection bound, saturate, or neither."""
    plant = models.get("satellite")
    x = np.array(x)
    y, r = plant.output(x), np.array([0.5])
    plans, violations = [], []
    for controller in (build_mpc("linear", "satellite"), build_mpc("nonlinear", "satellite")):
        xc = controller.initial_state(y, r)
        xc[:4] = x
        xc, _ = controller.step(xc, y, r)
        plans.append(xc[6:])
        violations.append(controller.step_info()["soft_violation"])
    np.testing.assert_allclose(plans[1], plans[0], atol=1e-4)
    assert violations[1] == pytest.approx(violations[0], abs=1e-6)


@pytest.mark.parametrize(
    "change, match",
    [
        (dict(horizon=0), "horizon"),
        (dict(state_weight=np.array([np.nan, 1.0, 1.0, 1.0])), "state_weight"),
        (dict(input_weight=0.0), "input_weight"),
        (dict(state_weight=np.array([-1.0, 1.0, 1.0, 1.0])), "positive semidefinite"),
        (dict(rate_limit=[0.0]), "rate_limit"),
        (dict(sample_period=-0.01), "sample_period"),
    ],
)
def test_bad_design_input_names_the_culprit(change, match, build_mpc):
    with pytest.raises(ValueError, match=match):
        build_mpc("linear", "pendulum", **change)


def test_bad_problem_and_runtime_input_name_the_culprit(build_mpc):
    with pytest.raises(ValueError, match="infeasible"):
        mpc.MPCProblem([[1.0]], [[1.0]], 1.0, 1.0, 5, 1.0, -1.0)
    with pytest.raises(ValueError, match="soft bound 'z'"):
        mpc.MPCProblem(
            [[1.0]],
            [[1.0]],
            1.0,
            1.0,
            5,
            -1.0,
            1.0,
            soft_rows=[[1.0]],
            soft_lower=[1.0],
            soft_upper=[0.0],
            soft_names=["z"],
        )
    with pytest.raises(ValueError, match="horizon"):
        build_mpc("nonlinear", "arm", horizon=0)
    controller = build_mpc("linear", "pendulum")
    xc = controller.initial_state(np.zeros(2), np.zeros(1))
    with pytest.raises(ValueError, match="measurement"):
        controller.step(xc, np.zeros(3), np.zeros(1))
    with pytest.raises(ValueError, match="reference"):
        controller.step(xc, np.zeros(2), np.array([np.inf]))


class CrashingSolver(mpc.CondensedDaqpSolver):
    def solve(self, params):
        raise RuntimeError("licence server unreachable")


def test_a_solver_that_raises_is_a_reported_failure_not_an_exception(build_mpc):
    plant = models.get("arm")
    controller = build_mpc("linear", "arm", solver=CrashingSolver)
    result = models.simulate_closed_loop(plant, controller, 0.3, 0.05)
    assert all(s["fallback"] and "licence server unreachable" in s["status"] for s in result.status)
    # The first plan holds the equilibrium input of the measured configuration.
    np.testing.assert_allclose(result.u[:, 0], plant.equilibrium_input([0.0])[0], atol=1e-12)
