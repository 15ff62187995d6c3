"""The stored tuned designs keep their claims on samples neither tuning nor validation used.

Each claim is re-checked by plain simulation of the nonlinear plant
(`models.simulate_closed_loop`) with the cost and metrics computed in numpy,
not by the CasADi expressions the tuner optimized.
"""

import dataclasses

import numpy as np
import pytest

import models
import studies
from designs.tuning import AGREEMENT, CONVERGED, WIDTHS, Specs
from models import metrics
from studies import tuner

PLANTS = studies.names()


CHECK_SEED, N_CHECK = 3, 4


def _cost_and_metrics(name, block, params, weight, scenario_name):
    case = studies.get(name)
    plant, sc = models.get(name), tuner.scenario(case, scenario_name)
    k = plant.state_names.index(case.tracked)
    run = models.simulate_closed_loop(
        plant,
        block,
        sc.reference,
        sc.duration,
        x0=sc.x0,
        params=params,
        input_disturbance=sc.input_disturbance,
        substeps=tuner.SUBSTEPS,
    )
    assert run.diverged_at is None
    ts = block.sample_period
    e = sc.reference - run.x[:-1, k]
    cost = ts * (np.sum(run.t[:-1] * np.abs(e)) + weight * np.sum(run.u**2))
    m = metrics.step_metrics(run.t, run.x[:, k], initial=sc.x0[k], target=sc.reference)
    return cost, m, np.max(np.abs(run.u), axis=0)


@pytest.fixture(scope="module")
def records():
    return {name: tuner.stored(studies.get(name)) for name in PLANTS}


@pytest.mark.parametrize("name", PLANTS)
def test_tuned_design_beats_the_hand_design_and_is_never_worse_on_any_scenarios_spec(name, records):
    """On samples neither tuning nor validation used, for each of the tuning scenarios (the step and the
    disturbance): the tuned design meets the hand design's own figures (its worst overshoot and settling
    time on the tuning samples, the stored specs) and is no worse than the hand design on these samples;
    summed over the scenarios its cost is lower on every sample."""
    assert records[name] is not None, f"no tuned gains stored for {name}; run python -m studies.tuner {name}"
    record = records[name]
    case = studies.get(name)
    hand = tuner.hand_design(case)
    tuned = tuner.controllers(case)["tuned"]
    for key, value in record["gains"].items():
        np.testing.assert_allclose(tuned.gains[key], value, rtol=0, atol=0)
    weight = record["cost"]["energy_weight"]
    limit = models.get(name).input_limit
    assert set(record["specs"]) == set(tuner.SCENARIOS) == {"step", "disturbance"}
    hand_total = tuned_total = 0.0
    for scenario_name, specs in record["specs"].items():
        worst = {"hand": {"overshoot": 0.0, "settling": 0.0}, "tuned": {"overshoot": 0.0, "settling": 0.0}}
        for params in tuner.samples(case, N_CHECK, CHECK_SEED):
            for label, block in (("hand", hand), ("tuned", tuned)):
                cost, m, peak = _cost_and_metrics(name, block, params, weight, scenario_name)
                worst[label]["overshoot"] = max(worst[label]["overshoot"], m["overshoot_pct"] / 100)
                worst[label]["settling"] = max(worst[label]["settling"], m["settling_time_s"])
                if label == "tuned":
                    tuned_total += cost
                    assert np.all(peak <= limit * (1 + 1e-12))
                    assert m["overshoot_pct"] <= 100 * specs["max_overshoot"] + 1e-9, scenario_name
                    if specs["settling_time_s"] is not None:
                        assert m["settling_time_s"] <= specs["settling_time_s"] + 1e-9, scenario_name
                else:
                    hand_total += cost
        # Overshoot below the floor counts as none (`tuner.OVERSHOOT_FLOOR`).
        no_worse = max(worst["hand"]["overshoot"], tuner.OVERSHOOT_FLOOR)
        assert worst["tuned"]["overshoot"] <= no_worse + 1e-9, scenario_name
        assert worst["tuned"]["settling"] <= worst["hand"]["settling"] + 1e-9, scenario_name
    assert tuned_total < hand_total


