"""The progress estimate of ``python -m studies``: runs weighted by their expected cost (studies.batch.run_weights).

The row times are a recorded ``python -m studies arm --quick`` run (its timings.csv, rows without the
per-sample lines), in the order the runner made them. quick_run_seconds.csv and quick_run_phases.csv are
one more such run of the arm and one of the UUV, with their designs' and files' seconds (run.json's
timing design_s, files_s) and the load average they ran at.
"""

import io
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from studies import batch, cases, cli

RECORDED = Path(__file__).parent / "data" / "arm_quick_row_seconds.csv"
WHOLE_RUNS = Path(__file__).parent / "data" / "quick_run_seconds.csv"
PHASES = Path(__file__).parent / "data" / "quick_run_phases.csv"


@pytest.fixture(scope="module")
def recorded():
    return pd.read_csv(RECORDED)


def _estimates(seconds, weights):
    """Whole-run estimates after each row, elapsed x whole / done (the bar's unsmoothed rate), from the
    first row at which 10 % of the true time has passed, as ratios to the true total."""
    seconds, weights = np.asarray(seconds), np.asarray(weights, dtype=float)
    elapsed, total = np.cumsum(seconds), seconds.sum()
    fraction = np.cumsum(weights) / weights.sum()
    first = int(np.argmax(elapsed >= 0.1 * total))
    return (elapsed / fraction)[first:] / total


def test_weighted_estimate_stays_within_2x_after_10_percent(recorded):
    case = cases.get("arm")
    controllers = list(dict.fromkeys(recorded.controller))
    assert controllers == list(case.controllers)
    weights = batch.run_weights(case, None, 10, controllers)
    assert len(weights) == len(recorded)
    ratios = _estimates(recorded.wall_s, weights)
    assert 0.5 <= ratios.min() and ratios.max() <= 2.0
    # Counting runs instead (every run alike) underestimates the whole by more than 2x once the MPC runs.
    plain = _estimates(recorded.wall_s, np.ones(len(recorded)))
    assert plain.min() < 0.5


def _whole_run_estimates(rows, phases, weights, after):
    """The bar's estimates after each row of a whole plant run (designs, then the rows, then the files;
    `weights[0]` carries the designs, `after` the files), from the first row at which 10 % of the whole
    run's time has passed, as ratios to that whole."""
    seconds, weights = np.asarray(rows.wall_s), np.asarray(weights, dtype=float)
    elapsed = phases.design_s + np.cumsum(seconds)
    total = phases.design_s + seconds.sum() + phases.files_s
    fraction = np.cumsum(weights) / (weights.sum() + after)
    first = int(np.argmax(elapsed >= 0.1 * total))
    return (elapsed / fraction)[first:] / total


@pytest.mark.parametrize("plant", ["arm", "uuv"])
def test_the_whole_run_estimate_counts_the_designs_and_files(plant):
    """The designs and files take about as long as the rows (run.json): left out, the first estimate is
    tens of times the whole run; counted (the constants fitted on the arm's run, the UUV's run at load 10
    is a check), every estimate from 10 % of the run on is within 2x of the whole run's time."""
    rows = pd.read_csv(WHOLE_RUNS).query("plant == @plant")
    phases = pd.read_csv(PHASES).set_index("plant").loc[plant]
    case = cases.get(plant)
    controllers = list(dict.fromkeys(rows.controller))
    assert controllers == list(case.controllers)
    weights, after = batch.plant_costs(case, None, 10, controllers)
    assert len(weights) == len(rows) and after > 0
    ratios = _whole_run_estimates(rows, phases, weights, after)
    assert 0.5 <= ratios.min() and ratios.max() <= 2.0, (ratios.min(), ratios.max())
    rows_only = _whole_run_estimates(rows, phases, batch.run_weights(case, None, 10, controllers), 0.0)
    assert rows_only.max() > 10.0


def test_the_bar_reaches_a_plants_files_when_it_is_done():
    bar = cli.Progress({"arm": ([3.0, 1.0], 4.0)}, io.StringIO())
    assert bar.bar.total == pytest.approx(8.0)
    bar.update("arm", 2, 2, "arm: PD / mc")  # the last run: its files are still to be written
    assert bar.bar.n == pytest.approx(4.0)
    bar.update("arm", 1, 1, "arm done")
    assert bar.bar.n == pytest.approx(8.0)
    bar.close()


def test_weights_follow_the_case_files():
    case = cases.get("arm")
    w = dict(zip([(c, s.name) for c in case.controllers for s in case.scenarios], batch.run_weights(case, None, 10)))
    assert w[("nonlinear MPC", "step")] > w[("linear MPC", "step")] > w[("PD", "step")]
    assert w[("linear MPC", "mc")] > w[("linear MPC", "step")] * 5  # ten samples of the step
    assert w[("PD", "steps")] > w[("PD", "step")]  # twice as long
    no_mc = batch.run_weights(case, None, 0)
    assert len(no_mc) == len(case.controllers) * (len(case.scenarios) - 1)


def test_the_bar_moves_by_cost_and_reports_the_runs():
    stream = io.StringIO()
    weights = [1.0, 1.0, 8.0]
    bar = cli.Progress({"arm": weights, "uuv": 3}, stream)
    assert bar.bar.total == pytest.approx(13.0)
    bar.update("arm", 2, 3, "arm: PD / steps")
    assert bar.bar.n == pytest.approx(2.0)
    bar.update("arm", 3, 3, "arm: LQR / mc")
    assert bar.bar.n == pytest.approx(10.0)
    bar.update("uuv", 4, 6, "a provider added three controllers")  # another count of runs: its share's fraction
    assert bar.bar.n == pytest.approx(12.0)
    assert "5/6 runs" in bar.bar.postfix
    bar.close()
