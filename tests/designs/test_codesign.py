"""Co-design against the closed form of the classic first-order problem, fresh evaluations and simulations."""

import types

import numpy as np
import pytest
import scipy.optimize

import models
from designs.codesign import (
    METHODS,
    ActuatorLimit,
    Codesign,
    SizingProblem,
    codesign,
    size_actuator,
    size_actuator_simultaneous,
)
from designs.tuning import Cost, Scenario, SolveOptions, Specs, TuningProblem, TuningSetup

Q, R, W = 1.0, 1.0, 0.5
B_RANGE, K_BOUNDS = (0.1, 2.0), (0.0, 10.0)


@models.declare(
    name="lag_b",
    title="x' = -b x + u",
    coordinates=(),
    inputs=("u",),
    first_order=("x",),
    params=(models.Param("b", 1.0, "1/s"),),
    input_limit=1e6,
    register=False,
)
def _lag(q, dq, u, p, s):
    return models.Physics(rates={"x": -p.b * s.x + u.u}, outputs={"x": s.x})


class Proportional(models.Block):
    """u = −k x (reads the state, no reference)."""

    def __init__(self, k, sample_period):
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


def continuous_optimum():
    """argmin of Ψ(b, k) = (q + r k²) / (2 (b + k)) + w b, by hand.

    For fixed b, dΨ/dk = 0 gives k = √(b² + q/r) − b and Ψ*(b) = r (√(b² + q/r) − b) + w b;
    dΨ*/db = 0 gives b/√(b² + q/r) = 1 − w/r. With q = r = 1, w = 1/2: b = k = 1/√3, Ψ = √3/2.
    """
    c = 1 - W / R
    b = c * np.sqrt(Q / R) / np.sqrt(1 - c**2)
    k = np.sqrt(b**2 + Q / R) - b
    return b, k, (Q + R * k**2) / (2 * (b + k)) + W * b


def sampled_psi(v, ts):
    """Ψ at v = (b, k) of the sampled loop: x⁺ = φ x + γ u (ZOH), Σ_k Ts (q x_k² + r u_k²) from x0 = 1, + w b."""
    b, k = v
    phi = np.exp(-b * ts)
    lam = phi - (1 - phi) / b * k
    return ts * (Q + R * k**2) / (1 - lam**2) + W * b


def _problem(ts, duration=20.0):
    plant = models.Plant(_lag)
    scenario = Scenario(reference=None, duration=duration, x0=[1.0], name="regulation from x = 1")
    cost = Cost(kind=None, state_weights={"x": Q}, input_weights={"u": R})
    return plant, Proportional(1.0, ts), scenario, cost


def test_first_order_codesign_converges_to_the_closed_form_optimum_as_the_sample_period_shrinks():
    """Ψ = ∫ (q x² + r u²) dt / x0² + w b, the plant declared first order, regulated from x0 = 1.

    At each Ts the simultaneous answer is the optimum of the sampled problem (its closed form minimized by
    scipy), and its distance to the continuous optimum shrinks in proportion to Ts.
    """
    b_star, k_star, psi_star = continuous_optimum()
    assert b_star == pytest.approx(1 / np.sqrt(3)) and k_star == pytest.approx(1 / np.sqrt(3))
    errors = []
    periods = (0.08, 0.04, 0.02, 0.01)
    for ts in periods:
        plant, block, scenario, cost = _problem(ts)
        answer = codesign(
            TuningSetup(plant, block, scenario, cost=cost, bounds={"k": K_BOUNDS}),
            {"b": B_RANGE},
            plant_cost=lambda p: W * p["b"],
            methods=("simultaneous",),
            options=SolveOptions(tol=1e-10),
        )["simultaneous"]
        assert answer.converged and answer.feasible, answer.message
        b, k = answer.params["b"], float(answer.block.gains["k"])
        sampled = scipy.optimize.minimize(
            sampled_psi, [0.5, 0.5], args=(ts,), method="Nelder-Mead", options={"xatol": 1e-10, "fatol": 1e-14}
        )
        sampled_psi_at = sampled_psi(sampled.x, ts)
        np.testing.assert_allclose([b, k], sampled.x, rtol=1e-4)
        assert answer.objective == pytest.approx(sampled_psi_at, rel=1e-7)
        errors.append(max(abs(b - b_star), abs(k - k_star), abs(answer.objective - psi_star)))
    # First order in Ts: halving it about halves the error.
    ratios = np.array(errors[1:]) / np.array(errors[:-1])
    np.testing.assert_allclose(ratios, 0.5, atol=0.05)
    assert errors[-1] < 0.01


