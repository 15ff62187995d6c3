"""mpc.tube_mpc tracking: the tube MPC with an artificial steady state (MPC for tracking) on the double
integrator with an additive disturbance in W, where its guarantee is exact. Its QP against the same
problem written out in cvxpy; its terminal set Ω_t invariant under the terminal law, point by point;
every constraint kept across reference changes of any size, under disturbances at W's corners (and a
nominal MPC of the same structure leaving them); convergence to the closest admissible steady state,
derived by hand; the offset a constant disturbance leaves, (I − A_K)⁻¹ w."""

from types import SimpleNamespace

import cvxpy as cp
import numpy as np
import pytest

from mpc.sets import Polytope, Zonotope
from mpc.tube import build_tube
from mpc.tube_mpc import STEADY_STATE_SCALE, TubeMPC, lyapunov_terminal_weight, nominal_sets

SAMPLE_PERIOD = 0.1
A = np.array([[1.0, SAMPLE_PERIOD], [0.0, 1.0]])
B = np.array([[SAMPLE_PERIOD**2 / 2], [SAMPLE_PERIOD]])
W_BOX = Zonotope.box([-0.01, -0.02], [0.01, 0.02])
#: Position within ±1, velocity within ±0.5: a reference change makes the plan ride the velocity limit.
LIMITS = Polytope.box([-1.0, -0.5], [1.0, 0.5])
MODEL = SimpleNamespace(A=A, B=B, xe=np.zeros(2), ue=np.zeros(1), sample_period=SAMPLE_PERIOD)
HORIZON = 15
POSITION = np.array([[1.0, 0.0]])
EAGER = {"state_weight": np.diag([100.0, 1e-2]), "input_weight": 1e-2}
#: The references, each held for its number of samples: within reach, beyond the position limit, back.
REFERENCES = ((0.5, 40), (3.0, 50), (-0.8, 60), (0.2, 50))
#: Clarabel's tolerances for the reference solution.
TIGHT = {"tol_gap_abs": 1e-12, "tol_gap_rel": 1e-12, "tol_feas": 1e-12, "tol_ktratio": 1e-10}


@pytest.fixture(scope="module")
def tube():
    return build_tube(A, B, W_BOX, LIMITS, [-1.0], [1.0], state_weight=np.eye(2), input_weight=1.0)


def tracker(sets, **kwargs):
    options = dict(horizon=HORIZON, tracked_rows=POSITION) | EAGER | kwargs
    return TubeMPC(MODEL, sets, **options)


def reference_signal():
    return np.concatenate([np.full(n, r) for r, n in REFERENCES])


def closed_loop(mpc, disturbances, start=(0.0, 0.0)):
    """x⁺ = A x + B u + w_k for the references of REFERENCES: states (K + 1, 2), inputs (K,), step records,
    until a QP fails (the nominal twin's, replanning from a state it cannot keep feasible, raises)."""
    x, records = np.array(start, dtype=float), []
    states, inputs = [x], []
    refs = reference_signal()
    z = mpc.initial_state(x, refs[:1])
    for r, w in zip(refs, disturbances):
        try:
            z, u = mpc.step(z, x, [r])
        except RuntimeError as error:
            records.append({"success": False, "status": str(error)})
            break
        records.append(mpc.step_info())
        x = A @ x + B @ u + w
        states.append(x)
        inputs.append(u[0])
    return np.array(states), np.array(inputs), records


def corner_disturbances(seed):
    """One w per sample: half the seeds at W's corners (its extreme points), half uniform inside."""
    rng, count = np.random.default_rng(seed), sum(n for _, n in REFERENCES)
    corners = W_BOX.corners()
    if seed % 2:
        return corners[rng.integers(len(corners), size=count)]
    return rng.uniform([-0.01, -0.02], [0.01, 0.02], size=(count, 2))


def excess(states, inputs) -> float:
    """The largest excess over |position| <= 1, |velocity| <= 0.5, |u| <= 1 (<= 0 inside)."""
    return max(float(np.max(np.abs(states) - [1.0, 0.5])), float(np.max(np.abs(inputs))) - 1.0)


def test_every_constraint_holds_across_reference_changes_for_disturbances_in_w(tube):
    """The reference jumps within reach, beyond the position limit and back: the plan rides the
    velocity limit and then the tightened position limit, and W's corners push against both. The
    nominal twin (untightened, replanning from the measured state) crosses them, or loses its QP's
    feasibility once it has."""
    robust = tracker(tube)
    twin = tracker(nominal_sets(A, B, tube.feedback, LIMITS, [-1.0], [1.0]), replan=True)
    worst_robust, worst_twin, twin_failed = -np.inf, -np.inf, 0
    for seed in range(30):
        w = corner_disturbances(seed)
        states, inputs, records = closed_loop(robust, w)
        assert len(records) == len(w) and all(r["success"] and r["error_in_tube"] for r in records)
        worst_robust = max(worst_robust, excess(states, inputs))
        states, inputs, records = closed_loop(twin, w)
        worst_twin, twin_failed = max(worst_twin, excess(states, inputs)), twin_failed + (not records[-1]["success"])
    assert worst_robust <= 0.0
    assert worst_twin > 1e-3  # the same loop without the tightening leaves the constraints
    assert twin_failed > 0


