"""The newer MPC APIs' arguments: a one-line error naming the argument, its value and what it must be."""

from __future__ import annotations

import pytest

import models
import mpc


@pytest.mark.parametrize("args", [("a", 2), (1, "b"), (True, 2), (1, 2, "c")])
def test_free_time_names_the_argument_that_is_not_a_number(args):
    # before: "could not convert string to float", naming no argument; True was taken as 1 s
    with pytest.raises(TypeError, match=r"FreeTime (lower|upper|guess) must be a real number of seconds, got"):
        mpc.FreeTime(*args)


def test_free_time_takes_numbers():
    assert mpc.FreeTime(1, 3).guess == 2.0


@pytest.mark.parametrize("final_time", ["abc", True, None])
def test_a_final_time_that_is_not_a_number_is_named(final_time):
    # before: "could not convert string to float" for "abc", and True taken as 1 s
    with pytest.raises(TypeError, match=r"final_time must be a real number of seconds or a FreeTime, got"):
        mpc.OptimalControlProblem(models.get("arm"), final_time)


def test_a_soft_bound_with_equal_sides_does_not_speak_of_a_scale_not_given():
    # before: "scale must be finite and > 0, got 0.0", a scale the caller never gave
    with pytest.raises(ValueError, match=r"lower = upper = 0.5; need lower < upper") as refused:
        mpc.SoftBound.on(models.get("arm"), {"theta": 1.0}, 0.5, 0.5, linear_weight=1.0, quadratic_weight=1.0)
    assert "scale must" not in str(refused.value)