def test_every_method_reaches_the_sampled_optimum_and_control_blind_sequential_does_not():
    """Nested and both simultaneous starts agree on the sampled optimum; the control-blind sequential plant
    (its price alone: the cheapest b) with its best k is worse, as the closed form says."""
    ts = 0.1
    plant, block, scenario, cost = _problem(ts)
    answers = codesign(
        TuningSetup(plant, block, scenario, cost=cost, bounds={"k": K_BOUNDS}),
        {"b": B_RANGE},
        plant_cost=lambda p: W * p["b"],
        nested_tol=1e-5,
        options=SolveOptions(tol=1e-10),
    )
    sampled = scipy.optimize.minimize(
        sampled_psi, [0.5, 0.5], args=(ts,), method="Nelder-Mead", options={"xatol": 1e-10, "fatol": 1e-14}
    )
    for method in ("nested", "simultaneous", "simultaneous from sequential"):
        a = answers[method]
        assert a.converged and a.feasible, (method, a.status, a.message)
        assert a.params["b"] == pytest.approx(sampled.x[0], rel=1e-3), method
        assert a.objective == pytest.approx(sampled.fun, rel=1e-6), method
    assert answers["nested"].status.startswith("outer: bounded Brent: Solution found")
    assert answers["nested"].evaluations == len(answers["nested"].history) > 3
    seq = answers["sequential"]
    assert seq.converged and seq.params["b"] == pytest.approx(B_RANGE[0], abs=1e-6)
    best_k = scipy.optimize.minimize_scalar(
        lambda k: sampled_psi((B_RANGE[0], k), ts), bounds=K_BOUNDS, method="bounded", options={"xatol": 1e-10}
    )
    assert float(seq.block.gains["k"]) == pytest.approx(best_k.x, rel=1e-4)
    assert seq.objective == pytest.approx(best_k.fun, rel=1e-7) and seq.objective > 1.01 * sampled.fun
    # Each reported objective is what a fresh problem on the designed plant gives.
    for a in answers.values():
        fresh = TuningProblem(a.plant, a.block, scenario, cost=cost)
        assert a.closed_loop_cost == pytest.approx(fresh.values(fresh.start())[0], rel=1e-12)
        assert a.plant_cost == pytest.approx(W * a.params["b"], rel=1e-12)
        assert "Maximum_Iterations" not in a.status


def test_the_nested_methods_tunings_share_one_compiled_problem(tmp_path, monkeypatch):
    """Each evaluation of the outer search tunes the same problem (the parameter fixed by its bounds, the
    decision's scale a parameter): its solvers built and compiled once, however many evaluations and
    starts, with the answer of the uncompiled run."""
    monkeypatch.setenv("CODESIGN_CONTROL_CACHE", str(tmp_path / "cache"))
    monkeypatch.setattr(models.compile, "STATS", models.compile.Counters())
    plant, block, scenario, cost = _problem(0.1)
    setup = TuningSetup(plant, block, scenario, cost=cost, bounds={"k": K_BOUNDS})
    kwargs = dict(plant_cost=lambda p: W * p["b"], methods=("nested",))
    compiled = codesign(setup, {"b": B_RANGE}, options=SolveOptions(tol=1e-10, jit=True), **kwargs)["nested"]
    assert compiled.evaluations > 3 and compiled.converged
    # Two problems per tuning, each built and compiled once: the coarse level's and the problem's own (no
    # specs here); no later evaluation generates their code again, not even to find it in the cache.
    assert models.compile.STATS.compiled == 2 and models.compile.STATS.cache_hits == 0
    plain = codesign(setup, {"b": B_RANGE}, options=SolveOptions(tol=1e-10), **kwargs)["nested"]
    assert compiled.params["b"] == pytest.approx(plain.params["b"], rel=1e-9)
    assert compiled.objective == pytest.approx(plain.objective, rel=1e-9)


