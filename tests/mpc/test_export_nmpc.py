"""Nonlinear MPC exported as C (mpc.export_nmpc): the C closed loop on the project's simulator gives the
Python controller's commands to 1e-9 over 10 s on two plants (the pendulum with its soft bound, whose QP
both solve slack first, slacks freed at some samples; and the arm); a C program replaying that loop
gives them again with no allocation after init; what cannot be exported, and a reference outside the
exported table, are named."""

from __future__ import annotations

import numpy as np
import pytest

import models
import studies
from models.export import UnsupportedExport
from mpc.export_nmpc import STATUS, export_nonlinear_mpc
from mpc.export_nmpc_replay import replay

from .conftest import build

DURATION = 10.0


@pytest.fixture(autouse=True)
def private_cache(tmp_path_factory, monkeypatch):
    monkeypatch.setenv("CODESIGN_CONTROL_CACHE", str(tmp_path_factory.getbasetemp() / "compile-cache"))


def step_reference(name: str) -> float:
    plant, case = models.get(name), studies.get(name)
    return float(plant.equilibrium()[0][plant.state_names.index(case.tracked)] + case.step)


@pytest.mark.parametrize("name", ["pendulum", pytest.param("arm", marks=pytest.mark.slow)])
def test_exported_nmpc_gives_the_python_commands_in_closed_loop(name, tmp_path):
    plant, case = models.get(name), studies.get(name)
    controller, reference = build("nonlinear", name), step_reference(name)
    exported = export_nonlinear_mpc(controller, f"nmpc_{name}", [reference - 0.1, reference])
    compiled = exported.load()
    qp, rounds = controller.nlp.rti.qp_solver, []  # the Python path's QPs per sample (SlackFirstQP.solve)
    solve = qp.solve

    def counted(*args):
        answer = solve(*args)
        rounds.append(answer[4])
        return answer

    qp.solve = counted
    runs = [
        models.simulate_closed_loop(
            plant, c, reference, DURATION, input_disturbance=case.input_disturbance, noise_std=1e-4, seed=3
        )
        for c in (controller, compiled)
    ]
    assert runs[0].diverged_at is None
    assert runs[1].u.shape == runs[0].u.shape == (round(DURATION / controller.sample_period), plant.nu)
    assert all(s["success"] for s in runs[0].status)
    assert all(s["success"] for s in runs[1].status)
    np.testing.assert_allclose(runs[1].u, runs[0].u, atol=1e-9, rtol=0)
    if name == "pendulum":  # its soft bound: the C's sequence must free slacks where Python's did
        assert qp.slack_first and max(rounds) > 1
    # The same loop replayed by a C program: the same commands, and the steps allocate nothing.
    replayed = replay(exported, runs[0].measured, runs[0].r[:-1], tmp_path)
    assert replayed.init_code == 0 and np.all(replayed.codes == 0)
    np.testing.assert_allclose(replayed.commands, runs[0].u, atol=1e-9, rtol=0)
    if replayed.init_allocations:  # counted (Linux): DAQP's workspace, once
        assert replayed.step_allocations == 0
    assert np.all(replayed.step_seconds > 0)


def test_a_reference_outside_the_exported_table_is_refused():
    controller = build("nonlinear", "arm")
    compiled = export_nonlinear_mpc(controller, "nmpc_table", [0.5]).load()
    y0 = np.zeros(controller.plant.ny)
    with pytest.raises(ValueError, match=r"init returned 9 \(reference not exported\)"):
        compiled.initial_state(y0, [0.25])
    xc = compiled.initial_state(y0, [0.5])
    xc_next, u = compiled.step(xc, y0, [0.25])
    info = compiled.step_info()
    assert info["code"] == 9 and info["status"] == STATUS[9] and not info["success"]
    np.testing.assert_array_equal(u, xc[controller.plant.nx + 2 : controller.plant.nx + 3])  # the plan, shifted


def test_what_cannot_be_exported_is_named():
    with pytest.raises(UnsupportedExport, match=r"linear MPC: only mpc.NonlinearMPC is exported here; LinearMPC"):
        export_nonlinear_mpc(build("linear", "arm"), "nmpc", [0.5])
    with pytest.raises(UnsupportedExport, match=r"iteration='sqp' \(SQP to convergence at every sample"):
        export_nonlinear_mpc(build("nonlinear", "arm", iteration="sqp"), "nmpc", [0.5])
    with pytest.raises(UnsupportedExport, match=r"references must be finite"):
        export_nonlinear_mpc(build("nonlinear", "arm"), "nmpc", [np.nan])
