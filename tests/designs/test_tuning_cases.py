"""The stored tuned designs keep their claims on samples neither tuning nor validation used.

Each claim is re-checked by plain simulation of the nonlinear plant
(`models.simulate_closed_loop`) with the cost and metrics computed in numpy,
not by the CasADi expressions the tuner optimized.
"""

import numpy as np
import pytest

import models
from designs import tuning_cases
from models import metrics

PLANTS = tuning_cases.PLANTS
CHECK_SEED, N_CHECK = 3, 4


def _cost_and_metrics(name, block, params, weight):
    plant, sc = models.get(name), tuning_cases.scenario(name)
    k = plant.state_names.index(models.case(name).tracked)
    run = models.simulate_closed_loop(plant, block, sc.reference, sc.duration, x0=sc.x0, params=params,
                                      input_disturbance=sc.input_disturbance, substeps=tuning_cases.SUBSTEPS)
    assert run.diverged_at is None
    ts = block.sample_period
    e = sc.reference - run.x[:-1, k]
    cost = ts * (np.sum(run.t[:-1] * np.abs(e)) + weight * np.sum(run.u ** 2))
    m = metrics.step_metrics(run.t, run.x[:, k], initial=sc.x0[k], target=sc.reference)
    return cost, m, np.max(np.abs(run.u), axis=0)


@pytest.fixture(scope="module")
def records():
    return tuning_cases.stored()


@pytest.mark.parametrize("name", PLANTS)
def test_tuned_design_beats_the_hand_design_and_meets_its_specs_on_unseen_samples(name, records):
    assert name in records, f"no tuned gains stored for {name}; run python -m designs.tuning_cases {name}"
    record = records[name]
    hand = tuning_cases.hand_design(name)
    tuned = tuning_cases.controllers(name)["tuned"]
    for key, value in record["gains"].items():
        np.testing.assert_allclose(tuned.gains[key], value, rtol=0, atol=0)
    specs, weight = record["specs"], record["cost"]["energy_weight"]
    limit = models.get(name).input_limit
    for params in tuning_cases.samples(name, N_CHECK, CHECK_SEED):
        hand_cost, _, _ = _cost_and_metrics(name, hand, params, weight)
        cost, m, peak = _cost_and_metrics(name, tuned, params, weight)
        assert cost < hand_cost
        assert np.all(peak <= limit * (1 + 1e-12))
        assert m["overshoot_pct"] <= 100 * specs["max_overshoot"] + 1e-9
        if specs["settling_time_s"] is not None:
            assert m["settling_time_s"] <= specs["settling_time_s"] + 1e-9


@pytest.mark.parametrize("name", PLANTS)
def test_stored_record_is_consistent(name, records):
    assert name in records, f"no tuned gains stored for {name}; run python -m designs.tuning_cases {name}"
    record = records[name]
    tuning, validation = record["tuning"], record["validation"]
    assert tuning["feasible"] and tuning["cost"] < tuning["initial_cost"]
    assert validation["tuned_mean"] < validation["hand_mean"] and not validation["tuned_violations"]
    assert validation["seed"] == tuning_cases.VALIDATION_SEED != tuning_cases.TUNING_SEED
    assert CHECK_SEED not in (tuning_cases.TUNING_SEED, validation["seed"])
    rows, chosen = tuning_cases.tuning_samples(name)
    assert (tuning["samples"], tuning["chosen"]) == (len(rows), chosen)


def test_a_changed_hand_design_refuses_the_stored_gains():
    other = models.perturbed(models.get("arm"), 0.10, 1.0)
    with pytest.raises(ValueError, match="start from a different 'PID' design"):
        tuning_cases.controllers("arm", other)
    with pytest.raises(ValueError, match="no tuned gains stored for 'crane1'"):
        tuning_cases.controllers("crane1")


@pytest.mark.slow
def test_retuning_the_arm_reproduces_its_stored_record(records):
    fresh = tuning_cases.tune_case("arm")
    assert fresh["tuning"]["cost"] == pytest.approx(records["arm"]["tuning"]["cost"], rel=1e-3)
    assert fresh["validation"]["tuned_better_on"] == fresh["validation"]["samples"]
