"""The poll search on the exact problem (`designs.tuning.polish`): it meets reachable specs from outside them
and then lowers the cost, its answer is stationary for the poll (checked by evaluating the poll's points
again), the gains keep their signs and bounds, and on specs physics puts out of reach it converges no
closer than the physical bound."""

import numpy as np
import pytest

import models
from designs.tuning import (
    AGREEMENT,
    IterationLog,
    Scenario,
    SolveOptions,
    Specs,
    TuningProblem,
    decision_scale,
    gain_bounds,
    phase_one,
)
from designs.tuning import polish as polishing
from designs.tuning.phase_one import _better_logged
from designs.tuning.polish import polish
from tests.designs.test_tuning_stops import UMAX, SaturatedPD, _double_integrator


def _problem(specs: Specs) -> tuple[TuningProblem, np.ndarray, np.ndarray]:
    problem = TuningProblem(
        models.Plant(_double_integrator),
        SaturatedPD(kp=0.3, kd=0.2),
        Scenario(reference=1.0, duration=6.0, x0=[0.0, 0.0], tracked="s"),
        specs=specs,
        substeps=2,
    )
    lbx, ubx = gain_bounds(problem, {"kp": (0.01, 100.0), "kd": (0.01, 100.0)})
    return problem, lbx, ubx


def _score(problem, decision, reference):
    objective, excess = problem.merit(decision)
    return objective / reference if excess <= AGREEMENT else polishing.BARRIER + excess


@pytest.fixture(scope="module")
def reachable():
    """kp = 0.3, kd = 0.2 overshoots a 5 % spec (ζ = 0.18); well-damped gains meet it."""
    problem, lbx, ubx = _problem(Specs(max_overshoot_pct=5.0))
    start = problem.start()
    return problem, lbx, ubx, start, polish(problem, lbx, ubx, start)


def test_from_outside_the_specs_it_meets_them_and_converges_on_its_mesh(reachable):
    problem, lbx, ubx, start, found = reachable
    assert problem.merit(start)[1] > 0.1  # the start misses the overshoot spec
    assert found.converged and found.feasible and found.excess <= AGREEMENT
    assert found.search.step < polishing.MIN_STEP
    objective, excess = problem.merit(found.decision)
    assert (objective, excess) == (found.objective, found.excess)
    assert np.all(found.decision >= lbx) and np.all(found.decision <= ubx)
    assert np.all(np.sign(found.decision) == np.sign(start))


def test_no_poll_point_around_the_answer_lowers_the_score_by_the_sufficient_decrease(reachable):
    """The poll's stationarity, evaluated here again: every gain × e^{±2h} (2h: the last poll step that found
    nothing) scores no better than the answer less c (2h)²."""
    problem, _, _, start, found = reachable
    reference = problem.merit(start)[0]
    here = _score(problem, found.decision, reference)
    h = 2 * found.search.step
    for i in range(found.decision.size):
        for sign in (1, -1):
            moved = found.decision.copy()
            moved[i] *= np.exp(sign * h)
            assert _score(problem, moved, reference) >= here - polishing.DECREASE * h * h, (i, sign)


def test_out_of_reach_specs_end_at_least_as_far_out_as_physics_says():
    """The rise spec of 1 s that s'' = u, |u| <= 1 cannot meet (tests/designs/test_tuning_stops.py derives
    the bound: at t = 1 s, s <= 0.5, so the spec's row misses by at least 0.4): the poll converges outside
    the specs, no closer than that."""
    problem, lbx, ubx = _problem(Specs(max_rise_time_s=1.0))
    found = polish(problem, lbx, ubx, problem.start())
    bound = 0.9 - UMAX * 1.0**2 / 2
    assert found.converged and not found.feasible
    assert found.excess >= bound - 1e-9


def test_a_capped_phase_one_returns_the_point_it_passed_furthest_inside():
    """Of a failed stage's logged iterates, the one of smallest smoothed excess (s plus its largest row) is
    returned where the exact loop puts it further inside the specs than the last iterate, else the last."""
    problem, lbx, ubx = _problem(Specs(max_overshoot_pct=5.0))
    start = problem.start()
    scale = decision_scale(start)
    inside = np.array([0.5, 1.5])  # ζ ≈ 1: no overshoot
    assert problem.largest_excess(inside) < 0 < problem.largest_excess(start)
    log = IterationLog()
    log.add(np.append(start / scale, -0.3), -0.3, 0.8)  # the smallest s, 0.8 below the rows: excess 0.5
    log.add(np.append(inside / scale, -0.1), -0.1, 0.05)  # -0.05, the smallest
    log.add(np.append(start / scale, 0.4), 0.4, 0.0)  # the last: 0.4
    last = (start, problem.largest_excess(start))
    decision, excess = _better_logged(problem, log, scale, lbx, ubx, last)
    np.testing.assert_allclose(decision, inside, rtol=1e-15)
    assert excess == problem.largest_excess(inside)
    assert _better_logged(problem, log, scale, lbx, ubx, (inside, -np.inf)) == (inside, -np.inf)


def test_a_capped_phase_one_returns_an_exactly_checked_point_no_worse_than_its_last():
    problem, lbx, ubx = _problem(Specs(max_overshoot_pct=5.0))
    found = phase_one(problem, lbx, ubx, problem.start(), SolveOptions(max_iter=3, widths=(1e-2,)))
    assert not found.converged and found.excess == problem.largest_excess(found.decision)
