"""The tuner's spec constraints and the study table's verdict read the same run with the same numbers.

For each scenario the table judges, the tuner's problem (`studies.tuner.scenarios`, the case's own specs)
and the table's run (`studies.runner.simulate_scenario`, judged by `studies.judging.judge_run`) are built
independently; the commands agree to 1e-12, the overshoot and steady-state error the constraints carry are
the table's metrics to 1e-12, and a spec the tuner finds met is met by the table's verdict.
"""

import dataclasses

import numpy as np
import pytest

import models
import studies
from designs.tuning import Cost, TuningProblem
from models import specs as model_specs
from studies import judging, runner, tuner

CASE = studies.get("arm")


def _designs():
    hand = tuner.hand_design(CASE)
    # The hand design, a faster variant of it and one the table finds meeting the step specs (a hand-picked
    # point of a gain grid): both sides of the specs.
    return {
        "hand": hand,
        "fast": hand.with_gains(**{k: 3 * np.asarray(v) for k, v in hand.gains.items()}),
        "meets": hand.with_gains(kp=np.asarray(2.0), kd=np.asarray(0.2), ki=np.asarray(1.0)),
    }


def _table_run(block, name: str):
    """The table's run of scenario `name` on the nominal arm; the noise drawn as the tuner's sample 0 is
    (`SeedSequence([seed, 0])`, `models.run_setup.RunSetup.noise`), the table's own seed 0."""
    plant = models.get(CASE.plant)
    _, base = runner.tracked_equilibrium(plant, CASE)
    table = tuner.table_scenarios(CASE)[name]
    if not table.noise:
        return runner.simulate_scenario(plant, block, table, CASE, runner.Options(), base, CASE.substeps)
    noise = runner.measurement_noise_std(plant, block, table.noise, sigma=CASE.derivative_time_constant)
    run = table.run(CASE, base, noise)
    return models.simulate_closed_loop(
        plant,
        block,
        run.reference,
        run.duration,
        substeps=CASE.substeps,
        input_disturbance=run.input_disturbance,
        noise_std=run.noise_std,
        seed=np.random.SeedSequence([runner.Options().seed, 0]),
        allow_divergence=True,
    )


@pytest.mark.parametrize("design", ["hand", "fast", "meets"])
@pytest.mark.parametrize("name", tuner.SCENARIOS)
def test_a_spec_the_tuner_finds_met_is_met_by_the_tables_verdict_with_the_same_numbers(name, design):
    plant = models.get(CASE.plant)
    block = _designs()[design]
    nominal = plant.param_vector()[None, :]
    specs = tuner.case_specs(CASE, nominal)[name]
    (scenario,) = [s for s in tuner.scenarios(CASE, block, {name: specs}) if s.name == name]
    problem = TuningProblem(plant, block, scenario, cost=Cost("itae"), samples=nominal, substeps=CASE.substeps)
    _, g, u, _ = (np.asarray(v) for v in problem.evaluate(problem.start()))
    g = g.ravel()
    result = _table_run(block, name)
    judged = judging.judge_run(CASE, name, result, dict(zip(plant.params, nominal[0])))
    # The same run: the tuner's commands are the table's.
    np.testing.assert_allclose(u.T, result.u, rtol=0, atol=1e-12)
    rows = dict(problem.constraint_names)
    step = abs(CASE.step)  # every step of the table's scenarios has the case's size
    over = [g[sl] for label, sl in rows.items() if label.startswith("overshoot")]
    ss = [g[sl] for label, sl in rows.items() if label.startswith("ss error")]
    assert over and ss and len(over) == len(ss) == (4 if name == "steps" else 1)
    overshoot = max(0.0, max(float(np.max(rows_)) for rows_ in over)) / step * 100
    assert overshoot == pytest.approx(judged.metrics["overshoot_pct"], rel=1e-12, abs=1e-12)
    error = max(float(np.max(np.abs(rows_))) for rows_ in ss)
    assert error == pytest.approx(judged.metrics["ss_error"], rel=1e-12, abs=1e-14)
    # Met according to the tuner implies met according to the table, spec by spec and as a whole.
    missed = problem.violated_names(g)
    if not any(label.startswith("within") for label in missed):
        assert judged.metrics["settling_time_s"] <= specs.max_settling_time_s
    if not any(label.startswith("overshoot") for label in missed):
        assert judged.metrics["overshoot_pct"] <= specs.max_overshoot_pct + 1e-12
    if not missed:
        assert judged.verdict.label == model_specs.MEETS, judged.verdict


def test_the_designs_cover_both_sides_of_the_specs():
    """The designs above include one the table says meets the arm's step specs and one it says violates
    them, so the implication is tested where it can fail."""
    plant = models.get(CASE.plant)
    nominal = dict(zip(plant.params, plant.param_vector()))
    labels = {
        design: judging.judge_run(CASE, "step", _table_run(block, "step"), nominal).verdict.label
        for design, block in _designs().items()
    }
    assert model_specs.MEETS in labels.values() and model_specs.VIOLATES in labels.values(), labels


