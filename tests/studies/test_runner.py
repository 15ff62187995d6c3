"""The runner: providers plugged in or skipped, rows from the nonlinear plant, seeded Monte Carlo,
divergence reported as such, noise levels of full-state controllers."""

import dataclasses
import math

import example_providers
import numpy as np
import pandas as pd
import pytest

import models
import studies
from designs.discrete import dirty_derivative
from models import metrics, specs
from studies import batch, provider_calls, runner

EXAMPLE = "example_providers:controllers"
STEP_ONLY = runner.Options(scenarios=("step",), mc=0)


def arm_study(**changes):
    """The arm case with `changes` (e.g. its providers)."""
    return dataclasses.replace(studies.get("arm"), **changes)


def test_missing_providers_are_skipped_with_a_note_and_the_others_run():
    """Providers named by 'module:function' strings (as the command line names them) are found before
    the run; one that does not exist is noted where it stands, and a failing one does not stop the others."""
    study = arm_study(
        providers=(
            "no_such_package_for_studies.designs:controllers",
            "json:controllers",
            "example_providers:failing",
            EXAMPLE,
        )
    )
    result = runner.run_study(study, STEP_ONLY)
    notes = "\n".join(result.notes)
    assert (
        "no_such_package_for_studies.designs:controllers: skipped, no module named 'no_such_package_for_studies'"
    ) in notes
    assert "json:controllers: skipped, module json has no function controllers()" in notes
    assert "example_providers:failing: failed (RuntimeError: no design for arm" in notes
    # The declared order first (PD, LQR, linear MPC), then the provider's other labels.
    assert list(result.table.controller) == ["PD", "LQR", "linear MPC", "LQR fast", "LQR slow"]
    # The example "linear MPC" reports max_iter_reached on every 50th of its 500 steps.
    status = result.table.set_index("controller").status
    assert status["linear MPC"] == "degraded: solver failed on 10 of 500 steps"
    assert set(status.drop("linear MPC")) == {"ok"}
    # Strict: the first provider that is missing stops the study, and one that fails.
    with pytest.raises(provider_calls.ProviderNotFound, match="no module named 'no_such_package_for_studies'"):
        runner.run_study(study, runner.Options(scenarios=("step",), mc=0, strict=True))
    with pytest.raises(RuntimeError, match="no design for arm"):
        runner.run_study(
            dataclasses.replace(study, providers=study.providers[2:]),
            runner.Options(scenarios=("step",), mc=0, strict=True),
        )


def test_a_table_row_is_the_nonlinear_plant_under_the_recorded_input():
    """Each recorded sample, integrated through CVODES (a different integrator) from the recorded state
    under the recorded, clipped command, lands on the next recorded state; a linear model does not."""
    study = arm_study(providers=(example_providers.controllers,))
    result = runner.run_study(study, STEP_ONLY)
    run = result.runs[("LQR", "step")]
    plant = result.plant
    applied = np.clip(run.u, -plant.input_limit, plant.input_limit)
    for k in range(0, len(applied), 7):
        one = models.simulate(plant, run.x[k], applied[k : k + 1], run.t[1] - run.t[0], method="adaptive")
        # RK4 with 2 sub-steps of 5 ms against CVODES at 1e-12: a local error of a few 1e-9.
        np.testing.assert_allclose(one.x[-1], run.x[k + 1], rtol=1e-7, atol=1e-9)
    lin = plant.linearize().discretize(run.t[1])
    x = run.x[0] - lin.xe
    linear = [x]
    for u in applied:
        x = lin.A @ x + lin.B @ (u - lin.ue)
        linear.append(x)
    assert np.max(np.abs(np.array(linear) + lin.xe - run.x)) > 0.05  # gravity at 50 deg is not linear
    row = result.table[(result.table.controller == "LQR") & (result.table.scenario == "step")].iloc[0]
    expected = metrics.run_metrics(run, "theta")
    assert row.iae == expected["iae"] and row.peak_u == expected["peak_u"]


