"""Homework answers from the models against hand derivations, and the errata each study picks."""

import dataclasses

import numpy as np
import pytest

import studies
from studies import answers


def coefficients(tf):
    return np.ravel(tf.num[0][0]), np.ravel(tf.den[0][0])


def test_satellite_cascade_is_the_panel_on_its_spring():
    found = answers.model_answers(studies.get("satellite"))["III.6"]
    num, den = coefficients(found["cascade outer phi/theta"])
    # Jp φ̈ = −b(φ̇ − θ̇) − k(φ − θ)  ⇒  φ/θ = (b s + k) / (Jp s² + b s + k), Jp = 1, b = 0.05, k = 0.15.
    assert num == pytest.approx([0.05, 0.15]) and den == pytest.approx([1.0, 0.05, 0.15])


def test_crane_cascade_is_the_frictionless_single_load_of_vi6():
    found = answers.model_answers(studies.get("crane"))["VI.6"]
    mc, m, ell, g = 1500.0, 500.0, 10.0, 9.81
    num, den = coefficients(found["cascade inner theta/F (crane1, b = 0)"])
    # θ/F = −1/(mc ℓ) / (s² + (mc + m) g / (mc ℓ))
    assert num == pytest.approx([-1 / (mc * ell)]) and den == pytest.approx([1.0, 0.0, (mc + m) * g / (mc * ell)])
    num, den = coefficients(found["cascade outer x/theta (crane1, b = 0)"])
    # x/θ = −(ℓ s² + g) / s² from the load's horizontal balance.
    assert num == pytest.approx([-ell, 0.0, -g]) and den == pytest.approx([1.0, 0.0, 0.0])


def test_ballbeam_equilibrium_force_of_the_v14_hint():
    found = answers.model_answers(studies.get("ballbeam"))["V.5"]
    m1, m2, ell, g = 0.35, 2.0, 0.5, 9.8
    # F_e = m1 g z_e / ℓ + m2 g / 2 with z_e = ℓ/2.
    assert found["u_e"]["F"] == pytest.approx(m1 * g * (ell / 2) / ell + m2 * g / 2)
    assert found["x_e"]["z"] == pytest.approx(ell / 2)


@pytest.mark.parametrize(
    "plant,present,absent",
    [
        ("uuv", ["IV.3(b) vs IV.7", "IV.8(c)", "IV.15, V.15, VI.15"], ["V.14 hint", "VI.14(b)"]),
        ("ballbeam", ["V.14 (ball on beam)", "V.14 hint", "IV.15, V.15, VI.15"], ["IV.3(b) vs IV.7", "VI.14(b)"]),
        ("arm", ["I.15 (arm)", "I.15(c)", "pendulum, satellite, arm parameters"], ["II.8(a)", "III.12"]),
    ],
)
def test_errata_declared_in_the_case_files_are_picked_for_the_case(plant, present, absent):
    items = [row["item"] for row in answers.errata(studies.get(plant))]
    for item in present:
        assert item in items
    for item in absent:
        assert item not in items


def test_provider_answers_are_merged_by_item():
    study = studies.get("arm")
    asked = []

    def provider(case):
        asked.append(case)
        return {"I.8(c)": {"kp": 0.3}, "I.5": {"note": "from the design"}}

    patched = dataclasses.replace(study, answer_providers=(provider,))
    found, notes = answers.collect(patched)
    assert asked == [patched] and asked[0] is patched  # the provider receives the case itself
    assert found["I.8(c)"] == {"kp": 0.3}
    assert found["I.5"]["note"] == "from the design" and "u_e" in found["I.5"]
    assert list(found).index("I.7") < list(found).index("I.8(c)") < list(found).index("errata")
    assert "I.8(c)" in answers.format_answers(patched, found, "arm")


def test_kinetic_energy_and_equations_of_motion_are_printed_answers():
    found = answers.model_answers(studies.get("ballbeam"))
    assert found["V.1"]["latex"].startswith("$T = ") and r"\dot{z}" in found["V.1"]["latex"]
    assert len(found["V.3"]["equations"]) == len(found["V.3"]["latex"]) == 2  # one per coordinate (z, θ)
    assert all(text.startswith("$") and " = " in text for text in found["V.3"]["latex"])
