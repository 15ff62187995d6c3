"""The stored tuned designs keep their claims, judged by the study table's own rule.

Each claim is re-checked by plain simulation of the nonlinear plant through the table's own run and
verdict (`studies.runner.simulate_scenario`, `studies.judging.judge_run`), not by the CasADi expressions
the tuner optimized.
"""

import argparse
import dataclasses

import numpy as np
import pytest

import models
import studies
from designs.tuning import CONVERGED, Specs, polish
from designs.weight_search import CONVERGED as POLL_CONVERGED
from models import specs as model_specs
from studies import tuner

PLANTS = studies.names()
CHECK_SEED, N_CHECK = 3, 2


@pytest.fixture(scope="module")
def records():
    return {name: tuner.stored(studies.get(name)) for name in PLANTS}


@pytest.mark.parametrize("name", PLANTS)
def test_the_tuned_row_meets_every_spec_of_its_case_or_says_it_cannot(name, records):
    """On the nominal plant (the table's rows) and on samples neither tuning nor validation used, every
    scenario the table judges meets the case's specs by the table's verdict, or the record carries the
    phase one's certificate that this structure cannot, and the row's remark says so."""
    record = records[name]
    assert record is not None and "provenance" in record, f"re-tune with python -m studies.tuner {name} --install"
    case = studies.get(name)
    ((label, tuned),) = tuner.controllers(case).items()
    for key, value in record["gains"].items():
        np.testing.assert_allclose(tuned.gains[key], value, rtol=0, atol=0)
    assert label == tuner.LABEL
    if record["infeasible"]:
        assert tuned.remark == record["infeasible"] and tuned.remark.startswith("infeasible for this structure: ")
        return
    assert tuned.remark is None
    rows = np.vstack([models.get(name).param_vector()[None, :], tuner.samples(case, N_CHECK, CHECK_SEED)])
    verdicts = tuner.table_verdicts(case, tuned, rows)
    assert set(verdicts) == set(tuner.SCENARIOS) == {"step", "steps", "disturbance", "noise"}
    for scenario_name, verdict in verdicts.items():  # the samples combined as the Monte Carlo combines them
        assert verdict == f"{model_specs.MEETS}: in all {len(rows)} samples", (scenario_name, verdict)


@pytest.mark.parametrize("name", PLANTS)
def test_stored_record_ended_on_a_test_and_says_why_each_stage_ended(name, records):
    record = records[name]
    assert record is not None and "provenance" in record, f"re-tune with python -m studies.tuner {name} --install"
    tuning = record["tuning"]
    assert tuner.finished(record), tuning["message"]
    if "polish" in tuning:  # IPOPT's stages did not converge; the poll on the exact loop did, from their answer
        assert tuning["status"] == tuning["polish"]["status"] == POLL_CONVERGED
        assert tuning["polish"]["step"] < polish.MIN_STEP
    else:
        assert tuning["status"] in CONVERGED and "Maximum_Iterations" not in tuning["message"]
    for stage in tuning["stages"]:
        assert stage["stop"] and np.isfinite(stage["stationarity"]), stage
    rows, chosen = tuner.tuning_samples(studies.get(name))
    assert (tuning["samples"], tuning["chosen"]) == (len(rows), chosen)
    np.testing.assert_array_equal(record["provenance"]["samples"], rows)
    assert set(record["specs"]) == set(tuner.SCENARIOS)
    validation = record["validation"]
    assert validation["seed"] == tuner.VALIDATION_SEED != tuner.TUNING_SEED
    assert CHECK_SEED not in (tuner.TUNING_SEED, validation["seed"])
    if not record["infeasible"]:
        assert tuning["feasible"] and tuning["converged"]
        assert all(v == model_specs.MEETS for v in validation["nominal_table_verdicts"].values())


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
    """The tuner run again gives the stored cost to `REPRODUCED` and says so."""
    stored = records["arm"]
    options = dataclasses.replace(tuner.TUNE_OPTIONS, widths=stored["tuning"]["widths"])
    fresh = tuner.tune_case(studies.get("arm"), options, paths=stored["tuning"]["paths"])
    same, text = tuner.reproduction(fresh, stored)
    assert same, text
    assert text.startswith("reproduced the stored record's cost")


