"""designs.trajectory_tracking: Jacobians against finite differences, the schedule against the linear
deviation dynamics it was designed for, the catch against the stationary LQR."""

import numpy as np
import pytest

import models
import mpc
from designs import trajectory_tracking as tracking
from models.lqr import bryson_weights, dlqr

TS, SUBSTEPS = 0.01, 2
ANGLE = np.radians(10)
WEIGHTS = bryson_weights([0.01, 0.1], [5.0])


def test_step_jacobians_match_central_differences():
    plant = models.get("pendulum")
    rng = np.random.default_rng(3)
    states = rng.uniform(-1, 1, (4, plant.nx)) + [0, np.pi / 2, 0, 0]
    inputs = rng.uniform(-3, 3, (4, plant.nu))
    As, Bs = tracking.linearize_along(plant, TS, states, inputs, SUBSTEPS)
    step = plant.step_function(TS, SUBSTEPS)
    p = plant.param_vector()
    F = lambda x, u: np.asarray(step(x, u, p), dtype=float).ravel()
    h = 1e-6
    for k in range(4):
        A = np.column_stack(
            [(F(states[k] + h * e, inputs[k]) - F(states[k] - h * e, inputs[k])) / (2 * h) for e in np.eye(plant.nx)]
        )
        B = (F(states[k], inputs[k] + h) - F(states[k], inputs[k] - h))[:, None] / (2 * h)
        np.testing.assert_allclose(As[k], A, atol=1e-8)
        np.testing.assert_allclose(Bs[k], B, atol=1e-8)


@pytest.fixture(scope="module")
def roll():
    """A 2 s UUV roll 0 -> 10 deg, rest to rest (then held against the restoring moment), least ∫τ², on the
    simulator's own step: multiple shooting with one interval per sample and the closed loop's RK4 sub-steps."""
    plant = models.get("uuv")
    steps = 200
    ocp = mpc.OptimalControlProblem(plant, steps * TS)
    ocp.minimize(ocp.integral(ocp.u.tau**2))
    ocp.subject_to(ocp.at_start(ocp.state) == [0.0, 0.0])
    ocp.subject_to(ocp.at_end(ocp.state) == [ANGLE, 0.0])
    solution = ocp.solve(mpc.MultipleShooting(intervals=steps, substeps=SUBSTEPS), solver_options={"tolerance": 1e-12})
    assert solution.success, solution.status
    assert np.max(np.abs(solution.inputs)) < 0.5 * plant.input_limit[0]  # room for the feedback: no saturation
    Q, R = WEIGHTS
    design = tracking.tvlqr_tracking(plant, TS, solution.states, solution.inputs, Q, R, substeps=SUBSTEPS)
    return plant, solution, design


def test_on_the_trajectory_the_block_reproduces_it(roll):
    plant, solution, design = roll
    run = models.simulate_closed_loop(
        plant, design.block, design.reference(2.5), 2.5, x0=solution.states[0], substeps=SUBSTEPS
    )
    steps = len(solution.inputs)
    np.testing.assert_allclose(run.x[: steps + 1], solution.states, atol=1e-8)
    np.testing.assert_allclose(run.u[:steps], solution.inputs, atol=1e-6)
    # Held at the end by the LQR with the equilibrium torque.
    np.testing.assert_allclose(run.x[-1], solution.states[-1], atol=1e-8)
    np.testing.assert_allclose(run.u[-1], plant.equilibrium_input([ANGLE]), atol=1e-6)


def test_a_small_start_error_follows_the_designed_deviation_dynamics(roll):
    """δx_{k+1} = (A_k − B_k K_k) δx_k to first order: the gains are wired in the right order and sign."""
    plant, solution, design = roll
    delta = np.array([1e-4, -2e-4])
    run = models.simulate_closed_loop(
        plant, design.block, design.reference(2.0), 2.0, x0=solution.states[0] + delta, substeps=SUBSTEPS
    )
    As, Bs = tracking.linearize_along(plant, TS, solution.states, solution.inputs, SUBSTEPS)
    predicted = [delta]
    for k in range(len(solution.inputs)):
        predicted.append((As[k] - Bs[k] @ design.gains[k]) @ predicted[-1])
    deviation = run.x - solution.states
    np.testing.assert_allclose(deviation, np.array(predicted), atol=1e-8)
    assert np.max(np.abs(deviation)) > 1e-5  # the deviation is there, and shrinks
    assert np.linalg.norm(deviation[-1]) < 0.1 * np.linalg.norm(delta)


def test_gains_join_the_stationary_lqr_at_the_end(roll):
    plant, solution, design = roll
    end = solution.states[-1]
    As, Bs = tracking.linearize_along(plant, TS, [end], [design.final_input], SUBSTEPS)
    K, P = dlqr(As[0], Bs[0], *WEIGHTS)
    np.testing.assert_allclose(design.final_gain, K, rtol=1e-12)
    np.testing.assert_allclose(design.cost_to_go[-1], P, rtol=1e-12)
    # The last gain is one Riccati step from P: close to K on a move that ends where it is held.
    np.testing.assert_allclose(design.gains[-1], K, rtol=0.05)
    reference = design.reference(2.2)
    assert reference.shape == (221, 2 + 1 + 2)
    np.testing.assert_allclose(reference[200:, 3:], np.repeat(K, 21, 0), rtol=1e-15)


def test_a_trajectory_that_does_not_end_at_rest_is_refused():
    plant = models.get("arm")
    states = np.array([[0.0, 0.0], [0.001, 0.1]])
    with pytest.raises(ValueError, match="must end at rest"):
        tracking.tvlqr_tracking(plant, TS, states, [[1.0]], np.eye(2), np.eye(1))
    with pytest.raises(ValueError, match="one row more than inputs"):
        tracking.tvlqr_tracking(plant, TS, states, [[1.0], [1.0]], np.eye(2), np.eye(1))
