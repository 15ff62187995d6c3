"""The sweep: its grid, and its points against runs made another way (the study's own step row at the nominal
value; a directly simulated plant with the parameter changed elsewhere)."""

import fault_providers
import numpy as np
import pandas as pd
import pytest
from conftest import EXAMPLE

import models
import studies
from models import metrics
from studies import runner, sweep


def test_grid_parse_and_its_errors():
    grid = sweep.Grid.parse("m=0.3:0.7:5")
    assert grid.param == "m" and grid.values == pytest.approx((0.3, 0.4, 0.5, 0.6, 0.7))
    for text, message in (
        ("m", "a sweep is PARAM=LOW:HIGH:N"),
        ("m=1:0:3", "finite LOW < HIGH and N >= 2"),
        ("m=0:1:1", "N >= 2"),
        ("m=a:1:3", "a sweep is PARAM=LOW:HIGH:N|must be numbers"),
    ):
        with pytest.raises(ValueError, match=message):
            sweep.Grid.parse(text)
    arm = models.get("arm")
    with pytest.raises(ValueError, match="arm has no parameter 'mass'; its parameters are m, ell"):
        sweep.grid_params(arm, sweep.Grid("mass", (1.0, 2.0)))
    with pytest.raises(ValueError, match="sweep of m at -0.1"):
        sweep.grid_params(arm, sweep.Grid("m", (-0.1, 0.5)))


@pytest.fixture(scope="module")
def swept():
    case = studies.get("arm")
    grid = sweep.Grid("m", (0.5, 0.8))  # 0.5 kg: the nominal arm
    table, notes = sweep.run_sweep(case, grid, providers=(EXAMPLE,))
    return case, grid, table, notes


def test_the_nominal_point_is_the_studys_step_row(swept):
    case, grid, table, _ = swept
    study = studies.run("arm", scenarios=["step"], mc=0, providers=[EXAMPLE])
    assert set(table.controller) == set(study.controller)
    nominal = table[table[grid.param] == 0.5].set_index("controller")
    rows = study.set_index("controller")
    for column in ("rise_time_s", "settling_time_s", "overshoot_pct", "iae", "itae", "peak_u", "energy"):
        np.testing.assert_allclose(
            nominal.loc[rows.index, column].astype(float), rows[column].astype(float), rtol=1e-9, err_msg=column
        )
    assert list(nominal.loc[rows.index, "verdict"]) == list(rows.verdict)


def test_an_off_nominal_point_is_the_plant_with_that_parameter(swept):
    case, grid, table, _ = swept
    heavy = models.get("arm", m=0.8)
    block = {label: c for label, c in runner.design_controllers(case, case.known_plant(), (EXAMPLE,))[0].items()}["LQR"]
    run = models.simulate_closed_loop(
        heavy, block, case.scenarios[0].reference(case, 0.0), case.duration, substeps=case.substeps
    )
    expected = metrics.run_metrics(run, "theta")
    row = table[(table.controller == "LQR") & (table.m == 0.8)].iloc[0]
    for column in ("settling_time_s", "overshoot_pct", "itae", "energy"):
        assert row[column] == pytest.approx(expected[column], rel=1e-9)
    assert row.itae != pytest.approx(table[(table.controller == "LQR") & (table.m == 0.5)].iloc[0].itae, rel=1e-3)


def test_write_sweep_leaves_its_files(swept, tmp_path):
    case, grid, table, notes = swept
    written = sweep.write_sweep(case, grid, table, tmp_path, notes)
    for name in written:
        assert (tmp_path / "arm" / name).stat().st_size > 0
    back = pd.read_csv(tmp_path / "arm" / "sweep.csv")
    assert len(back) == table.controller.nunique() * len(grid.values)
    text = (tmp_path / "arm" / "sweep.md").read_text()
    assert all(f"- {label}: meets its specs" in text for label in set(table.controller))


def test_a_point_judged_by_the_sweep_is_the_row_the_runner_judges(swept):
    """The nominal point's status, verdict, its detail and every metric are the study's step row's: both
    come from `studies.judging.judge_run` (the time per step is a measured duration, not judged)."""
    case, grid, table, _ = swept
    study = studies.run("arm", scenarios=["step"], mc=0, providers=[EXAMPLE]).set_index("controller")
    nominal = table[table[grid.param] == 0.5].set_index("controller").loc[study.index]
    for column in ("status", "verdict", "verdict_detail"):
        assert list(nominal[column].fillna("")) == list(study[column].fillna("")), column
    for column in (c for c in metrics.METRIC_COLUMNS if not c.startswith("step_ms")):  # not wall-clock times
        np.testing.assert_allclose(
            nominal[column].astype(float), study[column].astype(float), rtol=1e-12, equal_nan=True, err_msg=column
        )


def test_a_degraded_run_in_the_sweep_says_degraded():
    """An MPC whose solver fails on every step (falling back each time) is "degraded" at every sweep point,
    with the counts, as in the study's own row."""
    grid = sweep.Grid("m", (0.5, 0.55))
    table, _ = sweep.run_sweep(studies.get("arm"), grid, providers=(fault_providers.solver_always_fails,))
    failing = table[table.controller == "failing MPC"]
    assert len(failing) == 2
    assert set(failing.status) == {"degraded: solver failed on 500 of 500 steps, fallback on 500"}