@pytest.mark.parametrize("name", PLANTS)
def test_stored_record_is_consistent_and_converged(name, records):
    assert records[name] is not None, f"no tuned gains stored for {name}; run python -m studies.tuner {name}"
    record = records[name]
    tuning, validation = record["tuning"], record["validation"]
    assert tuning["feasible"] and tuning["cost"] < tuning["initial_cost"]
    # Stopped on IPOPT's convergence test with the continuation settled, never at the iteration cap.
    assert tuning["converged"] and tuning["status"] in CONVERGED, tuning["message"]
    assert all(stage["status"] in CONVERGED for stage in tuning["stages"])
    assert tuning["smoothing_gap"] <= AGREEMENT and "Maximum_Iterations" not in tuning["message"]
    # The stored design is the last stage's answer, or an iterate met on the way that is feasible on
    # the exact loop and clearly cheaper there (`tune` returns it and says so).
    final = tuning["stages"][-1]["exact"]
    if "best feasible point found (the iterate)" in tuning["message"]:
        assert tuning["cost"] < final * (1 - 1e-6)
    else:
        assert final == pytest.approx(tuning["cost"], rel=1e-9)
    # The stages ran the recorded widths in order (the default ones where none are recorded).
    widths = tuning.get("widths", list(WIDTHS))
    assert [stage["width"] for stage in tuning["stages"]] == widths[: len(tuning["stages"])]
    assert validation["tuned_mean"] < validation["hand_mean"] and not validation["tuned_violations"]
    assert validation["seed"] == tuner.VALIDATION_SEED != tuner.TUNING_SEED
    assert CHECK_SEED not in (tuner.TUNING_SEED, validation["seed"])
    rows, chosen = tuner.tuning_samples(studies.get(name))
    assert (tuning["samples"], tuning["chosen"]) == (len(rows), chosen)
    # The stored specs are the hand design's own worst figures on the tuning samples (overshoot floored).
    for scenario_name, specs in record["specs"].items():
        measured = record["hand_measured"][scenario_name]
        assert specs["max_overshoot"] == max(measured["overshoot"], tuner.OVERSHOOT_FLOOR)
        settling = measured["settling_time_s"]
        assert specs["settling_time_s"] == (None if settling == "inf" else settling)


def test_a_changed_hand_design_refuses_the_stored_gains():
    other = models.perturbed(models.get("arm"), 0.10, 1.0)
    with pytest.raises(ValueError, match="start from a different 'PID' design"):
        tuner.controllers(studies.get("arm"), other)


def test_a_case_without_stored_gains_has_no_tuned_row():
    from studies import providers
    from studies.runner import NotProvided

    renamed = dataclasses.replace(studies.get("arm"), plant="arm_copy")
    assert tuner.stored(renamed) is None
    with pytest.raises(ValueError, match="no tuned gains stored for 'arm_copy'"):
        tuner.controllers(renamed)
    studies.register(renamed)
    try:
        with pytest.raises(NotProvided, match="no tuned gains stored for arm_copy"):
            providers.tuned("arm_copy")
    finally:
        studies.unregister("arm_copy")


@pytest.mark.slow
def test_retuning_the_arm_reproduces_its_stored_record(records):
    stored = records["arm"]["tuning"]
    options = dataclasses.replace(
        tuner.TUNE_OPTIONS, widths=stored.get("widths", WIDTHS), hessian=stored.get("hessian", "limited-memory")
    )
    fresh = tuner.tune_case(studies.get("arm"), options, paths=stored.get("paths", "pointwise"))
    assert fresh["tuning"]["cost"] == pytest.approx(records["arm"]["tuning"]["cost"], rel=1e-3)
    assert fresh["validation"]["tuned_better_on"] == fresh["validation"]["samples"]


