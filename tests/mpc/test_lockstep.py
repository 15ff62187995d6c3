"""MPC Monte Carlo samples stepped in lockstep (`models.simulate_closed_loop_many`, `step_many`) against
the same runs one by one (`models.simulate_closed_loop`): the second method is the per-sample loop the
lockstep replaces, and the runs must agree bit for bit (same compiled code, same order of operations)."""

import numpy as np
import pytest

import models
import mpc

from .test_controller import FailingSolver

RUN_KEYS = ("x", "y", "u", "measured")


def _without_times(records):
    return [{k: v for k, v in r.items() if not k.endswith("time")} for r in records]


def _assert_same_runs(alone, together):
    assert len(alone) == len(together)
    for one, many in zip(alone, together):
        for key in RUN_KEYS:
            np.testing.assert_array_equal(getattr(many, key), getattr(one, key), err_msg=key)
        assert many.diverged_at == one.diverged_at
        assert _without_times(many.status) == _without_times(one.status)
        assert np.all(np.isfinite(many.step_time[: len(many.status)]))


def _runs(plant, controller, params, duration, chunk, reference=0.3, **kwargs):
    alone = [
        models.simulate_closed_loop(
            plant, controller, reference, duration, params=p, allow_divergence=True, substeps=2, seed=3, **kwargs
        )
        for p in params
    ]
    together = list(
        models.simulate_closed_loop_many(
            plant, controller, reference, duration, params, substeps=2, seed=3, chunk=chunk, **kwargs
        )
    )
    return alone, together


@pytest.mark.parametrize("kind", ["linear", "nonlinear"])
def test_lockstep_runs_equal_the_runs_one_by_one(kind, build_mpc):
    # The pendulum's 2 m step: the soft |theta| bound is reached (slacks, the whole QP and the reduced one).
    plant = models.get("pendulum")
    controller = build_mpc(kind, "pendulum")
    params = models.sample_params(plant, 5, rel=0.05, seed=1)
    alone, together = _runs(plant, controller, params, 0.6, chunk=2, reference=2.0, noise_std=1e-3)
    _assert_same_runs(alone, together)
    assert any(r["soft_violation"] > 0 for run in alone for r in run.status)


def test_lockstep_keeps_each_samples_warm_start_and_fallback(build_mpc):
    # Injected failures every few solves: the fallback to the shifted plan, per sample, as alone.
    plant = models.get("arm")
    controller = build_mpc("linear", "arm", solver=lambda problem: FailingSolver(problem, range(3, 400, 7)))
    params = models.sample_params(plant, 3, rel=0.05, seed=0)
    alone, together = [], []
    for p in params:  # the failing solver counts its calls: from 0 in every run on both sides
        controller.solver.calls = 0
        alone.append(
            models.simulate_closed_loop(plant, controller, 0.3, 0.5, params=p, substeps=2, allow_divergence=True)
        )
        controller.solver.calls = 0
        together += models.simulate_closed_loop_many(plant, controller, 0.3, 0.5, p[None], substeps=2)
    _assert_same_runs(alone, together)
    assert any(r["fallback"] for r in together[0].status)


def test_nonlinear_lockstep_falls_back_to_each_sample_alone_when_the_batch_raises(build_mpc, monkeypatch):
    plant = models.get("arm")
    controller = build_mpc("nonlinear", "arm")
    params = models.sample_params(plant, 3, rel=0.05, seed=2)
    alone = [models.simulate_closed_loop(plant, controller, 0.3, 0.3, params=p, substeps=2) for p in params]

    def raising(*args):
        raise RuntimeError("NaN detected")

    monkeypatch.setattr(controller.nlp.rti, "prepare_many", raising)
    together = list(models.simulate_closed_loop_many(plant, controller, 0.3, 0.3, params, substeps=2))
    _assert_same_runs(alone, together)


def test_a_run_that_diverges_stops_alone(build_mpc):
    # A sample whose arm has next to no mass (1e-9 kg): the first command flings it past the divergence
    # bound; the run stops there, as alone, and the samples before and after it run to the end.
    plant = models.get("arm")
    controller = build_mpc("linear", "arm")
    params = np.tile(plant.param_vector(), (3, 1))
    params[1, 0] = 1e-9
    alone, together = _runs(plant, controller, params, 0.5, chunk=3)
    _assert_same_runs(alone, together)
    assert [run.diverged_at is None for run in together] == [True, False, True]
    assert len(together[1].status) < len(together[0].status) == 50


def test_controllers_that_cannot_step_in_lockstep_are_refused(build_mpc):
    plant = models.get("arm")
    with pytest.raises(TypeError, match="lockstep"):
        next(
            models.simulate_closed_loop_many(
                plant, build_mpc("linear", "arm", solver="osqp"), 0.3, 0.1, plant.param_vector()[None]
            )
        )
    assert not build_mpc("linear", "arm", solver="osqp").lockstep
    assert build_mpc("linear", "arm").lockstep and mpc.NonlinearMPC.lockstep
