"""mpc.tube: the tube MPC's sets, each checked against something independent: a hand-derived
mRPI set, simulated error trajectories, worst-case disturbance sequences, cvxpy's LP, brute force
over the corners of the error's region, and a closed loop on a plant where the guarantee is exact."""

import re

import cvxpy as cp
import numpy as np
import pytest

import models
from models.uncertainty import corner_params
from mpc.sets import EmptySetError, Polytope, Zonotope, maximal_invariant_set
from mpc.tube import (
    TubeOptions,
    ancillary_feedback,
    build_tube,
    disturbance_set,
    input_disturbance_set,
    invariant_polytope,
    minimal_rpi_approximation,
    parametric_error_set,
    tighten,
    vertex_models,
)

SAMPLE_PERIOD = 0.1
#: The double integrator x = (position, velocity) with a unit mass, held input (exact ZOH).
A = np.array([[1.0, SAMPLE_PERIOD], [0.0, 1.0]])
B = np.array([[SAMPLE_PERIOD**2 / 2], [SAMPLE_PERIOD]])
W_BOX = Zonotope.box([-0.01, -0.02], [0.01, 0.02])
LIMITS = Polytope.box([-1.0, -1.0], [1.0, 1.0])
NAMES = ("position upper", "velocity upper", "position lower", "velocity lower")


def cvxpy_support(P: Polytope, d) -> float:
    """max dᵀx over P by cvxpy with Clarabel (an interior-point method, not the module's DAQP or HiGHS)."""
    x = cp.Variable(P.dimension)
    problem = cp.Problem(cp.Maximize(np.asarray(d) @ x), [P.H @ x <= P.h])
    problem.solve(solver=cp.CLARABEL)
    assert problem.status == cp.OPTIMAL
    return float(problem.value)


def points_of(P: Polytope, rng, count: int = 200) -> np.ndarray:
    """Boundary points (support maximizers in random directions) and random convex combinations of them."""
    _, boundary = P.support_points(rng.normal(size=(count, P.dimension)))
    weights = rng.dirichlet(np.ones(len(boundary)) * 0.3, size=count)
    return np.vstack([boundary, weights @ boundary])


@pytest.fixture(scope="module")
def tube():
    return build_tube(
        A, B, W_BOX, LIMITS, [-1.0], [1.0], state_weight=np.eye(2), input_weight=1.0, state_constraint_names=NAMES
    )


@pytest.fixture(scope="module")
def template_tube():
    """The same tube with Z from the template LP (no exact facets allowed)."""
    return build_tube(
        A, B, W_BOX, LIMITS, [-1.0], [1.0], state_weight=np.eye(2), input_weight=1.0, options=TubeOptions(facet_limit=0)
    )


# ------------------------------------------------------------------------------- invariance of Z
@pytest.mark.parametrize("which", ["tube", "template_tube"])
def test_error_set_maps_into_itself_under_every_corner_of_W(which, request):
    sets = request.getfixturevalue(which)
    Z, A_K = sets.error_set, sets.closed_loop
    e = points_of(Z, np.random.default_rng(0))
    assert np.all(Z.contains(e, tolerance=1e-9))
    for w in W_BOX.corners():  # W is convex and the map affine in w: its corners suffice
        assert np.all(Z.contains(e @ A_K.T + w, tolerance=1e-9)), w
    assert sets.error_set_exact is (which == "tube")


def test_closed_loop_is_the_lqr_with_the_tube_sign():
    K = ancillary_feedback(A, B, np.eye(2), 1.0)
    P = np.eye(2)
    for _ in range(2000):  # the Riccati recursion, iterated to its fixed point: an independent LQR
        P = np.eye(2) + A.T @ P @ A - A.T @ P @ B @ np.linalg.solve(1.0 + B.T @ P @ B, B.T @ P @ A)
    np.testing.assert_allclose(K, -np.linalg.solve(1.0 + B.T @ P @ B, B.T @ P @ A), rtol=1e-9)
    assert np.all(np.abs(np.linalg.eigvals(A + B @ K)) < 1)