@pytest.mark.parametrize("text", ["0.1,x", "0.01,0.1", "0.1,0", "-1", "inf,1"])
def test_widths_option_refuses_bad_values(text, capsys):
    with pytest.raises(SystemExit) as stop:
        tuner.main(["arm", "--widths", text])
    assert stop.value.code == 2
    assert "widths must be" in capsys.readouterr().err


def test_widths_option_reads_a_decreasing_list():
    assert tuner._widths("0.1,0.01,1e-3") == (0.1, 0.01, 1e-3)


def test_tuning_enforces_the_specs_with_a_margin_and_no_overshoot_where_only_the_floor_allows_some():
    floor = tuner.OVERSHOOT_FLOOR
    some = tuner.with_margin(Specs(max_overshoot_pct=20.0, max_settling_time_s=4.0))
    assert some.max_overshoot_pct == pytest.approx(tuner.MARGIN * 20.0, rel=1e-12)
    assert some.max_settling_time_s == tuner.MARGIN * 4.0
    assert tuner.with_margin(Specs(max_overshoot_pct=100 * floor)).max_overshoot_pct == 0.0
    twice = tuner.with_margin(Specs(max_overshoot_pct=100 * (2 * floor))).max_overshoot_pct
    assert twice == pytest.approx(tuner.MARGIN * 100 * 2 * floor, rel=1e-12)


def test_a_record_is_written_only_when_converged_or_forced_and_never_into_the_source_by_default(tmp_path, monkeypatch):
    """An unconverged tuning writes nothing; --force writes it into --out; the default folder is the user
    cache (here redirected), never studies/cases."""
    step = {s: {"overshoot": 0.0, "settling_time_s": 1.0} for s in tuner.SCENARIOS}
    validation = {"hand_step": step, "tuned_step": step, "hand_mean": 1.0, "tuned_mean": 1.0}
    validation |= {"improvement_mean": 0.0, "tuned_better_on": 0, "samples": 0, "tuned_violations": []}
    tuning = {"status": "Maximum_Iterations_Exceeded", "converged": False, "message": "cap", "iterations": 1}
    tuning |= {"wall_time_s": 0.0, "initial_cost": 1.0, "cost": 1.0, "improvement": 0.0}
    record = {"tuning": tuning, "validation": validation}
    monkeypatch.setattr(tuner, "tune_case", lambda case, options, paths: record)
    monkeypatch.setenv("CODESIGN_CONTROL_CACHE", str(tmp_path / "cache"))
    before = (tuner.STORE_DIR / tuner.store_name(studies.get("arm"))).stat().st_mtime_ns
    assert tuner.main(["arm", "--out", str(tmp_path / "out")]) == 1
    assert not (tmp_path / "out").exists()
    assert tuner.main(["arm", "--out", str(tmp_path / "out"), "--force"]) == 1
    assert (tmp_path / "out" / tuner.store_name(studies.get("arm"))).exists()
    tuning |= {"status": next(iter(tuner.CONVERGED)), "converged": True}
    assert tuner.main(["arm"]) == 0
    assert list((tmp_path / "cache" / "tuned").iterdir())
    assert (tuner.STORE_DIR / tuner.store_name(studies.get("arm"))).stat().st_mtime_ns == before


def test_the_tuners_validation_judges_a_run_as_the_study_table_does():
    """The tuner's table verdicts on the nominal plant are the study's own "tuned" rows' verdicts."""
    case = studies.get("arm")
    block = tuner.controllers(case)[tuner.LABEL]
    verdicts = tuner.table_verdicts(case, block, models.get("arm").param_vector()[None, :])
    table = studies.run(case, scenarios=list(tuner.SCENARIOS), mc=0, providers=[tuner.controllers])
    rows = table[table.controller == tuner.LABEL].set_index("scenario")
    for name in tuner.SCENARIOS:
        row = rows.loc[name]
        assert verdicts[name] == (f"{row.verdict}: {row.verdict_detail}" if row.verdict_detail else row.verdict)
