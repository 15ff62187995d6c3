"""Sizes and values of ``python -m studies --sweep`` checked before any work: exit 2 naming --sweep."""

from __future__ import annotations

import tracemalloc

import pytest

import models.checks
from studies import cli, sweep


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