def test_the_nested_method_from_neutral_starts_reaches_the_answer_from_nearest_ones(monkeypatch):
    """With nested_start="neutral" every inner tuning starts from the block's gains (seen by the solver),
    and the outer search ends where the nearest starts lead it."""
    import designs.codesign as dc

    plant, block, scenario, cost = _problem(0.1)
    setup = TuningSetup(plant, block, scenario, cost=cost, bounds={"k": K_BOUNDS})
    kwargs = dict(plant_cost=lambda p: W * p["b"], options=SolveOptions(tol=1e-10), methods=("nested",))
    nearest = codesign(setup, {"b": B_RANGE}, **kwargs)["nested"]
    starts, real = [], dc.solve
    monkeypatch.setattr(
        dc, "solve", lambda *a, start, **k: starts.append(np.array(start)) or real(*a, start=start, **k)
    )
    neutral = codesign(setup, {"b": B_RANGE}, nested_start="neutral", **kwargs)["nested"]
    assert neutral.converged and len(starts) == neutral.evaluations > 3
    assert all(s[0] == pytest.approx(float(block.gains["k"])) for s in starts)
    assert neutral.params["b"] == pytest.approx(nearest.params["b"], rel=1e-6)
    assert neutral.objective == pytest.approx(nearest.objective, rel=1e-9)
    with pytest.raises(ValueError, match="nested_start must be one of"):
        codesign(setup, {"b": B_RANGE}, nested_start="closest", **kwargs)


def test_gain_bounds_hold_in_every_method_when_free_is_left_at_its_default():
    """With free=None (every gain free) the gain bounds hold in every method, the simultaneous one included."""
    plant, block, scenario, cost = _problem(0.1)
    told: list = []
    answers = codesign(
        TuningSetup(plant, block, scenario, cost=cost, bounds={"k": (0.0, 0.3)}, free=None),
        {"b": B_RANGE},
        plant_cost=lambda p: W * p["b"],
        nested_tol=1e-3,
        progress=told.append,
    )
    # Each answer was told as soon as it was found, in the methods' order.
    assert told == list(answers.values()) and [a.method for a in told] == list(METHODS)
    for method, a in answers.items():
        assert float(a.block.gains["k"]) <= 0.3 + 1e-9, method
    # The bound is active: the unbounded optimum has k = 0.57.
    assert float(answers["simultaneous"].block.gains["k"]) == pytest.approx(0.3, abs=1e-6)


class RollPD(models.Block):
    """τ = kp (r − φ) − kd φ', saturated at the plant's limit; reads the state."""

    def __init__(self, limit, kp=60.0, kd=40.0):
        self.limit = limit
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
        return xc, models.saturate(g["kp"] * (r[0] - y[0]) - g["kd"] * y[1], self.limit)


@pytest.mark.slow
def test_uuv_buoyancy_offset_simultaneous_from_sequential_is_never_worse():
    """UUV roll: the centre-of-buoyancy offset L (its ballast costs 200 per metre) with a PD."""
    uuv = models.get("uuv")
    scenario = Scenario(reference=np.deg2rad(30), duration=5.0, tracked="phi")
    results = codesign(
        TuningSetup(
            uuv,
            RollPD(uuv.input_limit[0]),
            scenario,
            cost=Cost("itae"),
            specs=Specs(max_overshoot_pct=5.0),
            bounds={"kp": (0, 500), "kd": (0, 500)},
        ),
        {"L": (0.01, 0.2)},
        plant_cost=lambda p: 200 * p["L"] * 1e-3,
        methods=("sequential", "simultaneous from sequential"),
    )
    seq, sim = results["sequential"], results["simultaneous from sequential"]
    assert seq.feasible and sim.feasible, (seq.message, sim.message)
    assert sim.objective <= seq.objective * (1 + 1e-9)
    for res in (seq, sim):
        problem = TuningProblem(res.plant, res.block, scenario, cost=Cost("itae"), specs=Specs(max_overshoot_pct=5.0))
        value, _, violations = problem.values(problem.start())
        assert value == pytest.approx(res.closed_loop_cost, rel=1e-9) and not violations
        assert res.plant_cost == pytest.approx(0.2 * res.params["L"], rel=1e-12)
        assert 0.01 <= res.params["L"] <= 0.2


def _arm_saturation_pd(plant):
    """I.8 by hand: kp uses the torque left after the largest gravity torque, ζ = 0.9."""
    p = plant.params
    inertia = p["m"] * p["ell"] ** 2 / 3
    spare = plant.input_limit[0] - p["m"] * p["g"] * p["ell"] / 2
    kp = spare / np.deg2rad(50)
    wn = np.sqrt(kp / inertia)
    kd = 2 * 0.9 * wn * inertia - p["b"]
    from tests.designs.test_tuning import ArmPD

    return ArmPD(plant, kp=kp, kd=kd)


