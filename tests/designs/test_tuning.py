"""Gain tuning against a closed-form optimum, finite differences and a fresh simulation."""

import dataclasses

import casadi as ca
import numpy as np
import pytest

import models
from designs import tuning
from designs.tuning import (
    AGREEMENT,
    STAGE_TOL_FACTOR,
    TOL,
    Continuation,
    Cost,
    Scenario,
    SolveOptions,
    Specs,
    TuningProblem,
    TuningSetup,
    closed_loop_spectral_abscissa,
    continuation,
    gain_bounds,
    phase_one,
    tune,
)
from designs.tuning.result import pick_answer
from models import metrics
from models import specs as model_specs


@models.declare(
    name="cart_velocity",
    title="m v' = u - b v",
    coordinates=("s",),
    inputs=("u",),
    params=(models.Param("m", 1.0, "kg"), models.Param("b", 1.0, "N s/m")),
    input_limit=1e6,
    register=False,
)
def _cart_velocity(q, dq, u, p):
    return models.Physics(kinetic=p.m * dq.s**2 / 2, potential=0 * q.s, forces=[u.u - p.b * dq.s], outputs={"s": q.s})


class VelocityGain(models.Block):
    """u = k (r − v), reading the state (s, v)."""

    def __init__(self, k):
        super().__init__(
            sample_period=0.01, n_state=0, n_measured=2, n_reference=1, n_input=1, gains={"k": k}, measures="state"
        )

    def expr(self, xc, y, r, g):
        return xc, g["k"] * (r[0] - y[1])


class ArmPD(models.Block):
    """τ = τe(θ) + kp (r − θ) − kd θ', saturated at the arm's limit; reads the state."""

    def __init__(self, known, kp=0.3, kd=0.1):
        self.known = known
        super().__init__(
            sample_period=0.01,
            n_state=0,
            n_measured=2,
            n_reference=1,
            n_input=1,
            gains={"kp": kp, "kd": kd},
            measures="state",
        )

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
    result = tune(
        TuningSetup(
            plant,
            VelocityGain(1.0),
            Scenario(reference=0.0, duration=40.0, x0=[0.0, 1.0], tracked="ds"),
            cost=Cost("ise", energy_weight=rho),
        ),
        SolveOptions(tol=1e-12),
    )
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
        fd = np.array(
            [
                (float(obj(point + h[i] * e)) - float(obj(point - h[i] * e))) / (2 * h[i])
                for i, e in enumerate(np.eye(point.size))
            ]
        )
        np.testing.assert_allclose(exact, fd, rtol=1e-5)


def _overshoot_and_settling(res, step_from, step_to, band=0.02):
    y = res.state("theta")
    over = max(0.0, (np.max(y) - step_to) / (step_to - step_from))
    outside = np.flatnonzero(np.abs(y - step_to) > band * abs(step_to - step_from))
    return over, (res.t[outside[-1] + 1] if outside.size else 0.0)


def test_tuned_design_beats_the_start_and_meets_its_specs(arm):
    block = ArmPD(arm)
    target = np.deg2rad(50)
    specs = Specs(max_overshoot_pct=2.0, max_settling_time_s=1.5)
    # Without bounds ITAE keeps falling towards bang-bang as the gains grow.
    result = tune(
        TuningSetup(
            arm,
            block,
            Scenario(reference=target, duration=3.0, tracked="theta"),
            specs=specs,
            bounds={"kp": (0, 1.0), "kd": (0, 0.2)},
        )
    )
    assert result.success and result.feasible, result.message
    assert result.cost < 0.9 * result.initial_cost
    res = models.simulate_closed_loop(arm, result.block, target, 3.0)
    over, settle = _overshoot_and_settling(res, 0.0, target)
    assert over <= 0.02 + 1e-6 and settle <= 1.5 + 0.01
    assert np.max(np.abs(res.u)) <= arm.input_limit[0]


def test_infeasible_specs_are_named(arm):
    result = tune(
        TuningSetup(
            arm,
            ArmPD(arm),
            Scenario(reference=np.deg2rad(50), duration=2.0, tracked="theta"),
            specs=Specs(max_rise_time_s=0.05, max_overshoot_pct=0.0),
        ),
        SolveOptions(max_iter=30),
    )
    assert not result.feasible and not result.success
    assert any("90 % of the step by 0.05 s" in v for v in result.violations)
    assert "infeasible" in result.message


def test_an_infeasibility_verdict_contradicted_by_its_own_iterates_is_retried_from_the_last_feasible_one(
    arm, monkeypatch
):
    """IPOPT made to claim local infeasibility (ending elsewhere) after a solve whose iterates met the
    specs: `solve` solves once more from the last of those iterates, whose answer stands."""
    real, starts, seen, progress = ca.nlpsol, [], [], []

    class Claims:
        def __init__(self, solver):
            self.solver, self.lie = solver, False

        def __call__(self, **kw):
            starts.append(np.asarray(kw["x0"], dtype=float).ravel())
            seen.append(len(progress))
            sol = self.solver(**kw)
            self.lie = len(starts) == 1
            return dict(sol, x=3 * sol["x"]) if self.lie else sol

        def stats(self):
            stats = dict(self.solver.stats())
            return stats | ({"return_status": "Infeasible_Problem_Detected"} if self.lie else {})

    monkeypatch.setattr(ca, "nlpsol", lambda *a, **k: Claims(real(*a, **k)))
    scenario = Scenario(reference=np.deg2rad(50), duration=3.0, tracked="theta")
    specs = Specs(max_overshoot_pct=5.0)
    problem = TuningProblem(arm, ArmPD(arm), scenario, specs=specs)
    result = tune(
        TuningSetup(arm, ArmPD(arm), scenario, specs=specs, bounds={"kp": (0, 1.0), "kd": (0, 0.2)}),
        SolveOptions(progress=lambda i, f, t: progress.append(i)),
    )
    assert len(starts) >= 2 and result.converged and result.feasible
    met = [d for d in result.iterates[: seen[1]] if not problem.values(d)[2]]
    assert met
    scale = np.abs(problem.start())
    np.testing.assert_allclose(starts[1] * scale, met[-1], rtol=1e-12)
    monkeypatch.undo()
    honest = tune(TuningSetup(arm, ArmPD(arm), scenario, specs=specs, bounds={"kp": (0, 1.0), "kd": (0, 0.2)}))
    assert honest.converged and result.cost == pytest.approx(honest.cost, rel=1e-6)


def test_iteration_limit_returns_the_best_feasible_point_and_says_it_did_not_converge(arm):
    calls = []
    result = tune(
        TuningSetup(
            arm,
            ArmPD(arm),
            Scenario(reference=np.deg2rad(50), duration=3.0, tracked="theta"),
            specs=Specs(max_overshoot_pct=5.0),
        ),
        SolveOptions(max_iter=2, progress=lambda *a: calls.append(a)),
    )
    assert result.status == "Maximum_Iterations_Exceeded"
    assert {s["substeps"] for s in result.stages} == {10}  # with specs, no coarse level first
    # A capped stage hands its point on once; two capped stages in a row end the continuation.
    assert not result.converged and [s["status"] for s in result.stages] == ["Maximum_Iterations_Exceeded"] * 2
    # Each of the two IPOPT solves reports its iterations 0, 1, 2.
    assert [c[0] for c in calls] == list(range(len(result.history))) == list(range(6))
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


