"""The tuned LQR and MPC rows: their objective's rules, their stored records and the provider."""

import dataclasses
import math
import pickle

import control
import numpy as np
import pytest

import models
from designs.statespace_blocks import TrackingModel
from designs.weight_search import poll_search
from models.specs import MEETS, VIOLATES, Specs, Verdict, Violation
from studies import cases, judging, providers, runner, tuned_rows

STORED = [
    name for name in cases.names() if tuned_rows.tuner.stored(cases.get(name), tuned_rows.store_name(cases.get(name)))
]


def test_relative_excess_reads_the_worst_violation():
    assert tuned_rows.relative_excess(Verdict(MEETS)) == 0.0
    verdict = Verdict(VIOLATES, (Violation("overshoot", 14.0, 10.0, "%"), Violation("settling", 3.0, 2.0, "s")))
    assert tuned_rows.relative_excess(verdict) == pytest.approx(0.5)
    assert tuned_rows.relative_excess(Verdict(VIOLATES, (Violation("drifts", 0.25, 0.0, "rad/s"),))) == 0.25
    assert tuned_rows.relative_excess(Verdict("diverged")) == tuned_rows.DIVERGED_EXCESS
    assert tuned_rows.relative_excess(Verdict(VIOLATES, (Violation("x", math.inf, 1.0),))) == tuned_rows.DIVERGED_EXCESS


def test_a_least_value_missed_counts_as_an_excess():
    """A margin below its minimum (Violation.minimum) is a positive excess, (bound − value) / bound, not a
    negative one that would let the point pass as feasible."""
    margin = Violation("gain margin", 4.0, 6.0, "dB", minimum=True)
    assert tuned_rows.relative_excess(Verdict(VIOLATES, (margin,))) == pytest.approx(2.0 / 6.0)
    worst = tuned_rows._worst(Verdict(VIOLATES, (margin,)), "step", 1 / 3)
    assert tuned_rows.infeasible_text(worst) == "infeasible for this structure: gain margin at best 4 dB < 6 dB (step)"


def test_infeasible_text_names_the_spec_and_how_close_the_best_came():
    worst = {"scenario": "step", "spec": "overshoot", "value": 14.04, "bound": 10.0, "unit": "%"}
    assert tuned_rows.infeasible_text(worst) == "infeasible for this structure: overshoot at best 14 % > 10 % (step)"
    assert tuned_rows.infeasible_text(None) is None
    limit = {"scenario": "steps", "spec": "leaves swing angle 1 by", "value": 0.0123, "bound": 0.0, "unit": "rad"}
    text = "infeasible for this structure: leaves swing angle 1 by 0.0123 rad at best (steps)"
    assert tuned_rows.infeasible_text(limit) == text


def test_a_point_leaving_only_a_physical_limit_scores_as_violating():
    """The crane's Bryson LQR meets every spec on the step; with its first swing limited to 0.8 of the largest
    |θ₁| of that run (read from the simulated states), the objective scores it BARRIER + the excess
    0.2 max |θ₁| (rad), and the table's judge_run finds that limit and nothing else."""
    crane = cases.get("crane")
    plant = models.get("crane")
    theta = tuned_rows.start(crane, "lqr")
    control = tuned_rows.controller(crane, "lqr", theta)
    step = {s.name: s for s in crane.scenarios}["step"]
    _, base = runner.tracked_equilibrium(plant, crane)
    result = runner.simulate_scenario(plant, control, step, crane, runner.Options(), base, crane.substeps)
    swing = float(np.max(np.abs(result.x[:, list(result.state_names).index("theta1")])))
    assert judging.judge_run(crane, "step", result, plant.params, controller=control, plant=plant).verdict.ok
    first = crane.state_limits[0]
    assert first.state == "theta1" and first.relative_to is None
    limited = dataclasses.replace(
        crane,
        state_limits=(dataclasses.replace(first, lower=-0.8 * swing, upper=0.8 * swing), *crane.state_limits[1:]),
    )
    table = judging.judge_run(limited, "step", result, plant.params, controller=control, plant=plant).verdict
    assert [v.spec for v in table.violations] == [f"leaves {first.name} by"]
    scored = tuned_rows.objective(limited, "lqr", runs=[("step", None)])(theta)
    assert scored.value == pytest.approx(tuned_rows.BARRIER + 0.2 * swing, rel=1e-9)
    assert scored.info["worst"]["spec"] == f"leaves {first.name} by"
    # The case's own limits are the ones the searches judge: tightening them by the margin does not drop them.
    assert tuned_rows.tightened(limited, tuned_rows.MARGIN).state_limits == limited.state_limits


