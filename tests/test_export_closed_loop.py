"""Every controller kind exported as C runs the same closed loop as in Python: PID with
anti-windup, transfer-function blocks (lead/lag, loopshaped with prefilter), cascades, state
feedback with and without integrator, observers, the disturbance observer, LQR with a Kalman
filter, and linear MPC. Each exported controller is compiled with the system compiler (through
models.compile: arguments as a list, in a temporary cache), loaded with ctypes as a
models.Controller and run on the nonlinear plant next to the Python controller; the commands must
agree to 1e-9 at every step of a 10 s step with the case's input disturbance and measurement noise.

The controllers come from `controllers_to_export`, the one place that knows where designs live."""

from __future__ import annotations

import numpy as np
import pytest

import models
import mpc
import studies
from models.export import export_block
from mpc.export import export_linear_mpc
from studies import providers

#: Plants covering every kind twice: PID and transfer-function blocks alone (arm, uuv, the
#: uuv's IV.11 lead-lag), inside cascades (pendulum, satellite), and the state-space designs
#: and linear MPC on all four.
PLANTS = ("arm", "pendulum", "satellite", "uuv")
DURATION = 10.0


def controllers_to_export(name: str) -> dict:
    """Label -> controller of every kind designed for plant `name` (nominal parameters)."""
    known = models.get(name)
    found = {f"classical {label}": block for label, block in providers.classical(name, known).items()}
    found |= {f"state space {label}": block for label, block in providers.statespace(name, known).items()}
    found["linear MPC"] = providers.mpc(name, known)["linear MPC"]
    return found


def export(controller, name: str):
    """The exported C of `controller`, compiled and loaded, starting as the Python one does."""
    if isinstance(controller, models.Block):
        return export_block(controller, name).load(initial_state=controller.initial_state)
    return export_linear_mpc(controller, name).load()


@pytest.fixture(autouse=True)
def private_cache(tmp_path_factory, monkeypatch):
    monkeypatch.setenv("CODESIGN_CONTROL_CACHE", str(tmp_path_factory.getbasetemp() / "compile-cache"))


@pytest.mark.parametrize("name", PLANTS)
def test_every_exported_controller_gives_the_python_commands(name):
    plant, case = models.get(name), studies.get(name)
    reference = plant.equilibrium()[0][plant.state_names.index(case.tracked)] + case.step
    for index, (label, controller) in enumerate(controllers_to_export(name).items()):
        compiled = export(controller, f"controller{index}")
        runs = [
            models.simulate_closed_loop(
                plant, c, reference, DURATION, input_disturbance=case.input_disturbance, noise_std=1e-4, seed=3
            )
            for c in (controller, compiled)
        ]
        assert runs[0].diverged_at is None, label
        assert runs[1].u.shape == runs[0].u.shape == (round(DURATION / controller.sample_period), plant.nu)
        np.testing.assert_allclose(runs[1].u, runs[0].u, atol=1e-9, rtol=0, err_msg=f"{name}: {label}")
        assert all(s["success"] for s in runs[1].status), label
        if isinstance(controller, mpc.LinearMPC):
            assert all(s["success"] for s in runs[0].status)


def kinds(controller) -> set[str]:
    """The controller kinds inside `controller`, a cascade's loops and a filtered block's block included."""
    if isinstance(controller, models.Cascade):
        return {"cascade"} | kinds(controller.outer) | kinds(controller.inner)
    kind = type(controller).__name__
    if kind == "FilteredBlock":  # a block followed by a Tustin filter (the pendulum's zero-cancelling filter)
        return {"Tustin filter"} | kinds(controller.block)
    name = {
        "PID": "PID",
        "TransferFunctionBlock": "transfer-function block",
        "StateFeedback": "state feedback",
        "ObserverFeedback": "observer",
        "LinearMPC": "linear MPC",
    }[kind]
    found = {name}
    if kind == "TransferFunctionBlock":
        found.add("Tustin filter")
        if "prefilter_num" in controller.gains:
            found.add("prefilter")
    if getattr(controller, "anti_windup", "none") != "none":
        found.add(f"{name} with anti-windup")
    if getattr(controller, "has_integrator", False) and kind == "StateFeedback":
        found.add("state feedback with integrator")
    if getattr(controller, "disturbance_observer", False):
        found.add("disturbance observer")
    return found


def test_the_plants_cover_every_kind_twice():
    plants_of: dict[str, set] = {}
    for name in PLANTS:
        for controller in controllers_to_export(name).values():
            for kind in kinds(controller):
                plants_of.setdefault(kind, set()).add(name)
    assert set(plants_of) == {
        "PID",
        "PID with anti-windup",
        "transfer-function block",
        "transfer-function block with anti-windup",
        "Tustin filter",
        "prefilter",
        "cascade",
        "state feedback",
        "state feedback with integrator",
        "observer",
        "disturbance observer",
        "linear MPC",
    }
    assert all(len(plants) >= 2 for plants in plants_of.values()), plants_of