@pytest.mark.parametrize(
    "kwargs,message",
    [
        ({"free": ["kq"]}, "has no gain"),
        ({"robust": "median"}, "robust must be"),
        ({"scenarios": Scenario(reference=0.5, duration=1.0, tracked="phi")}, "arm has no state 'phi'"),
        ({"cost": "itae"}, None),
    ],
)
def test_bad_tuning_input(arm, kwargs, message):
    if message is None:
        with pytest.raises(ValueError, match="unknown cost 'l1'"):
            Cost("l1")
        return
    with pytest.raises(ValueError, match=message):
        TuningProblem(
            arm, ArmPD(arm), **({"scenarios": Scenario(reference=0.5, duration=1.0, tracked="theta")} | kwargs)
        )


def test_a_violated_spec_reports_its_excess_from_a_fresh_simulation(arm):
    """The overshoot excess named in a violation is the simulated peak past the bound (unbounded below)."""
    block, reference = ArmPD(arm), np.deg2rad(50)
    scenario = Scenario(reference=reference, duration=3.0, tracked="theta")
    run = models.simulate_closed_loop(arm, block, reference, 3.0, x0=arm.equilibrium()[0], substeps=10)
    overshoot = (np.max(run.x[:, 0]) - reference) / reference
    assert overshoot > 0.01
    bound = overshoot / 2
    problem = TuningProblem(arm, block, scenario, specs=Specs(max_overshoot_pct=100 * bound))
    (violation,) = problem.values(problem.start())[2]
    reported = float(violation.split("violated by ")[1].split(" ")[0])
    # g = peak − r against bound·step; unbounded below, so the relative scale is 1.
    assert reported == pytest.approx((overshoot - bound) * reference, rel=1e-3)


# ----------------------------------------------------------------- through saturation
def _itae_by_simulation(plant, block, reference, duration, energy_weight=0.0, **kwargs):
    """ITAE (+ energy) of a fresh `simulate_closed_loop` run, in numpy: Ts Σ t_k |r − θ_k| over k = 0..N-1,
    |e| as sqrt(e² + δ²) with Cost's default δ = max(1e-6, 1e-4 |step|) (the step from rest at 0)."""
    run = models.simulate_closed_loop(plant, block, reference, duration, **kwargs)
    ts = block.sample_period
    e = run.r[:-1, 0] - run.x[:-1, 0]
    delta = max(1e-6, 1e-4 * abs(reference))
    return ts * (np.sum(run.t[:-1] * np.sqrt(e**2 + delta**2)) + energy_weight * np.sum(run.u**2)), run


def test_saturating_loop_tuned_smoothly_ends_where_exact_and_smoothed_costs_agree(arm):
    """The arm's PD, whose command sits at the 1 N m limit for the first samples: the continuation converges,
    and at its answer the exact loop (a fresh numpy simulation) and the smoothed loop (last width) cost the same."""
    block = ArmPD(arm)
    target = np.deg2rad(50)
    scenario = Scenario(reference=target, duration=3.0, tracked="theta")
    result = tune(
        TuningSetup(
            arm,
            block,
            scenario,
            cost=Cost("itae", energy_weight=0.01),
            specs=Specs(max_overshoot_pct=2.0),
            bounds={"kp": (0, 5.0), "kd": (0, 1.0)},
        )
    )
    assert result.method == "smooth" and result.converged and result.status == "Solve_Succeeded", result.message
    assert result.feasible and result.cost < result.initial_cost
    exact, run = _itae_by_simulation(arm, result.block, target, 3.0, energy_weight=0.01, substeps=10)
    assert np.sum(np.abs(run.u[:, 0]) >= arm.input_limit[0] - 1e-12) >= 20  # it saturates for 20 samples or more
    width = result.stages[-1]["width"]
    problem = TuningProblem(arm, block, scenario, cost=Cost("itae", energy_weight=0.01))
    smoothed = ca.Function("smoothed", [problem.decision, problem.width], [problem.aggregate(problem.smoothed()[0])])(
        result.decision, width
    )
    assert float(smoothed) == pytest.approx(exact, rel=AGREEMENT)
    assert result.cost == pytest.approx(exact, rel=1e-9)
    # Stopped on the rule, not because the widths ran out: the last two widths gave the same exact cost,
    # or the last answer has every switch outside its band (smoothed and exact costs equal).
    last = result.stages[-1]
    assert last["gap"] == 0.0 or last["exact"] == pytest.approx(result.stages[-2]["exact"], rel=AGREEMENT)
    assert all(stage["status"] == "Solve_Succeeded" for stage in result.stages)


def test_loose_intermediate_stages_end_where_tight_ones_do(arm, monkeypatch):
    """The continuation's intermediate widths are solved to STAGE_TOL_FACTOR x tol and the last one to tol:
    on the saturating arm loop it ends at the answer of the continuation solved to tol at every width."""
    block, scenario = ArmPD(arm), Scenario(reference=np.deg2rad(50), duration=3.0, tracked="theta")
    kwargs = dict(cost=Cost("itae", energy_weight=0.01), bounds={"kp": (0, 5.0), "kd": (0, 1.0)})
    loose = tune(TuningSetup(arm, block, scenario, **kwargs))
    monkeypatch.setattr(continuation, "STAGE_TOL_FACTOR", 1.0)
    tight = tune(TuningSetup(arm, block, scenario, **kwargs))
    assert loose.converged and tight.converged, (loose.message, tight.message)
    assert len(loose.stages) >= 2 and loose.stages[-1]["tol"] == TOL
    assert all(stage["tol"] == STAGE_TOL_FACTOR * TOL for stage in loose.stages[:-1])
    assert all(stage["tol"] == TOL for stage in tight.stages)
    assert loose.cost == pytest.approx(tight.cost, rel=AGREEMENT)
    np.testing.assert_allclose(loose.decision, tight.decision, rtol=1e-3)


def test_smoothed_gradient_equals_central_differences(arm):
    problem = TuningProblem(arm, ArmPD(arm, kp=2.0), Scenario(reference=np.deg2rad(50), duration=2.0, tracked="theta"))
    per_sample, _ = problem.smoothed()
    value = problem.aggregate(per_sample)
    f = ca.Function("f", [problem.decision, problem.width], [value, ca.gradient(value, problem.decision)])
    point, width = problem.start(), 0.05
    exact = np.asarray(f(point, width)[1]).ravel()
    h = 1e-6 * np.abs(point)
    fd = [
        (float(f(point + h[i] * e, width)[0]) - float(f(point - h[i] * e, width)[0])) / (2 * h[i])
        for i, e in enumerate(np.eye(point.size))
    ]
    np.testing.assert_allclose(exact, fd, rtol=1e-5)


