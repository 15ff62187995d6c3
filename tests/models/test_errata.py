"""The text's hint matrices, typed as printed, against our linearizations.

Each test states which entries agree and which disagree, and reproduces the
disagreement from its cause; docs/errata.md explains them.
"""

import numpy as np
import pytest

import models


def test_arm_hint_I15_agrees():
    lin = models.get("arm").linearize()
    np.testing.assert_allclose(lin.A, [[0, 1.0], [0, -0.667]], atol=5e-4)  # printed to 3 decimals
    np.testing.assert_allclose(lin.B, [[0], [66.667]], atol=5e-4)
    np.testing.assert_allclose(lin.C, [[1, 0]])


def test_pendulum_hint_II15_agrees():
    lin = models.get("pendulum").linearize()
    A = [[0, 0, 1, 0], [0, 0, 0, 1], [0, -2.45, -0.05, 0], [0, 24.5, 0.1, 0]]
    np.testing.assert_allclose(lin.A, A, atol=1e-12)
    np.testing.assert_allclose(lin.B.ravel(), [0, 0, 1, -2], atol=1e-12)
    np.testing.assert_allclose(lin.C, [[1, 0, 0, 0], [0, 1, 0, 0]])


def test_satellite_hint_III15_has_the_third_row_sign_flipped():
    sat = models.get("satellite")
    Js, Jp, k, b = (sat.params[n] for n in ("Js", "Jp", "k", "b"))
    hint_A = np.array(
        [[0, 0, 1, 0], [0, 0, 0, 1], [k / Js, -k / Js, b / Js, -b / Js], [k / Jp, -k / Jp, b / Jp, -b / Jp]]
    )
    lin = sat.linearize()
    np.testing.assert_allclose(lin.A[[0, 1, 3]], hint_A[[0, 1, 3]], atol=1e-15)
    np.testing.assert_allclose(lin.A[2], -hint_A[2], atol=1e-15)
    np.testing.assert_allclose(lin.B.ravel(), [0, 0, 1 / Js, 0])
    np.testing.assert_allclose(lin.C, [[1, 0, 0, 0], [-1, 1, 0, 0]])
    # The flipped row moves the panel mode from √(k(1/Js + 1/Jp)) to about √(k(1/Jp − 1/Js)).
    true_mode = np.max(np.abs(np.linalg.eigvals(lin.A).imag))
    hint_mode = np.max(np.abs(np.linalg.eigvals(hint_A).imag))
    assert true_mode == pytest.approx(np.sqrt(k * (1 / Js + 1 / Jp) - (b * (1 / Js + 1 / Jp) / 2) ** 2), rel=1e-9)
    assert hint_mode == pytest.approx(0.3458, abs=1e-4)


def test_ballbeam_hint_V14_uses_g_981_not_98():
    plant = models.get("ballbeam")
    hint_F = np.array([[0, 0, 1, 0], [0, 0, 0, 1], [0, -9.81, 0, 0], [-18.2108, 0, 0, 0]])
    hint_G = np.array([0, 0, 0, 2.6519])
    lin = plant.linearize()
    assert lin.A[2, 1] == pytest.approx(-9.8) and lin.A[3, 0] == pytest.approx(-18.1923, abs=1e-4)
    assert abs(lin.A[3, 0] - hint_F[3, 0]) / abs(hint_F[3, 0]) == pytest.approx(1e-3, rel=0.02)
    np.testing.assert_allclose(lin.B.ravel(), hint_G, atol=5e-5)
    # With g = 9.81 the hint is reproduced to its printed digits.
    with_981 = plant.linearize(params={"g": 9.81})
    np.testing.assert_allclose(with_981.A, hint_F, atol=5e-5)


def test_crane_hint_VI14_used_b_2000_and_flips_a_sign_in_symbolic_G():
    plant = models.get("crane1")
    order = [2, 3, 0, 1]  # the hint's states are (x', θ', x, θ)
    hint_F = np.array([[-1.3333, 0, 0, 3.2700], [0.1333, 0, 0, -1.3080], [1, 0, 0, 0], [0, 1, 0, 0]])
    hint_G = np.array([6.6667e-04, -6.6667e-05, 0, 0])
    lin = plant.linearize()
    A = lin.A[np.ix_(order, order)]
    B = lin.B[order, 0]
    disagree = ~np.isclose(A, hint_F, atol=5e-5)
    assert np.argwhere(disagree).tolist() == [[0, 0], [1, 0]]  # only the two damping entries
    np.testing.assert_allclose(A[:2, 0], hint_F[:2, 0] / 10, atol=5e-6)  # ten times too large
    np.testing.assert_allclose(B, hint_G, rtol=1e-4)
    with_2000 = plant.linearize(params={"b": 2000.0})
    np.testing.assert_allclose(with_2000.A[np.ix_(order, order)], hint_F, atol=5e-5)
    # Symbolic hint G = (−1/mc, −1/(mc ℓ), 0, 0): the first entry has the wrong sign.
    mc = plant.params["mc"]
    assert B[0] == pytest.approx(+1 / mc) and hint_G[0] == pytest.approx(1 / mc, rel=1e-4)