# ----------------------------------------------------------------- the mRPI set against a hand case
@pytest.mark.parametrize("a", [0.5, -0.8, 0.9])
def test_scalar_mrpi_approximation_contains_the_hand_set_within_its_epsilon(a):
    """e⁺ = a e + w, |w| ≤ 1: F_∞ = [−1/(1 − |a|), 1/(1 − |a|)]; A^s W = |a|^s W, so α = |a|^s and s is
    the first with α/(1 − α) ≤ relative_epsilon."""
    relative = 0.01
    approximation = minimal_rpi_approximation([[a]], Zonotope.box([-1.0], [1.0]), relative_epsilon=relative)
    s = int(np.ceil(np.log(relative / (1 + relative)) / np.log(abs(a))))
    assert approximation.terms == s
    assert approximation.alpha == pytest.approx(abs(a) ** s, rel=1e-12)
    exact = 1 / (1 - abs(a))
    epsilon = approximation.epsilon[0]
    assert epsilon == pytest.approx(abs(a) ** s / (1 - abs(a)), rel=1e-9)  # α/(1 − α)·h_{F_s}, by hand
    Z, is_exact = invariant_polytope(approximation)
    assert is_exact
    for values in (approximation.support([[1.0], [-1.0]]), Z.support([[1.0], [-1.0]])):
        assert np.all(values >= exact * (1 - 1e-12))
        assert np.all(values <= exact + epsilon)


# --------------------------------------------------------------- the double integrator, by simulation
def test_error_set_contains_simulated_error_trajectories(tube):
    rng = np.random.default_rng(1)
    lower, upper = W_BOX.interval_hull()
    runs, steps = 200, 300
    e = np.zeros((runs, 2))
    for k in range(steps):
        w = rng.uniform(lower, upper, size=(runs, 2))
        w[: runs // 4] = np.where(rng.uniform(size=(runs // 4, 2)) < 0.5, lower, upper)  # corners too
        e = e @ tube.closed_loop.T + w
        assert np.all(tube.error_set.contains(e, tolerance=1e-9)), k


def test_error_set_is_tight_against_worst_case_disturbance_sequences(tube):
    """The sequence w_k = G sign(Gᵀ (A_K^(N−1−k))ᵀ d) drives dᵀe_N to h_{F_N}(d) ≤ h_{F_∞}(d); Z must hold it,
    and h_Z(d) ≤ h_{F_∞}(d)/(1 − α)·(1 + 1e-6) by Raković et al.'s bound (with the certificate's dilation)."""
    A_K, G = tube.closed_loop, W_BOX.generators
    steps = 400
    for d in np.random.default_rng(2).normal(size=(20, 2)):
        e, directions = np.zeros(2), [d]
        for _ in range(steps - 1):
            directions.append(A_K.T @ directions[-1])
        for k in range(steps):
            e = A_K @ e + G @ np.sign(G.T @ directions[steps - 1 - k])
        reached, h_Z = d @ e, tube.error_set.support(d)[0]
        assert reached <= h_Z + 1e-9
        assert h_Z <= reached / (1 - tube.alpha) * (1 + 1e-6) + 1e-12


def test_tightened_bounds_equal_an_independent_lp(tube):
    margins = [cvxpy_support(tube.error_set, row) for row in LIMITS.H]
    np.testing.assert_allclose(tube.state_margins, margins, rtol=1e-6)
    np.testing.assert_allclose(tube.state_constraints.h, LIMITS.h - np.array(margins), rtol=1e-6)
    K = tube.feedback[0]
    np.testing.assert_allclose(tube.input_upper, 1.0 - cvxpy_support(tube.error_set, K), rtol=1e-6)
    np.testing.assert_allclose(tube.input_lower, -1.0 + cvxpy_support(tube.error_set, -K), rtol=1e-6)
    # Z is F(α, s) itself here: the margins are also its closed-form support values
    F = tube.approximation.zonotope()
    np.testing.assert_allclose(tube.state_margins, F.support(LIMITS.H), rtol=1e-4)


def test_template_error_set_is_between_the_mrpi_bound_and_f_alpha_s(tube, template_tube):
    """Z from the template LP is RPI, so it holds F_∞ ⊇ (1 − α) F(α, s); its chains reach about the mRPI set."""
    lower = (1 - tube.alpha) * tube.approximation.support(LIMITS.H)
    assert np.all(template_tube.state_margins >= lower * (1 - 1e-9))
    assert np.all(template_tube.state_margins <= tube.state_margins * 1.01)


def test_template_error_set_in_three_dimensions_is_rpi_and_holds_the_mrpi_bound():
    """A 3-state closed loop (a rotation-contraction and a slow real mode), W a box: the template LP's Z."""
    c, s_ = 0.9 * np.cos(0.4), 0.9 * np.sin(0.4)
    A_K = np.array([[c, -s_, 0.1], [s_, c, 0.0], [0.0, 0.05, 0.95]])
    W = Zonotope.box([-0.1, -0.05, -0.02], [0.1, 0.05, 0.02])
    approximation = minimal_rpi_approximation(A_K, W)
    rows = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 1.0], [1.0, -1.0, 2.0]])
    Z, exact = invariant_polytope(approximation, facet_limit=0, template=rows)
    assert not exact
    e = points_of(Z, np.random.default_rng(7), count=300)
    for w in W.corners():
        assert np.all(Z.contains(e @ A_K.T + w, tolerance=1e-9))
    D = np.vstack([rows, -rows, np.random.default_rng(8).normal(size=(20, 3))])
    assert np.all(Z.support(D) >= (1 - approximation.alpha) * approximation.support(D) * (1 - 1e-9))
    # along the chained rows the template reaches about the mRPI set: no worse than F(α, s) itself
    assert np.all(Z.support(rows) <= approximation.support(rows) * (1 + 1e-3))