def test_early_rejection_is_a_lower_bound_of_the_complete_value():
    case = cases.get("arm")
    f = tuned_rows.objective(case, "lqr", runs=[("step", None), ("disturbance", None), ("steps", None)])
    theta = tuned_rows.start(case, "lqr") + np.array([0.5, 0.0, 0.5, -0.5])
    full = f(theta)
    assert full.complete and full.runs == 3
    cut = f(theta, bound=-1.0)  # below any value: rejected after the first run
    assert not cut.complete and cut.runs == 1 and -1.0 <= cut.value <= full.value
    # What a worker of `studies.distributed` receives: the pickled objective gives the same value.
    assert pickle.loads(pickle.dumps(f))(theta).value == full.value


def test_the_provider_is_standard_and_needs_stored_weights(monkeypatch):
    assert tuned_rows.tuned_weights in providers.STANDARD
    monkeypatch.setattr(tuned_rows, "stored", lambda case, kind: None)
    with pytest.raises(providers.NotProvided, match="tuned_rows"):
        tuned_rows.tuned_weights("arm")


@pytest.mark.parametrize("name", STORED)
def test_stored_lqr_weights_give_the_lqr_of_the_linearization(name):
    case = cases.get(name)
    record = tuned_rows.stored(case, "lqr")
    if record is None:
        pytest.skip(f"{name}: no tuned LQR stored")
    known = case.known_plant()
    Q = np.diag(np.exp(record["log_weights"][:-1]))
    R = np.exp(record["log_weights"][-1])
    model = TrackingModel.from_plant(known, case.tracked)
    lin, index = known.linearize(), known.state_names.index(case.tracked)
    A_I = np.block([[lin.A, np.zeros((model.nx, 1))], [-np.eye(model.nx)[[index]], np.zeros((1, 1))]])
    B_I = np.vstack([lin.B, [[0.0]]])
    K_ref, _, _ = control.lqr(A_I, B_I, Q, R)
    np.testing.assert_allclose(record["K_augmented"], K_ref, rtol=1e-7, atol=1e-9)
    rows = tuned_rows.tuned_weights(case, known)
    block = next(c for label, c in rows.items() if label.startswith("tuned LQR"))
    np.testing.assert_allclose(np.ravel(block.gains["K"]), K_ref[0, :-1], rtol=1e-7, atol=1e-9)
    assert float(np.ravel(block.gains["ki"])[0]) == pytest.approx(-K_ref[0, -1], rel=1e-7)


@pytest.mark.parametrize("name", STORED)
def test_rows_are_labelled_by_their_record(name):
    case = cases.get(name)
    rows = tuned_rows.tuned_weights(case)
    for kind in tuned_rows.KINDS:
        record = tuned_rows.stored(case, kind)
        if record is None:
            continue
        (label,) = [label for label in rows if label.startswith(tuned_rows.LABELS[kind])]
        assert (label == tuned_rows.LABELS[kind]) == record["feasible"]
        assert record["search"]["converged"]


def test_a_changed_start_is_refused(monkeypatch):
    if "arm" not in STORED:
        pytest.skip("no weights stored for the arm")
    shifted = tuned_rows.start
    monkeypatch.setattr(tuned_rows, "start", lambda case, kind: shifted(case, kind) + 0.1)
    with pytest.raises(ValueError, match="different design"):
        tuned_rows.tuned_weights("arm")


