"""Faults injected into the MPC package: Ctrl-C during a nonlinear MPC run, non-finite
measurements, estimates, solver answers and commands, and bad input at the edges. Each test
asserts the exact behaviour: the exception type and the culprit named in a one-line message,
the step status, the exit code."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import models
import mpc
from mpc.estimator import DisturbanceObserver
from mpc.linear import QPSolution, SoftBound
from mpc.reference_cvxpy import CvxpySolver

from .conftest import build

REPO = Path(models.__file__).resolve().parent.parent

# ---------------------------------------------------------------------------- Ctrl-C
RUN_UNTIL_INTERRUPTED = """
import sys
import models, mpc, studies
plant, case = models.get("pendulum"), studies.get("pendulum")
controller = mpc.nonlinear_mpc(plant, case.mpc, tracked=case.tracked)
for attempt in range(int(sys.argv[1])):
    print("running", flush=True)
    try:
        models.simulate_closed_loop(plant, controller, 0.5, 60.0)
        print("finished", flush=True)
        # What the test reports when a signal was lost: counted and delivered SIGINTs, the signal masks.
        masks = [line for line in open("/proc/self/status").read().splitlines() if line.startswith("Sig")]
        print("SIGINTs counted", models.interrupts._received, "delivered", models.interrupts._handled, masks,
              file=sys.stderr, flush=True)
    except BaseException as err:
        # The simulator's own CasADi calls may still turn Ctrl-C into a SystemError (outside
        # the MPC's steps): models.interrupts recognizes it, as every runner must.
        if not models.interrupts.is_interrupt(err) or attempt == int(sys.argv[1]) - 1:
            raise
        print("interrupted", flush=True)
"""
#: Offsets of the SIGINT after a run started, s: inside the solver, the estimator, the
#: simulator and CasADi's array conversions alike.
OFFSETS = [0.05 + 0.09 * k for k in range(12)]


def interrupt_script(tmp_path) -> tuple[Path, dict]:
    script = tmp_path / "run.py"
    script.write_text(RUN_UNTIL_INTERRUPTED)
    return script, dict(os.environ, PYTHONPATH=str(REPO), PYTHONDONTWRITEBYTECODE="1")


def test_ctrl_c_interrupts_every_run_of_a_session(tmp_path):
    """One process runs the nonlinear MPC loop again after each Ctrl-C: twelve SIGINTs at twelve
    offsets each end their run promptly with KeyboardInterrupt (never a finished run), and the
    last one, not caught, gives a non-zero exit. Before the fix about a third of the signals
    were swallowed (a "solver error" step and the run went on, or no trace at all)."""
    script, env = interrupt_script(tmp_path)
    process = subprocess.Popen(
        [sys.executable, str(script), str(len(OFFSETS))],
        cwd=tmp_path,
        env=env,
        text=True,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    try:
        for k, offset in enumerate(OFFSETS):
            assert process.stdout.readline().strip() == "running"
            time.sleep(offset)
            sent = time.perf_counter()
            process.send_signal(signal.SIGINT)
            if k < len(OFFSETS) - 1:
                line = process.stdout.readline().strip()
                if line != "interrupted":
                    process.kill()
                    pytest.fail(f"offset {offset:.2f} s: {line!r}; stderr: {process.communicate()[1][-2000:]}")
                assert time.perf_counter() - sent < 5.0, f"offset {offset:.2f} s: not stopped promptly"
        out, err = process.communicate(timeout=60)
    finally:
        process.kill()
    assert process.returncode != 0 and "finished" not in out
    assert "KeyboardInterrupt" in err


@pytest.mark.slow
def test_ctrl_c_stops_a_nonlinear_mpc_run_at_every_offset(tmp_path):
    """As above with a fresh process per signal: twelve processes, each interrupted once at
    its own offset, all end promptly with a non-zero status and a KeyboardInterrupt."""
    script, env = interrupt_script(tmp_path)
    outcomes = []
    for batch in (OFFSETS[:4], OFFSETS[4:8], OFFSETS[8:]):
        processes = [
            subprocess.Popen(
                [sys.executable, str(script), "1"],
                cwd=tmp_path,
                env=env,
                text=True,
                stdout=subprocess.PIPE,
                stderr=subprocess.PIPE,
            )
            for _ in batch
        ]
        started = []
        for process in processes:
            assert process.stdout.readline().strip() == "running"
            started.append(time.perf_counter())
        sent = []
        for process, begun, offset in sorted(zip(processes, started, batch), key=lambda item: item[1] + item[2]):
            time.sleep(max(0.0, begun + offset - time.perf_counter()))
            process.send_signal(signal.SIGINT)
            sent.append((process, time.perf_counter(), offset))
        for process, when, offset in sent:
            out, err = process.communicate(timeout=60)
            outcomes.append((offset, process.returncode, time.perf_counter() - when, out, err))
    for offset, code, delay, out, err in outcomes:
        assert code != 0, f"offset {offset:.2f} s: exit 0\n{out}\n{err[-2000:]}"
        assert "finished" not in out
        assert "KeyboardInterrupt" in err, err[-2000:]
        assert delay < 20.0, f"offset {offset:.2f} s: stopped {delay:.1f} s after the signal"


def test_casadi_reports_of_an_interrupt_are_recognized():
    """CasADi's forms of a Ctrl-C (seen in the runs above) are interrupts; other errors are not."""
    casadi_report = RuntimeError(
        "Error in Function::call for 'nmpc' [Sqpmethod] at .../function.cpp:1655:\n"
        ".../function.cpp:514:\nKeyboardInterrupt"
    )
    assert models.interrupts.is_interrupt(casadi_report)
    wrapped = SystemError("<function DM.__array__> returned a result with an exception set")
    wrapped.__cause__ = KeyboardInterrupt()
    assert models.interrupts.is_interrupt(wrapped)
    assert not models.interrupts.is_interrupt(RuntimeError("Error in Function::call: NaN detected"))