def test_monte_carlo_is_reproducible_from_its_seed():
    study = arm_study(providers=(example_providers.controllers,))
    options = runner.Options(scenarios=("mc",), mc=6, seed=3)
    first = runner.run_study(study, options)
    again = runner.run_study(study, options)
    other = runner.run_study(study, runner.Options(scenarios=("mc",), mc=6, seed=4))
    columns = [c for c in first.samples.columns if c not in ("step_ms", "step_ms_max")]
    assert first.samples[columns].equals(again.samples[columns])
    timing = [c for c in ("wall_s", "step_ms", "step_ms_max") if c in first.table]
    assert first.table.drop(columns=timing).equals(again.table.drop(columns=timing))
    assert not np.allclose(first.samples.iae, other.samples.iae)
    # The samples are the seeded ±5 % draws of models.sample_params, the same for every controller,
    # the one simulated step by step included.
    names = list(first.plant.params)
    drawn = models.sample_params(first.plant, 6, seed=3)
    for label in ("LQR", "linear MPC"):
        mine = first.samples[first.samples.controller == label]
        np.testing.assert_array_equal(mine[names].to_numpy(), drawn)
    row = first.table[first.table.controller == "LQR"].iloc[0]
    assert row.samples == 6 and row.iae == first.samples[first.samples.controller == "LQR"].iae.max()


def test_python_controllers_run_every_scenario_on_as_many_samples_and_report_solver_status():
    study = arm_study(providers=(example_providers.controllers,))
    options = runner.Options(scenarios=("step", "noise", "mc"), mc=4)
    result = runner.run_study(study, options)
    table = result.table.set_index(["controller", "scenario"])
    assert table.loc[("linear MPC", "mc"), "samples"] == table.loc[("LQR", "mc"), "samples"] == 4
    # The example controller reports "max_iter_reached" on every 50th step: 10 of 500, 40 of 2000.
    assert table.loc[("linear MPC", "step"), "status"] == "degraded: solver failed on 10 of 500 steps"
    assert table.loc[("linear MPC", "mc"), "status"] == "degraded: solver failed on 40 of 2000 steps of 4 samples"
    assert (result.table[result.table.controller != "linear MPC"].status == "ok").all()
    assert table.loc[("linear MPC", "step"), "solver_issues"] == 10
    assert math.isnan(table.loc[("LQR", "step"), "solver_issues"])


def test_a_diverged_run_is_reported_as_diverged_with_its_time():
    result = runner.run_study(arm_study(providers=(example_providers.diverging,)), STEP_ONLY)
    row = result.table.iloc[0]
    # The example controller commands NaN from its 100th step (t = 1 s): the run diverges at that command,
    # before the plant integrates it.
    assert row.status == "diverged at t = 1 s"
    assert row.diverged_at_s == pytest.approx(1.0)
    assert all(math.isnan(row[k]) for k in metrics.METRIC_COLUMNS if k != "u_limit")
    assert result.best() is None


class _Reader:
    def __init__(self, measures):
        self.measures, self.sample_period = measures, 0.01


def test_noise_on_a_full_state_measurement_follows_the_outputs_and_a_dirty_derivative():
    sat = models.get("satellite")
    noise = {"theta": 1e-3, "phi_minus_theta": 2e-3}
    np.testing.assert_array_equal(
        runner.measurement_noise_std(sat, _Reader("outputs"), noise, sigma=0.05), [1e-3, 2e-3]
    )
    std = runner.measurement_noise_std(sat, _Reader("state"), noise, sigma=0.05)
    # phi = theta + (phi − theta): independent noises add in variance.
    assert std[:2] == pytest.approx([1e-3, math.hypot(1e-3, 2e-3)])
    # Velocities: the spread a dirty derivative (σ = 0.05 s) makes of white position noise, measured.
    rng = np.random.default_rng(1)
    samples = rng.standard_normal(200_000) * 1e-3
    rate, rates = 0.0, []
    for prev, now in zip(samples[:-1], samples[1:]):
        rate = dirty_derivative(rate, prev, now, 0.05, 0.01)
        rates.append(rate)
    assert std[2] == pytest.approx(np.std(rates[1000:]), rel=0.02)
    with pytest.raises(ValueError, match="has no output"):
        runner.measurement_noise_std(sat, _Reader("outputs"), {"phi": 1e-3}, sigma=0.05)