# ----------------------------------------------------------------------------------- terminal set
@pytest.mark.parametrize("which", ["tube", "template_tube"])
def test_terminal_set_is_invariant_and_inside_the_tightened_constraints(which, request):
    sets = request.getfixturevalue(which)
    X_f, A_K, K = sets.terminal_set, sets.closed_loop, sets.feedback
    z = points_of(X_f, np.random.default_rng(3))
    assert np.all(X_f.contains(z @ A_K.T, tolerance=1e-9))
    assert X_f.contains(np.zeros(2), tolerance=0.0)[0]
    for row, bound in zip(sets.state_constraints.H, sets.state_constraints.h):
        assert cvxpy_support(X_f, row) <= bound + 1e-7
    assert cvxpy_support(X_f, K[0]) <= sets.input_upper[0] + 1e-7
    assert -cvxpy_support(X_f, -K[0]) >= sets.input_lower[0] - 1e-7


# ------------------------------------------------------------------- the parametric error and W
def mass_models(rel=0.05):
    """The double integrator with mass 1 ± rel: the corners of the parameter box (B scales with 1/m)."""
    return [(A, B / m) for m in (1 - rel, 1 + rel)]


def test_parametric_error_box_holds_sampled_errors_and_is_attained_at_corners():
    rng = np.random.default_rng(4)
    models = [(A + rng.normal(size=(2, 2)) * 1e-3, B * (1 + 0.05 * s)) for s in (-1.0, 1.0, 0.5)]
    xl, xu, ul, uu = np.array([-1.0, -2.0]), np.array([1.0, 0.5]), np.array([-1.0]), np.array([2.0])
    box = parametric_error_set(A, B, models, xl, xu, ul, uu)
    lower, upper = box.interval_hull()
    theta = rng.dirichlet(np.ones(3), size=2000)  # models inside the hull, at random points of the region
    x, u = rng.uniform(xl, xu, size=(2000, 2)), rng.uniform(ul, uu, size=(2000, 1))
    A_t = np.einsum("ki,ijl->kjl", theta, np.array([m[0] for m in models]))
    B_t = np.einsum("ki,ijl->kjl", theta, np.array([m[1] for m in models]))
    error = np.einsum("kjl,kl->kj", A_t - A, x) + np.einsum("kjl,kl->kj", B_t - B, u)
    assert np.all(error >= lower - 1e-15) and np.all(error <= upper + 1e-15)
    corners = np.array(np.meshgrid(*zip(np.r_[xl, ul], np.r_[xu, uu]))).reshape(3, -1).T  # brute force
    reached = np.vstack([corners @ np.hstack([Ai - A, Bi - B]).T for Ai, Bi in models])
    np.testing.assert_allclose(reached.max(axis=0), upper, rtol=1e-12)
    np.testing.assert_allclose(reached.min(axis=0), lower, rtol=1e-12)


