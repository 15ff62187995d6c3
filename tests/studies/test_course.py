"""studies.course, the walk the case notebooks take: each step's numbers against a hand derivation, and each
check fails when its two sides disagree."""

import dataclasses
from types import SimpleNamespace

import control
import numpy as np
import pytest

import studies
from studies import course


def test_the_pd_gains_are_the_closed_form_and_a_wrong_design_is_caught(monkeypatch):
    # 2 / (s² + 3 s + 1) at ωn = 4, ζ = 0.5: kp = (16 − 1) / 2, kd = (2·0.5·4 − 3) / 2 by hand.
    loop = control.tf([2.0], [1.0, 3.0, 1.0])
    pd = course.pd_by_poles(loop, wn=4.0, zeta=0.5)
    assert (pd.kp, pd.kd) == pytest.approx((7.5, 0.5), rel=1e-12)
    np.testing.assert_allclose(np.sort_complex(pd.closed_poles), np.sort_complex(np.roots([1, 4, 16])), rtol=1e-12)
    # The PID's cubic with ki = 0 has the PD's poles and a root at the origin.
    np.testing.assert_allclose(np.sort(np.abs(pd.pid_poles(7.5, 0.0, 0.5))), [0.0, 4.0, 4.0], atol=1e-9)
    wrong = dataclasses.replace(pd.design, kp=7.5 * (1 + 1e-6))
    monkeypatch.setattr(course, "pd_design", lambda *args, **kwargs: wrong)
    with pytest.raises(AssertionError):
        course.pd_by_poles(loop, wn=4.0, zeta=0.5)


def test_the_scalar_lqr_gain_is_sqrt_q_over_r():
    # ẋ = u, cost q x² + r u²: P = √(q r), K = P / r = √(q / r).
    K = course.lqr_gain(np.zeros((1, 1)), np.ones((1, 1)), np.array([[9.0]]), np.array([[4.0]]))
    np.testing.assert_allclose(K, [[1.5]], rtol=1e-10)


def test_the_prediction_model_is_the_zero_order_hold_and_a_wrong_one_is_caught():
    # The double integrator held over T: A_d = [[1, T], [0, 1]], B_d = [T²/2, T].
    A, B, T = np.array([[0.0, 1.0], [0.0, 0.0]]), np.array([[0.0], [1.0]]), 0.1
    held = SimpleNamespace(A=np.array([[1.0, T], [0.0, 1.0]]), B=np.array([[T**2 / 2], [T]]))
    model = course.prediction_model(SimpleNamespace(sample_period=T, model=held), A, B)
    assert model.sample_period == T and "1.000000" in model.report()
    euler = SimpleNamespace(A=held.A, B=np.array([[0.0], [T]]))  # forward Euler's B_d misses T²/2
    with pytest.raises(AssertionError):
        course.prediction_model(SimpleNamespace(sample_period=T, model=euler), A, B)


def test_the_arm_linearization_has_its_transfer_function_poles_as_eigenvalues():
    plant = course.linearization(studies.get("arm"))
    np.testing.assert_allclose(np.sort_complex(plant.poles), np.sort_complex(plant.eigenvalues), atol=1e-9)
    loop = course.loop_model(studies.get("arm"))  # a single loop: θ/τ itself
    np.testing.assert_allclose(np.sort_complex(control.poles(loop)), np.sort_complex(plant.eigenvalues), atol=1e-9)
    assert "tracked: theta" in plant.report()
