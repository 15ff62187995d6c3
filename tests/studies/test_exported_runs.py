"""An MPC row run by its exported C (studies.exported_runs) is the row its Python controller gives: every
scenario's and the Monte Carlo's metrics to 1e-9, the same status and verdict; the step times are the C
step's; and a controller the export refuses runs in Python with a note naming why."""

from __future__ import annotations

import numpy as np
import pytest

import models
import studies
from models import metrics
from mpc import nonlinear_mpc
from studies import exported_runs, runner

OPTIONS = dict(scenarios=("step", "steps", "noise", "mc"), mc=3)
TIMES = {"step_ms", "step_ms_max"}


@pytest.fixture(autouse=True)
def private_cache(tmp_path_factory, monkeypatch):
    monkeypatch.setenv("CODESIGN_CONTROL_CACHE", str(tmp_path_factory.getbasetemp() / "compile-cache"))


def uuv_rows(jit: bool):
    """The UUV case's nonlinear MPC (its shortest runs) through step, steps, noise and 3 Monte Carlo samples."""
    case = studies.get("uuv")
    controller = nonlinear_mpc(case.known_plant(models.get("uuv")), case.mpc, tracked=case.tracked)
    options = runner.Options(jit=jit, **OPTIONS)
    return runner.run_study(case, options, providers=[], controllers={"nonlinear MPC": controller})


def test_the_c_rows_are_the_python_rows():
    python, c = uuv_rows(False), uuv_rows(True)
    assert not any("stepped in Python" in note for note in c.notes)
    for (_, a), (_, b) in zip(python.table.iterrows(), c.table.iterrows()):
        assert (a.scenario, a.status, a.verdict, a.verdict_detail) == (
            b.scenario,
            b.status,
            b.verdict,
            b.verdict_detail,
        )
        for column in set(metrics.METRIC_COLUMNS) - TIMES:
            if isinstance(a[column], float):
                np.testing.assert_allclose(b[column], a[column], rtol=1e-9, atol=1e-9, err_msg=f"{a.scenario} {column}")
    python_step = python.table.set_index("scenario").step_ms
    c_step = c.table.set_index("scenario").step_ms
    assert (c_step > 0).all() and (c_step < python_step).all()  # the C step's own time, not Python's


def test_a_controller_the_export_refuses_steps_in_python_with_a_note():
    """A Python MPC iterating to convergence (iteration="sqp") has no C: its rows run, a note says why."""
    case = studies.get("uuv")
    controller = nonlinear_mpc(case.known_plant(models.get("uuv")), case.mpc, tracked=case.tracked, iteration="sqp")
    assert exported_runs.wanted(True, controller)
    result = runner.run_study(
        case, runner.Options(jit=True, scenarios=("step",), mc=0), providers=[], controllers={"SQP MPC": controller}
    )
    assert result.table.status.tolist() == ["ok"]
    assert any(
        note.startswith("SQP MPC: stepped in Python, not its C (") and "iteration='sqp'" in note
        for note in result.notes
    )
