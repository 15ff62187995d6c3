"""mpc.sets: support functions, facets, differences, redundancy and invariant sets, each against
a second method (brute force over corners, cvxpy's LP, a closed form or a simulation)."""

import itertools

import cvxpy as cp
import numpy as np
import pytest

from mpc.sets import EmptySetError, Polytope, Zonotope, maximal_invariant_set


def cvxpy_support(H, h, d) -> float:
    """max dᵀx over {H x ≤ h} by cvxpy (its own solver, not DAQP or HiGHS)."""
    x = cp.Variable(H.shape[1])
    problem = cp.Problem(cp.Maximize(d @ x), [H @ x <= h])
    problem.solve(solver=cp.CLARABEL)
    assert problem.status == cp.OPTIMAL
    return float(problem.value)


def random_zonotope(rng, n, m) -> Zonotope:
    return Zonotope(rng.normal(size=n) * 0.1, rng.normal(size=(n, m)))


def test_zonotope_support_is_the_maximum_over_its_sign_corners():
    rng = np.random.default_rng(0)
    Z = random_zonotope(rng, 3, 5)
    D = rng.normal(size=(50, 3))
    brute = np.max(D @ Z.corners().T, axis=1)  # every vertex is a sign corner
    np.testing.assert_allclose(Z.support(D), brute, rtol=1e-13, atol=1e-13)
    values, points = Z.support_points(D)
    np.testing.assert_allclose(np.einsum("ij,ij->i", D, points), values, rtol=1e-13, atol=1e-13)


@pytest.mark.parametrize("n, m", [(1, 3), (2, 4), (3, 5), (4, 6)])
def test_zonotope_facets_are_exactly_the_zonotope(n, m):
    rng = np.random.default_rng(n)
    Z = random_zonotope(rng, n, m)
    P = Z.facets()
    assert np.all(P.contains(Z.corners(), tolerance=1e-9))
    D = rng.normal(size=(40, n))
    np.testing.assert_allclose(P.support(D), Z.support(D), rtol=1e-9, atol=1e-12)


def test_zonotope_facets_refuse_a_flat_zonotope():
    flat = Zonotope(np.zeros(3), np.array([[1.0, 0.0], [0.0, 1.0], [1.0, 1.0]]))
    with pytest.raises(ValueError, match="not full-dimensional: its generators span 2 of 3"):
        flat.facets()


def test_polytope_support_agrees_with_cvxpy_and_its_maximizers_are_feasible():
    rng = np.random.default_rng(1)
    H = rng.normal(size=(30, 4))
    h = 1.0 + rng.uniform(size=30)  # contains a ball about 0; bounded for 30 random rows in 4-D
    P = Polytope(H, h)
    D = rng.normal(size=(10, 4))
    values, points = P.support_points(D)
    np.testing.assert_allclose(values, [cvxpy_support(H, h, d) for d in D], rtol=1e-7)
    assert np.all(P.contains(points, tolerance=1e-9))


def test_unbounded_direction_is_infinite_and_empty_polytope_is_refused():
    half_plane = Polytope(np.array([[1.0, 0.0]]), np.array([1.0]))
    assert np.isinf(half_plane.support([0.0, 1.0])[0])
    assert half_plane.support([1.0, 0.0])[0] == pytest.approx(1.0, abs=1e-12)
    empty = Polytope(np.array([[1.0], [-1.0]]), np.array([1.0, -2.0]))  # x ≤ 1 and x ≥ 2
    with pytest.raises(EmptySetError, match="empty"):
        empty.support([1.0])


def test_pontryagin_difference_of_boxes_is_the_hand_box():
    outer = Polytope.box([-1.0, -2.0], [3.0, 2.0])
    inner = Zonotope.box([-0.25, -0.5], [0.5, 0.5])  # x + [-0.25, 0.5] × [-0.5, 0.5] ⊆ outer
    difference = outer.minus(inner)
    np.testing.assert_allclose(difference.support(np.vstack([np.eye(2), -np.eye(2)])), [2.5, 1.5, 0.75, 1.5])


def test_redundancy_removal_keeps_exactly_the_square():
    square = Polytope.box([-1.0, -1.0], [1.0, 1.0])
    extra = np.array([[1.0, 1.0], [1.0, 0.0], [2.0, 0.0], [1.0, -0.5]])
    bounds = np.array([2.0, 1.0, 3.0, 1.5])  # a corner cut, a duplicate, a looser copy, one through a corner
    P = Polytope(np.vstack([square.H, extra]), np.concatenate([square.h, bounds])).without_redundancy()
    rows = {tuple(np.round(r, 12)) for r in P.H}
    assert rows == {tuple(r) for r in np.round(square.H, 12)}
    np.testing.assert_allclose(np.sort(P.h), np.ones(4))


