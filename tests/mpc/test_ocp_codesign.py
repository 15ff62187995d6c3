"""Open-loop co-design of the spring-mass system: stiffness and force history chosen together.

    m s'' = -k s + u,  |u| <= 1,  s(0) = s'(0) = 0,  s'(T) = 0,  maximize s(T) over u(.) and k.

For a fixed k (ω = sqrt(k/m), θ = ωT < π) the problem is linear in u, so
Pontryagin's conditions are sufficient: u = sign(λ_v) with λ_v'' = -ω² λ_v,
a sinusoid, which changes sign at most once on [0, T] because its zeros are
π/ω > T apart. u = +1 throughout leaves s'(T) = sin(θ)/(mω) ≠ 0, so the
optimum is +1 then -1 with one switch at t_s. By superposition of steps,

    s(t) = [1 - cos ωt - 2 (1 - cos ω(t - t_s))] / k,  s'(t) = [ω sin ωt - 2ω sin ω(t - t_s)] / k

and with σ = ω(T - t_s): s'(T) = 0 gives sin σ = sin(θ)/2 (the root with cos σ > 0
gives the larger s(T)), so

    s*(k) = [2 sqrt(1 - sin²θ / 4) - 1 - cos θ] / k,   t_s = T - asin(sin(θ)/2) / ω.

As k -> 0 this tends to T²/(4m), the double integrator's d = a T²/4. The
co-design answer maximizes s*(k) over the range, a scalar problem solved
here with SciPy's bounded Brent search on the formula.
"""

import numpy as np
import pytest
from scipy.optimize import minimize_scalar

import models
import mpc

MASS, FINAL_TIME, K_RANGE = 1.0, 2.0, (0.1, 2.0)


def best_displacement(k):
    theta = np.sqrt(k / MASS) * FINAL_TIME
    return (2 * np.sqrt(1 - np.sin(theta) ** 2 / 4) - 1 - np.cos(theta)) / k


def switch_time(k):
    omega = np.sqrt(k / MASS)
    return FINAL_TIME - np.arcsin(np.sin(omega * FINAL_TIME) / 2) / omega


@pytest.fixture(scope="module")
def semi_analytic():
    result = minimize_scalar(
        lambda k: -best_displacement(k), bounds=K_RANGE, method="bounded", options={"xatol": 1e-12}
    )
    assert np.sqrt(result.x / MASS) * FINAL_TIME < np.pi  # one switch, as derived
    return result.x, -result.fun


def spring_mass_problem():
    @models.declare(
        name="spring",
        title="spring and mass",
        coordinates=("s",),
        inputs=("u",),
        params=(models.Param("m", MASS, "kg"), models.Param("k", 0.5, "N/m")),
        input_limit=1.0,
        register=False,
    )
    def declaration(q, dq, u, p):
        return models.Physics(kinetic=p.m * dq.s**2 / 2, potential=p.k * q.s**2 / 2, forces=[u.u], outputs={"s": q.s})

    ocp = mpc.OptimalControlProblem(models.Plant(declaration), FINAL_TIME)
    ocp.choose("k", *K_RANGE)
    ocp.maximize(ocp.at_end(ocp.x.s))
    ocp.subject_to(ocp.at_start(ocp.state) == 0)
    ocp.subject_to(ocp.at_end(ocp.x.ds) == 0)
    return ocp


@pytest.fixture(scope="module")
def simultaneous():
    return spring_mass_problem().solve(mpc.Collocation(intervals=100), solver_options={"tolerance": 1e-10})


def test_simultaneous_codesign_matches_the_semi_analytic_answer(simultaneous, semi_analytic):
    """s(T) to the held input's O(h²); k to 1 %: s*(k) is flat at its maximum
    (s*'' ≈ -0.55 m/(N/m)², so a 1e-5 m shortfall allows |Δk| ≈ 0.006 N/m)."""
    k_best, s_best = semi_analytic
    solution = simultaneous
    assert solution.success, solution.status
    assert -solution.objective == pytest.approx(s_best, rel=2e-5)
    assert solution.chosen["k"] == pytest.approx(k_best, abs=0.01)
    assert best_displacement(solution.chosen["k"]) == pytest.approx(s_best, abs=1e-5)
    # Bang-bang with one switch, where the formula puts it for the chosen k (within an interval).
    u, t = solution.inputs[:, 0], solution.t
    h = FINAL_TIME / 100
    switched = t[:-1] >= switch_time(solution.chosen["k"]) + h
    before = t[1:] <= switch_time(solution.chosen["k"]) - h
    np.testing.assert_allclose(u[before], 1.0, atol=1e-5)
    np.testing.assert_allclose(u[switched], -1.0, atol=1e-5)
    assert np.sum(~(before | switched)) <= 3  # the intervals within h of the switch


def test_nested_codesign_agrees_with_simultaneous(simultaneous):
    nested = mpc.solve_nested(spring_mass_problem(), mpc.Collocation(intervals=100))
    assert nested.success, nested.outer_status
    assert all(status == "solved" for status in nested.inner_statuses)
    assert nested.inner_solves >= nested.outer_iterations > 1
    assert nested.params["k"] == pytest.approx(simultaneous.chosen["k"], abs=1e-5)
    assert nested.objective == pytest.approx(simultaneous.objective, rel=1e-8)


@pytest.mark.parametrize("k", [0.7, 1.2])
def test_nested_gradient_is_the_derivative_of_the_optimal_value(k):
    """Envelope theorem: dJ*/dk = ∂L/∂k = -lam_p, against central differences of J*."""
    solver = spring_mass_problem().solver(mpc.Collocation(intervals=40), chosen_as_parameters=True, tolerance=1e-12)
    position = solver.transcription.fixed_param_names.index("k")
    solution = solver.solve(plant_params={"k": k})
    step = 1e-5
    difference = (
        solver.solve(plant_params={"k": k + step}).objective - solver.solve(plant_params={"k": k - step}).objective
    ) / (2 * step)
    assert -solution.lam_p[position] == pytest.approx(difference, rel=1e-5)