def test_disturbance_set_covers_the_true_model_with_the_input_disturbance():
    """W ∋ x⁺ − (A x + B u) for x⁺ = A_θ x + B_θ (u + d), |d| ≤ d_max, θ in the mass box: support check."""
    rng = np.random.default_rng(5)
    W = disturbance_set(
        A,
        B,
        input_bound=0.1,
        vertex_models=mass_models(),
        state_lower=[-1, -1],
        state_upper=[1, 1],
        input_lower=[-1],
        input_upper=[1],
    )
    mass = rng.uniform(0.95, 1.05, size=3000)
    u, d = rng.uniform(-1, 1, 3000), rng.uniform(-0.1, 0.1, 3000)  # A_θ = A: x does not enter the error
    w = B[:, 0] * ((u + d) / mass - u)[:, None]  # B_θ (u + d) − B u with B_θ = B / m
    directions = rng.normal(size=(50, 2))
    assert np.all(w @ directions.T <= W.support(directions) + 1e-15)
    np.testing.assert_allclose(input_disturbance_set(B, 0.1).support(B.T), 0.1 * np.sum(B**2), rtol=1e-14)


def test_tube_keeps_the_true_plant_inside_its_limits():
    """The guarantee where it is exact: the true plant a corner model switching at random, with an input
    disturbance, its error in W by construction; nominal z⁺ = A_K z from a point of X_f (the terminal
    control v = K z is a feasible nominal plan), u = v + K (x − z). Every x stays in X, every u in U."""
    d_max = 0.05
    W = disturbance_set(
        A,
        B,
        input_bound=d_max,
        vertex_models=mass_models(),
        state_lower=[-1, -1],
        state_upper=[1, 1],
        input_lower=[-1],
        input_upper=[1],
    )
    sets = build_tube(A, B, W, LIMITS, [-1.0], [1.0], state_weight=np.eye(2), input_weight=1.0)
    K, rng = sets.feedback, np.random.default_rng(6)
    models = mass_models()
    _, starts = sets.terminal_set.support_points(rng.normal(size=(20, 2)))
    worst_state, worst_input = 0.0, 0.0
    for z in starts:
        x = z.copy()
        for _ in range(300):
            v = K @ z
            u = v + K @ (x - z)
            A_t, B_t = models[rng.integers(2)]
            x = A_t @ x + B_t @ (u + rng.choice([-d_max, d_max], size=1))
            z = A @ z + B @ v
            worst_state = max(worst_state, float(np.max(np.abs(x))))
            worst_input = max(worst_input, float(np.max(np.abs(u))))
    assert worst_state <= 1.0 and worst_input <= 1.0
    assert worst_state > 0.2  # the runs went somewhere: the check is not vacuous