# ----------------------------------------------------------------- several scenarios
def _step_and_disturbance(target, **fields):
    return [
        Scenario(reference=target, duration=3.0, tracked="theta", name="step", **fields),
        Scenario(
            reference=target,
            duration=3.0,
            input_disturbance=0.2,
            tracked="theta",
            name="disturbance",
            weight=2.0,
            **fields,
        ),
    ]


def test_several_scenarios_sum_their_weighted_costs_per_sample(arm):
    block = ArmPD(arm)
    target = np.deg2rad(50)
    corners = models.corner_params(arm)
    both = TuningProblem(arm, block, _step_and_disturbance(target), samples=corners)
    alone = [TuningProblem(arm, block, s, samples=corners) for s in _step_and_disturbance(target)]
    objective, per_sample, _ = both.values(both.start())
    parts = [p.scenario_values(p.start())[0] for p in alone]  # unweighted, one row each
    np.testing.assert_allclose(per_sample, parts[0] + 2.0 * parts[1], rtol=1e-12)
    assert objective == pytest.approx(np.mean(parts[0] + 2.0 * parts[1]), rel=1e-12)
    np.testing.assert_allclose(both.scenario_values(both.start()), np.vstack(parts), rtol=1e-12)
    # The disturbance run is a different run: its cost differs from the step's.
    assert not np.allclose(parts[0], parts[1])


def _two_steps():
    """The 50° step that saturates the arm's motor and a 20° step that does not."""
    return [
        Scenario(reference=np.deg2rad(50), duration=3.0, tracked="theta", name="large step"),
        Scenario(reference=np.deg2rad(20), duration=3.0, tracked="theta", name="small step", weight=2.0),
    ]


def _step_figures(plant, block, scenario):
    run = models.simulate_closed_loop(plant, block, scenario.reference, scenario.duration)
    m = metrics.step_metrics(run.t, run.state("theta"), initial=0.0, target=scenario.reference)
    return m["overshoot_pct"] / 100, m["settling_time_s"]


def test_multi_scenario_tuning_is_never_worse_than_the_hand_design_on_any_scenarios_spec(arm):
    """Each scenario's specs are the hand design's own overshoot and settling time there; tuning on both
    steps beats the hand cost without giving either figure away on either (checked by fresh simulations)."""
    block = ArmPD(arm, kp=0.6, kd=0.12)
    plain = _two_steps()
    hand = {s.name: _step_figures(arm, block, s) for s in plain}
    assert all(np.isfinite(settle) for _, settle in hand.values())
    scenarios = [
        Scenario(
            s.reference,
            s.duration,
            tracked="theta",
            name=s.name,
            weight=s.weight,
            specs=Specs(max_overshoot_pct=100 * hand[s.name][0], max_settling_time_s=hand[s.name][1]),
        )
        for s in plain
    ]
    result = tune(
        TuningSetup(
            arm, block, scenarios, cost=Cost("itae", energy_weight=0.01), bounds={"kp": (0.06, 6.0), "kd": (0.012, 1.2)}
        )
    )
    assert result.converged and result.feasible, result.message
    assert result.cost < 0.9 * result.initial_cost
    for s in plain:
        overshoot, settle = _step_figures(arm, result.block, s)
        assert overshoot <= hand[s.name][0] + 1e-6, s.name
        assert settle <= hand[s.name][1] + block.sample_period, s.name


# ----------------------------------------------------------------- general costs and regulation
def test_quadratic_cost_terminal_and_output_terms_equal_a_numpy_sum_over_a_fresh_run(arm):
    block = ArmPD(arm)
    target = np.deg2rad(30)
    cost = Cost(
        kind=None,
        state_weights=np.array([[2.0, 0.3], [0.3, 0.5]]),
        input_weights={"tau": 0.7},
        output_weights=[1.5],
        terminal_weights={"dtheta": 4.0},
        input_target={"tau": 0.4},
    )
    problem = TuningProblem(arm, block, Scenario(reference=target, duration=2.0, tracked="theta"), cost=cost)
    run = models.simulate_closed_loop(arm, block, target, 2.0, substeps=10)
    ts = block.sample_period
    dx = run.x[:-1] - np.array([target, 0.0])  # default target: the equilibrium with θ at the final reference
    Q = np.array([[2.0, 0.3], [0.3, 0.5]])
    expected = (
        ts
        * (
            np.einsum("ki,ij,kj->", dx, Q, dx)
            + 0.7 * np.sum((run.u[:, 0] - 0.4) ** 2)
            + 1.5 * np.sum((run.y[:-1, 0] - target) ** 2)
        )
        + 4.0 * run.x[-1, 1] ** 2
    )
    assert problem.values(problem.start())[0] == pytest.approx(expected, rel=1e-10)


def test_criterion_of_any_signal_and_regulation_from_an_initial_state(arm):
    """IAE of the rate dθ/dt and ISE of the input while the arm regulates back to rest from θ = 0.3 rad."""
    xe, ue = arm.equilibrium()
    block = ArmPD(arm)
    scenario = Scenario(reference=None, duration=2.0, x0=[0.3, 0.0], tracked="theta", name="regulation")
    run = models.simulate_closed_loop(arm, block, 0.0, 2.0, x0=[0.3, 0.0], substeps=10)
    ts = block.sample_period
    iae = TuningProblem(arm, block, scenario, cost=Cost("iae", signal="dtheta"))
    assert iae.values(iae.start())[0] == pytest.approx(ts * np.sum(np.sqrt(run.x[:-1, 1] ** 2 + 1e-12)), rel=1e-10)
    ise = TuningProblem(arm, block, scenario, cost=Cost("ise", signal="tau", input_target={"tau": ue[0]}))
    assert ise.values(ise.start())[0] == pytest.approx(ts * np.sum((run.u[:, 0] - ue[0]) ** 2), rel=1e-10)
    # Specs on any state of a regulation: a bound and a final value, checked against the run.
    bound = float(np.max(np.abs(run.x[1:, 1])))
    holds = TuningProblem(
        arm,
        block,
        scenario,
        cost=Cost("iae", signal="theta"),
        specs=Specs(state_bounds={"dtheta": 1.01 * bound}, final_values={"theta": (0.0, 0.05)}),
    )
    assert holds.values(holds.start())[2] == [] and abs(run.x[-1, 0]) < 0.05
    assert run.x[1:, 1].min() == -bound  # it swings back with a negative rate
    fails = TuningProblem(
        arm,
        block,
        scenario,
        cost=Cost("iae", signal="theta"),
        specs=Specs(state_bounds={"dtheta": (-0.5 * bound, np.inf)}),
    )
    (violation,) = fails.values(fails.start())[2]
    assert violation.startswith(f"{-0.5 * bound:g} <= dtheta <= inf (regulation)")


