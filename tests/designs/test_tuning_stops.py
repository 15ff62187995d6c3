"""The tuner stops: a stage that makes the exact cost worse is undone, and a phase one proves a spec that
physics puts out of reach."""

import numpy as np
import pytest

import models
from designs.tuning import (
    AGREEMENT,
    PATIENCE,
    STOPPED,
    WATCH_MARGIN,
    Continuation,
    Scenario,
    SolveOptions,
    Specs,
    TuningProblem,
    gain_bounds,
    phase_one,
)
from designs.tuning.continuation import Kept
from tests.designs.test_tuning import ArmPD

UMAX = 1.0


@models.declare(
    name="unit_double_integrator",
    title="s'' = u, |u| <= 1",
    coordinates=("s",),
    inputs=("u",),
    params=(models.Param("m", 1.0, "kg"),),
    input_limit=UMAX,
    register=False,
)
def _double_integrator(q, dq, u, p):
    return models.Physics(kinetic=p.m * dq.s**2 / 2, potential=0 * q.s, forces=[u.u], outputs={"s": q.s})


class SaturatedPD(models.Block):
    """u = sat(kp (r − s) − kd v) at the plant's limit; reads the state (s, v)."""

    def __init__(self, kp=1.0, kd=1.5, limit=UMAX):
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


@pytest.fixture(scope="module")
def arm_problem():
    arm = models.get("arm")
    scenario = Scenario(reference=np.deg2rad(50), duration=2.0, tracked="theta")
    # Both designs below meet this overshoot spec, so the cost alone ranks them.
    problem = TuningProblem(arm, ArmPD(arm), scenario, specs=Specs(max_overshoot_pct=50.0))
    lbx, ubx = gain_bounds(problem, {"kp": (0, 1.0), "kd": (0, 0.2)})
    return problem, lbx, ubx


class WorseningContinuation(Continuation):
    """A continuation whose stages do not solve: the first moves to `worse_point`, every other one stays;
    `starts` records (width, decision) of each solve it was asked for."""

    def __init__(self, *args, worse_point, status="Solve_Succeeded", **kwargs):
        super().__init__(*args, **kwargs)
        self.worse_point, self.starts, self.first_status = np.asarray(worse_point, dtype=float), [], status

    def run_stage(self, level, w, tight, warm):
        self.starts.append((w, self.decision().copy()))
        if len(self.starts) == 1:
            self.z = self.worse_point / self.scale[: self.n]
            return self.first_status, 1
        return "Solve_Succeeded", 1


@pytest.mark.parametrize("status", ["Solve_Succeeded", STOPPED])
def test_a_stage_that_makes_the_exact_cost_worse_is_undone_and_its_start_kept(arm_problem, status):
    """The first stage ends (converged, or stopped by the watch) at gains whose exact cost is higher, both
    meeting the specs: the stage is undone and the continuation's point is the start again; a stage run
    after it starts from there."""
    problem, lbx, ubx = arm_problem
    start = np.array([0.3, 0.1])
    bad = np.array([0.05, 0.19])  # a sluggish loop: a larger ITAE
    options = SolveOptions(widths=(1e-2, 1e-3))
    assert problem.values(bad)[0] > problem.values(start)[0] * 1.5  # the premise: worse on the exact loop
    assert not problem.values(bad)[2] and not problem.values(start)[2]  # both meet the specs
    continuation = WorseningContinuation(problem, lbx, ubx, start, options, worse_point=bad, status=status)
    continuation.run()
    first = continuation.stages[0]
    assert first["stop"].startswith("worse than the best point so far") and first["undone"]
    assert "its start kept" in first["stop"]
    np.testing.assert_allclose(continuation.decision(), start, rtol=1e-12)
    for width, later in continuation.starts:
        if width != options.widths[0]:  # a later stage began at the kept start
            np.testing.assert_allclose(later, start, rtol=1e-12)
    if status == STOPPED:  # the next width ran from the start, and its verdict is the continuation's
        assert len(continuation.stages) == 2 and "undone" not in continuation.stages[1]


def test_a_stage_whose_exact_cost_only_falls_is_kept(arm_problem):
    """The converse: a first stage ending at a better point is not undone."""
    problem, lbx, ubx = arm_problem
    start = np.array([0.05, 0.19])
    good = np.array([0.3, 0.1])
    assert problem.values(good)[0] < problem.values(start)[0]
    continuation = WorseningContinuation(problem, lbx, ubx, start, SolveOptions(widths=(1e-2, 1e-3)), worse_point=good)
    continuation.run()
    assert all("undone" not in stage for stage in continuation.stages)
    np.testing.assert_allclose(continuation.decision(), good, rtol=1e-12)


def test_the_watch_stops_ipopt_after_patience_iterations_above_the_best_cost(arm_problem):
    """IPOPT's iteration callback asks it to stop on the `PATIENCE`-th iterate in a row `WATCH_MARGIN` above
    the best exact cost, once the exact loop confirms that point is worse; not before, and not within the
    margin."""
    problem, lbx, ubx = arm_problem
    start = np.array([0.3, 0.1])
    continuation = Continuation(problem, lbx, ubx, start, SolveOptions(widths=(1e-2,)))
    best = continuation.merit(start)
    continuation.best = Kept(best, start / continuation.scale, None)
    bad = np.array([0.05, 0.19]) / continuation.scale
    above = best[1] * 2
    stops = [continuation.watch(bad, above) for _ in range(PATIENCE)]
    assert stops == [False] * (PATIENCE - 1) + [True]
    continuation.above = 0
    assert not any(continuation.watch(bad, best[1] * (1 + WATCH_MARGIN / 2)) for _ in range(2 * PATIENCE))
    assert STOPPED == "User_Requested_Stop"


