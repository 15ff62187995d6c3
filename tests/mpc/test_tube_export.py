"""Tube MPC exported as C (mpc.export.export_linear_mpc on a TubeMPC): the C closed loop on the true
pendulum gives the Python TubeMPC's commands to 1e-9 at every sample of a 10 s run, on the tube of
benchmarks/robust_mpc.py (the known model's linearization, the text's 0.5 N input disturbance, the
stiff ancillary LQR, the cart travel ±0.5 m; slow: that tube's sets take about 9 s of CPU). In the
default suite, on the double integrator of test_tube_mpc: the C's commands and nominal states against
the Python ones under disturbances at W's corners, its QP against TubeMPC.solve, the exported init
refusing a first state where the tightened problem is infeasible as the Python one does, and a
changed tube law refused by name."""

from __future__ import annotations

import ctypes
from types import SimpleNamespace

import numpy as np
import pytest

import models
import studies
from models import compile as mc
from models.export import UnsupportedExport
from models.uncertainty import sample_params
from mpc.export import build_flags, export_linear_mpc
from mpc.sets import Polytope, Zonotope
from mpc.tube import TubeOptions, ancillary_feedback, build_tube, disturbance_set
from mpc.tube_mpc import TubeMPC, nominal_sets

#: benchmarks/robust_mpc.py's pendulum tube: horizon, region (z, θ, ż, θ̇), nominal cost, ancillary LQR, start.
HORIZON = 50
REGION = np.array([0.5, 0.2, 2.0, 2.0])
COST = (np.diag([1.0, 10.0, 0.1, 0.1]), 1e-2)
ANCILLARY = (np.diag([100.0, 100.0, 1.0, 1.0]), 1e-2)
START = np.array([0.35, 0.0, 0.3, 0.0])
DURATION = 10.0
#: tests/mpc/test_tube_mpc.py's double integrator: sample period (s) and W.
SAMPLE_PERIOD = 0.1
W_BOX = Zonotope.box([-0.01, -0.02], [0.01, 0.02])


@pytest.fixture(autouse=True)
def private_cache(tmp_path_factory, monkeypatch):
    monkeypatch.setenv("CODESIGN_CONTROL_CACHE", str(tmp_path_factory.getbasetemp() / "compile-cache"))


@pytest.fixture(scope="module")
def pendulum():
    """(plant, case, model, tube sets, nominal twin's sets) of the benchmark's pendulum tube."""
    plant, case = models.get("pendulum"), studies.get("pendulum")
    known = case.known_plant(plant)
    xe, ue = known.equilibrium()
    model = known.linearize(xe, ue).discretize(case.sample_period)
    A, B, umax = model.A, model.B, plant.input_limit
    K = ancillary_feedback(A, B, *ANCILLARY)
    X = Polytope.box(-REGION, REGION)
    W = disturbance_set(A, B, input_bound=case.input_disturbance).plus(
        Zonotope.box(-1e-6 * np.ones(4), 1e-6 * np.ones(4))
    )
    tube = build_tube(A, B, W, X, -umax, umax, feedback=K, options=TubeOptions(facet_limit=0))
    return plant, case, model, tube, nominal_sets(A, B, K, X, -umax, umax)


def tube_mpc(pendulum, replan=False, **kwargs):
    _, _, model, tube, twin = pendulum
    return TubeMPC(
        model,
        twin if replan else tube,
        horizon=HORIZON,
        state_weight=COST[0],
        input_weight=COST[1],
        replan=replan,
        **kwargs,
    )