# ---------------------------------------------------------------------------- non-finite values
def start(kind: str, name: str = "pendulum"):
    """A controller of `kind` on plant `name`, its initial state at the equilibrium, and (y, r)."""
    plant = models.get(name)
    controller = build(kind, name)
    y = plant.output(plant.equilibrium()[0])
    r = np.array([0.3])
    xc = controller.initial_state(y, r)
    for _ in range(3):  # leave the initial plan: a non-trivial plan to fall back on
        xc, _ = controller.step(xc, y, r)
        assert controller.step_info()["success"]
    return plant, controller, xc, y, r


@pytest.mark.parametrize("kind", ["linear", "nonlinear"])
def test_a_nan_estimate_is_reported_and_never_optimal(kind):
    plant, controller, xc, y, r = start(kind)
    nx, nu, n = plant.nx, plant.nu, controller.horizon
    xc = xc.copy()
    xc[1] = np.nan  # the estimator's state
    for _ in range(4):
        plan = xc[nx + nu :].reshape(n, nu)
        xc, u = controller.step(xc, y, r)
        info = controller.step_info()
        assert info["status"] == "non-finite estimate"
        assert not info["success"] and info["fallback"]
        # The shifted plan is followed: a finite command, never NaN, within the limit.
        np.testing.assert_array_equal(u, np.clip(plan[1], -plant.input_limit, plant.input_limit))
        assert np.all(np.isfinite(u))


@pytest.mark.parametrize("kind", ["linear", "nonlinear"])
def test_a_nan_measurement_is_skipped_the_prediction_used_and_the_next_one_recovers(kind):
    plant, controller, xc, y, r = start(kind)
    nx, nu, n = plant.nx, plant.nu, controller.horizon
    plan = xc[nx + nu :].reshape(n, nu)
    x_pred, d_pred = xc[:nx].copy(), xc[nx : nx + nu].copy()
    bad = y.copy()
    bad[0] = np.nan
    xc_next, u = controller.step(xc, bad, r)
    info = controller.step_info()
    assert info["status"] == "non-finite measurement" and not info["success"] and info["fallback"]
    np.testing.assert_array_equal(u, plan[1])
    # The estimate is the prediction, carried one sample on by the model, uncorrected.
    if kind == "linear":
        model = controller.model
        expected = model.A @ x_pred + model.B @ (u - model.ue + d_pred)
    else:
        expected = np.asarray(controller.step_model(x_pred, u + d_pred, controller.plant.param_vector())).ravel()
    np.testing.assert_allclose(xc_next[:nx], expected, rtol=1e-12, atol=1e-14)
    np.testing.assert_array_equal(xc_next[nx : nx + nu], d_pred)
    _, u = controller.step(xc_next, y, r)
    assert controller.step_info()["success"] and controller.step_info()["status"] != "non-finite measurement"


class NaNButOptimal(mpc.CondensedDaqpSolver):
    """Reports "optimal" with a NaN plan, as a solver fed NaN data may."""

    def solve(self, params):
        solution = super().solve(params)
        return QPSolution(np.full_like(solution.inputs, np.nan), solution.slacks, True, "optimal", 1, 0.0)