def test_chebyshev_ball_of_a_box_and_of_an_empty_set():
    centre, radius = Polytope.box([0.0, -1.0], [4.0, 1.0]).chebyshev_ball()
    assert radius == pytest.approx(1.0)
    assert centre[1] == pytest.approx(0.0, abs=1e-12) and 1.0 <= centre[0] <= 3.0
    assert Polytope(np.array([[1.0], [-1.0]]), np.array([1.0, -2.0])).chebyshev_ball()[1] < 0


def test_polytope_refuses_non_finite_data_and_zero_rows():
    with pytest.raises(ValueError, match="non-finite"):
        Polytope(np.array([[1.0, np.nan]]), np.array([1.0]))
    with pytest.raises(ValueError, match="non-finite"):
        Polytope(np.eye(2), np.array([1.0, np.inf]))
    with pytest.raises(ValueError, match="row 1 of H is zero"):
        Polytope(np.array([[1.0, 0.0], [0.0, 0.0]]), np.ones(2))


def test_maximal_invariant_set_of_a_scalar_contraction_is_the_constraint():
    O_inf = maximal_invariant_set([[0.5]], Polytope.box([-1.0], [2.0]))
    np.testing.assert_allclose(O_inf.support(np.array([[1.0], [-1.0]])), [2.0, 1.0])


def test_maximal_invariant_set_is_what_simulation_keeps_inside():
    """x ∈ O_∞ exactly when A^t x stays in the box for every t (checked up to t = 200, beyond the decay)."""
    A = np.array([[0.9, 0.5], [-0.3, 0.7]])  # |eigenvalues| ≈ 0.86, rotating: the box alone is not invariant
    box = Polytope.box([-1.0, -1.0], [1.0, 1.0])
    O_inf = maximal_invariant_set(A, box)
    points = np.random.default_rng(2).uniform(-1, 1, size=(4000, 2))
    stays = np.ones(len(points), dtype=bool)
    x = points.copy()
    for _ in range(200):
        stays &= box.contains(x, tolerance=0.0)
        x = x @ A.T
    inside = O_inf.contains(points, tolerance=0.0)
    margin = np.min(np.abs(points @ O_inf.H.T - O_inf.h), axis=1) > 1e-9  # not on a face
    assert np.array_equal(inside[margin], stays[margin])
    assert 0 < inside.sum() < len(points)  # the set cut the box


def test_maximal_invariant_set_refuses_an_empty_set_and_a_low_cap():
    with pytest.raises(EmptySetError, match="empty|no interior"):
        maximal_invariant_set([[0.5]], Polytope.box([1.0], [2.0]))  # 1 ≤ x ≤ 2 excludes the origin x → 0 heads to
    A = np.array([[0.99, 0.2], [-0.2, 0.99]])
    with pytest.raises(ValueError, match="not determined within iterations = 2"):
        maximal_invariant_set(A, Polytope.box([-1.0, -1.0], [1.0, 1.0]), iterations=2)


def test_zonotope_corners_cover_its_box_corners():
    box = Zonotope.box([-1.0, 0.0, 2.0], [1.0, 0.0, 3.0])  # a zero-width side has no generator
    assert box.generators.shape == (3, 2)
    expected = {(a, 0.0, b) for a, b in itertools.product((-1.0, 1.0), (2.0, 3.0))}
    assert {tuple(c) for c in box.corners()} == expected


def test_zonotope_membership_agrees_with_its_exact_facets():
    """Points of a random 3-D zonotope's box, judged by the LP and by the zonotope's facets (exact H-rep)."""
    rng = np.random.default_rng(4)
    Z = Zonotope(rng.normal(size=3), rng.normal(size=(3, 6)))
    lower, upper = Z.interval_hull()
    points = rng.uniform(lower, upper, (60, 3))
    facets = Z.facets()
    slack = np.max(points @ facets.H.T - facets.h, axis=1)
    clear = np.abs(slack) > 1e-6  # away from the boundary, where the tolerances differ
    np.testing.assert_array_equal(Z.contains(points[clear]), slack[clear] <= 0)
    assert 0 < np.count_nonzero(slack[clear] <= 0) < np.count_nonzero(clear)  # both kinds
