"""The one weight normalizer (`models.checks.weight_matrix`) of the LQR, MPC and tuning layers."""

import numpy as np
import pytest

from models.checks import weight_matrix


def test_every_form_gives_the_same_matrix():
    expected = np.array([[2.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 5.0]])
    names = ("a", "b", "c")
    assert np.array_equal(weight_matrix([2.0, 0.0, 5.0], 3, "Q"), expected)
    assert np.array_equal(weight_matrix(expected, 3, "Q"), expected)
    assert np.array_equal(weight_matrix({"a": 2.0, "c": 5.0}, 3, "Q", names=names), expected)
    assert np.array_equal(weight_matrix(3.0, 2, "R", definite=True), 3.0 * np.eye(2))


def test_a_symmetric_matrix_is_returned_exactly():
    rng = np.random.default_rng(3)
    root = rng.normal(size=(4, 4))
    W = root @ root.T
    W = (W + W.T) / 2
    assert np.array_equal(weight_matrix(W, 4, "Q"), W)


@pytest.mark.parametrize(
    ("value", "kwargs", "message"),
    [
        ([[1.0, 2.0], [0.0, 1.0]], {}, "Q must be symmetric"),
        ([[1.0, 0.0], [0.0, -1.0]], {}, "Q must be positive semidefinite"),
        ([1.0, 0.0], {"definite": True}, "Q must be positive definite"),
        ([1.0, np.nan], {}, "Q has non-finite entries"),
        ([1.0, 2.0, 3.0], {}, r"Q must be a scalar, 2 diagonal entries or a \(2, 2\) matrix"),
        ({"z": 1.0}, {"names": ("a", "b")}, r"Q: no signal named \['z'\]"),
    ],
)
def test_bad_weights_are_refused_by_name(value, kwargs, message):
    with pytest.raises(ValueError, match=message):
        weight_matrix(value, 2, "Q", **kwargs)


def test_a_dict_needs_names_and_strings_are_not_numbers():
    with pytest.raises(TypeError, match="got a dict"):
        weight_matrix({"a": 1.0}, 1, "Q")
    with pytest.raises(TypeError, match="Q must hold real numbers"):
        weight_matrix(["1", "2"], 2, "Q")