@pytest.mark.parametrize("text", ["0.1,x", "0.01,0.1", "0.1,0", "-1", "inf,1"])
def test_widths_option_refuses_bad_values(text, capsys):
    with pytest.raises(SystemExit) as stop:
        tuner.main(["arm", "--widths", text])
    assert stop.value.code == 2
    assert "widths must be" in capsys.readouterr().err


def test_phase_hessian_option_refuses_other_values_and_reaches_the_solve_options(monkeypatch, tmp_path):
    with pytest.raises(SystemExit) as stop:
        tuner.main(["arm", "--phase-hessian", "bfgs"])
    assert stop.value.code == 2
    seen = []

    def tune_case(case, options, paths, log, margin):
        seen.append(options.phase_hessian)
        raise KeyboardInterrupt  # stop before any work

    monkeypatch.setattr(tuner, "tune_case", tune_case)
    with pytest.raises(KeyboardInterrupt):
        tuner.main(["arm", "--phase-hessian", "exact", "--out", str(tmp_path)])
    assert seen == ["exact"]


def test_phase_max_iter_option_refuses_non_positive_values_and_reaches_the_solve_options(monkeypatch, tmp_path, capsys):
    with pytest.raises(SystemExit) as stop:
        tuner.main(["arm", "--phase-max-iter", "0"])
    assert stop.value.code == 2 and "--phase-max-iter must be >= 1" in capsys.readouterr().err
    seen = []

    def tune_case(case, options, paths, log, margin):
        seen.append((options.max_iter, options.phase_iterations))
        raise KeyboardInterrupt  # stop before any work

    monkeypatch.setattr(tuner, "tune_case", tune_case)
    for argv in (["--max-iter", "30", "--phase-max-iter", "600"], ["--max-iter", "30"]):
        with pytest.raises(KeyboardInterrupt):
            tuner.main(["arm", *argv, "--out", str(tmp_path)])
    assert seen == [(30, 600), (30, 30)]


def test_margin_option_refuses_values_outside_zero_to_one_and_reaches_the_tuning(monkeypatch, tmp_path, capsys):
    for bad in ("0", "-0.5", "1.01", "nan"):
        with pytest.raises(SystemExit) as stop:
            tuner.main(["arm", "--margin", bad])
        assert stop.value.code == 2 and "--margin must be in (0, 1]" in capsys.readouterr().err
    seen = []

    def tune_case(case, options, paths, log, margin):
        seen.append(margin)
        raise KeyboardInterrupt  # stop before any work

    monkeypatch.setattr(tuner, "tune_case", tune_case)
    for argv in (["--margin", "1"], []):
        with pytest.raises(KeyboardInterrupt):
            tuner.main(["arm", *argv, "--out", str(tmp_path)])
    assert seen == [1.0, tuner.MARGIN]


def test_a_margin_of_one_enforces_the_case_specs_and_others_are_refused():
    specs = Specs(max_overshoot_pct=20.0, max_settling_time_s=4.0, max_rise_time_s=1.0, max_ss_error_pct=2.0)
    assert tuner.with_margin(specs, 1.0) == specs
    for bad in (0.0, 1.5, float("nan")):
        with pytest.raises(ValueError, match="tuning margin must be in"):
            tuner.with_margin(specs, bad)


def test_widths_option_reads_a_decreasing_list():
    assert tuner.widths_option("0.1,0.01,1e-3") == (0.1, 0.01, 1e-3)


def test_tuning_enforces_the_step_specs_with_a_margin_and_the_rest_as_they_are():
    specs = Specs(max_overshoot_pct=20.0, max_settling_time_s=4.0, max_ss_error_pct=2.0, state_bounds={"z": 1.0})
    tight = tuner.with_margin(specs)
    assert tight.max_overshoot_pct == pytest.approx(tuner.MARGIN * 20.0, rel=1e-12)
    assert tight.max_settling_time_s == tuner.MARGIN * 4.0 and tight.max_rise_time_s is None
    assert tight.max_ss_error_pct == pytest.approx(tuner.MARGIN * 2.0, rel=1e-12)
    assert tight.state_bounds == {"z": (-1.0, 1.0)} and tight.settling_band_pct == specs.settling_band_pct