# ------------------------------------------------------------------------------------- refusals
def test_refuses_a_closed_loop_that_is_not_schur():
    with pytest.raises(ValueError, match=r"tube is empty: A \+ B K is not Schur \(eigenvalue\(s\) 1, 1"):
        build_tube(A, B, W_BOX, LIMITS, [-1.0], [1.0], feedback=[[0.0, 0.0]])


def test_refuses_a_flat_disturbance_set():
    with pytest.raises(ValueError, match="not full-dimensional.*add a small box to W"):
        build_tube(A, B, input_disturbance_set(B, 0.1), LIMITS, [-1.0], [1.0], state_weight=np.eye(2), input_weight=1.0)


def test_refuses_an_accuracy_not_reached_within_the_cap_and_says_about_how_many_terms_it_needs():
    """The estimate of the terms still needed (at ρ(A_K) per term) against the s the accuracy takes."""
    with pytest.raises(ValueError, match=r"at s = max_terms = 2 the smallest α is") as refusal:
        build_tube(
            A,
            B,
            W_BOX,
            LIMITS,
            [-1.0],
            [1.0],
            state_weight=np.eye(2),
            input_weight=1.0,
            options=TubeOptions(max_terms=2),
        )
    message = str(refusal.value)
    assert "A_K is Schur" in message and "grows" not in message  # the error does not grow
    more = int(re.search(r"about (\d+) more terms would reach it", message).group(1))
    K = ancillary_feedback(A, B, np.eye(2), 1.0)
    needed = minimal_rpi_approximation(A + B @ K, W_BOX).terms - 2
    assert needed / 2 <= more <= 2 * needed


NUMBER = r"-?\d+(?:\.\d+)?(?:e[-+]?\d+)?"


def lacking(message: str, name: str) -> tuple[float, float, float]:
    """(bound, margin, lacks) of the row `name` in a refusal."""
    found = re.search(
        rf"'{name}' lacks (?:at least )?({NUMBER}) \(bound ({NUMBER}), needs a margin of (?:at least )?({NUMBER})",
        message,
    )
    assert found, message
    lacks, bound, margin = (float(v) for v in found.groups())
    return bound, margin, lacks


def minimal_rpi_support(closed_loop, d, terms: int = 3000) -> float:
    """h_{F_∞}(d) = Σ_i h_W((A_K^i)ᵀ d), truncated where ρ(A_K)^terms is far below round-off: W_BOX's
    support is |d|ᵀ(half-widths) in closed form."""
    half, total, d = np.array([0.01, 0.02]), 0.0, np.asarray(d, dtype=float)
    for _ in range(terms):
        total += float(np.abs(d) @ half)
        d = d @ closed_loop
    return total


def test_refuses_a_state_constraint_no_error_set_fits_in_before_building_one(tube):
    """|position| <= 0.3 is below the minimal RPI set's support: refused with a margin between that
    support's lower bound and Z's, before Z is built."""
    narrow = Polytope.box([-0.3, -1.0], [0.3, 1.0])
    with pytest.raises(ValueError, match="larger than the constraints can hold, for every RPI set") as refusal:
        build_tube(
            A, B, W_BOX, narrow, [-1.0], [1.0], state_weight=np.eye(2), input_weight=1.0, state_constraint_names=NAMES
        )
    message = str(refusal.value)
    assert "velocity" not in message  # only the rows that fail are named
    least = minimal_rpi_support(tube.closed_loop, [1.0, 0.0])
    for name in ("position upper", "position lower"):
        bound, margin, lacks = lacking(message, name)
        assert bound == 0.3
        assert (1 - 0.01) * least <= margin <= least * (1 + 1e-12)  # α <= 0.01 by the default accuracy
        assert margin <= cvxpy_support(tube.error_set, [1.0, 0.0])  # and below what the Z built needs
        assert lacks == pytest.approx(margin - 0.3, rel=1e-2)