def test_phase_one_proves_a_rise_time_below_the_actuators_bound_out_of_reach():
    """s'' = u, |u| <= umax, from rest at s = 0 to r = 1: whatever the controller, s(t) <= umax t² / 2, so s
    covers 90 % of the step no sooner than t* = sqrt(2 · 0.9 r / umax) = 1.342 s. A rise spec of 1 s (the
    tuner's form: at 90 % from t = 1 s on) is out of reach: at t = 1 s, s <= 0.5, so the spec's row there
    misses by at least 0.9 − 0.5 = 0.4 (its relative excess: the bound 0.9 is one-sided, scale 1). The phase
    one must converge and report at least that much; a tuner claiming less would contradict physics."""
    plant = models.Plant(_double_integrator)
    r, rise = 1.0, 1.0
    t_star = np.sqrt(2 * 0.9 * r / UMAX)
    assert rise < t_star - 0.3  # well below the physical bound
    problem = TuningProblem(
        plant,
        SaturatedPD(),
        Scenario(reference=r, duration=4.0, x0=[0.0, 0.0], tracked="s"),
        specs=Specs(max_rise_time_s=rise),
        substeps=2,
    )
    lbx, ubx = gain_bounds(problem, {"kp": (0.01, 100.0), "kd": (0.01, 100.0)})
    found = phase_one(problem, lbx, ubx, problem.start(), SolveOptions())
    bound = 0.9 * r - UMAX * rise**2 / 2
    assert found.converged and found.infeasible, (found.status, found.excess)
    assert found.excess >= bound - 1e-9
    # The answer is a real minimum of the violation, not a stall: it pushes the actuator (close to the
    # bang-bang bound at t = 1 s, within the sampled, saturated loop's reach).
    assert found.excess <= bound + 0.1
    assert found.excess > AGREEMENT


@pytest.mark.parametrize("hessian", ["limited-memory", "exact"])
def test_phase_one_uses_the_hessian_its_options_ask_for(hessian):
    """The phase one's IPOPT evaluates second derivatives only when `SolveOptions.phase_hessian` is "exact":
    with L-BFGS it never calls the Lagrangian's Hessian."""
    problem = TuningProblem(
        models.Plant(_double_integrator),
        SaturatedPD(),
        Scenario(reference=1.0, duration=4.0, x0=[0.0, 0.0], tracked="s"),
        specs=Specs(max_rise_time_s=1.0),
        substeps=2,
    )
    lbx, ubx = gain_bounds(problem, {"kp": (0.01, 100.0), "kd": (0.01, 100.0)})
    reported = []
    options = SolveOptions(phase_hessian=hessian, widths=(1e-2,), progress=lambda *args: reported.append(args))
    found = phase_one(problem, lbx, ubx, problem.start(), options)
    ((_, solvers),) = problem._solvers.values()
    stats = solvers["phase_one"].stats()
    calls = stats.get("n_call_nlp_hess_l", 0)
    assert (calls > 0) == (hessian == "exact"), calls
    # Every iterate is reported to the progress callback, IPOPT's iteration 0 included (one solve here).
    assert stats["iter_count"] == found.iterations and len(reported) == found.iterations + 1


def test_the_phase_one_takes_its_own_iteration_cap_or_else_max_iter():
    """`SolveOptions.phase_max_iter` caps each of the phase one's IPOPT solves (counted by IPOPT), and
    without it the phase one takes `max_iter`."""
    problem = TuningProblem(
        models.Plant(_double_integrator),
        SaturatedPD(),
        Scenario(reference=1.0, duration=4.0, x0=[0.0, 0.0], tracked="s"),
        specs=Specs(max_rise_time_s=0.05),  # out of reach: the phase one runs until a cap or its test
        substeps=2,
    )
    lbx, ubx = gain_bounds(problem, {"kp": (0.01, 100.0), "kd": (0.01, 100.0)})
    capped = phase_one(problem, lbx, ubx, problem.start(), SolveOptions(max_iter=50, phase_max_iter=2, widths=(1e-2,)))
    assert capped.status == "Maximum_Iterations_Exceeded" and not capped.converged
    assert capped.iterations == 2
    assert SolveOptions(max_iter=7).phase_iterations == 7
    assert SolveOptions(max_iter=7, phase_max_iter=3).phase_iterations == 3
    with pytest.raises(ValueError, match="phase_max_iter"):
        SolveOptions(phase_max_iter=0)


def test_a_phase_one_ending_farther_outside_the_exact_specs_than_its_start_returns_the_start_uncertified():
    """When the exact loop says a stage's answer misses the specs by more than the start did (here made so
    by replacing the exact measure), the phase one keeps the start and claims no certificate."""
    problem = TuningProblem(
        models.Plant(_double_integrator),
        SaturatedPD(),
        Scenario(reference=1.0, duration=4.0, x0=[0.0, 0.0], tracked="s"),
        specs=Specs(max_rise_time_s=1.0),
        substeps=2,
    )
    lbx, ubx = gain_bounds(problem, {"kp": (0.01, 100.0), "kd": (0.01, 100.0)})
    start = problem.start()
    exact = problem.largest_excess
    problem.largest_excess = lambda d: 0.5 if np.array_equal(d, start) else 1.0 + exact(d)
    found = phase_one(problem, lbx, ubx, start, SolveOptions(widths=(1e-2,)))
    assert found.uphill and not found.converged and not found.infeasible
    np.testing.assert_array_equal(found.decision, start)
    assert found.excess == 0.5