@pytest.mark.parametrize(
    "plant_name,row",
    [
        ("satellite", None),  # the panel deflection φ − θ: a limit on the difference of two states
        ("pendulum", None),  # the cart travel
        ("ballbeam", 0),  # the beam length: a bound read from the parameter ell, on a sample where ell ≠ 0.5 m
    ],
)
def test_the_tuners_physical_limit_rows_are_the_tables_departures_on_the_same_run(plant_name, row):
    """The limit rows of the tuner's problem (`studies.tuner.case_specs`, each sample's own bound) carry the
    limited quantity of the table's own run (`studies.runner.simulate_scenario`) to 1e-12, and the tuner
    finds a limit left exactly where the table's verdict (`models.state_limits.check_state_limits` inside
    `studies.judging.judge_run`) says the run leaves it, by the same excess: on the case's limits (which the
    hand design keeps) and on the same limits with their lower bound raised into the run's range (left)."""
    declared = studies.get(plant_name)
    plant = models.get(plant_name)
    params = plant.param_vector()[None, :] if row is None else tuner.samples(declared, 1, 5)
    named = dict(zip(plant.params, params[0]))
    block = tuner.hand_design(declared)
    _, base = runner.tracked_equilibrium(plant, declared)
    table = tuner.table_scenarios(declared)["step"]
    options, substeps = runner.Options(), declared.substeps
    result = runner.simulate_scenario(plant, block, table, declared, options, base, substeps, params[0])
    ranges = {limit.name: limit.at(named).values(result.x, result.state_names) for limit in declared.state_limits}
    raised = tuple(
        dataclasses.replace(limit, lower=float(np.min(ranges[limit.name]) + np.ptp(ranges[limit.name]) / 2))
        for limit in declared.state_limits
    )
    for case, left in ((declared, False), (dataclasses.replace(declared, state_limits=raised), True)):
        specs = tuner.case_specs(case, params)["step"]
        assert [limit.name for limit in specs.state_limits] == [limit.name for limit in case.state_limits]
        (scenario,) = [s for s in tuner.scenarios(case, block, {"step": specs}) if s.name == "step"]
        problem = TuningProblem(plant, block, scenario, cost=Cost("itae"), samples=params, substeps=case.substeps)
        g = np.asarray(problem.evaluate(problem.start())[1]).ravel()
        judged = judging.judge_run(case, "step", result, named)
        rows = dict(problem.constraint_names)
        missed = problem.violated_names(g, tol=0.0)
        for limit in (limit.at(named) for limit in case.state_limits):
            if plant_name == "ballbeam":
                assert limit.upper == named["ell"] != 0.5
            (label,) = [label for label in rows if label.startswith(limit.describe())]
            values = ranges[limit.name]
            np.testing.assert_allclose(g[rows[label]], values[1:], rtol=0, atol=1e-12)
            departure = [v for v in judged.verdict.violations if v.spec == f"leaves {limit.name} by"]
            assert (label in missed) == bool(departure) == left, (label, judged.verdict)
            assert all(v.left for v in departure)  # what `studies.tuner.departures` reads
            # The table reads x_0 too (the run's given initial state, which the tuning cannot move).
            excess = max(float(np.max(values - limit.upper)), float(np.max(limit.lower - values)), 0.0)
            assert (departure[0].value if departure else 0.0) == pytest.approx(excess, rel=1e-12, abs=1e-15)


def test_the_certificates_runs_are_the_tunings_own_noise_draws_included():
    """`studies.tuner.certificate` judges the tuning's runs: on each tuning sample j the table's run with the
    tuning problem's noise draw for sample j (`noise_sample=j`) gives the tuning's commands to 1e-12. The
    table's own draw is sample 0's, so on the other samples it gives other commands: the draws are what
    is compared."""
    plant = models.get(CASE.plant)
    block = tuner.hand_design(CASE)
    rows = tuner.samples(CASE, 3, 5)
    (scenario,) = [s for s in tuner.scenarios(CASE, block) if s.name == "noise"]
    problem = TuningProblem(plant, block, scenario, cost=Cost("itae"), samples=rows, substeps=CASE.substeps)
    u = np.asarray(problem.evaluate(problem.start())[2])
    _, base = runner.tracked_equilibrium(plant, CASE)
    table = tuner.table_scenarios(CASE)["noise"]
    n = u.shape[1] // len(rows)
    for j, row in enumerate(rows):
        own = runner.simulate_scenario(
            plant, block, table, CASE, runner.Options(), base, CASE.substeps, row, noise_sample=j
        )
        np.testing.assert_allclose(u[:, j * n : (j + 1) * n].T, own.u, rtol=0, atol=1e-12)
        tables = runner.simulate_scenario(plant, block, table, CASE, runner.Options(), base, CASE.substeps, row)
        differs = np.max(np.abs(u[:, j * n : (j + 1) * n].T - tables.u))
        assert differs == 0 if j == 0 else differs > 1e-6