def test_converges_to_the_closest_admissible_steady_state(tube):
    """Undisturbed, from rest: a reference beyond the tightened position bound ends at λ (1 − h_Z(e_1)),
    the admissible steady state closest to it (the double integrator's steady states are (p, 0) with
    u = 0); one within reach ends at the reference itself."""
    mpc = tracker(tube)
    bound = 1.0 - tube.error_set.support(np.array([[1.0, 0.0]]))[0]
    for reference, expected in ((3.0, STEADY_STATE_SCALE * bound), (-0.4, -0.4)):
        x = np.zeros(2)
        z = mpc.initial_state(x, [reference])
        for _ in range(400):
            z, u = mpc.step(z, x, [reference])
            x = A @ x + B @ u
        np.testing.assert_allclose(x, [expected, 0.0], atol=1e-6)
        np.testing.assert_allclose(mpc.step_info()["target"], [expected], atol=1e-6)


def test_a_constant_disturbance_leaves_the_ancillary_loops_offset(tube):
    """The nominal state settles at the reference; the error e⁺ = A_K e + w settles at (I − A_K)⁻¹ w."""
    mpc, w = tracker(tube), np.array([0.004, -0.01])
    x, reference = np.zeros(2), 0.3
    z = mpc.initial_state(x, [reference])
    for _ in range(500):
        z, u = mpc.step(z, x, [reference])
        x = A @ x + B @ u + w
    offset = np.linalg.solve(np.eye(2) - tube.closed_loop, w)
    np.testing.assert_allclose(x, [reference, 0.0] + offset, atol=1e-6)


def test_plan_and_target_equal_cvxpy_on_the_tracking_problem(tube):
    """The condensed, scaled DAQP plan and θ against the uncondensed problem written out in cvxpy
    (the k = 0 stage cost included: it depends on θ), for a reference beyond the limit."""
    mpc, z0, reference = tracker(tube), np.array([0.3, 0.2]), 2.0
    plan, success, _, _ = mpc.solve(z0, [reference])
    assert success
    Q, R = EAGER["state_weight"], EAGER["input_weight"]
    P = lyapunov_terminal_weight(tube.closed_loop, tube.feedback, Q, np.eye(1) * R)
    Sx, Sv = mpc.target.state_per_reference, mpc.target.input_per_reference
    T = 100 * Sx.T @ P @ Sx
    z, v, theta = cp.Variable((HORIZON + 1, 2)), cp.Variable((HORIZON, 1)), cp.Variable(1)
    xs, us = Sx @ theta, Sv @ theta
    G, g = tube.state_constraints.H, tube.state_constraints.h
    cons = [z[0] == z0, mpc.terminal_set.H @ cp.hstack([z[HORIZON], theta]) <= mpc.terminal_set.h]
    cons += [z[k + 1] == A @ z[k] + B @ v[k] for k in range(HORIZON)]
    cons += [G @ z[k] <= g for k in range(1, HORIZON)]
    cons += [v >= tube.input_lower[0], v <= tube.input_upper[0]]
    cost = sum(cp.quad_form(z[k] - xs, Q) + R * cp.sum_squares(v[k] - us) for k in range(HORIZON))
    cost += cp.quad_form(z[HORIZON] - xs, P) + cp.quad_form(theta - reference, T)
    cp.Problem(cp.Minimize(cost), cons).solve(solver=cp.CLARABEL, **TIGHT)
    np.testing.assert_allclose(plan, v.value, atol=1e-6)
    np.testing.assert_allclose(mpc.last_target, theta.value, atol=1e-6)
    assert theta.value[0] < 1.0 - 1e-3  # the terminal set holds θ back: the constraint is active


def test_the_tracking_terminal_set_is_invariant_under_the_terminal_law(tube):
    """Points of Ω_t (sampled in its bounding box) map inside it under v = K (z − x_s) + u_s with θ held,
    and keep z in X ⊖ Z, v in U ⊖ K Z and the steady state in λ (X ⊖ Z)."""
    mpc = tracker(tube)
    omega, K = mpc.terminal_set, tube.feedback
    Sx, Sv = mpc.target.state_per_reference, mpc.target.input_per_reference
    rng = np.random.default_rng(3)
    box = omega.support(np.vstack([np.eye(3), -np.eye(3)]))
    points = rng.uniform(-box[3:], box[:3], size=(20000, 3))
    points = points[omega.contains(points, tolerance=0.0)]
    assert len(points) > 500
    z, theta = points[:, :2], points[:, 2:]
    xs, us = theta @ Sx.T, theta @ Sv.T
    v = (z - xs) @ K.T + us
    following = np.hstack([z @ A.T + v @ B.T, theta])
    assert np.all(omega.contains(following, tolerance=1e-9))
    assert np.all(tube.state_constraints.contains(z, tolerance=1e-9))
    assert np.all((v >= tube.input_lower - 1e-9) & (v <= tube.input_upper + 1e-9))
    assert np.all(tube.state_constraints.contains(xs / STEADY_STATE_SCALE, tolerance=1e-9))


def test_the_reference_changes_the_cost_not_the_constraints(tube):
    """Feasibility does not depend on r: the QP's rows and bounds are the same for every reference."""
    mpc, z0 = tracker(tube), np.array([0.2, 0.1])
    _, upper_a, lower_a = mpc._vectors(np.concatenate([z0, [0.5]]))
    _, upper_b, lower_b = mpc._vectors(np.concatenate([z0, [50.0]]))
    np.testing.assert_array_equal(upper_a, upper_b)
    np.testing.assert_array_equal(lower_a, lower_b)


def test_refuses_coordinates_no_steady_state_holds_and_a_missing_reference(tube):
    with pytest.raises(ValueError, match="cannot be held at a steady state"):
        tracker(tube, tracked_rows=[[0.0, 1.0]])  # a constant velocity other than 0 is no steady state
    with pytest.raises(ValueError, match="needs the reference"):
        tracker(tube).solve(np.zeros(2))
    with pytest.raises(ValueError, match=r"λ must be in \(0, 1\)"):
        tracker(tube, steady_state_scale=1.0)