def test_the_infeasibility_text_names_each_missed_spec_with_the_phase_ones_numbers():
    case = studies.get("arm")
    specs = {name: Specs(max_overshoot_pct=10.0, max_settling_time_s=2.0) for name in tuner.SCENARIOS}
    worst = {
        name: {"overshoot_pct": 14.0, "settling_time_s": 1.5, "rise_time_s": 0.3, "ss_error": 0.0} for name in specs
    }
    worst["steps"]["overshoot_pct"] = 14.2
    assert tuner.infeasible_text(case, specs, worst) == (
        "infeasible for this structure: overshoot at best 14.2 % > 10 % (steps)"
    )
    # each spec in the scenario it misses by the largest factor, against that scenario's own bound
    specs["step"] = Specs(max_overshoot_pct=10.0, max_settling_time_s=1.0)
    worst["step"]["settling_time_s"], worst["noise"]["settling_time_s"] = 1.2, 2.5
    worst["disturbance"]["ss_error"] = 0.03 * abs(case.step)  # 3 % of the step, no spec to miss
    assert tuner.infeasible_text(case, specs, worst) == (
        "infeasible for this structure: overshoot at best 14.2 % > 10 % (steps); "
        "settling time at best 2.5 s > 2 s (noise)"
    )
    specs["disturbance"] = Specs(max_ss_error_pct=2.0)
    assert tuner.infeasible_text(case, specs, worst).endswith("; steady-state error at best 3 % > 2 % (disturbance)")


def test_the_infeasibility_text_names_each_limit_left_with_its_largest_excess():
    from types import SimpleNamespace

    def judged(*violations):
        return SimpleNamespace(verdict=model_specs.Verdict(model_specs.VIOLATES, violations, ""))

    panel = "leaves panel deflection by"
    runs = {
        "step": [judged(model_specs.Violation(panel, 0.001, 0.0, "rad", left=True)), judged()],
        "disturbance": [
            judged(
                model_specs.Violation(panel, 0.003, 0.0, "rad", left=True),
                model_specs.Violation("overshoot", 12.0, 10.0),
            ),
            judged(model_specs.Violation("θ leaves [-1, 1] by", 0.5, 0.0, "rad", left=True)),
        ],
        "noise": [judged(model_specs.Violation("drifts", 0.1, 0.0, "rad/s"))],  # no spec of the tuning's
    }
    left = tuner.departures(runs)
    assert left == {panel: (0.003, "rad", "disturbance"), "θ leaves [-1, 1] by": (0.5, "rad", "disturbance")}
    case = studies.get("satellite")
    specs = {name: Specs(max_overshoot_pct=10.0) for name in tuner.SCENARIOS}
    met = {"overshoot_pct": 8.0, "settling_time_s": 1.0, "rise_time_s": 1.0, "ss_error": 0.0}
    worst = {name: met for name in specs}
    assert tuner.infeasible_text(case, specs, worst, left) == (
        "infeasible for this structure: leaves panel deflection by 0.003 rad at best (disturbance); "
        "θ leaves [-1, 1] by 0.5 rad at best (disturbance)"
    )
    assert tuner.infeasible_text(case, specs, worst, {}) is None


def test_reproduction_says_why_a_cost_was_not_reproduced():
    record = {"tuning": {"cost": 2.0}, "start_gains": {"kp": 1.0}}
    record["provenance"] = {"samples": [[1.0]], "enforced": {}, "energy_weight": 0.5, "versions": {"casadi": "3.8"}}
    same, text = tuner.reproduction(record, record | {"tuning": {"cost": 2.0 * (1 + 1e-7)}})
    assert same and "reproduced" in text
    old = {"tuning": {"cost": 1.5}, "start_gains": {"kp": 1.0}}
    assert tuner.reproduction(record, old) == (
        False,
        "did not reproduce the stored record's cost 1.5: got 2 (relative 3.3e-01); the stored record "
        "predates tuning against the case's specs (no provenance)",
    )
    other = old | {"provenance": record["provenance"] | {"energy_weight": 0.4, "versions": {"casadi": "3.6"}}}
    same, text = tuner.reproduction(record, other)
    assert not same and text.endswith("energy_weight differ, casadi 3.6 -> 3.8")
    same, text = tuner.reproduction(record | {"tuning_margin": 0.95}, other | {"tuning_margin": 1.0})
    assert not same and text.endswith("energy_weight differ, tuning margin 1.0 -> 0.95 (--margin), casadi 3.6 -> 3.8")