def test_a_nan_answer_reported_optimal_is_a_failure():
    plant = models.get("arm")
    controller = build("linear", "arm", solver=NaNButOptimal)
    result = models.simulate_closed_loop(plant, controller, 0.3, 0.1)
    assert all(s["status"] == "non-finite solution (solver: optimal)" for s in result.status)
    assert not any(s["success"] for s in result.status) and all(s["fallback"] for s in result.status)
    assert np.all(np.isfinite(result.u))


@pytest.mark.parametrize("kind", ["linear", "nonlinear"])
def test_a_nan_command_is_reported_not_passed_off(kind):
    plant, controller, xc, y, r = start(kind, "arm")
    nx, nu = plant.nx, plant.nu
    xc = xc.copy()
    xc[0] = np.nan  # no solve ...
    xc[nx + nu :] = np.nan  # ... and no plan to fall back on
    _, u = controller.step(xc, y, r)
    info = controller.step_info()
    assert np.all(np.isnan(u))
    assert info["status"] == "non-finite command (non-finite estimate)" and not info["success"]


class DropsMeasurement:
    """A controller that loses the measurement at sample `k` (a sensor glitch)."""

    def __init__(self, controller, k):
        self.controller, self.k, self.calls = controller, k, 0
        self.sample_period, self.measures = controller.sample_period, controller.measures
        self.n_reference, self.name = controller.n_reference, controller.name

    def initial_state(self, y0, r0):
        self.calls = 0
        return self.controller.initial_state(y0, r0)

    def step(self, xc, y, r):
        self.calls += 1
        return self.controller.step(xc, np.full_like(y, np.nan) if self.calls - 1 == self.k else y, r)

    def step_info(self):
        return self.controller.step_info()


def test_a_glitch_in_a_closed_loop_is_one_reported_step():
    plant = models.get("pendulum")
    clean = models.simulate_closed_loop(plant, build("linear", "pendulum"), 0.5, 1.0)
    glitch = models.simulate_closed_loop(plant, DropsMeasurement(build("linear", "pendulum"), 30), 0.5, 1.0)
    statuses = [s["status"] for s in glitch.status]
    assert statuses[30] == "non-finite measurement"
    assert all(s["success"] for k, s in enumerate(glitch.status) if k != 30)
    np.testing.assert_array_equal(glitch.u[:30], clean.u[:30])
    assert np.all(np.isfinite(glitch.u)) and glitch.diverged_at is None
    # The loop recovers: one sample without a measurement barely moves the end state.
    np.testing.assert_allclose(glitch.x[-1], clean.x[-1], atol=1e-2)


# ---------------------------------------------------------------------------- clear errors
def pendulum():
    return models.get("pendulum")