@models.declare(
    name="lag",
    title="x' = -b x + u",
    coordinates=(),
    inputs=("u",),
    first_order=("x",),
    params=(models.Param("b", 2.0, "1/s"),),
    input_limit=1e6,
    register=False,
)
def _lag(q, dq, u, p, s):
    return models.Physics(rates={"x": -p.b * s.x + u.u}, outputs={"x": s.x})


class Proportional(models.Block):
    """u = −k x on a one-state plant (reads the state, no reference)."""

    def __init__(self, k, sample_period=0.01):
        super().__init__(
            sample_period=sample_period,
            n_state=0,
            n_measured=1,
            n_reference=0,
            n_input=1,
            gains={"k": k},
            measures="state",
        )

    def expr(self, xc, y, r, g):
        return xc, -g["k"] * y[0]


def test_a_first_order_plant_tunes_without_registering_to_its_sampled_lqr_gain():
    """ẋ = −b x + u with ZOH at Ts: x⁺ = φ x + γ u; J = Ts Σ (q x² + r u²) from x0 = 1 is minimized by the
    k of the closed form in `test_tuner_finds_the_closed_form_optimum_of_a_first_order_loop`."""
    plant = models.Plant(_lag)
    assert "lag" not in models.names()
    b, ts, q, r = 2.0, 0.01, 3.0, 0.5
    phi = np.exp(-b * ts)
    gamma = (1 - phi) / b
    rho = r / q
    lin = rho * (1 - phi**2) + gamma**2
    k_star = (-lin + np.sqrt(lin**2 + 4 * rho * phi**2 * gamma**2)) / (2 * rho * phi * gamma)
    result = tune(
        TuningSetup(
            plant,
            Proportional(1.0, ts),
            Scenario(reference=None, duration=12.0, x0=[1.0]),
            cost=Cost(kind=None, state_weights={"x": q}, input_weights={"u": r}),
        ),
        SolveOptions(tol=1e-12),
    )
    assert result.converged and result.success, result.message
    assert float(result.gains["k"]) == pytest.approx(k_star, rel=1e-6)
    assert result.cost == pytest.approx(q * ts * (1 + rho * k_star**2) / (1 - (phi - gamma * k_star) ** 2), rel=1e-9)


def test_worst_case_tuning_minimizes_the_largest_sample_cost_of_the_closed_form():
    """Two plants b = 1 and b = 3 (the decision is one k): the epigraph solve reaches min_k max_b J_b(k),
    with J_b(k) = q Ts (1 + ρ k²) / (1 − λ_b²) in closed form, minimized here by scipy."""
    import scipy.optimize

    plant = models.Plant(_lag)
    ts, q, r = 0.01, 3.0, 0.5
    rows = np.array([[1.0], [3.0]])

    def closed_form(k, b):
        phi = np.exp(-b * ts)
        lam = phi - (1 - phi) / b * k
        return ts * (q + r * k**2) / (1 - lam**2)

    best = scipy.optimize.minimize_scalar(
        lambda k: max(closed_form(k, b) for b in rows[:, 0]), bounds=(0, 10), method="bounded", options={"xatol": 1e-12}
    )
    result = tune(
        TuningSetup(
            plant,
            Proportional(1.0, ts),
            Scenario(reference=None, duration=12.0, x0=[1.0]),
            samples=rows,
            robust="worst",
            cost=Cost(kind=None, state_weights={"x": q}, input_weights={"u": r}),
        ),
        SolveOptions(tol=1e-12),
    )
    assert result.converged, result.message
    assert float(result.gains["k"]) == pytest.approx(best.x, rel=1e-5)
    assert result.cost == pytest.approx(best.fun, rel=1e-8)


def test_soft_max_excess_lies_within_the_width_below_the_largest_excess_and_has_its_gradient():
    """The aggregated inequality of `paths="aggregated"`: between max v - width and max v (v the relative
    excesses of both bounds), and its gradient equals central differences."""
    rng = np.random.default_rng(4)
    values = rng.normal(size=40)
    lo, hi = -0.5, np.full(40, 0.3)
    x, w = ca.MX.sym("x", 40), ca.MX.sym("w")
    soft = tuning.soft_max_excess(x, lo, hi, w)
    f = ca.Function("f", [x, w], [soft, ca.gradient(soft, x)])
    scale = 1 + max(abs(lo), 0.3)
    largest = max(np.max(values - hi), np.max(lo - values)) / scale
    for width in (0.3, 1e-2, 1e-5, 1e-9):
        value = float(f(values, width)[0])
        assert largest - width - 1e-15 <= value <= largest + 1e-15
    width = 0.05
    gradient = np.asarray(f(values, width)[1]).ravel()
    h = 1e-6
    fd = [(float(f(values + h * e, width)[0]) - float(f(values - h * e, width)[0])) / (2 * h) for e in np.eye(40)]
    np.testing.assert_allclose(gradient, fd, rtol=1e-5, atol=1e-9)


def test_aggregated_path_specs_reach_the_pointwise_answer(arm):
    """The arm's PD with an active overshoot spec and a settling spec: one soft-maximum inequality per spec
    on the smoothed stages instead of one per sample, the same converged answer, judged pointwise."""
    block = ArmPD(arm)
    scenario = Scenario(reference=np.deg2rad(50), duration=3.0, tracked="theta")
    kwargs = dict(specs=Specs(max_overshoot_pct=2.0, max_settling_time_s=1.5), bounds={"kp": (0, 1.0), "kd": (0, 0.2)})
    pointwise = tune(TuningSetup(arm, block, scenario, **kwargs))
    aggregated = tune(TuningSetup(arm, block, scenario, paths="aggregated", **kwargs))
    problem = TuningProblem(arm, block, scenario, specs=kwargs["specs"], paths="aggregated")
    _, g = problem.smoothed()
    assert g.numel() == len(problem.constraint_names) == 2 and problem.g.numel() > 100
    for result in (pointwise, aggregated):
        assert result.converged and result.feasible, result.message
    assert aggregated.cost == pytest.approx(pointwise.cost, rel=1e-5)
    np.testing.assert_allclose(aggregated.decision, pointwise.decision, rtol=1e-3)
    with pytest.raises(ValueError, match="paths must be"):
        TuningProblem(arm, block, scenario, paths="sampled")