def _meets(arm, limit, block, tol=1e-6):
    """The rise-time and overshoot specs on a fresh simulation, to `tol` of the step (an optimal
    design sits on a spec's edge, which IPOPT holds to its constraint tolerance)."""
    plant = arm.with_input_limit(limit)
    res = models.simulate_closed_loop(plant, block, np.deg2rad(50), 3.0)
    assert np.max(np.abs(res.u)) <= limit * (1 + 1e-12)
    theta = res.state("theta") / np.deg2rad(50)
    risen = np.flatnonzero(res.t >= 0.8)
    return bool(np.all(theta[risen] >= 0.9 - tol) and np.max(theta) <= 1.05 + tol)


def test_actuator_sizing_finds_the_edge_of_the_rise_time_spec():
    arm = models.get("arm")
    scenario = Scenario(reference=np.deg2rad(50), duration=3.0, tracked="theta")
    specs = Specs(max_rise_time_s=0.8, max_overshoot_pct=5.0)
    sized = size_actuator(
        SizingProblem(arm, _arm_saturation_pd, scenario, specs, low=0.8, high=3.0), retune=False, rel_tol=0.01
    )
    limit = sized["limit"]
    smaller = arm.with_input_limit(limit / 1.02)
    assert _meets(arm, limit, sized["block"]) and not _meets(arm, limit / 1.02, _arm_saturation_pd(smaller))
    assert sized["evaluations"] <= 10 and sized["statuses"] == []


def test_a_decided_limit_is_the_same_loop_as_a_block_built_for_it():
    """ActuatorLimit(block at 3 N m) on a 3 N m plant = the block built for 0.9 N m on a 0.9 N m plant."""
    arm = models.get("arm")
    top, small = arm.with_input_limit(3.0), arm.with_input_limit(0.9)
    from tests.designs.test_tuning import ArmPD

    wrapped = ActuatorLimit(ArmPD(top, kp=2.0, kd=0.2), 0.9)
    assert wrapped.gains["actuator_limit"] == 0.9 and wrapped.gain_names[-1] == "actuator_limit"
    direct = ArmPD(small, kp=2.0, kd=0.2)
    a = models.simulate_closed_loop(top, wrapped, np.deg2rad(50), 2.0)
    b = models.simulate_closed_loop(small, direct, np.deg2rad(50), 2.0)
    np.testing.assert_array_equal(a.x, b.x)
    assert np.max(np.abs(a.u)) == 0.9
    retuned = wrapped.with_gains(kp=3.0, actuator_limit=0.8)
    assert retuned.block.gains["kp"] == 3.0 and "actuator_limit" not in retuned.block.gains


@pytest.mark.slow
def test_simultaneous_sizing_meets_the_spec_at_no_more_than_the_nested_limit():
    arm = models.get("arm")
    scenario = Scenario(reference=np.deg2rad(50), duration=3.0, tracked="theta")
    specs = Specs(max_rise_time_s=0.8, max_overshoot_pct=5.0)
    bounds = {"kp": (0, 5), "kd": (0, 1)}
    nested = size_actuator(
        SizingProblem(arm, _arm_saturation_pd, scenario, specs, low=0.75, high=3.0, bounds=bounds),
        retune=True,
        rel_tol=0.01,
    )
    assert nested["converged"] and "Maximum_Iterations_Exceeded" not in nested["statuses"]
    assert nested["final"].feasible and nested["final"].block is nested["block"]
    sim = size_actuator_simultaneous(
        SizingProblem(arm, _arm_saturation_pd, scenario, specs, low=0.75, high=3.0, bounds=bounds), start_limit=1.5
    )
    assert sim["converged"] and sim["feasible"], sim["message"]
    assert sim["limit"] <= nested["limit"] * 1.01
    assert _meets(arm, sim["limit"], sim["block"]) and _meets(arm, nested["limit"], nested["block"])