@pytest.mark.slow
@pytest.mark.parametrize("name", STORED)
def test_stored_records_reproduce_their_score_and_verdict(name):
    """The stored weights, judged again by the table's rule on the same runs, give the stored score."""
    case = cases.get(name)
    for kind in tuned_rows.KINDS:
        record = tuned_rows.stored(case, kind)
        if record is None:
            continue
        theta = np.asarray(record["log_weights"])
        runs = [(name, None if row is None else np.asarray(row)) for name, row in record["runs"]]
        now = tuned_rows.tuning_runs(case)
        assert [name for name, _ in runs] == [name for name, _ in now]
        for (_, row), (_, row_now) in zip(runs, now):
            assert (row is None and row_now is None) or np.array_equal(row, row_now)
        tuned = tuned_rows.objective(case, kind, margin=record["objective"]["margin"])(theta)
        assert tuned.value == pytest.approx(record["objective"]["value"], rel=1e-9)
        judged = tuned_rows.objective(case, kind)(theta)
        assert judged.value == pytest.approx(record["objective"]["value_at_the_case_specs"], rel=1e-9)
        assert (judged.value < tuned_rows.BARRIER) == record["feasible"]


@pytest.mark.slow
def test_a_rise_time_below_the_actuators_bound_is_reported_infeasible():
    """The arm (J = m ℓ²/3) from rest with |τ| ≤ τ_max accelerates at most τ_max / J while gravity and damping
    oppose the rise; reaching 10 % of the step s at speed ≤ √(2 a 0.1 s) and covering the next 0.8 s takes
    at least (√1.8 − √0.2) √(s / a). A spec of half that bound is out of reach for any weights."""
    arm = cases.get("arm")
    plant = models.get("arm")
    inertia = plant.params["m"] * plant.params["ell"] ** 2 / 3
    bound = (math.sqrt(1.8) - math.sqrt(0.2)) * math.sqrt(arm.step * inertia / float(plant.input_limit[0]))
    case = dataclasses.replace(arm, specs={"*": Specs(max_rise_time_s=bound / 2)})
    f = tuned_rows.objective(case, "lqr", runs=[("step", None)])
    found = poll_search(f, tuned_rows.start(case, "lqr"), min_step=0.2, max_evaluations=300)
    assert found.converged and found.value > tuned_rows.BARRIER
    worst = found.info["worst"]
    assert worst["spec"].startswith("rise") and worst["value"] >= bound - arm.sample_period > bound / 2
    assert tuned_rows.infeasible_text(worst).startswith("infeasible for this structure: rise")


def test_an_infeasible_record_is_its_rows_remark(monkeypatch):
    if "arm" not in STORED:
        pytest.skip("no weights stored for the arm")
    case = cases.get("arm")
    record = dict(tuned_rows.stored(case, "lqr"), feasible=False)
    record["worst"] = {"scenario": "steps", "spec": "overshoot", "value": 14.0, "bound": 10.0, "unit": "%"}
    monkeypatch.setattr(tuned_rows, "stored", lambda case, kind: record if kind == "lqr" else None)
    ((label, row),) = tuned_rows.tuned_weights(case).items()
    assert label == "tuned LQR"
    assert row.remark == "infeasible for this structure: overshoot at best 14 % > 10 % (steps)"


def test_the_monte_carlo_check_is_the_tables_monte_carlo():
    """The check's samples and runs are the study's own: the runner's Monte Carlo (the LQR's as a batched map,
    the MPC's run by run) gives each sample the same metrics and verdict."""
    if "arm" not in STORED:
        pytest.skip("no weights stored for the arm")
    case = cases.get("arm")
    table = runner.run_study(
        case, runner.Options(scenarios=("mc",), mc=4, seed=0), providers=(tuned_rows.tuned_weights,)
    ).samples
    for kind in tuned_rows.KINDS:
        judged = tuned_rows.monte_carlo_check(case, kind, np.asarray(tuned_rows.stored(case, kind)["log_weights"]), 4)
        rows = table[table.controller == tuned_rows.LABELS[kind]]
        np.testing.assert_allclose([j.metrics["itae"] for j in judged], rows.itae, rtol=1e-6)
        np.testing.assert_allclose([j.metrics["energy"] for j in judged], rows.energy, rtol=1e-6)
        assert [j.verdict.label for j in judged] == list(rows.verdict)


def test_the_console_refuses_bad_arguments_before_work(capsys):
    for argv in (["nowhere"], ["arm", "--max-evaluations", "0"], ["arm", "--workers", "0"], ["arm", "--check", "0"]):
        with pytest.raises(SystemExit):
            tuned_rows.main(argv)
    assert ">= 1" in capsys.readouterr().err