def test_phase_one_certifies_unreachable_specs_no_worse_than_a_grid(arm):
    """A 50 deg step risen in 0.05 s is beyond the 1 N m arm: phase one converges outside the spec, at an
    excess no grid point of the gain box beats (the bang-bang start bounds how far the arm can rise)."""
    problem = TuningProblem(
        arm,
        ArmPD(arm),
        Scenario(reference=np.deg2rad(50), duration=1.0, tracked="theta"),
        specs=Specs(max_rise_time_s=0.05),
    )
    lbx, ubx = gain_bounds(problem, {"kp": (0, 1.0), "kd": (0, 0.2)})
    found = phase_one(problem, lbx, ubx, problem.start())
    assert found.converged and found.infeasible, found
    grid = [
        np.max(problem.excess(np.asarray(problem.evaluate([kp, kd])[1]).ravel()))
        for kp in np.linspace(0.05, 1.0, 8)
        for kd in np.linspace(0.0, 0.2, 6)
    ]
    assert 0 < found.excess <= min(grid) * (1 + 1e-6)
    exact = np.max(problem.excess(np.asarray(problem.evaluate(found.decision)[1]).ravel()))
    assert exact == pytest.approx(found.excess, rel=1e-12)


def test_a_phase_one_stopped_by_a_numerical_failure_is_retried_from_where_it_stopped(arm, monkeypatch):
    """IPOPT made to report Restoration_Failed on the phase one's first solve: it is solved once more from
    that solve's answer, and the verdict (here: a certificate of infeasibility) is the second solve's."""
    problem = TuningProblem(
        arm,
        ArmPD(arm),
        Scenario(reference=np.deg2rad(50), duration=1.0, tracked="theta"),
        specs=Specs(max_rise_time_s=0.05),
    )
    lbx, ubx = gain_bounds(problem, {"kp": (0, 1.0), "kd": (0, 0.2)})
    real, starts, answers = ca.nlpsol, [], []

    class FailsOnce:
        def __init__(self, solver):
            self.solver = solver

        def __call__(self, **kw):
            starts.append(np.asarray(kw["x0"], dtype=float).ravel())
            answers.append(np.asarray(self.solver(**kw)["x"], dtype=float).ravel())
            return {"x": ca.DM(answers[-1])}

        def stats(self):
            failed = len(starts) == 1
            return dict(self.solver.stats()) | ({"return_status": "Restoration_Failed"} if failed else {})

    monkeypatch.setattr(ca, "nlpsol", lambda *a, **k: FailsOnce(real(*a, **k)))
    found = phase_one(problem, lbx, ubx, problem.start())
    assert len(starts) >= 2 and found.converged and found.infeasible, found
    np.testing.assert_allclose(starts[1][:-1], answers[0][:-1], rtol=1e-12)  # the gains it stopped at
    monkeypatch.undo()
    fresh = TuningProblem(
        arm,
        ArmPD(arm),
        Scenario(reference=np.deg2rad(50), duration=1.0, tracked="theta"),
        specs=Specs(max_rise_time_s=0.05),
    )  # the first problem keeps its (wrapped) solver
    honest = phase_one(fresh, lbx, ubx, fresh.start())
    assert found.excess == pytest.approx(honest.excess, rel=1e-6)


def test_a_problem_solved_again_reuses_its_solvers_and_answers_as_a_fresh_one(arm, monkeypatch):
    """The second solve of one problem (another start, as a nested co-design's next evaluation) builds no
    solver, and its answer and iterate history are those of the same solve on a newly built problem."""
    scenario = Scenario(reference=np.deg2rad(50), duration=2.0, tracked="theta")
    specs = Specs(max_overshoot_pct=5.0)

    def problem():
        return TuningProblem(arm, ArmPD(arm), scenario, specs=specs)

    built, real = [], ca.nlpsol
    monkeypatch.setattr(ca, "nlpsol", lambda *a, **k: built.append(a[0]) or real(*a, **k))
    again = problem()
    lbx, ubx = gain_bounds(again, {"kp": (0, 1.0), "kd": (0, 0.2)})
    tuning.solve(again, lbx, ubx, start=[0.2, 0.05])
    first = len(built)
    second = tuning.solve(again, lbx, ubx, start=[0.5, 0.15])
    assert first > 0 and len(built) == first  # nothing built the second time
    fresh = tuning.solve(problem(), lbx, ubx, start=[0.5, 0.15])
    assert second.converged and fresh.converged
    np.testing.assert_allclose(second.decision, fresh.decision, rtol=1e-12)
    assert len(second.history) == len(fresh.history) == len(second.iterates)
    assert [s["iterations"] for s in second.stages] == [s["iterations"] for s in fresh.stages]


def test_a_start_outside_the_specs_is_tuned_from_phase_ones_answer_and_converges(arm):
    """Without the phase one, this tuning ended at IPOPT's 3000-iteration cap (its restoration wandering
    along a feasible set of one corner); the answer must meet the specs on a fresh simulation."""
    target = np.deg2rad(50)
    specs = Specs(max_overshoot_pct=0.0, max_settling_time_s=0.8)
    scenario = Scenario(reference=target, duration=3.0, tracked="theta")
    start = TuningProblem(arm, ArmPD(arm), scenario, specs=specs)
    assert start.values(start.start())[2]  # the start misses both specs
    result = tune(
        TuningSetup(arm, ArmPD(arm), scenario, specs=specs, bounds={"kp": (0, 1.0), "kd": (0, 0.2)}),
        SolveOptions(phase=True),
    )
    assert result.phase_one is not None and result.phase_one.converged and not result.phase_one.infeasible
    assert result.converged and result.feasible and result.stopped_on_test, result.message
    assert "phase one" in result.message
    res = models.simulate_closed_loop(arm, result.block, target, 3.0)
    over, settle = _overshoot_and_settling(res, 0.0, target)
    assert over * target <= 1e-6 and settle <= 0.8 + 0.01  # the specs are judged to 1e-6 rad


def test_a_capped_intermediate_stage_hands_its_point_on_and_two_in_a_row_end_the_continuation(arm):
    """The continuation's verdict rests on its last stage: at 16 iterations per solve the width-1e-3 stage
    stops at its cap and the next one converges to the answer of the uncapped tuning; at 4 every stage
    caps, and the continuation stops after two instead of running all seven widths. One level of
    fidelity (no coarse level first): the rule is the continuation's."""
    scenario = Scenario(reference=np.deg2rad(50), duration=3.0, tracked="theta")
    bounds = {"kp": (0, 1.0), "kd": (0, 0.2)}
    free = tune(TuningSetup(arm, ArmPD(arm), scenario, bounds=bounds), SolveOptions(coarse_substeps=None))
    capped = tune(
        TuningSetup(arm, ArmPD(arm), scenario, bounds=bounds), SolveOptions(coarse_substeps=None, max_iter=16)
    )
    assert free.converged and "Maximum_Iterations_Exceeded" not in [s["status"] for s in free.stages]
    assert [s["status"] for s in capped.stages][:2] == ["Solve_Succeeded", "Maximum_Iterations_Exceeded"]
    assert capped.converged and capped.stopped_on_test
    assert capped.cost == pytest.approx(free.cost, rel=1e-6)
    stuck = tune(TuningSetup(arm, ArmPD(arm), scenario, bounds=bounds), SolveOptions(coarse_substeps=None, max_iter=4))
    assert [s["status"] for s in stuck.stages] == ["Maximum_Iterations_Exceeded"] * 2 and not stuck.converged