@pytest.mark.parametrize(
    "kwargs,message",
    [
        ({"mc": -1}, "mc .* must be an integer >= 0"),
        ({"scenarios": ("step", "ramp")}, "unknown scenario 'ramp' in scenarios"),
        ({"jit": "sometimes"}, "jit must be"),
    ],
)
def test_bad_options_say_what_is_wrong(kwargs, message):
    with pytest.raises(ValueError, match=message):
        runner.Options(**kwargs)


def test_run_returns_the_table_as_a_dataframe_with_the_documented_columns():
    table = studies.run("uuv", scenarios=["step", "disturbance"], mc=0, providers=[EXAMPLE])
    required = [
        "controller",
        "scenario",
        "rise_time_s",
        "settling_time_s",
        "overshoot_pct",
        "ss_error",
        "iae",
        "itae",
        "peak_u",
        "u_limit",
        "saturated_frac",
        "energy",
        "violation",
        "step_ms",
    ]
    assert set(required) <= set(table.columns)
    assert set(table.scenario) == {"step", "disturbance"} and (table.u_limit == 50.0).all()
    # The example provider gives a few of the study's labels; the notes name the others.
    assert any(note.startswith("not provided yet: PID,") for note in table.attrs["notes"])
    with pytest.raises(ValueError, match="unknown plant 'crane1'"):
        studies.run("crane1")


@pytest.mark.parametrize("plant", studies.names())
def test_two_rk4_substeps_give_the_tables_of_ten(plant):
    """The studies integrate with 2 RK4 sub-steps per sample; 10 (the simulator's default) change
    no metric of the step by more than 1e-5 relative."""
    base = dataclasses.replace(studies.get(plant), providers=(example_providers.lqr_only,))
    rows = [runner.run_study(dataclasses.replace(base, substeps=n), STEP_ONLY).table.iloc[0] for n in (2, 10)]
    for key in ("rise_time_s", "settling_time_s", "overshoot_pct", "iae", "itae", "peak_u", "energy"):
        assert rows[0][key] == pytest.approx(rows[1][key], rel=1e-5, abs=1e-9), key


def test_a_design_with_its_own_actuator_runs_on_it():
    """IV.11 assumes 250 N m thrusters: that row's plant has them, the others keep 50 N m."""
    study = dataclasses.replace(studies.get("uuv"), providers=(example_providers.with_own_actuator,))
    result = runner.run_study(study, STEP_ONLY)
    table = result.table.set_index("controller")
    assert table.loc["LQR", "u_limit"] == 50.0 and table.loc["lead-lag (IV.11)", "u_limit"] == 250.0
    fast, slow = (result.runs[(label, "step")] for label in ("lead-lag (IV.11)", "LQR"))
    assert np.max(np.abs(fast.u)) > 50.0  # the same law asks for more than 50 N m ...
    assert table.loc["lead-lag (IV.11)", "rise_time_s"] < table.loc["LQR", "rise_time_s"]  # ... and gets it


# ---------------------------------------------------------------------------- the steps of run_study
def test_the_scenarios_asked_for_keep_the_studys_order_and_without_samples_no_monte_carlo():
    study = studies.get("arm")
    notes: list = []
    chosen = runner.chosen_scenarios(study, runner.Options(scenarios=("mc", "step"), mc=0), notes)
    assert [s.name for s in chosen] == ["step"] and notes == ["Monte Carlo skipped (0 samples requested)"]
    notes = []
    chosen = runner.chosen_scenarios(study, runner.Options(scenarios=("mc", "step"), mc=3), notes)
    assert [s.name for s in chosen] == ["step", "mc"] and notes == []
    assert [s.name for s in runner.chosen_scenarios(study, runner.Options(), [])] == list(studies.SCENARIO_NAMES)


def test_a_callers_controller_replaces_a_providers_of_the_same_label_with_a_note():
    designed = {"PD": "provided PD", "LQR": "provided LQR"}
    notes = runner.add_controllers(designed, {"LQR": "mine", "extra": "also mine"})
    assert designed == {"PD": "provided PD", "LQR": "mine", "extra": "also mine"}
    assert notes == ["controller 'LQR' given twice; the provider's is replaced"]


