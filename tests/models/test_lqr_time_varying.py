"""models.lqr.dlqr_time_varying against the stationary Riccati solution and the batch least-squares optimum."""

import numpy as np
import pytest

from models import lqr


def random_system(steps, n=3, m=2, seed=1):
    rng = np.random.default_rng(seed)
    As = np.eye(n) + 0.3 * rng.standard_normal((steps, n, n))
    Bs = rng.standard_normal((steps, n, m))
    root = rng.standard_normal((n, n))
    return As, Bs, np.diag([1.0, 2.0, 0.5]), np.diag([0.3, 1.5]), root @ root.T


def test_constant_model_converges_to_the_stationary_gain():
    A = np.array([[1.0, 0.1], [0.2, 0.97]])
    B = np.array([[0.005], [0.1]])
    Q, R = np.diag([10.0, 1.0]), np.array([[0.5]])
    K, P = lqr.dlqr(A, B, Q, R)
    gains, costs = lqr.dlqr_time_varying(np.repeat(A[None], 400, 0), np.repeat(B[None], 400, 0), Q, R, np.zeros((2, 2)))
    np.testing.assert_allclose(gains[0], K, rtol=1e-9)
    np.testing.assert_allclose(costs[0], P, rtol=1e-9)
    # Started from the stationary cost, the recursion stays there: every gain is K.
    gains, _ = lqr.dlqr_time_varying(np.repeat(A[None], 5, 0), np.repeat(B[None], 5, 0), Q, R, P)
    np.testing.assert_allclose(gains, np.repeat(K[None], 5, 0), rtol=1e-10)


def test_optimal_cost_and_inputs_equal_the_batch_least_squares_answer():
    """The finite-horizon LQ problem is a quadratic in the stacked inputs: x = Φ x₀ + Γ u; its minimizer
    (normal equations) must be the feedback's inputs, its value x₀ᵀ P₀ x₀."""
    steps = 6
    As, Bs, Q, R, final = random_system(steps)
    n, m = Bs.shape[1], Bs.shape[2]
    x0 = np.array([1.0, -0.5, 2.0])
    Phi = np.zeros(((steps + 1) * n, n))
    Gamma = np.zeros(((steps + 1) * n, steps * m))
    Phi[:n] = np.eye(n)
    for k in range(steps):
        rows, previous = slice((k + 1) * n, (k + 2) * n), slice(k * n, (k + 1) * n)
        Phi[rows] = As[k] @ Phi[previous]
        Gamma[rows] = As[k] @ Gamma[previous]
        Gamma[rows, k * m : (k + 1) * m] += Bs[k]
    weight = np.zeros(((steps + 1) * n, (steps + 1) * n))
    for k in range(steps):
        weight[k * n : (k + 1) * n, k * n : (k + 1) * n] = Q
    weight[steps * n :, steps * n :] = final
    input_weight = np.kron(np.eye(steps), R)
    hessian = Gamma.T @ weight @ Gamma + input_weight
    u_best = -np.linalg.solve(hessian, Gamma.T @ weight @ Phi @ x0)
    x_best = Phi @ x0 + Gamma @ u_best
    cost_best = x_best @ weight @ x_best + u_best @ input_weight @ u_best

    gains, costs = lqr.dlqr_time_varying(As, Bs, Q, R, final)
    x, u = x0.copy(), []
    for k in range(steps):
        u.append(-gains[k] @ x)
        x = As[k] @ x + Bs[k] @ u[-1]
    np.testing.assert_allclose(np.concatenate(u), u_best, rtol=1e-9, atol=1e-12)
    assert x0 @ costs[0] @ x0 == pytest.approx(cost_best, rel=1e-10)


def test_bad_shapes_and_weights_are_named():
    As, Bs, Q, R, final = random_system(4)
    with pytest.raises(ValueError, match=r"Bs must have shape \(4, 3, nu\)"):
        lqr.dlqr_time_varying(As, Bs[:3], Q, R, final)
    with pytest.raises(ValueError, match="As must have shape"):
        lqr.dlqr_time_varying(As[0], Bs, Q, R, final)
    with pytest.raises(ValueError, match="final_weight must be a symmetric"):
        lqr.dlqr_time_varying(As, Bs, Q, R, np.ones((3, 2)))
    with pytest.raises(ValueError, match="final_weight must be positive semidefinite"):
        lqr.dlqr_time_varying(As, Bs, Q, R, -np.eye(3))
    with pytest.raises(ValueError, match="R must be positive definite"):
        lqr.dlqr_time_varying(As, Bs, Q, np.zeros((2, 2)), final)