def test_a_coarse_level_first_ends_at_the_one_level_answer_on_the_fine_loop(arm):
    """Without specs, a coarse level (one RK4 step per sample) runs its continuation first, loosely, and
    starts the problem's own (ten sub-steps) where it settled; the converged answer is the one-level
    tuning's, whose iterates never saw the coarse loop."""
    scenario = Scenario(reference=np.deg2rad(50), duration=3.0, tracked="theta")
    bounds = {"kp": (0, 1.0), "kd": (0, 0.2)}
    one = tune(TuningSetup(arm, ArmPD(arm), scenario, bounds=bounds), SolveOptions(coarse_substeps=None))
    two = tune(TuningSetup(arm, ArmPD(arm), scenario, bounds=bounds))
    levels = [s["substeps"] for s in two.stages]
    assert levels[0] == tuning.COARSE_SUBSTEPS == 1 and levels[-1] == 10 and levels == sorted(levels)
    assert {s["substeps"] for s in one.stages} == {10}
    assert all(s["tol"] == STAGE_TOL_FACTOR * TOL for s in two.stages if s["substeps"] == 1)
    fine = [s for s in two.stages if s["substeps"] == 10]
    coarse_end = [s for s in two.stages if s["substeps"] == 1][-1]
    assert fine[0]["width"] == coarse_end["width"]  # the fine continuation starts where the coarse settled
    assert one.converged and two.converged and two.stopped_on_test
    assert two.cost == pytest.approx(one.cost, rel=1e-6)
    fresh = TuningProblem(arm, ArmPD(arm), scenario)
    assert fresh.values(two.decision)[0] == pytest.approx(two.cost, rel=1e-12)  # judged on the fine loop


def test_one_width_with_a_coarse_level_ends_at_the_one_level_answer(arm):
    """A single width (no continuation) on a problem without specs: the coarse level, then the problem's own
    from its answer, warm (this raised KeyError: no warm solver was built without a continuation)."""
    scenario = Scenario(reference=np.deg2rad(50), duration=3.0, tracked="theta")
    bounds = {"kp": (0, 1.0), "kd": (0, 0.2)}
    two = tune(TuningSetup(arm, ArmPD(arm), scenario, bounds=bounds), SolveOptions(widths=(1e-3,), tol=1e-10))
    one = tune(
        TuningSetup(arm, ArmPD(arm), scenario, bounds=bounds),
        SolveOptions(widths=(1e-3,), tol=1e-10, coarse_substeps=None),
    )
    assert [s["substeps"] for s in two.stages] == [1, 10] and two.converged and one.converged
    assert two.cost == pytest.approx(one.cost, rel=1e-8)
    np.testing.assert_allclose(two.decision, one.decision, rtol=1e-5)


def test_relaxed_keeps_the_unconstrained_answer_only_where_it_meets_the_specs(arm):
    """An overshoot bound of 50 % is inactive at the ITAE optimum: solved without it first, that answer is
    kept, and the solve with the bound reaches it too. A bound of 0 % is active: the first answer misses
    it, and the result is the usual solve's, the first one named in its message."""
    scenario = Scenario(reference=np.deg2rad(50), duration=3.0, tracked="theta")
    bounds = {"kp": (0, 1.0), "kd": (0, 0.2)}
    loose = Specs(max_overshoot_pct=50.0)
    kept = tune(
        TuningSetup(arm, ArmPD(arm), scenario, specs=loose, bounds=bounds), SolveOptions(relaxed=True, tol=1e-10)
    )
    with_specs = tune(TuningSetup(arm, ArmPD(arm), scenario, specs=loose, bounds=bounds), SolveOptions(tol=1e-10))
    assert kept.converged and with_specs.converged and kept.message.startswith("solved without the specs")
    assert kept.cost == pytest.approx(with_specs.cost, rel=1e-7)
    np.testing.assert_allclose(kept.decision, with_specs.decision, rtol=1e-4)
    target = np.deg2rad(50)
    over, _ = _overshoot_and_settling(models.simulate_closed_loop(arm, kept.block, target, 3.0), 0.0, target)
    assert 0 < over < 0.5  # overshoots (so the 0 % bound below is active), within the 50 % one
    tight = Specs(max_overshoot_pct=0.0)
    fallback = tune(TuningSetup(arm, ArmPD(arm), scenario, specs=tight, bounds=bounds), SolveOptions(relaxed=True))
    usual = tune(TuningSetup(arm, ArmPD(arm), scenario, specs=tight, bounds=bounds))
    assert fallback.message.startswith("without the specs: ") and "missing overshoot" in fallback.message
    assert fallback.cost == usual.cost and fallback.feasible and fallback.converged


def test_no_coarse_level_where_it_disagrees_at_the_start(arm, monkeypatch):
    scenario = Scenario(reference=np.deg2rad(50), duration=3.0, tracked="theta")
    problem = TuningProblem(arm, ArmPD(arm), scenario)
    coarse = problem.with_substeps(1)
    gap = abs(coarse.values(problem.start())[0] / problem.values(problem.start())[0] - 1)
    assert 0 < gap < tuning.COARSE_AGREEMENT  # it runs by default (the test above)
    monkeypatch.setattr(continuation, "COARSE_AGREEMENT", gap / 2)
    result = tune(
        TuningSetup(arm, ArmPD(arm), scenario, bounds={"kp": (0, 1.0), "kd": (0, 0.2)}), SolveOptions(max_iter=2)
    )
    assert {s["substeps"] for s in result.stages} == {10}


def test_until_feasible_stops_at_the_first_decision_meeting_the_specs(arm):
    """The feasibility verdict of an outer search: the same problem as above, stopped where the specs hold."""
    target = np.deg2rad(50)
    specs = Specs(max_overshoot_pct=0.0, max_settling_time_s=0.8)
    scenario = Scenario(reference=target, duration=3.0, tracked="theta")
    bounds = {"kp": (0, 1.0), "kd": (0, 0.2)}
    found = tune(
        TuningSetup(arm, ArmPD(arm), scenario, specs=specs, bounds=bounds),
        SolveOptions(phase=True, until_feasible=True),
    )
    assert found.feasible and found.converged and found.stopped_on_test and found.phase_one is not None
    assert found.iterations == found.phase_one.iterations and "cost not tuned" in found.message
    res = models.simulate_closed_loop(arm, found.block, target, 3.0)
    over, settle = _overshoot_and_settling(res, 0.0, target)
    assert over * target <= 1e-6 and settle <= 0.8 + 0.01
    # A start that already meets the specs is the verdict itself: no solve, its gains returned.
    again = tune(
        TuningSetup(arm, found.block, scenario, specs=specs, bounds=bounds),
        SolveOptions(phase=True, until_feasible=True),
    )
    assert again.iterations == 0 and again.phase_one is None and again.feasible
    np.testing.assert_array_equal(again.block.gain_vector(), found.block.gain_vector())
    fresh = TuningProblem(arm, found.block, scenario, specs=specs)
    assert again.cost == pytest.approx(fresh.values(fresh.start())[0], rel=1e-12)
    with pytest.raises(ValueError, match="until_feasible needs phase=True"):
        tune(TuningSetup(arm, ArmPD(arm), scenario, specs=specs), SolveOptions(until_feasible=True))


