"""The Monte Carlo of an MPC by its exported C (models.exported_loop): each sample's run is the Python
lockstep's (models.simulate_closed_loop_many) to 1e-9, status counts and divergence included; threads and
chunks change nothing; what the C cannot start from is named."""

from __future__ import annotations

import numpy as np
import pytest

import models
import studies
from models.exported_loop import compile_loop, simulate_exported_many
from mpc.exporting import export_controller
from studies.judging import solver_counts

from .conftest import build

DURATION, SUBSTEPS, SAMPLES = 3.0, 2, 4


@pytest.fixture(autouse=True)
def private_cache(tmp_path_factory, monkeypatch):
    monkeypatch.setenv("CODESIGN_CONTROL_CACHE", str(tmp_path_factory.getbasetemp() / "compile-cache"))


def pendulum_runs(kind: str, **overrides):
    """(plant, controller, compiled loop, reference, samples, run arguments) of the pendulum case's MPC,
    designed on the +5 % model, over samples of the ±5 % box with the case's disturbance and noise."""
    plant, case = models.get("pendulum"), studies.get("pendulum")
    controller = build(kind, "pendulum", models.perturbed(plant, 0.05), **overrides)
    reference = float(plant.equilibrium()[0][plant.state_names.index(case.tracked)] + case.step)
    loop = compile_loop(plant, export_controller(controller, f"loop_{kind}", [reference]), SUBSTEPS)
    samples = models.sample_params(plant, SAMPLES, rel=0.05, seed=4)
    arguments = dict(substeps=SUBSTEPS, input_disturbance=case.input_disturbance, noise_std=1e-4, seed=7)
    return plant, controller, loop, reference, samples, arguments


@pytest.mark.parametrize("kind", ["linear", "nonlinear"])
def test_the_c_loop_gives_the_python_lockstep_runs(kind):
    plant, controller, loop, reference, samples, arguments = pendulum_runs(kind)
    python = list(models.simulate_closed_loop_many(plant, controller, reference, DURATION, samples, **arguments))
    c = list(simulate_exported_many(plant, controller, loop, reference, DURATION, samples, **arguments))
    assert len(c) == len(python) == SAMPLES
    for a, b in zip(python, c):
        assert a.diverged_at is None and b.diverged_at is None
        np.testing.assert_allclose(b.u, a.u, atol=1e-9, rtol=0)
        np.testing.assert_allclose(b.x, a.x, atol=1e-9, rtol=0)
        np.testing.assert_allclose(b.measured, a.measured, atol=1e-9, rtol=0)
        np.testing.assert_array_equal(b.t, a.t)
        np.testing.assert_array_equal(b.params, a.params)
        assert solver_counts(b.status) == solver_counts(a.status) == (len(a.u), 0, 0)
        assert np.all(b.step_time > 0)


def test_threads_and_chunks_change_nothing():
    plant, controller, loop, reference, samples, arguments = pendulum_runs("linear")
    one = list(simulate_exported_many(plant, controller, loop, reference, 1.0, samples, threads=1, **arguments))
    split = list(
        simulate_exported_many(plant, controller, loop, reference, 1.0, samples, threads=2, chunk=3, **arguments)
    )
    for a, b in zip(one, split):
        np.testing.assert_array_equal(a.x, b.x)
        np.testing.assert_array_equal(a.u, b.u)


def test_a_run_leaving_the_bound_stops_as_in_python():
    """A start beyond models.simulate.DIVERGENCE_BOUND: both loops report divergence at t = 0, and both
    stepped the same samples before stopping."""
    plant, controller, loop, reference, samples, arguments = pendulum_runs("linear")
    x0 = plant.equilibrium()[0].copy()
    x0[plant.state_names.index("z")] = 2e6
    python = list(models.simulate_closed_loop_many(plant, controller, reference, 1.0, samples, x0=x0, **arguments))
    c = list(simulate_exported_many(plant, controller, loop, reference, 1.0, samples, x0=x0, **arguments))
    for a, b in zip(python, c):
        assert a.diverged_at == b.diverged_at == 0.0
        np.testing.assert_array_equal(np.isnan(b.u), np.isnan(a.u))
        np.testing.assert_allclose(b.u[~np.isnan(b.u)], a.u[~np.isnan(a.u)], atol=1e-9, rtol=0)


def test_a_reference_the_export_did_not_prepare_is_named():
    plant, controller, loop, reference, samples, arguments = pendulum_runs("nonlinear")
    with pytest.raises(ValueError, match="init refused sample 0.*code 9 \\(reference not exported\\)"):
        next(simulate_exported_many(plant, controller, loop, reference + 0.25, 1.0, samples, **arguments))


def test_an_export_for_another_plant_is_refused():
    _, _, loop, *_ = pendulum_runs("linear")
    with pytest.raises(ValueError, match="its C reads 2 values and commands 1; arm gives 1"):
        compile_loop(models.get("arm"), loop.exported, SUBSTEPS)
