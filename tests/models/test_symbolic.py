"""Printed expressions: the sympy form of CasADi expressions evaluated against CasADi, and the arm's
equation of motion against its hand derivation."""

import casadi as ca
import numpy as np
import pytest
import sympy

import models
from models import symbolic


def test_sympy_form_of_an_expression_evaluates_as_casadi_does():
    x, y = ca.SX.sym("x"), ca.SX.sym("y")
    expr = (
        ca.sin(x) * y**2
        - ca.cos(x * y) / (1 + x**2)
        + ca.sqrt(ca.exp(y) + 2) * ca.tan(x / 3)
        - ca.log(2 + y**2)
        + ca.atan2(y, 2 + x)
        + ca.fabs(x - y)
        - 2 * x
    )
    converted = symbolic.to_sympy(expr)
    f = ca.Function("f", [x, y], [expr])
    g = sympy.lambdify([sympy.Symbol("x"), sympy.Symbol("y")], converted, "numpy")
    rng = np.random.default_rng(0)
    for a, b in rng.uniform(-1.5, 1.5, (20, 2)):
        assert float(g(a, b)) == pytest.approx(float(f(a, b)), rel=1e-12, abs=1e-12)
    with pytest.raises(ValueError, match="scalar"):
        symbolic.to_sympy(ca.vertcat(x, y))


@pytest.mark.parametrize("name", models.names())
def test_printed_model_evaluates_as_the_derived_one(name):
    """T and every equation M q̈ = Q − C q̇ − ∂V/∂q at random points equal CasADi's energy and dynamics."""
    plant = models.get(name)
    named = symbolic.DeclarationSymbols(plant.declaration)
    T = symbolic.kinetic_energy(plant)
    equations = symbolic.equations_of_motion(plant)
    rng = np.random.default_rng(1)
    p = plant.param_vector()
    for _ in range(3):
        x = rng.uniform(-0.8, 0.8, plant.nx)
        u = rng.uniform(-1, 1, plant.nu)
        xdot = plant.f(x, u)
        values = dict(zip(plant.coordinate_names, x[: plant.nq]))
        values |= {"d" + c: v for c, v in zip(plant.coordinate_names, x[plant.nq :])}
        values |= {"dd" + c: v for c, v in zip(plant.coordinate_names, xdot[plant.nq :])}
        values |= dict(zip(plant.input_names, u)) | dict(zip(plant.params, p))
        subs = {named.symbols[k]: v for k, v in values.items()}
        kinetic = plant.energy(x) - plant.energy(np.concatenate([x[: plant.nq], np.zeros(plant.nq)]))
        assert float(T.subs(subs)) == pytest.approx(kinetic, rel=1e-10, abs=1e-12)
        for eq in equations:  # the true accelerations satisfy each printed equation
            lhs, rhs = float(eq.lhs.subs(subs)), float(eq.rhs.subs(subs))
            assert lhs == pytest.approx(rhs, rel=1e-9, abs=1e-9 * (1 + abs(rhs)))


def test_arm_equation_of_motion_is_the_hand_derivation():
    """m ℓ²/3 θ̈ = τ − b θ̇ − m g ℓ/2 cos θ for a rod pivoted at one end, θ from level."""
    m, ell, g, b, tau, th, dth, ddth = sympy.symbols("m ell g b tau theta dtheta ddtheta", real=True)
    (eq,) = symbolic.equations_of_motion(models.get("arm"))
    names = {s.name: s for s in eq.free_symbols}
    hand_lhs = m * ell**2 / 3 * ddth
    hand_rhs = tau - b * dth - m * g * ell / 2 * sympy.cos(th)
    rename = {names[s.name]: s for s in (m, ell, g, b, tau, th, dth, ddth) if s.name in names}
    assert sympy.simplify(eq.lhs.subs(rename) - hand_lhs) == 0
    assert sympy.simplify(eq.rhs.subs(rename) - hand_rhs) == 0
    text = symbolic.latex(eq, models.get("arm"))
    assert r"\ddot{\theta}" in text and r"\dot{\theta}" in text and r"\ell" in text
    assert symbolic.kinetic_energy(models.get("arm")).subs(rename) == m * ell**2 * dth**2 / 6
