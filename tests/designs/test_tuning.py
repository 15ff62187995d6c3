"""Gain tuning against a closed-form optimum, finite differences and a fresh simulation."""

import casadi as ca
import numpy as np
import pytest

import models
from designs.tuning import Cost, Scenario, Specs, TuningProblem, closed_loop_spectral_abscissa, tune


@models.declare(name="cart_velocity", title="m v' = u - b v", coordinates=("s",), inputs=("u",),
                params=(models.Param("m", 1.0, "kg"), models.Param("b", 1.0, "N s/m")),
                input_limit=1e6, register=False)
def _cart_velocity(q, dq, u, p):
    return models.Physics(kinetic=p.m * dq.s**2 / 2, potential=0 * q.s, forces=[u.u - p.b * dq.s],
                          outputs={"s": q.s})


class VelocityGain(models.Block):
    """u = k (r − v), reading the state (s, v)."""

    def __init__(self, k):
        super().__init__(sample_period=0.01, n_state=0, n_measured=2, n_reference=1, n_input=1,
                         gains={"k": k}, measures="state")

    def expr(self, xc, y, r, g):
        return xc, g["k"] * (r[0] - y[1])


class ArmPD(models.Block):
    """τ = τe(θ) + kp (r − θ) − kd θ', saturated at the arm's limit; reads the state."""

    def __init__(self, known, kp=0.3, kd=0.1):
        self.known = known
        super().__init__(sample_period=0.01, n_state=0, n_measured=2, n_reference=1, n_input=1,
                         gains={"kp": kp, "kd": kd}, measures="state")

    def expr(self, xc, y, r, g):
        feedforward = self.known.casadi_equilibrium_input(y[0], self.known.param_vector())
        u = feedforward + g["kp"] * (r[0] - y[0]) - g["kd"] * y[1]
        return xc, models.saturate(u, self.known.input_limit[0])


@pytest.fixture(scope="module")
def arm():
    return models.get("arm")


def test_tuner_finds_the_closed_form_optimum_of_a_first_order_loop():
    """v' = −(b/m) v + u/m sampled with ZOH: v⁺ = φ v + γ u, u = −k v, J = Σ (v² + ρ u²) Ts.

    With λ = φ − γ k, J(k) = Ts (1 + ρ k²) / (1 − λ²) over an infinite horizon, and
    dJ/dk = 0 reduces to ρ φ γ k² + (ρ (1 − φ²) + γ²) k − γ φ = 0 (the k³ terms cancel).
    """
    plant = models.Plant(_cart_velocity)
    m, b, ts, rho = 1.0, 1.0, 0.01, 0.1
    phi = np.exp(-b / m * ts)
    gamma = (1 - phi) / b
    lin = rho * (1 - phi**2) + gamma**2
    k_star = (-lin + np.sqrt(lin**2 + 4 * rho * phi**2 * gamma**2)) / (2 * rho * phi * gamma)
    # 40 s: λ^(2N) ≈ e^-270, so the finite horizon is the infinite one to machine precision.
    result = tune(plant, VelocityGain(1.0),
                  Scenario(reference=0.0, duration=40.0, x0=[0.0, 1.0], tracked="ds"),
                  cost=Cost("ise", energy_weight=rho), tol=1e-12)
    assert result.success, result.message
    assert float(result.gains["k"]) == pytest.approx(k_star, abs=1e-6)
    assert result.cost == pytest.approx(ts * (1 + rho * k_star**2) / (1 - (phi - gamma * k_star) ** 2), rel=1e-9)


def test_cost_gradient_equals_central_differences(arm):
    block = ArmPD(arm)
    problem = TuningProblem(arm, block, Scenario(reference=np.deg2rad(50), duration=3.0, tracked="theta"))
    grad = ca.Function("grad", [problem.decision], [ca.gradient(problem.objective, problem.decision)])
    obj = ca.Function("obj", [problem.decision], [problem.objective])
    for point in (problem.start(), np.array([0.8, 0.12])):
        exact = np.asarray(grad(point)).ravel()
        h = 1e-6 * np.maximum(1, np.abs(point))
        fd = np.array([(float(obj(point + h[i] * e)) - float(obj(point - h[i] * e))) / (2 * h[i])
                       for i, e in enumerate(np.eye(point.size))])
        np.testing.assert_allclose(exact, fd, rtol=1e-5)


def _overshoot_and_settling(res, step_from, step_to, band=0.02):
    y = res.state("theta")
    over = max(0.0, (np.max(y) - step_to) / (step_to - step_from))
    outside = np.flatnonzero(np.abs(y - step_to) > band * abs(step_to - step_from))
    return over, (res.t[outside[-1] + 1] if outside.size else 0.0)