@pytest.mark.slow
@pytest.mark.parametrize("replan", [False, True], ids=["tube", "nominal twin"])
def test_exported_tube_mpc_gives_the_python_commands_over_a_10_s_run(pendulum, replan):
    """On a ±5 % sample of the true pendulum with the 0.5 N disturbance, so that the error x − z
    moves and the ancillary law acts; the first 0.5 s ride the tightened cart bound."""
    plant, case, *_ = pendulum
    python = tube_mpc(pendulum, replan)
    compiled = export_linear_mpc(python, "tube").load()
    params = sample_params(plant, 1, seed=0)[0]
    runs = [
        models.simulate_closed_loop(
            plant, c, 0.0, DURATION, x0=START, params=params, input_disturbance=case.input_disturbance
        )
        for c in (python, compiled)
    ]
    assert len(runs[0].u) == round(DURATION / python.sample_period)
    np.testing.assert_allclose(runs[1].u, runs[0].u, atol=1e-9, rtol=0)
    assert compiled.step_info()["code"] == 0
    u = runs[0].u[:, 0]
    assert np.ptp(u) > 1.0  # the run moves: not a loop at rest
    if not replan:  # the plan rides the tightened input or state bounds somewhere in the run
        assert np.max(np.abs(u)) > 0.5 * plant.input_limit[0]


@pytest.fixture(scope="module")
def double_integrator():
    """The double integrator of tests/mpc/test_tube_mpc.py: its tube (W a box, |x_i| <= 1, |u| <= 1) and model."""
    A = np.array([[1.0, SAMPLE_PERIOD], [0.0, 1.0]])
    B = np.array([[SAMPLE_PERIOD**2 / 2], [SAMPLE_PERIOD]])
    model = SimpleNamespace(A=A, B=B, xe=np.zeros(2), ue=np.zeros(1), sample_period=SAMPLE_PERIOD)
    tube = build_tube(
        A, B, W_BOX, Polytope.box([-1.0, -0.5], [1.0, 0.5]), [-1.0], [1.0], state_weight=np.eye(2), input_weight=1.0
    )
    return model, tube


def small_tube_mpc(double_integrator, **kwargs):
    model, tube = double_integrator
    return TubeMPC(model, tube, horizon=15, state_weight=np.diag([100.0, 1e-2]), input_weight=1e-2, **kwargs)


def test_exported_tube_mpc_gives_the_python_commands_under_disturbances_in_w(double_integrator):
    """x⁺ = A x + B u + w with w at W's corners: the C's commands and nominal states are the Python
    ones to 1e-9 over 60 samples that ride the velocity bound and saturate the input."""
    model, tube = double_integrator
    python = small_tube_mpc(double_integrator, name="small tube")
    compiled = export_linear_mpc(python, "small_tube").load()
    rng, x = np.random.default_rng(2), np.array([0.6, 0.0])
    corners = W_BOX.corners()
    z_python, z_c = python.initial_state(x), compiled.initial_state(x, [0.0])
    moves = []
    for _ in range(60):
        z = z_python
        (z_python, u_python), (z_c, u_c) = python.step(z, x), compiled.step(z_c, x, [0.0])
        np.testing.assert_allclose(u_c, u_python, atol=1e-9, rtol=0)
        np.testing.assert_allclose(z_c, z_python, atol=1e-9, rtol=0)
        assert compiled.step_info()["code"] == 0
        moves.append(float(u_python[0] - tube.feedback[0] @ (x - z)))  # v_0
        x = model.A @ x + model.B @ u_python + corners[rng.integers(len(corners))]
    assert min(moves) <= tube.input_lower[0] + 1e-9  # the plan reaches the tightened input bound
    assert not np.allclose(z_python, x)  # the error x − z is not zero: the ancillary law acts