ERRORS = [
    # (what to call, exception type, the culprit as a regex)
    (
        lambda: build("linear", "pendulum", solver="gurobi"),
        ValueError,
        r"solver must be one of 'daqp', 'osqp', 'cvxpy' or a callable problem -> solver, got 'gurobi'",
    ),
    (
        lambda: build("nonlinear", "arm", iteration="newton"),
        ValueError,
        r"iteration must be one of 'rti', 'sqp', got 'newton'",
    ),
    (
        lambda: SoftBound.on(pendulum(), {"theta": 1.0}, 0.2, -0.2),
        ValueError,
        r"soft bound '\+1 theta': lower 0.2 > upper -0.2",
    ),
    (lambda: build("linear", "pendulum", solver=42), ValueError, r"solver must be one of .*got 42"),
    (
        lambda: build("linear", "pendulum", solver=lambda problem: object()),
        ValueError,
        r"made object, which has no solve or reset method",
    ),
    (lambda: build("linear", "pendulum", horizon=True), TypeError, r"horizon must be an integer, got bool True"),
    (lambda: build("linear", "pendulum", horizon=2.5), ValueError, r"horizon must be an integer, got 2.5"),
    (lambda: build("linear", "pendulum", horizon="50"), TypeError, r"horizon must be an integer, got str '50'"),
    (lambda: build("linear", "pendulum", sample_period="0.01"), TypeError, r"sample_period \(s\) must be a real"),
    (lambda: build("nonlinear", "arm", sample_period=float("nan")), ValueError, r"sample_period \(s\) must be .* nan"),
    (
        lambda: mpc.NonlinearMPCProblem(models.get("arm"), 0.01, 10, 1.0, 1.0, substeps=2.7),
        ValueError,
        r"substeps must be an integer, got 2.7",
    ),
    (lambda: build("nonlinear", "arm", max_iterations=2.5), ValueError, r"max_iterations must be an integer, got 2.5"),
    (lambda: build("nonlinear", "arm", max_iterations=0), ValueError, r"max_iterations must be an integer >= 1, got 0"),
    (
        lambda: mpc.NonlinearMPCProblem(models.get("arm"), 0.01, 10, 1.0, 1.0, tolerance=-1e-4),
        ValueError,
        r"tolerance must be a finite number > 0, got -0.0001",
    ),
    (lambda: SoftBound.on(pendulum(), {"theta": 1.0}, np.nan, 0.2), ValueError, r"bounds must not be NaN"),
    (lambda: SoftBound.on(pendulum(), {"theta": 1.0}, -np.inf, np.inf), ValueError, r"has no finite side"),
    (lambda: SoftBound.on(pendulum(), {}, -1, 1), ValueError, r"combination is empty"),
    (lambda: SoftBound.on(pendulum(), ["theta"], -1, 1), TypeError, r"combination must be a mapping"),
    (lambda: SoftBound.on(pendulum(), {"theta": "one"}, -1, 1), TypeError, r"coefficient of theta must hold real"),
    (lambda: SoftBound.on(pendulum(), {"theta": 0.0}, -1, 1), ValueError, r"needs finite coefficients, not all zero"),
    (
        lambda: SoftBound.on(pendulum(), {"theta": 1.0}, -1, 1, linear_weight=-5),
        ValueError,
        r"linear_weight must be finite and >= 0, got -5.0",
    ),
    (lambda: SoftBound.on(pendulum(), {"theta": 1.0}, -1, "1"), TypeError, r"upper must hold real numbers, got '1'"),
    (
        lambda: CvxpySolver(build("linear", "arm").problem, solver="GUROBI"),
        ValueError,
        r"solver 'GUROBI' is not an installed cvxpy solver",
    ),
    (
        lambda: mpc.OsqpSolver(build("linear", "arm").problem, {"eps_abs": -1.0}),
        ValueError,
        r"OSQP setting eps_abs must be a number >= 0, got -1.0",
    ),
    (
        lambda: mpc.OsqpSolver(build("linear", "arm").problem, {"max_iter": "many"}),
        TypeError,
        r"OSQP setting max_iter must be a number or True/False, got str 'many'",
    ),
    (
        lambda: mpc.CondensedDaqpSolver(build("linear", "arm").problem, iteration_limit=0.5),
        ValueError,
        r"iteration_limit must be an integer, got 0.5",
    ),
    (lambda: build("linear", "pendulum", state_weight="heavy"), TypeError, r"state_weight Q must hold real numbers"),
    (lambda: build("linear", "pendulum", rate_limit="fast"), TypeError, r"rate_limit must hold real numbers"),
    (
        lambda: build("linear", "pendulum", soft_bounds=[("theta", -1, 1)]),
        TypeError,
        r"soft_bounds must be SoftBound objects",
    ),
    (
        lambda: mpc.LinearMPC(
            "pendulum", sample_period=0.01, horizon=10, state_weight=1.0, input_weight=1.0, tracked="z"
        ),
        TypeError,
        r"known must be a models.Plant, got str 'pendulum'",
    ),
    (
        lambda: DisturbanceObserver(np.eye(2), np.ones((2, 1)), np.ones((1, 3)), 1.0, 1.0, 1.0),
        ValueError,
        r"C \(1, 3\)",
    ),
    (
        lambda: DisturbanceObserver(np.eye(2), np.ones((2, 1)), np.ones((1, 2)), 1.0, 1.0, [1.0, 2.0, 3.0]),
        ValueError,
        r"measurement_std must be a number or 1 numbers",
    ),
]


@pytest.mark.parametrize("call, error, culprit", ERRORS, ids=[e[2][:40] for e in ERRORS])
def test_bad_input_gets_a_one_line_error_naming_the_culprit(call, error, culprit):
    with pytest.raises(error, match=culprit) as raised:
        call()
    assert "\n" not in str(raised.value)


@pytest.mark.parametrize(
    "y, error, culprit",
    [
        ("abc", TypeError, r"measurement \('z', 'theta'\) must hold real numbers, got 'abc'"),
        (np.zeros(3), ValueError, r"measurement \('z', 'theta'\) must have 2 entries"),
    ],
)
def test_bad_step_input_gets_a_one_line_error(y, error, culprit):
    controller = build("linear", "pendulum")
    xc = controller.initial_state(np.zeros(2), np.zeros(1))
    with pytest.raises(error, match=culprit) as raised:
        controller.step(xc, y, np.zeros(1))
    assert "\n" not in str(raised.value)
