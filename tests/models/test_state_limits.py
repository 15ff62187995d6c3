"""check_state_limits: a run that leaves a limit is reported with its excess and time."""

import importlib

import numpy as np
import pytest

import models
from models import specs
from models.state_limits import StateLimit, check_state_limits, summarize_limit_violations

TRAVEL = StateLimit("cart travel", "z", -1.0, 1.0, source="test")
SWING = StateLimit("swing", "theta", -0.2, 0.2, source="test")


def test_violation_in_a_monte_carlo_sample_is_reported():
    rng = np.random.default_rng(0)
    t = 0.01 * np.arange(500)
    samples = []
    for _ in range(20):
        z = 0.5 * np.sin(t + rng.uniform()) * rng.uniform(0.5, 1.0)
        theta = 0.1 * np.cos(t)
        samples.append(np.column_stack([z, theta]))
    # plant one excursion by hand: z reaches 1.3 at t = 2.0 s in sample 7
    samples[7][200, 0] = 1.3
    results = [check_state_limits(t, x, ["z", "theta"], [TRAVEL, SWING]) for x in samples]
    bad = [k for k, r in enumerate(results) if any(v.violated for v in r)]
    assert bad == [7]
    travel = results[7][0]
    assert travel.violated and travel.excess == pytest.approx(0.3) and travel.first_time == pytest.approx(2.0)
    assert not results[7][1].violated and results[7][1].excess == 0.0
    summary = summarize_limit_violations(results)
    assert summary["cart travel"] == {"count": 1, "largest": pytest.approx(0.3)}
    assert summary["swing"] == {"count": 0, "largest": 0.0}


def test_lower_side_and_tolerance():
    t = np.array([0.0, 0.1, 0.2])
    x = np.array([[0.0, 0.0], [0.0, -0.25], [0.0, -0.205]])
    (v,) = check_state_limits(t, x, ["z", "theta"], [SWING])
    assert v.violated and v.excess == pytest.approx(0.05) and v.first_time == pytest.approx(0.1)
    (w,) = check_state_limits(t, x, ["z", "theta"], [SWING], tol=0.06)
    assert not w.violated and w.excess == pytest.approx(0.05)


def test_bad_input_refused():
    with pytest.raises(ValueError, match="lower"):
        StateLimit("x", "z", 1.0, -1.0, source="s")
    with pytest.raises(ValueError, match="no state 'q'"):
        check_state_limits(np.zeros(2), np.zeros((2, 2)), ["z", "theta"], [StateLimit("q", "q", -1, 1, "s")])


@pytest.mark.parametrize("case", ["pendulum", "crane", "ballbeam"])
def test_case_limits_name_their_plants_states(case):
    mod = importlib.import_module(f"studies.cases.{case}")
    names = models.get(mod.CASE.plant).state_names
    assert mod.STATE_LIMITS
    for lim in mod.STATE_LIMITS:
        assert lim.state in names and lim.source


def test_a_deflection_limit_reads_the_difference_of_two_states():
    deflection = StateLimit("panel deflection", "z", -0.2, 0.2, source="test", unit="rad", relative_to="theta")
    t = np.array([0.0, 1.0, 2.0])
    x = np.array([[0.0, 0.0], [0.5, 0.2], [0.1, 0.4]])  # z − θ = 0, 0.3, −0.3
    (v,) = check_state_limits(t, x, ["z", "theta"], [deflection])
    assert v.violated and v.excess == pytest.approx(0.1) and v.first_time == 1.0
    with pytest.raises(ValueError, match="no state 'phi'"):
        check_state_limits(t, x, ["z", "theta"], [StateLimit("d", "z", -1, 1, "s", relative_to="phi")])


def test_a_limit_whose_bound_is_a_parameter_reads_the_plant_simulated():
    beam = StateLimit("beam length", "z", 0.0, 0.5, source="test", unit="m", upper_parameter="ell")
    assert beam.at({"ell": 0.45}).upper == 0.45 and beam.at(None) is beam
    with pytest.raises(ValueError, match="'ell'"):
        beam.at({"m1": 1.0})


def test_the_verdict_names_the_limit_and_its_excess_once():
    """A spec bound that the named limit implies is not reported twice."""
    swing = StateLimit("swing", "theta", -0.2, 0.2, source="test", unit="rad")
    judged = specs.Specs(state_bounds={"theta": 0.25}).with_limits([swing])
    found = specs.check(judged, {}, 1.0, excursions={"theta": 0.0}, departures={"swing": 0.033})
    assert [str(v) for v in found] == ["leaves swing by 0.033 rad"]
    tighter = specs.Specs(state_bounds={"theta": 0.1}).with_limits([swing])
    found = specs.check(tighter, {}, 1.0, excursions={"theta": 0.133}, departures={"swing": 0.033})
    assert len(found) == 2
    assert judged.bounds_and_limits == {"theta": (-0.2, 0.2)}
    with pytest.raises(ValueError, match="'swing'; pass its excess"):
        specs.check(judged, {}, 1.0, excursions={"theta": 0.0})
