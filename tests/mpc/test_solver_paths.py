"""Every solver path solves the same QP: the condensed DAQP path, OSQP on the sparse
problem and cvxpy rebuilt from numbers return the first input of the cvxpy reference
(Clarabel, parametrized) to 1e-5 (DAQP, exact, to 1e-8 of the input limit), on instances
that saturate the input, violate a soft bound and hit a rate limit.

The tolerance is 1e-5 in the plant's input unit (N or N m) and, for the crane, 1e-5 of
its 5 kN limit. One exception, measured and kept visible here: OSQP (first-order) does
not reach its 1e-7 tolerances within 20000 iterations on most crane instances (a 4 s
horizon of lightly damped swing modes, kilonewtons against radians). It then reports
"maximum iterations reached", which the controller treats as a failure, and when it
does report "solved" its first input is up to 0.06 N (1.2e-5 of the limit) off; that
case is checked at 1e-4 of the limit. Whenever a path reports success its first input
must agree; DAQP and cvxpy must succeed everywhere. (The crane's states are spread less
than the others': with swings beyond ±0.1 rad Clarabel itself stops at
"optimal_inaccurate" at the reference's 1e-12 tolerances.)"""

import numpy as np
import pytest

import models
import mpc
from mpc.linear import QPParameters, SoftBound, problem_from_model
from mpc.reference_cvxpy import CvxpySolver

PATHS = {
    "daqp": mpc.CondensedDaqpSolver,
    "osqp": mpc.OsqpSolver,
    "cvxpy rebuilt": lambda problem: CvxpySolver(problem, parametrized=False),
}
#: Paths that must succeed on every instance of a case.
ALWAYS_SUCCEED = {"daqp", "cvxpy rebuilt"}
#: DAQP's active-set solution is exact: its first input is held to this fraction of the input limit
#: (measured: 5e-10 of the limit or less; the crane's 1e-5 N is the reference's own error).
EXACT = 1e-8


def pendulum_problem(rate_limit=1.0):
    plant = models.get("pendulum")
    model = plant.linearize().discretize(0.01)
    soft = [SoftBound.on(plant, {"theta": 1.0}, -0.15, 0.15, name="theta")]
    return problem_from_model(
        model, [1.0, 10.0, 0.1, 0.1], 1e-2, 30, plant.input_limit, rate_limit=rate_limit, soft_bounds=soft
    )


def ballbeam_problem():
    plant = models.get("ballbeam")
    model = plant.linearize().discretize(0.01)
    soft = [SoftBound.on(plant, {"z": 1.0}, 0.05, 0.45, name="ball on beam")]
    return problem_from_model(model, [100.0, 10.0, 1.0, 1.0], 1 / 15**2, 40, plant.input_limit, soft_bounds=soft)


def crane_problem():
    plant = models.get("crane1")
    model = plant.linearize().discretize(0.1)
    soft = [SoftBound.on(plant, {"theta": 1.0}, -0.05, 0.05, name="swing")]
    return problem_from_model(model, [1.0, 100.0, 1.0, 100.0], 1 / 5000**2, 40, plant.input_limit, soft_bounds=soft)


def arm_problem():
    plant = models.get("arm")
    return problem_from_model(plant.linearize().discretize(0.01), [100.0, 0.1], 1.0, 50, plant.input_limit)


def random_instances(problem, scale, count, seed):
    """Estimates, disturbances and targets spread wide enough to saturate and violate."""
    rng = np.random.default_rng(seed)
    nx, nu = problem.nx, problem.nu
    out = []
    for _ in range(count):
        x_target = np.zeros(nx)
        x_target[0] = rng.normal() * scale[0]
        out.append(
            QPParameters(
                rng.normal(size=nx) * scale,
                rng.normal(size=nu) * 0.1 * problem.input_upper,
                x_target,
                rng.normal(size=nu) * 0.1 * problem.input_upper,
                rng.uniform(problem.input_lower, problem.input_upper),
            )
        )
    return out