def test_a_failed_row_has_no_metrics_and_the_failed_verdict():
    row = runner.failed_row(ValueError("first line\nsecond line " + "x" * 300))
    assert row["status"] == "failed: ValueError: first line"
    assert all(math.isnan(row[k]) for k in metrics.METRIC_COLUMNS)
    assert row["verdict"] == specs.FAILED and row["verdict_detail"] == row["status"]
    assert len(runner.failed_row(ValueError("y" * 300))["status"]) == 200


def test_a_row_of_the_simulation_is_the_plant_simulated_directly():
    """`Simulation.row` of the LQR's step: the metrics of the same closed loop run by
    `models.simulate_closed_loop` (a second path), and the row's run kept for the plots."""
    study = arm_study(providers=(example_providers.lqr_only,))
    plant = models.get("arm")
    lqr = example_providers.lqr_only(study, study.known_plant(plant))["LQR"]
    simulation = runner.Simulation(study, STEP_ONLY, plant, None)
    step = study.scenarios[0]
    row = simulation.row("LQR", lqr, plant, step)
    _, base = runner.tracked_equilibrium(plant, study)
    run = models.simulate_closed_loop(
        plant, lqr, step.reference(study, base), step.duration(study), substeps=study.substeps
    )
    expected = metrics.run_metrics(run, study.tracked)
    assert (row["controller"], row["scenario"], row["kind"], row["status"]) == ("LQR", "step", "block", "ok")
    for key in ("iae", "itae", "peak_u", "settling_time_s"):
        assert row[key] == expected[key], key
    assert simulation.runs[("LQR", "step")].x.shape == run.x.shape and simulation.notes == []


def test_best_is_never_a_violating_or_degraded_row():
    """The lowest ITAE belongs to a violating row, the next to a degraded one, the next to a controller that
    meets the step but violates its specs under noise: the best is the controller behind them that meets
    everywhere, and None (not a violating row) once no row meets."""
    table = pd.DataFrame(
        {
            "controller": ["fast", "degraded", "slow", "fast", "elsewhere", "elsewhere"],
            "scenario": ["step", "step", "step", "noise", "step", "noise"],
            "status": ["ok", "degraded: solver failed on 1 of 10 steps", "ok", "ok", "ok", "ok"],
            "verdict": [specs.VIOLATES, specs.MEETS, specs.MEETS, specs.MEETS, specs.MEETS, specs.VIOLATES],
            "itae": [0.1, 0.2, 0.5, 0.1, 0.3, 0.3],
        }
    )
    fields = {f.name: None for f in dataclasses.fields(runner.StudyResult) if f.name != "table"}
    result = runner.StudyResult(table=table, **fields)
    assert result.best("step") == "slow"
    assert result.best("step", meeting=False) == "fast"
    result.table = table.assign(verdict=specs.VIOLATES)
    assert result.best("step") is None
    expected = {"fast": 0.2, "degraded": 0.4, "slow": 1.0, "elsewhere": 0.6}
    assert studies.overview.relative_itae(table) == pytest.approx(expected)


def test_a_controllers_remark_leads_the_verdict_detail_of_each_of_its_rows_and_the_console():
    """A tuned design's certificate travels on the controller (`remark`), not in its label: every row of it,
    the Monte Carlo's included, says it first in the verdict detail and in the remark column, its own
    verdict is still the run's, and the console lists it once under the plant."""
    study = arm_study(providers=(example_providers.lqr_only,))
    plant = models.get("arm")
    lqr = example_providers.lqr_only(study, study.known_plant(plant))["LQR"]
    lqr.remark = "infeasible for this structure: overshoot at best 19 % > 10 %"
    options = runner.Options(scenarios=("step", "mc"), mc=3)
    result = runner.run_study(study, options, providers=[], controllers={"remarked LQR": lqr})
    plain = runner.run_study(study, options)
    rows = result.table.set_index("scenario")
    assert list(rows.remark) == [lqr.remark] * 2
    for scenario in ("step", "mc"):
        expected = plain.table.set_index("scenario").loc[scenario]
        detail = rows.loc[scenario, "verdict_detail"]
        assert rows.loc[scenario, "verdict"] == expected.verdict
        assert detail == (
            f"{lqr.remark}; this run: {expected.verdict_detail}" if expected.verdict_detail else lqr.remark
        )
    assert plain.table.remark.isna().all()
    lines = batch.not_ok_lines(result.table)
    assert lines.count(f"  remarked LQR: {lqr.remark}") == 1