def test_exported_tracking_tube_mpc_gives_the_python_commands_across_reference_changes(double_integrator):
    """Tracking the position through references within reach, beyond the limit and back, with w at
    W's corners: the C's commands, nominal states and QP solutions (the plan and θ) are the Python
    ones to 1e-9; a non-finite reference is refused with its status and a NaN command."""
    model, tube = double_integrator
    python = small_tube_mpc(double_integrator, tracked_rows=[[1.0, 0.0]], name="tracking tube")
    compiled = export_linear_mpc(python, "tracking_tube").load()
    assert compiled.n_reference == 1
    rng, x = np.random.default_rng(4), np.array([0.1, 0.0])
    corners = W_BOX.corners()
    references = np.concatenate([np.full(40, 0.5), np.full(40, 3.0), np.full(40, -0.8)])
    z_python, z_c = python.initial_state(x, references[:1]), compiled.initial_state(x, references[:1])
    targets = []
    for r in references:
        z = z_python
        (z_python, u_python), (z_c, u_c) = python.step(z, x, [r]), compiled.step(z_c, x, [r])
        np.testing.assert_allclose(u_c, u_python, atol=1e-9, rtol=0)
        np.testing.assert_allclose(z_c, z_python, atol=1e-9, rtol=0)
        assert compiled.step_info()["code"] == 0
        targets.append(python.step_info()["target"][0])
        x = model.A @ x + model.B @ u_python + corners[rng.integers(len(corners))]
    assert max(targets) < 1.0 < 3.0  # the far reference is held back to an admissible steady state
    _, u = compiled.step(z_c, x, [np.nan])
    assert np.isnan(u).all() and compiled.step_info()["code"] == 7 | 16


def test_exported_init_refuses_where_the_tightened_problem_is_infeasible(double_integrator):
    """0.95 m out, moving outwards at 0.45 m/s: too close to the position limit to stop inside the
    tightened set; Python's feasibility LP refuses it, and so does the C's init."""
    python = small_tube_mpc(double_integrator)
    compiled = export_linear_mpc(python, "tube_far").load()
    far = np.array([0.95, 0.45])
    with pytest.raises(ValueError, match="the tightened problem is infeasible"):
        python.initial_state(far)
    with pytest.raises(ValueError, match=r"init returned 3 \(QP infeasible\)"):
        compiled.initial_state(far, [0.0])
    near = np.array([0.3, 0.2])
    np.testing.assert_allclose(compiled.initial_state(near, [0.0]), python.initial_state(near), atol=0, rtol=0)


def test_a_tube_mpc_whose_law_is_changed_is_not_exported(double_integrator):
    class Clipped(TubeMPC):
        def step(self, xc, y, r=None):
            xc_next, u = super().step(xc, y, r)
            return xc_next, np.clip(u, -0.5, 0.5)

    model, tube = double_integrator
    changed = Clipped(model, tube, horizon=5, state_weight=np.eye(2), input_weight=1.0, name="clipped tube")
    with pytest.raises(UnsupportedExport, match=r"clipped tube: Clipped overrides TubeMPC\.step; the export writes"):
        export_linear_mpc(changed, "clipped")


def test_the_exported_qp_is_the_python_one(double_integrator):
    """name_solve_qp against TubeMPC.solve from states inside the tightened set and beyond it."""
    python = small_tube_mpc(double_integrator)
    files = export_linear_mpc(python, "qp").files()
    library = ctypes.CDLL(str(mc.build_library(files, (*mc.FLAGS, *build_flags()), fallback=False)))
    library.qp_state_size.restype = ctypes.c_ulong
    memory = ctypes.create_string_buffer(library.qp_state_size())
    library.qp_solve_qp.argtypes = [ctypes.c_void_p] * 3
    rng, failed = np.random.default_rng(5), 0
    for z0 in rng.uniform([-1.0, -0.6], [1.0, 0.6], (30, 2)):
        plan, success, _, _ = python.solve(z0)
        z0 = np.ascontiguousarray(z0, dtype=float)
        out = np.zeros(python.qp.n)
        code = library.qp_solve_qp(ctypes.addressof(memory), z0.ctypes.data, out.ctypes.data)
        assert (code == 0) == success
        failed += not success
        if success:
            np.testing.assert_allclose(out, plan.ravel(), atol=1e-9, rtol=0)
    assert 0 < failed < 30  # both kinds of state are among them