def test_tuned_design_beats_the_start_and_meets_its_specs(arm):
    block = ArmPD(arm)
    target = np.deg2rad(50)
    specs = Specs(max_overshoot=0.02, settling_time=1.5)
    # Without bounds ITAE keeps falling towards bang-bang as the gains grow.
    result = tune(arm, block, Scenario(reference=target, duration=3.0, tracked="theta"), specs=specs,
                  bounds={"kp": (0, 1.0), "kd": (0, 0.2)})
    assert result.success and result.feasible, result.message
    assert result.cost < 0.9 * result.initial_cost
    res = models.simulate_closed_loop(arm, result.block, target, 3.0)
    over, settle = _overshoot_and_settling(res, 0.0, target)
    assert over <= 0.02 + 1e-6 and settle <= 1.5 + 0.01
    assert np.max(np.abs(res.u)) <= arm.input_limit[0]


def test_infeasible_specs_are_named(arm):
    result = tune(arm, ArmPD(arm), Scenario(reference=np.deg2rad(50), duration=2.0, tracked="theta"),
                  specs=Specs(rise_time=0.05, max_overshoot=0.0), max_iter=30)
    assert not result.feasible and not result.success
    assert any("90 % of the step by 0.05 s" in v for v in result.violations)
    assert "infeasible" in result.message


def test_iteration_limit_returns_the_best_feasible_point(arm):
    calls = []
    result = tune(arm, ArmPD(arm), Scenario(reference=np.deg2rad(50), duration=3.0, tracked="theta"),
                  specs=Specs(max_overshoot=0.05), max_iter=2, progress=lambda *a: calls.append(a))
    assert result.status == "Maximum_Iterations_Exceeded"
    assert [c[0] for c in calls] == list(range(len(result.history))) == [0, 1, 2]
    assert [c[1] for c in calls] == [value for _, value in result.history]
    assert result.feasible and not result.success
    assert result.cost <= result.initial_cost


def test_robust_worst_case_is_no_better_than_nominal(arm):
    corners = models.corner_params(arm)
    block = ArmPD(arm)
    scenario = Scenario(reference=np.deg2rad(50), duration=3.0, tracked="theta")
    nominal = TuningProblem(arm, block, scenario)
    worst = TuningProblem(arm, block, scenario, samples=corners, robust="worst")
    obj_nominal = nominal.values(nominal.start())[0]
    obj_worst, costs, _ = worst.values(worst.start())
    assert obj_worst == pytest.approx(np.max(costs)) and obj_worst >= obj_nominal - 1e-12
    assert costs.shape == (len(corners),)


def test_spectral_abscissa_of_a_linear_loop_equals_its_eigenvalues():
    sat = models.get("satellite")
    from tests.models.test_closed_loop import StateFeedback  # the closed-loop tests' fixture block

    K = np.array([2.0, 1.0, 6.0, 0.5])
    block = StateFeedback(K, 3.0)
    disc = sat.linearize().discretize(0.01)
    expected = np.log(np.max(np.abs(np.linalg.eigvals(disc.A - disc.B @ K[None])))) / 0.01
    alpha = closed_loop_spectral_abscissa(sat, block, np.zeros(4), np.zeros(0), [0.0])
    assert alpha == pytest.approx(expected, rel=1e-9)


@pytest.mark.parametrize("kwargs,message", [
    ({"free": ["kq"]}, "has no gain"),
    ({"robust": "median"}, "robust must be"),
    ({"scenario": Scenario(reference=0.5, duration=1.0, tracked="phi")}, "arm has no state 'phi'"),
    ({"cost": "itae"}, None),
])
def test_bad_tuning_input(arm, kwargs, message):
    if message is None:
        with pytest.raises(ValueError, match="unknown cost 'l1'"):
            Cost("l1")
        return
    with pytest.raises(ValueError, match=message):
        TuningProblem(arm, ArmPD(arm), **({"scenario": Scenario(reference=0.5, duration=1.0, tracked="theta")}
                                          | kwargs))


def test_a_violated_spec_reports_its_excess_from_a_fresh_simulation(arm):
    """The overshoot excess named in a violation is the simulated peak past the bound (unbounded below)."""
    block, reference = ArmPD(arm), np.deg2rad(50)
    scenario = Scenario(reference=reference, duration=3.0, tracked="theta")
    run = models.simulate_closed_loop(arm, block, reference, 3.0, x0=arm.equilibrium()[0], substeps=10)
    overshoot = (np.max(run.x[:, 0]) - reference) / reference
    assert overshoot > 0.01
    bound = overshoot / 2
    problem = TuningProblem(arm, block, scenario, specs=Specs(max_overshoot=bound))
    (violation,) = problem.values(problem.start())[2]
    reported = float(violation.split("violated by ")[1].split(" ")[0])
    # g = peak − r against bound·step; unbounded below, so the relative scale is 1.
    assert reported == pytest.approx((overshoot - bound) * reference, rel=1e-3)