def test_a_controller_failing_alike_on_every_scenario_is_one_note_naming_them():
    """A controller whose every row fails with the same status (a refused construction's stand-in) is
    noted once, with the scenarios in order; a different failure of it is its own note."""

    class Failing:
        sample_period, measures, n_reference = 0.01, "state", 1
        message = "no controller"

        def initial_state(self, y0, r0=None):
            raise RuntimeError(self.message)

        def step(self, xc, y, r=None):
            raise RuntimeError(self.message)

    study = arm_study(providers=())
    failing = Failing()
    simulation = runner.Simulation(study, runner.Options(scenarios=("step", "steps")), models.get("arm"), None)
    plant = models.get("arm")
    for scenario in study.scenarios[:2]:
        assert simulation.row("broken", failing, plant, scenario)["status"] == "failed: RuntimeError: no controller"
    failing.message = "another failure"
    simulation.row("broken", failing, plant, study.scenarios[2])
    names = [s.name for s in study.scenarios[:3]]
    assert simulation.notes == [
        f"broken / {names[0]}, {names[1]}: failed: RuntimeError: no controller",
        f"broken / {names[2]}: failed: RuntimeError: another failure",
    ]


def test_a_long_remark_takes_at_most_its_lines_in_the_console_and_all_of_it_in_the_table():
    """A refusal naming many constraints is cut in the console (`batch.REMARK_LINES`, ending on where
    the whole text is), never in the table's remark column."""
    remark = "refused at construction: " + "; ".join(f"state constraint 'x{i}' lacks at least {i}" for i in range(40))
    table = pd.DataFrame(
        [{"controller": "tube MPC", "scenario": "step", "verdict": specs.FAILED, "status": "failed", "remark": remark}]
    )
    lines = batch.not_ok_lines(table)
    cut = [line for line in lines if line.lstrip().startswith("tube MPC:") or line.startswith("      ")]
    assert len(cut) == batch.REMARK_LINES and cut[-1].endswith("(whole: table.md)")
    assert all(len(line) <= 118 for line in lines)
    assert table.remark[0] == remark


def test_controllers_asked_to_be_left_out_have_no_rows_and_the_others_are_unchanged():
    """`Options.without` removes the labels it names after the providers answered, each with a note (and
    a note for a label nobody provided); the rows kept are the same numbers as in a run without it."""
    study = arm_study(providers=(EXAMPLE,))
    plain = runner.run_study(study, STEP_ONLY)
    options = runner.Options(scenarios=("step",), mc=0, without=["LQR fast", "no such", "LQR fast"])
    assert options.without == ("LQR fast", "no such")
    result = runner.run_study(study, options)
    assert list(result.table.controller) == ["PD", "LQR", "linear MPC", "LQR slow"]
    assert result.left_out == ("LQR fast",)
    assert "LQR fast: left out, as asked (without)" in result.notes
    assert "without 'no such': no controller of that label here" in result.notes
    kept = plain.table[plain.table.controller != "LQR fast"].reset_index(drop=True)
    pd.testing.assert_frame_equal(
        result.table.drop(columns=["wall_s", "step_ms", "step_ms_max"], errors="ignore"),
        kept.drop(columns=["wall_s", "step_ms", "step_ms_max"], errors="ignore"),
    )


@pytest.mark.parametrize(
    "without,error,message",
    [(5, TypeError, "without must be a controller label or a list of them"), ([""], ValueError, "empty")],
)
def test_without_is_checked_naming_it(without, error, message):
    with pytest.raises(error, match=message):
        runner.Options(without=without)
    assert runner.Options(without="PD").without == ("PD",)
