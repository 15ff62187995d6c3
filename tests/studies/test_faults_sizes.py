"""Sizes and values of ``python -m studies --sweep`` checked before any work: exit 2 naming --sweep."""

from __future__ import annotations

import tracemalloc
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import models.checks
import mpc
import studies
from studies import cli, runner, sweep

#: The recorded rows of ``python -m studies arm --quick`` (s), which the estimates are calibrated on.
RECORDED = Path(__file__).parent / "data" / "arm_quick_row_seconds.csv"


def refused(argv, capsys) -> str:
    """Run the command line in this process; the last stderr line of its exit 2."""
    with pytest.raises(SystemExit) as stopped:
        cli.main(argv)
    assert stopped.value.code == 2
    return capsys.readouterr().err.strip().splitlines()[-1]


@pytest.fixture
def no_run(monkeypatch):
    """Any design or run of a sweep fails the test: the refusal must come before the work."""

    def never(*args, **kwargs):
        raise AssertionError("the sweep ran")

    monkeypatch.setattr(sweep, "run_sweep", never)


def test_a_sweep_of_a_billion_points_is_refused_at_once_naming_its_size_and_the_limit(tmp_path, capsys, no_run):
    """1e9 points (before: 24 GB allocated until the kernel killed it): exit 2 naming --sweep, the points,
    their size (1e9 x 40 bytes = 37.3 GiB by hand) and the limit, without allocating the grid."""
    tracemalloc.start()
    try:
        line = refused(["arm", "--sweep", "m=0.3:0.7:1000000000", "--out", str(tmp_path / "out")], capsys)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert line == (
        "python -m studies: error: --sweep: a sweep of 1000000000 points needs about "
        f"{1e9 * 40 / 2**30:.1f} GiB, above the limit of 1 GiB (models.checks.MEMORY_LIMIT_BYTES); sweep fewer points"
    )
    assert peak < 100 * 2**20, f"{peak / 2**20:.0f} MiB allocated before the refusal"
    assert list((tmp_path / "out").glob("**/*")) == []


def test_the_limit_is_the_one_of_models_checks(monkeypatch):
    """The grid's limit is read from models.checks.MEMORY_LIMIT_BYTES at each call: with a limit of 100
    points' worth, 100 points are made and 101 refused."""
    monkeypatch.setattr(models.checks, "MEMORY_LIMIT_BYTES", 100 * sweep.POINT_BYTES)
    assert len(sweep.Grid.parse("m=0.3:0.7:100").values) == 100
    with pytest.raises(models.checks.ResourceLimitError, match="a sweep of 101 points needs"):
        sweep.Grid.parse("m=0.3:0.7:101")


def test_a_value_the_plant_refuses_exits_2_before_the_run(tmp_path, capsys, no_run):
    """m from -1 to 1 (before: exit 1 after the run had started): exit 2 naming --sweep, the value and the
    plant's rule, before any controller is designed."""
    line = refused(["arm", "--sweep", "m=-1:1:3", "--out", str(tmp_path / "out")], capsys)
    assert line.startswith("python -m studies: error: --sweep: sweep of m at -1: arm: parameter m"), line
    assert "must be finite and > 0" in line
    assert list((tmp_path / "out").glob("**/*")) == []


def test_a_sweep_estimated_beyond_the_time_limit_is_refused_naming_the_estimate(tmp_path, capsys, no_run):
    """200 000 points of the arm (8 MB: within memory) with its nonlinear MPC at about 0.27 s a point in the
    recorded study (tests/studies/data/arm_quick_row_seconds.csv): many hours, refused with exit 2 naming
    --sweep, the estimate and the limit, before any design."""
    line = refused(["arm", "--sweep", "m=0.3:0.7:200000", "--out", str(tmp_path / "out")], capsys)
    assert line.startswith("python -m studies: error: --sweep: a sweep of 200000 points of m on arm is estimated at ")
    assert "above the limit of 30 min (studies.sweep.TIME_LIMIT_S)" in line and "--long" in line
    _, seconds = sweep.estimate_seconds(studies.get("arm"), sweep.Grid.parse("m=0.3:0.7:200000"))
    assert seconds > 200000 * 0.2  # the nonlinear MPC's points alone, by the recorded row
    assert list((tmp_path / "out").glob("**/*")) == []


def test_long_accepts_the_estimate_and_the_estimate_is_printed_before_the_run(tmp_path, capsys, monkeypatch):
    """With --long the same sweep reaches the run, and the estimate was printed before it started."""
    seen = []

    def reached(*args, **kwargs):
        seen.append(capsys.readouterr().err)
        raise RuntimeError("stopped at the run")

    monkeypatch.setattr(sweep, "run_sweep", reached)
    assert cli.main(["arm", "--sweep", "m=0.3:0.7:200000", "--long", "--quiet", "--out", str(tmp_path / "out")]) == 1
    assert len(seen) == 1 and "arm: sweep of 200000 points, estimated " in seen[0]


def test_the_time_limit_is_read_at_each_call(monkeypatch):
    """`check_time` refuses what exceeds `TIME_LIMIT_S` at the call, and accepts it when asked."""
    case, grid = studies.get("arm"), sweep.Grid.parse("m=0.3:0.7:10")
    _, seconds = sweep.estimate_seconds(case, grid)
    monkeypatch.setattr(sweep, "TIME_LIMIT_S", seconds / 2)
    with pytest.raises(models.checks.ResourceLimitError, match="a sweep of 10 points of m on arm is estimated"):
        sweep.check_time(case, grid)
    assert sweep.check_time(case, grid, accept=True) == seconds


def test_the_estimate_scales_as_the_sweeps_runs():
    """The estimate counts what a sweep does: the linear MPC's points run one by one, one whole run each,
    so the estimate is linear in the points (8 to 32 adds twice what 8 to 20 adds), and a sweep of 12
    points makes 12 runs of the scenario's whole duration, one per grid value in order. Counted, not timed:
    the machine's load scales a measured sweep, point by point, by up to 2 here. And the estimate of one
    point is the recorded study's step row of the linear MPC (tests/studies/data/arm_quick_row_seconds.csv,
    measured on ``python -m studies arm --quick``)."""
    case = studies.get("arm")
    counts = (8, 20, 32)
    estimate = {n: sweep.estimate_seconds(case, sweep.Grid("m", (0.5,) * n), "step", ["linear MPC"])[1] for n in counts}
    assert (estimate[32] - estimate[8]) / (estimate[20] - estimate[8]) == pytest.approx(2.0)

    plant = models.get("arm")
    controller = mpc.linear_mpc(case.known_plant(plant), case.mpc, tracked=case.tracked)
    simulate, runs = runner.simulate_scenario, []

    def counted(*args, **kwargs):
        result = simulate(*args, **kwargs)
        runs.append((kwargs["params"], result.t[-1]))
        return result

    grid = sweep.Grid("m", tuple(np.linspace(0.4, 0.6, 12)))
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(runner, "simulate_scenario", counted)
        table, _ = sweep.run_sweep(case, grid, providers=[], controllers={"linear MPC": controller})
    step = next(s for s in case.scenarios if s.name == "step")
    assert len(table) == len(runs) == 12
    assert [row[list(plant.params).index("m")] for row, _ in runs] == list(grid.values)
    assert all(end == pytest.approx(step.duration(case)) for _, end in runs)

    recorded = pd.read_csv(RECORDED)
    row = recorded[(recorded.controller == "linear MPC") & (recorded.scenario == "step")].wall_s.item()
    assert estimate[8] / 8 == pytest.approx(row, rel=0.5)
