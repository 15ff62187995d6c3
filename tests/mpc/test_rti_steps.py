"""The real-time iteration's construction steps alone (mpc.rti_linearization, mpc.condensed_qp,
mpc.rti), each against a hand derivation or the stacked matrices built with numpy loops: the forward
recursion against simulating the linear dynamics, the backward recursion's condensed Hessian and
gradient against the stacked QP, the rows' assignment to intervals and the shift on a hand-written
layout."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from mpc import condensed_qp
from mpc.condensed_qp import Dimensions
from mpc.rti import shift_index
from mpc.rti_linearization import assign_rows


def random_dynamics(rng, dims: Dimensions):
    """N random (A_k, B_k, a_k), and the same side by side as the recursions take them (DM)."""
    N, nx, nd = dims.intervals, dims.nx, dims.nd
    A = [rng.normal(scale=0.5, size=(nx, nx)) for _ in range(N)]
    B = [rng.normal(size=(nx, nd)) for _ in range(N)]
    a = [rng.normal(size=nx) for _ in range(N)]
    sequences = (ca.DM(np.hstack(A)), ca.DM(np.hstack(B)), ca.DM(np.column_stack(a)))
    return (A, B, a), sequences


def simulate(A, B, a, s0, d):
    """s_0..s_N of s_{k+1} = A_k s_k + B_k d_k + a_k."""
    states = [np.asarray(s0, dtype=float)]
    for k in range(len(A)):
        states.append(A[k] @ states[-1] + B[k] @ d[k] + a[k])
    return states


def test_forward_recursion_gives_the_states_of_the_linear_dynamics():
    """Γ_k z = s_k for z = (Δs_0, 1, Δd_0, ..., Δd_{N-1}), s_k simulated step by step."""
    rng = np.random.default_rng(3)
    dims = Dimensions(intervals=6, nx=3, nq=2, dynamic=(0, 1), static=())
    (A, B, a), (A_seq, B_seq, a_seq) = random_dynamics(rng, dims)
    Gamma = condensed_qp.forward(A_seq, B_seq, a_seq, condensed_qp.selections(dims), dims)
    assert len(Gamma) == dims.intervals + 1
    for _ in range(3):
        s0, d = rng.normal(size=dims.nx), rng.normal(size=(dims.intervals, dims.nd))
        z = np.concatenate([s0, [1.0], d.ravel()])
        for k, state in enumerate(simulate(A, B, a, s0, d)):
            np.testing.assert_allclose(np.asarray(Gamma[k]) @ z, state, rtol=0, atol=1e-12)


def stacked_qp(A, B, a, hessians, gradients, dims: Dimensions):
    """The QP in v = (d_0..d_{N-1}, σ_0..σ_{N-1}) with Δs_0 as a parameter, by stacking: the map
    (v, Δs_0, 1) -> every (s_k, q_k) built column by column from `simulate`, then Σ Tᵀ H_k T.
    Returns (Hessian in v, ∂²/∂v∂Δs_0, gradient in v at v = 0, Δs_0 = 0)."""
    N, nx, nq, nd = dims.intervals, dims.nx, dims.nq, dims.nd
    nD, nV = dims.n_dynamic, dims.n_variables
    n_in = nV + nx + 1  # (v, Δs_0, 1)

    def stage_values(column):
        v, s0, one = column[:nV], column[nV : nV + nx], column[-1]
        d = v[:nD].reshape(N, nd)
        sigma = v[nD:].reshape(N, dims.nst)
        states = simulate(A, B, [one * ak for ak in a], s0, d)
        values = []
        for k in range(N):
            q = np.zeros(nq)
            q[list(dims.dynamic)], q[list(dims.static)] = d[k], sigma[k]
            values.append(np.concatenate([states[k], q]))
        return values + [states[N]]

    T = [np.column_stack(parts) for parts in zip(*[stage_values(e) for e in np.eye(n_in)])]
    H = sum(Tk.T @ Hk @ Tk for Tk, Hk in zip(T, hessians))
    g = sum(Tk.T @ gk for Tk, gk in zip(T, gradients))
    # cost(v, s0, 1) = ½ yᵀ H y + gᵀ y with y = (v, s0, 1): ∇_v at (0, 0, 1) = H[v, one] + g[v]
    return H[:nV, :nV], H[:nV, nV : nV + nx], H[:nV, -1] + g[:nV]


@pytest.mark.parametrize("coupled", [False, True])
def test_backward_recursion_gives_the_stacked_qps_hessian_and_gradient(coupled):
    """The condensed Hessian's blocks (H_dd mirrored from its lower triangle, H_σd, H_σσ), the
    gradient's matrix on Δs_0 and its constant part against the stacked QP of random stage
    Hessians (positive definite) and gradients, with a static control (σ) in the middle of q;
    without coupling, the σ rows and columns of the stage Hessians hold only H_σσ."""
    rng = np.random.default_rng(11)
    dims = Dimensions(intervals=5, nx=3, nq=3, dynamic=(0, 2), static=(1,))
    N, nx, nq = dims.intervals, dims.nx, dims.nq
    (A, B, a), (A_seq, B_seq, a_seq) = random_dynamics(rng, dims)
    hessians, gradients = [], []
    for k in range(N + 1):
        n = nx + nq if k < N else nx
        root = rng.normal(size=(n, n))
        H = root @ root.T + n * np.eye(n)
        if not coupled and k < N:
            sigma = nx + 1
            others = [i for i in range(n) if i != sigma]
            H[sigma, others] = H[others, sigma] = 0.0
        hessians.append(H)
        gradients.append(rng.normal(size=n))
    E_seq = condensed_qp.selections(dims)
    Gamma = condensed_qp.forward(A_seq, B_seq, a_seq, E_seq, dims)
    H_dm, g_dm = [ca.DM(H) for H in hessians], [ca.DM(g) for g in gradients]
    Hd_all, Hs_all = condensed_qp.backward(Gamma, A_seq, B_seq, E_seq, H_dm, g_dm, dims, coupled)
    blocks = condensed_qp.hessian_blocks(Hd_all, Hs_all, H_dm, dims, coupled)
    H_vv, H_v0, h = stacked_qp(A, B, a, hessians, gradients, dims)
    nD = dims.n_dynamic
    scale = np.abs(H_vv).max()
    dense = lambda M: np.asarray(ca.densify(M))
    np.testing.assert_allclose(dense(blocks.H_dd), H_vv[:nD, :nD], rtol=0, atol=1e-12 * scale)
    np.testing.assert_allclose(dense(blocks.H_ss), H_vv[nD:, nD:], rtol=0, atol=1e-12 * scale)
    if coupled:
        np.testing.assert_allclose(dense(blocks.H_sd), H_vv[nD:, :nD], rtol=0, atol=1e-12 * scale)
    else:
        np.testing.assert_array_equal(H_vv[nD:, :nD], 0.0)
        assert blocks.H_sd.shape == (dims.n_static, 0)
    np.testing.assert_allclose(dense(blocks.H_v0), H_v0, rtol=0, atol=1e-12 * np.abs(H_v0).max())
    np.testing.assert_allclose(dense(blocks.h_const).ravel(), h, rtol=0, atol=1e-12 * np.abs(h).max())


def test_couples_names_a_slack_that_meets_a_state_or_an_input_in_the_hessian():
    stage_q = np.array([[1, 2], [4, 5]])  # w = (x0, u0, σ0, x1, u1, σ1, x2): σ at column 1
    alone = ca.Sparsity.triplet(7, 7, [2, 5, 0, 1], [2, 5, 0, 1])
    with_state = ca.Sparsity.triplet(7, 7, [2, 0, 5], [0, 2, 5])
    with_input = ca.Sparsity.triplet(7, 7, [4, 5], [5, 4])
    assert not condensed_qp.couples(alone, stage_q, (1,))
    assert condensed_qp.couples(with_state, stage_q, (1,))
    assert condensed_qp.couples(with_input, stage_q, (1,))


# w = (x_0, u_0, x_1, u_1, x_2): one state, one input, two intervals
STATES, STAGE_Q = np.array([[0], [2], [4]]), np.array([[1], [3]])
STAGE_OF = np.array([0, 0, 1, 1, 2])


def rows_reading(*columns):
    rows = [r for r, cols in enumerate(columns) for _ in cols]
    cols = [c for cols in columns for c in cols]
    return ca.Sparsity.triplet(len(columns), 5, rows, cols)


def test_rows_go_to_the_last_interval_whose_decisions_hold_them():
    """By hand: (x_0, u_0) only fits interval 0; x_1 alone fits 0 (as s_{k+1}) and 1, so 1; the rate
    u_1 - u_0 fits 1 (q_k, q_{k-1}); (x_2, u_1) fits 1 and the end, so the end."""
    pattern = rows_reading([0, 1], [2], [1, 3], [3, 4])
    rows = assign_rows(pattern, np.array([10, 11, 12, 13]), STATES, STAGE_Q, STAGE_OF)
    assert rows == [[10], [11, 12], [13]]


def test_a_row_spanning_intervals_is_named_with_its_mesh_points():
    with pytest.raises(ValueError, match=r"row 7 spans mesh points \[0, 2\]"):
        assign_rows(rows_reading([0, 4]), np.array([7]), STATES, STAGE_Q, STAGE_OF)


def test_shift_moves_every_interval_up_and_repeats_the_last_input():
    """By hand: (x_0, u_0, x_1, u_1, x_2) one interval later is (x_1, u_1, x_2, u_1, x_2)."""
    np.testing.assert_array_equal(shift_index(STATES, STAGE_Q), [2, 3, 4, 3, 4])
