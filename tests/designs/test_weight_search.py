"""The poll search: it finds a known minimizer, and early rejection changes its work, not its path."""

import math

import numpy as np
import pytest

from designs import weight_search
from designs.weight_search import Evaluation, poll_search

CENTER = np.array([1.3, -0.4, 0.8])


def terms(x):
    """Three non-negative terms whose sum is minimal (0) at CENTER."""
    return (x - CENTER) ** 2 * np.array([1.0, 4.0, 0.5])


def complete(x, bound):
    return Evaluation(float(np.sum(terms(x))), runs=3)


def early(x, bound):
    total = 0.0
    for k, term in enumerate(terms(x)):
        total += term
        if total >= bound and k < 2:
            return Evaluation(total, complete=False, runs=k + 1)
    return Evaluation(total, runs=3)


def test_finds_the_minimizer_within_its_mesh():
    found = poll_search(complete, np.zeros(3), step=1.0, min_step=1e-3)
    assert found.converged and found.status == weight_search.CONVERGED
    np.testing.assert_allclose(found.x, CENTER, atol=2e-3)
    assert found.step < 1e-3


def test_early_rejection_takes_the_same_path_with_fewer_runs():
    full = poll_search(complete, np.zeros(3), step=1.0, min_step=1e-3)
    cut = poll_search(early, np.zeros(3), step=1.0, min_step=1e-3)
    np.testing.assert_array_equal(cut.x, full.x)
    assert cut.evaluations == full.evaluations and cut.value == full.value
    assert cut.runs < full.runs


def test_a_mapped_poll_converges_too_and_the_cap_is_reported():
    mapped = poll_search(complete, np.zeros(3), step=1.0, min_step=1e-3, mapper=lambda f, items: list(map(f, items)))
    np.testing.assert_allclose(mapped.x, CENTER, atol=2e-3)
    capped = poll_search(complete, np.zeros(3), step=1.0, min_step=1e-3, max_evaluations=5)
    assert capped.status == weight_search.CAPPED and not capped.converged and capped.evaluations == 5


def test_bad_steps_are_refused():
    with pytest.raises(ValueError, match="step"):
        poll_search(complete, np.zeros(3), step=0.0)
    with pytest.raises(ValueError, match="step"):
        poll_search(complete, np.zeros(3), min_step=-math.log(2))


def test_bounds_keep_the_search_inside_its_box():
    found = poll_search(complete, np.zeros(3), step=0.5, min_step=1e-3, bounds=(-np.ones(3), [1.0, 1.0, 0.5]))
    assert found.converged
    np.testing.assert_allclose(found.x, [1.0, -0.4, 0.5], atol=2e-3)  # CENTER with its first and last clipped
    with pytest.raises(ValueError, match="outside"):
        poll_search(complete, np.full(3, 2.0), bounds=(-np.ones(3), np.ones(3)))


def crawl(x, bound):
    """CENTER's bowl plus a term that keeps falling by 1e-7 per unit of x₃: a weight that barely matters."""
    return Evaluation(float(np.sum(terms(x)[:2]) - 1e-7 * x[2]), runs=1)


def test_a_sufficient_decrease_stops_the_crawl_along_a_flat_weight():
    """With simple decrease the poll walks x₃ to its bound, one poll of the others after each step; with c h²
    it leaves x₃ where it started and finds the bowl's minimizer with fewer evaluations."""
    box = (np.full(3, -20.0), np.full(3, 20.0))
    simple = poll_search(crawl, np.zeros(3), step=1.0, min_step=1e-3, bounds=box)
    sufficient = poll_search(crawl, np.zeros(3), step=1.0, min_step=1e-3, bounds=box, decrease=1e-3)
    assert simple.converged and sufficient.converged
    assert simple.x[2] == pytest.approx(20.0) and sufficient.x[2] == 0.0
    np.testing.assert_allclose(sufficient.x[:2], CENTER[:2], atol=2e-3)
    assert sufficient.evaluations < simple.evaluations
    # Its certificate: at the last step 2h no poll point lowers f by more than c (2h)².
    h = 2 * sufficient.step
    for i in range(3):
        for sign in (1.0, -1.0):
            y = sufficient.x + sign * h * np.eye(3)[i]
            assert crawl(y, np.inf).value >= sufficient.value - 1e-3 * h * h


def test_early_rejection_keeps_the_path_with_a_sufficient_decrease():
    full = poll_search(complete, np.zeros(3), step=1.0, min_step=1e-3, decrease=1e-2)
    cut = poll_search(early, np.zeros(3), step=1.0, min_step=1e-3, decrease=1e-2)
    np.testing.assert_array_equal(cut.x, full.x)
    assert cut.evaluations == full.evaluations and cut.runs < full.runs
    np.testing.assert_allclose(full.x, CENTER, atol=5e-3)
    with pytest.raises(ValueError, match="decrease"):
        poll_search(complete, np.zeros(3), decrease=-1.0)


def test_a_poll_starts_with_the_direction_of_the_last_improvement():
    """f = |x − 5 e₃|² from 0, steps of 1 down to 0.5. By hand: the start; the first poll finds +e₃ fifth;
    with the direction that improved polled first, the next four steps cost one evaluation each; at 5 e₃ a
    poll of all six fails at h = 1 and at h = 0.5, and h = 0.25 ends the search: 1 + 5 + 4 + 6 + 6 = 22."""
    target = np.array([0.0, 0.0, 5.0])
    found = poll_search(
        lambda x, bound: Evaluation(float(np.sum((x - target) ** 2))), np.zeros(3), step=1.0, min_step=0.5
    )
    np.testing.assert_array_equal(found.x, target)
    assert found.converged and found.evaluations == 22 and len(found.history) == 6


def test_the_reporter_says_the_state_once_per_every_evaluations():
    said = []
    report = weight_search.reporter(20, said.append)
    for evaluations, value in ((7, 3.0), (19, 2.0), (20, 1.5), (33, 1.25), (41, 1.0)):
        report(evaluations, value, 0.5)
    assert said == ["      20 evaluations: score 1.5, poll step 0.5", "      41 evaluations: score 1, poll step 0.5"]