@pytest.mark.parametrize(
    "lbg, ubg",
    [
        ([-1.0, -np.inf, 0.5, -2.0], [1.0, 2.0, np.inf, 2.0]),  # both sides, upper only, lower only
        ([-np.inf] * 4, [0.0] * 4),  # aggregated specs: upper bounds only
        ([0.9] * 4, [np.inf] * 4),  # a rise-time spec: lower bounds only
    ],
)
def test_relative_excess_rows_are_the_judges_excess(arm, lbg, ubg):
    """The phase one's symbolic excess rows (one per finite bound): their largest is the judge's largest excess."""
    lbg, ubg = np.array(lbg), np.array(ubg)
    problem = TuningProblem(arm, ArmPD(arm), Scenario(reference=0.5, duration=0.1, tracked="theta"))
    g = ca.MX.sym("g", 4)
    rows = ca.Function("rows", [g], [tuning.relative_excess(g, lbg, ubg)])
    for value in ([3.0, 5.0, 0.0, -1.0], [0.0, 0.0, 0.9, 2.5]):
        got = np.asarray(rows(value)).ravel()
        judged = problem.excess(np.array(value), (lbg, ubg))
        assert got.size == np.isfinite(lbg).sum() + np.isfinite(ubg).sum()
        assert np.max(got) == pytest.approx(np.max(judged), rel=1e-15)


def test_bad_phase_one_input_is_named(arm):
    scenario = Scenario(reference=0.5, duration=0.2, tracked="theta")
    problem = TuningProblem(arm, ArmPD(arm), scenario, specs=Specs(max_rise_time_s=0.1))
    lbx, ubx = gain_bounds(problem, None)
    with pytest.raises(ValueError, match="method must be 'smooth' or 'exact'"):
        phase_one(problem, lbx, ubx, problem.start(), SolveOptions(method="fast"))
    with pytest.raises(TypeError, match="phase"):
        tune(TuningSetup(arm, ArmPD(arm), scenario, specs=Specs(max_rise_time_s=0.1)), SolveOptions(phase="yes"))


# ----------------------------------------------------------------- the continuation's steps, alone
def _continuation(problem, bounds, options=None, start=None):
    lbx, ubx = gain_bounds(problem, bounds)
    begin = problem.start() if start is None else np.asarray(start, dtype=float)
    return Continuation(problem, lbx, ubx, begin, options or SolveOptions())


def test_a_stage_judgement_is_a_fresh_simulations_cost_and_names_the_spec_missed_by_hand(arm):
    """At the start (an arm PD saturating for 20 samples or more): the exact objective is the ITAE of a
    fresh numpy simulation; at a tiny width the smoothed one agrees with it and both loops miss the
    overshoot bound, which the simulation exceeds by a hand-computed margin; at a wide width the
    smoothing changes the cost of the saturated samples, and the gap says by how much."""
    target = np.deg2rad(50)
    block = ArmPD(arm, kp=2.0, kd=0.15)
    exact_cost, run = _itae_by_simulation(arm, block, target, 3.0, substeps=10)
    overshoot = (np.max(run.x[:, 0]) - target) / target
    assert np.sum(np.abs(run.u[:, 0]) >= arm.input_limit[0] - 1e-12) >= 20 and overshoot > 0.02
    scenario = Scenario(reference=target, duration=3.0, tracked="theta")
    problem = TuningProblem(arm, block, scenario, specs=Specs(max_overshoot_pct=100 * (overshoot - 0.01)))
    continuation = _continuation(problem, {"kp": (0, 5.0), "kd": (0, 1.0)})
    level = continuation.build(problem)
    tiny = continuation.judge_stage(level, 1e-9)
    assert tiny.exact == pytest.approx(exact_cost, rel=1e-9)
    assert tiny.gap < 1e-6 and tiny.same
    (missed,) = problem.values(continuation.decision())[2]
    excess = float(missed.split("violated by ")[1].split(" ")[0])
    assert excess == pytest.approx(0.01 * target, rel=1e-3)  # g = peak − r against bound × step, scale 1
    wide = continuation.judge_stage(level, 0.3)
    assert wide.exact == tiny.exact and wide.gap == pytest.approx(abs(wide.exact - wide.smoothed) / wide.exact)
    assert wide.gap > 1e3 * tiny.gap


def test_a_stage_run_alone_reaches_the_closed_form_optimum_of_a_loop_without_switches():
    """One IPOPT solve, cold and to the tolerance, on ẋ = −b x + u regulated by u = −k x (no saturation, so
    every width gives the exact loop): it ends at the sampled LQR gain of the closed form (see
    `test_a_first_order_plant_tunes_without_registering_to_its_sampled_lqr_gain`), and the judgement
    finds the exact and smoothed objectives equal there."""
    plant = models.Plant(_lag)
    b, ts, q, r = 2.0, 0.01, 3.0, 0.5
    phi = np.exp(-b * ts)
    gamma = (1 - phi) / b
    rho = r / q
    lin = rho * (1 - phi**2) + gamma**2
    k_star = (-lin + np.sqrt(lin**2 + 4 * rho * phi**2 * gamma**2)) / (2 * rho * phi * gamma)
    cost = Cost(kind=None, state_weights={"x": q}, input_weights={"u": r})
    problem = TuningProblem(plant, Proportional(1.0, ts), Scenario(reference=None, duration=12.0, x0=[1.0]), cost=cost)
    continuation = _continuation(problem, None, SolveOptions(tol=1e-12))
    level = continuation.build(problem)
    status, iterations = continuation.run_stage(level, 1e-3, tight=True, warm=False)
    assert status == "Solve_Succeeded" and iterations > 0 and set(continuation.multipliers) == {"lam_x0", "lam_g0"}
    assert float(continuation.decision()[0]) == pytest.approx(k_star, rel=1e-6)
    assert len(continuation.log.iterates) == iterations + 1  # IPOPT reports its iterations 0 .. n
    judged = continuation.judge_stage(level, 1e-3)
    assert judged.gap == 0.0 and judged.same
    expected = q * ts * (1 + rho * k_star**2) / (1 - (phi - gamma * k_star) ** 2)
    assert judged.exact == pytest.approx(expected, rel=1e-9)


