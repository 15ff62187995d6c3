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