CRANE_LIMIT = 5000.0
CASES = {  # problem, state spread, OSQP must succeed everywhere, first-input tolerance, OSQP's tolerance
    "pendulum (soft theta, rate limit)": (pendulum_problem, np.array([0.5, 0.08, 0.5, 0.5]), True, 1e-5, 1e-5),
    "ball on beam (soft ends)": (ballbeam_problem, np.array([0.15, 0.05, 0.5, 0.5]), True, 1e-5, 1e-5),
    "crane, kilonewtons (soft swing)": (
        crane_problem,
        np.array([1.0, 0.06, 0.3, 0.02]),
        False,
        1e-5 * CRANE_LIMIT,
        1e-4 * CRANE_LIMIT,
    ),
    "arm (input bounds only)": (arm_problem, np.array([1.0, 2.0]), True, 1e-5, 1e-5),
}


@pytest.mark.parametrize("case", list(CASES))
def test_first_input_of_every_path_matches_the_cvxpy_reference(case):
    build, scale, osqp_converges, tolerance, osqp_tolerance = CASES[case]
    problem = build()
    reference = CvxpySolver(problem)
    paths = {name: make(problem) for name, make in PATHS.items()}
    must_succeed = ALWAYS_SUCCEED | ({"osqp"} if osqp_converges else set())
    successes = dict.fromkeys(PATHS, 0)
    limit = max(1.0, float(np.max(problem.input_upper - problem.input_lower)) / 2)
    saturated = violated = rate_bound = 0
    for params in random_instances(problem, scale, 12, seed=len(case)):
        ref = reference.solve(params)
        assert ref.success, ref.status
        u0 = ref.inputs[0]
        saturated += np.any(
            np.isclose(ref.inputs, problem.input_lower, atol=1e-7)
            | np.isclose(ref.inputs, problem.input_upper, atol=1e-7)
        )
        violated += bool(problem.n_soft and np.max(ref.slacks) > 1e-4)
        if problem.rate_limit is not None:
            steps = np.abs(np.diff(np.vstack([params.u_previous, ref.inputs]), axis=0))
            rate_bound += bool(np.any(np.isclose(steps, problem.rate_limit, atol=1e-7)))
        for name, solver in paths.items():
            solution = solver.solve(params)
            if name in must_succeed:
                assert solution.success, f"{name}: {solution.status}"
            if not solution.success:
                continue
            successes[name] += 1
            atol = osqp_tolerance if name == "osqp" else (EXACT * limit if name == "daqp" else tolerance)
            np.testing.assert_allclose(solution.inputs[0], u0, atol=atol, rtol=0, err_msg=name)
            # Same optimum, not just the same first move.
            assert problem.cost(params, solution.inputs, solution.slacks) == pytest.approx(
                problem.cost(params, ref.inputs, ref.slacks), rel=1e-6 if atol <= tolerance else 1e-4, abs=1e-9
            ), name
    assert min(successes.values()) >= 1
    # The instances exercise the constraints they are meant to.
    assert saturated >= 2
    if problem.n_soft:
        assert violated >= 1
    if problem.rate_limit is not None:
        assert rate_bound >= 1


def test_daqp_matches_reference_along_a_closed_loop_with_the_soft_bound_riding(pendulum_qp_records):
    """Closed-loop instances where |theta| rides on its bound with zero slack (degenerate
    for first-order methods: OSQP does not reach 1e-5 there within 20000 iterations)."""
    controller, recorded = pendulum_qp_records
    reference = CvxpySolver(controller.problem)
    bound = controller.problem.soft_upper[0]
    riding = 0
    for params, solution in recorded:
        ref = reference.solve(params)
        np.testing.assert_allclose(solution.inputs[0], ref.inputs[0], atol=1e-5, rtol=0)
        theta = controller.problem.simulate(params.x0, ref.inputs, params.disturbance)[1:, 1]
        riding += np.sum(np.isclose(np.abs(theta), bound, atol=1e-7)) >= 3
    assert riding >= 5