def test_the_fidelity_levels_are_a_coarse_loop_then_the_problem_only_without_specs(arm):
    """A coarse level first where its objective agrees with the problem's at the start (both computed on
    fresh problems), never on a problem with specs."""
    scenario = Scenario(reference=np.deg2rad(50), duration=3.0, tracked="theta")
    free = TuningProblem(arm, ArmPD(arm), scenario)
    coarse = TuningProblem(arm, ArmPD(arm), scenario, substeps=1)
    start = free.start()
    assert abs(coarse.values(start)[0] / free.values(start)[0] - 1) < tuning.COARSE_AGREEMENT
    bounds = {"kp": (0, 1.0), "kd": (0, 0.2)}
    assert [p.substeps for p in _continuation(free, bounds).levels] == [1, 10]
    assert [p.substeps for p in _continuation(free, bounds, SolveOptions(coarse_substeps=None)).levels] == [10]
    with_specs = TuningProblem(arm, ArmPD(arm), scenario, specs=Specs(max_overshoot_pct=50.0))
    assert [p.substeps for p in _continuation(with_specs, bounds).levels] == [10]


def test_the_answer_is_the_final_point_unless_a_feasible_point_is_clearly_cheaper():
    """`pick_answer` on a judge by hand: objective x₀², infeasible where x₁ > 1."""

    def judge(x):
        return float(x[0] ** 2), (["x1 <= 1"] if x[1] > 1 else [])

    lbx, ubx = np.full(2, -10.0), np.full(2, 10.0)
    start = (judge([3.0, 0.0])[0], np.array([3.0, 0.0]), "start")
    # A feasible final point stands against iterates no cheaper by 1e-6 relative.
    kept = pick_answer(judge, np.array([1.0, 0.0]), [(1.0 - 1e-9, np.array([1.0 - 5e-10, 0.0]))], [start], lbx, ubx)
    assert kept.label == "final" and kept.value == 1.0
    # An infeasible final point loses to the cheapest feasible iterate, judged on the exact objective.
    iterates = [(0.1, np.array([0.5, 2.0])), (0.3, np.array([0.6, 0.0])), (0.2, np.array([0.7, 0.0]))]
    chosen = pick_answer(judge, np.array([0.1, 5.0]), iterates, [start], lbx, ubx)
    assert chosen.label == "iterate" and chosen.value == pytest.approx(0.49) and not chosen.violations
    # Nothing feasible but a finite final point: it is returned with its violations; nothing finite: None.
    alone = pick_answer(judge, np.array([0.1, 5.0]), [], [], lbx, ubx)
    assert alone.label == "final" and alone.violations == ["x1 <= 1"]
    assert pick_answer(lambda x: (np.inf, []), np.zeros(2), [], [], lbx, ubx) is None
    # Candidates are clipped to the bounds before they are judged.
    clipped = pick_answer(judge, np.array([0.0, 5.0]), [(0.0, np.array([-20.0, 0.0]))], [], lbx, ubx)
    assert clipped.value == 100.0 and np.array_equal(clipped.decision, [-10.0, 0.0])


def test_solve_options_are_normalized_and_checked_again_when_replaced():
    options = SolveOptions(widths=[1e-2, 1e-3], max_iter=10.0, tol=1)
    assert options.widths == (1e-2, 1e-3) and options.max_iter == 10 and isinstance(options.max_iter, int)
    assert options.tol == 1.0 and options.smooth
    with pytest.raises(ValueError, match="until_feasible needs phase=True"):
        dataclasses.replace(options, until_feasible=True)
    with pytest.raises(TypeError, match="options must be a designs.tuning.SolveOptions, got dict"):
        tuning.solve(None, [], [], {"max_iter": 3})
    with pytest.raises(TypeError, match="setup must be a designs.tuning.TuningSetup, got tuple"):
        tune((None, None, None))


def _tuner_and_table(arm, specs, kp=0.3, kd=0.1):
    """(the tuning problem's violated specs, its constraint rows by name, the table's verdict, the table's
    metrics) of one ArmPD step: the tuner's exact loop and `models.simulate_closed_loop` judged by
    `models.specs.judge`, as the study tables judge a run."""
    target = np.deg2rad(50)
    problem = TuningProblem(
        arm, ArmPD(arm, kp, kd), Scenario(reference=target, duration=3.0, tracked="theta"), specs=specs
    )
    g = np.asarray(problem.evaluate(problem.start())[1]).ravel()
    rows = {name.split(" <=")[0].split(" after")[0].split(" by")[0]: g[sl] for name, sl in problem.constraint_names}
    run = models.simulate_closed_loop(arm, ArmPD(arm, kp, kd), target, 3.0)
    measured = metrics.run_metrics(run, "theta", specs.state_bounds, band=specs.settling_band)
    return problem.violated(g), rows, model_specs.judge(specs, run, "theta", target, measured=measured), measured


def test_the_tuners_exact_specs_are_the_tables_numbers(arm):
    """Overshoot and steady-state error enter the tuning as the table's own numbers (the same run, to
    1e-12 of the step), and the tuner's settling and rise constraints imply the table's verdict. (The
    tuner tolerates an excess of 1e-6 of the step, so the bounds below the measured values are 0.01 % of
    the step below them.)"""
    step = np.deg2rad(50)
    specs = model_specs.Specs(max_overshoot_pct=50.0, max_ss_error_pct=50.0, max_settling_time_s=2.5)
    _, rows, verdict, measured = _tuner_and_table(arm, specs)
    assert np.max(rows["overshoot"]) / step * 100 == pytest.approx(measured["overshoot_pct"], abs=1e-10)
    assert abs(float(rows["ss error"][0])) == pytest.approx(measured["ss_error"], abs=1e-12 * step)
    assert verdict.ok
    for kp, kd in ((0.3, 0.1), (1.0, 0.05), (0.2, 0.2), (0.6, 0.02)):
        _, _, _, measured = _tuner_and_table(arm, specs, kp, kd)
        for spec in (
            model_specs.Specs(max_overshoot_pct=measured["overshoot_pct"] * (1 + 1e-6) + 1e-9),
            model_specs.Specs(max_overshoot_pct=max(0.0, measured["overshoot_pct"] - 0.01)),
            model_specs.Specs(max_ss_error_pct=100 * measured["ss_error"] / step * (1 + 1e-6) + 1e-9),
            model_specs.Specs(max_ss_error_pct=max(0.0, 100 * measured["ss_error"] / step - 0.01)),
            model_specs.Specs(max_settling_time_s=min(measured["settling_time_s"], 2.9) + 0.02),
            model_specs.Specs(max_settling_time_s=min(measured["settling_time_s"], 2.9) - 0.02),
            model_specs.Specs(max_rise_time_s=min(measured["rise_time_s"], 2.9) + 0.2),
            model_specs.Specs(max_rise_time_s=min(measured["rise_time_s"], 2.9) * 0.5),
        ):
            violated, _, verdict, _ = _tuner_and_table(arm, spec, kp, kd)
            if not violated:  # met according to the tuner: met according to the table
                assert verdict.ok, (kp, kd, spec, verdict)
            if spec.max_overshoot_pct is not None or spec.max_ss_error_pct is not None:  # exact: the same verdict
                assert (not violated) == verdict.ok, (kp, kd, spec, violated, verdict)