def test_a_record_is_written_only_when_converged_or_forced_and_never_into_the_source_by_default(tmp_path, monkeypatch):
    """An unconverged tuning writes nothing; --force writes it into --out; the default folder is the user
    cache (here redirected), never studies/cases."""
    validation = {"samples": 0, "nominal_table_verdicts": {}, "tuned_table_verdicts": {}}
    tuning = {"status": "Maximum_Iterations_Exceeded", "converged": False, "message": "cap", "iterations": 1}
    tuning |= {"wall_time_s": 0.0, "initial_cost": 1.0, "cost": 1.0}
    record = {"tuning": tuning, "validation": validation, "infeasible": None, "start_gains": {}}
    monkeypatch.setattr(tuner, "tune_case", lambda case, options, paths, log, margin: record)
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
    """The tuner's table verdicts on the nominal plant are the study's own "tuned" rows' verdicts (whose
    details start with the row's remark, when its record carries one)."""
    case = studies.get("arm")
    ((label, block),) = tuner.controllers(case).items()
    verdicts = tuner.table_verdicts(case, block, models.get("arm").param_vector()[None, :])
    table = studies.run(case, scenarios=list(tuner.SCENARIOS), mc=0, providers=[tuner.controllers])
    rows = table[table.controller == label].set_index("scenario")
    for name in tuner.SCENARIOS:
        row = rows.loc[name]
        detail = row.verdict_detail
        if block.remark:
            assert detail.startswith(block.remark)
            detail = detail[len(block.remark) :].removeprefix("; this run: ")
        assert verdicts[name] == (f"{row.verdict}: {detail}" if detail else row.verdict)


def _arguments(**given):
    names = ("max_iter", "phase_max_iter", "margin", "widths", "paths", "hessian", "phase_hessian")
    return argparse.Namespace(**{name: given.get(name) for name in names})


def test_a_setting_not_given_is_the_stored_records_else_the_default():
    record = {
        "tuning_margin": 1.0,
        "tuning": {"max_iter": 60, "phase_max_iter": 60, "widths": [0.1, 0.01], "paths": "pointwise"},
    }
    chosen, taken = tuner.run_settings(_arguments(), record)
    assert chosen == {
        "max_iter": 60,
        "phase_max_iter": None,  # the record's phase one followed its --max-iter, as this run's does
        "margin": 1.0,
        "widths": (0.1, 0.01),
        "paths": "pointwise",
        "hessian": "limited-memory",
        "phase_hessian": tuner.TUNE_OPTIONS.phase_hessian,
    }
    assert taken == ["--max-iter 60", "--margin 1.0", "--widths 0.1,0.01", "--paths pointwise"]
    given, taken = tuner.run_settings(_arguments(max_iter=5, margin=0.9), record | {"tuning": {"phase_max_iter": 600}})
    assert (given["max_iter"], given["phase_max_iter"], given["margin"]) == (5, 600, 0.9)
    assert taken == ["--phase-max-iter 600"]
    defaults, taken = tuner.run_settings(_arguments(), None)
    assert (defaults["max_iter"], defaults["margin"], defaults["widths"], taken) == (
        tuner.MAX_ITER,
        tuner.MARGIN,
        tuner.WIDTHS,
        [],
    )
    with pytest.raises(ValueError, match="--margin must be in"):
        tuner.run_settings(_arguments(), {"tuning_margin": 2.0})


def test_a_plain_run_passes_the_stored_records_settings_to_the_tuning(monkeypatch, tmp_path, capsys):
    seen = []

    def tune_case(case, options, paths, log, margin):
        seen.append((options.max_iter, options.phase_iterations, margin, paths))
        raise KeyboardInterrupt  # stop before any work

    record = {"tuning_margin": 1.0, "tuning": {"max_iter": 60, "phase_max_iter": 60, "paths": "aggregated"}}
    monkeypatch.setattr(tuner, "stored", lambda case: record)
    monkeypatch.setattr(tuner, "tune_case", tune_case)
    with pytest.raises(KeyboardInterrupt):
        tuner.main(["satellite", "--out", str(tmp_path)])
    assert seen == [(60, 60, 1.0, "aggregated")]
    assert "as the stored record: --max-iter 60 --margin 1.0 --paths aggregated" in capsys.readouterr().out
    record["tuning_margin"] = 1.5  # a damaged record is refused naming it, before any work
    with pytest.raises(SystemExit) as stop:
        tuner.main(["satellite", "--out", str(tmp_path)])
    assert stop.value.code == 2 and len(seen) == 1
    assert "the stored record of satellite (satellite_tuned_gains.json): --margin must be in" in capsys.readouterr().err