def test_simultaneous_sizing_proves_a_rise_time_beyond_the_largest_limit_out_of_reach():
    """From rest at level the arm's acceleration is at most τ_max / J (gravity only opposes the rise), so 90 %
    of a 50° step takes at least sqrt(2 · 0.9 · 50° · J / τ_max): 0.089 s at 3 N m. A 0.05 s rise time is
    out of reach at every limit; the sizing ends on a proof of that (converged) and reports it infeasible."""
    arm = models.get("arm")
    p = arm.params
    inertia, high, step = p["m"] * p["ell"] ** 2 / 3, 3.0, np.deg2rad(50)
    fastest = np.sqrt(2 * 0.9 * step * inertia / high)
    specs = Specs(max_rise_time_s=0.05)
    assert specs.max_rise_time_s < fastest
    scenario = Scenario(reference=step, duration=1.0, tracked="theta")
    sim = size_actuator_simultaneous(
        SizingProblem(
            arm, _arm_saturation_pd, scenario, specs, low=0.75, high=high, bounds={"kp": (0, 5), "kd": (0, 1)}
        ),
        start_limit=1.5,
    )
    assert sim["converged"] and not sim["feasible"], sim["message"]
    assert any("rise" in v or "90 %" in v for v in sim["violations"]), sim["violations"]


def test_a_numerical_stop_in_the_nested_sizing_is_retried_from_the_best_gains(monkeypatch):
    """Fake inner tunings, feasible from 1.2 N m: the first tuning at every limit in (1.2, 2) ends in
    Restoration_Failed, its repeat starts from the gains of the smallest feasible limit so far."""
    import designs.codesign as dc

    edge, calls = 1.2, []

    def fake_tune(setup, options):
        limit, block = float(setup.plant.input_limit[0]), setup.block
        if not options.until_feasible:  # the cost tuning at the limit found
            return types.SimpleNamespace(feasible=True, block=block)
        first = all(c[0] != limit for c in calls)
        calls.append((limit, float(block.gains["kp"])))
        feasible = limit >= edge
        status = "Restoration_Failed" if first and edge < limit < 2 else "Solve_Succeeded"
        status = status if feasible or not first else "Infeasible_Problem_Detected"
        return types.SimpleNamespace(
            feasible=feasible,
            block=block.with_gains(kp=limit),  # the "tuned" gains record the limit they were tuned at
            violations=[] if feasible else ["rise time"],
            status=status,
            stopped_on_test=status != "Restoration_Failed",
        )

    monkeypatch.setattr(dc, "tune", fake_tune)
    arm = models.get("arm")
    scenario = Scenario(reference=np.deg2rad(50), duration=3.0, tracked="theta")
    sized = size_actuator(
        SizingProblem(arm, _arm_saturation_pd, scenario, Specs(max_rise_time_s=0.8), low=0.8, high=3.0), retune=True
    )
    assert sized["converged"] and "Restoration_Failed" not in sized["statuses"]
    assert edge <= sized["limit"] <= edge * 1.01 and sized["block"].gains["kp"] == sized["limit"]
    repeats = [(limit, kp) for k, (limit, kp) in enumerate(calls) if any(c[0] == limit for c in calls[:k])]
    assert sized["retries"] == len(repeats) > 0
    for limit, kp in repeats:  # each repeat started from the smallest feasible limit tuned before it
        earlier = [c[0] for c in calls[: calls.index((limit, kp))] if c[0] >= edge and c[0] != limit]
        assert kp == min(earlier)