def test_tightening_refuses_a_row_the_error_set_does_not_fit_in(tube):
    """Between the minimal RPI set's support and Z's, the refusal comes from Z itself: its margin."""
    needed = cvxpy_support(tube.error_set, [1.0, 0.0])
    with pytest.raises(ValueError, match="larger than the constraints can hold") as refusal:
        tighten(
            np.array([[1.0, 0.0]]), np.array([0.9 * needed]), tube.error_set, ["position upper"], "state constraint"
        )
    bound, margin, lacks = lacking(str(refusal.value), "position upper")
    assert margin == pytest.approx(needed, rel=1e-5)
    assert lacks == pytest.approx(needed - bound, rel=1e-2)


def test_refuses_input_bounds_the_error_set_does_not_fit_in(tube):
    with pytest.raises(ValueError, match="input bound 'input 0 upper'") as refusal:
        build_tube(A, B, W_BOX, LIMITS, [-0.2], [0.2], state_weight=np.eye(2), input_weight=1.0)
    bound, margin, lacks = lacking(str(refusal.value), "input 0 upper")
    least = minimal_rpi_support(tube.closed_loop, tube.feedback[0])
    assert (1 - 0.01) * least <= margin <= min(least * (1 + 1e-12), cvxpy_support(tube.error_set, tube.feedback[0]))
    assert (bound, lacks) == (0.2, pytest.approx(margin - 0.2, rel=1e-2))


def test_refuses_an_empty_terminal_set_and_one_not_determined_within_the_cap():
    with pytest.raises(EmptySetError, match="empty|no interior"):  # constraints that exclude the origin
        maximal_invariant_set(A + B @ ancillary_feedback(A, B, np.eye(2), 1.0), Polytope.box([0.5, -1], [1, 1]))
    with pytest.raises(ValueError, match="the terminal set is refused: .* not determined within iterations = 1"):
        build_tube(
            A,
            B,
            W_BOX,
            LIMITS,
            [-1.0],
            [1.0],
            state_weight=np.eye(2),
            input_weight=1.0,
            options=TubeOptions(iterations=1),
        )


@pytest.mark.parametrize(
    "change, match",
    [
        (dict(A=np.array([[1.0, np.nan], [0.0, 1.0]])), "non-finite"),
        (dict(feedback=[[np.inf, 0.0]]), "non-finite"),
        (dict(input_lower=[np.nan]), "non-finite"),
        (dict(state_weight=None), "give the ancillary feedback K, or both weights"),
    ],
)
def test_refuses_bad_input(change, match):
    arguments = (
        dict(
            A=A,
            B=B,
            disturbance=W_BOX,
            state_constraints=LIMITS,
            input_lower=[-1.0],
            input_upper=[1.0],
            state_weight=np.eye(2),
            input_weight=1.0,
        )
        | change
    )
    with pytest.raises(ValueError, match=match):
        build_tube(**arguments)


def test_disturbance_bounds_are_checked():
    with pytest.raises(ValueError, match="input_bound"):
        input_disturbance_set(B, [np.inf])
    with pytest.raises(ValueError, match=">= 0"):
        input_disturbance_set(B, -0.1)
    with pytest.raises(ValueError, match="needs its region"):
        disturbance_set(A, B, vertex_models=mass_models())


def test_a_zonotope_error_set_is_f_alpha_s_and_robustly_invariant():
    """TubeOptions.zonotope: Z = F(α, s) with A_K Z ⊕ W ⊆ Z, checked by support values in many directions
    (h_Z(A_Kᵀ d) + h_W(d) ≤ h_Z(d)), and the same margins as the exact polytope of F(α, s) to round-off."""
    options = TubeOptions(zonotope=True)
    sets = build_tube(A, B, W_BOX, LIMITS, [-1.0], [1.0], state_weight=np.eye(2), input_weight=1.0, options=options)
    exact = build_tube(A, B, W_BOX, LIMITS, [-1.0], [1.0], state_weight=np.eye(2), input_weight=1.0)
    assert isinstance(sets.error_set, Zonotope) and sets.error_set_exact and exact.error_set_exact
    angles = np.linspace(0, 2 * np.pi, 721)
    D = np.column_stack([np.cos(angles), np.sin(angles)])
    Z = sets.error_set
    assert np.all(Z.support(D @ sets.closed_loop) + W_BOX.support(D) <= Z.support(D) * (1 + 1e-12))
    np.testing.assert_allclose(sets.state_margins, exact.state_margins, rtol=1e-6)
    np.testing.assert_allclose(sets.input_margins, exact.input_margins, rtol=1e-6)


