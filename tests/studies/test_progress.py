"""The progress estimate of ``python -m studies``: runs weighted by their expected cost (studies.batch.run_weights).

The row times are a recorded ``python -m studies arm --quick`` run (its timings.csv, rows without the
per-sample lines), in the order the runner made them.
"""

import io
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from studies import batch, cases, cli

RECORDED = Path(__file__).parent / "data" / "arm_quick_row_seconds.csv"


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