def test_a_feasible_design_decides_a_limit_whatever_the_repeat_claims(monkeypatch):
    """Fake inner tunings, feasible from 1.2 N m: at every limit in (1.2, 2) the first tuning finds a feasible
    design but stops at its iteration cap, the repeat claims local infeasibility. The feasible design is
    kept (the sizing still finds the edge), and decides its limit: the sizing counts as converged, every
    verdict resting on a feasible design or a proof. A limit left with neither makes it unconverged."""
    import designs.codesign as dc

    edge, seen = 1.2, set()

    def fake_tune(setup, options):
        limit, block = float(setup.plant.input_limit[0]), setup.block
        if not options.until_feasible:  # the cost tuning at the limit found
            return types.SimpleNamespace(feasible=True, block=block)
        first, feasible = limit not in seen, limit >= edge
        seen.add(limit)
        if edge < limit < 2:
            status, feasible = (
                ("Maximum_Iterations_Exceeded", True) if first else ("Infeasible_Problem_Detected", False)
            )
        else:
            status = "Solve_Succeeded" if feasible else "Infeasible_Problem_Detected"
        stopped = status == "Solve_Succeeded" or (status == "Infeasible_Problem_Detected" and not feasible)
        return types.SimpleNamespace(
            feasible=feasible, block=block, violations=[] if feasible else ["rise time"], status=status,
            stopped_on_test=stopped,
        )  # fmt: skip

    monkeypatch.setattr(dc, "tune", fake_tune)
    arm = models.get("arm")
    scenario = Scenario(reference=np.deg2rad(50), duration=3.0, tracked="theta")
    sized = size_actuator(
        SizingProblem(arm, _arm_saturation_pd, scenario, Specs(max_rise_time_s=0.8), low=0.8, high=3.0), retune=True
    )
    assert edge <= sized["limit"] <= edge * 1.01
    assert sized["retries"] > 0 and sized["converged"]
    assert "Maximum_Iterations_Exceeded" in sized["statuses"]
    # Below the edge, a numerical stop without a feasible design decides nothing.
    monkeypatch.setattr(
        dc,
        "tune",
        lambda setup, options: types.SimpleNamespace(
            feasible=setup.plant.input_limit[0] >= 2.0,
            block=setup.block,
            violations=[],
            status="Solve_Succeeded" if setup.plant.input_limit[0] >= 2.0 else "Restoration_Failed",
            stopped_on_test=setup.plant.input_limit[0] >= 2.0,
        ),
    )
    sized = size_actuator(
        SizingProblem(arm, _arm_saturation_pd, scenario, Specs(max_rise_time_s=0.8), low=0.8, high=3.0), retune=True
    )
    assert sized["limit"] >= 2.0 and not sized["converged"]


def test_a_claim_of_infeasibility_with_a_feasible_answer_is_not_a_stop_on_the_test():
    from designs.tuning import TuningResult

    stopped = TuningResult.stopped_on_test.fget
    ns = types.SimpleNamespace
    certificate = ns(infeasible=True)
    assert stopped(ns(converged=False, status="Infeasible_Problem_Detected", feasible=False, phase_one=None))
    assert not stopped(ns(converged=False, status="Infeasible_Problem_Detected", feasible=True, phase_one=None))
    assert stopped(ns(converged=True, status="Solve_Succeeded", feasible=True, phase_one=None))
    assert not stopped(ns(converged=False, status="Maximum_Iterations_Exceeded", feasible=True, phase_one=None))
    # A phase one that converged outside the specs is a certificate too, unless a feasible answer contradicts it.
    assert stopped(ns(converged=False, status="Restoration_Failed", feasible=False, phase_one=certificate))
    assert not stopped(ns(converged=False, status="Restoration_Failed", feasible=True, phase_one=certificate))
    assert not stopped(ns(converged=False, status="Restoration_Failed", feasible=False, phase_one=ns(infeasible=False)))


def test_a_nested_evaluation_is_the_best_gain_of_the_closed_form_at_its_parameter():
    """`Codesign.inner` at b = 0.5 alone: the gain it tunes is the sampled loop's best k at that b (its
    closed form minimized by scipy) and the value the outer search sees is Ψ there; a second evaluation
    starts from the first one's gain, the nearest."""
    ts = 0.1
    plant, block, scenario, cost = _problem(ts)
    setup = TuningSetup(plant, block, scenario, cost=cost, bounds={"k": K_BOUNDS})
    ranges = {"b": B_RANGE}
    problem = Codesign(setup, ranges, lambda p: W * p["b"], lambda p: W * p["b"], SolveOptions(tol=1e-10))
    tried: list = []
    result, value = problem.inner(np.array([0.5]), tried, from_nearest=True)
    best = scipy.optimize.minimize_scalar(
        lambda k: sampled_psi((0.5, k), ts), bounds=K_BOUNDS, method="bounded", options={"xatol": 1e-10}
    )
    assert result.converged and float(result.gains["k"]) == pytest.approx(best.x, rel=1e-4)
    assert value == pytest.approx(best.fun, rel=1e-7) and len(tried) == 1 and tried[0][2] == value
    again, _ = problem.inner(np.array([0.6]), tried, from_nearest=True)
    # IPOPT's first iterate is the start: the first evaluation's gain, at the parameter fixed to 0.6.
    np.testing.assert_allclose(again.iterates[0], [result.decision[0], 0.6], rtol=1e-12)
    assert len(tried) == 2