def rk4_affine(A_c, c, x0, Ts, steps=200):
    """x(Ts) of ẋ = A_c x + c from x0 by `steps` RK4 steps (error far below 1e-12 here)."""
    h, x = Ts / steps, np.array(x0, dtype=float)
    f = lambda x: A_c @ x + c  # noqa: E731
    for _ in range(steps):
        k1 = f(x)
        k2 = f(x + h / 2 * k1)
        k3 = f(x + h / 2 * k2)
        k4 = f(x + h * k3)
        x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return x


def test_vertex_models_integrate_each_corners_linearization_and_drift():
    """The arm (gravity: a corner's model drifts from the known operating point) at the ±5 % box's
    corners: (A_i, B_i, a_i) against RK4 of ẋ = A_c x̃ + B_c ũ + f_i(x_e, u_e) over the sample, column by
    column (the ZOH by a second method)."""
    plant, known = models.get("arm"), models.perturbed(models.get("arm"), 0.05, 1.0)
    xe, ue = known.equilibrium()
    corners, Ts = corner_params(plant), 0.01
    pairs, offsets = vertex_models(plant, corners, xe, ue, Ts)
    assert max(np.max(np.abs(a)) for a in offsets) > 1e-4  # the corners' gravity is not the known model's
    for (A_i, B_i), a_i, p in zip(pairs, offsets, corners):
        continuous = plant.linearize(xe, ue, params=p, check=False)
        drift = np.asarray(plant.f(xe, ue, p), dtype=float).ravel()
        np.testing.assert_allclose(a_i, rk4_affine(continuous.A, drift, np.zeros(2), Ts), rtol=1e-12, atol=1e-15)
        for j, e in enumerate(np.eye(2)):
            np.testing.assert_allclose(A_i[:, j], rk4_affine(continuous.A, 0 * drift, e, Ts), rtol=1e-12)
        np.testing.assert_allclose(B_i[:, 0], rk4_affine(continuous.A, continuous.B[:, 0], np.zeros(2), Ts), rtol=1e-12)


def test_vertex_models_are_the_nonlinear_steps_derivatives_at_a_common_equilibrium():
    """The pendulum upright is an equilibrium of every corner: no drift, and (A_i, B_i) are the central
    differences of the plant's own RK4 step (200 substeps) there."""
    plant = models.get("pendulum")
    xe, ue = plant.equilibrium()
    corners, Ts, h = corner_params(plant, names=["m2", "ell"]), 0.01, 1e-6
    step = plant.step_function(Ts, 200)
    pairs, offsets = vertex_models(plant, corners, xe, ue, Ts)
    for (A_i, B_i), a_i, p in zip(pairs, offsets, corners):
        moved = lambda x, u, p=p: np.asarray(step(x, u, p), dtype=float).ravel()  # noqa: E731
        np.testing.assert_allclose(a_i, 0.0, atol=1e-15)
        columns = [(moved(xe + h * e, ue) - moved(xe - h * e, ue)) / (2 * h) for e in np.eye(plant.nx)]
        np.testing.assert_allclose(A_i, np.array(columns).T, rtol=1e-6, atol=1e-9)
        np.testing.assert_allclose(B_i[:, 0], (moved(xe, ue + h) - moved(xe, ue - h)) / (2 * h), rtol=1e-6, atol=1e-9)
