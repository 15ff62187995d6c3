"""Tube MPC exported as C (mpc.export.export_linear_mpc on a TubeMPC): the C closed loop on the true
pendulum gives the Python TubeMPC's commands to 1e-9 at every sample of a 10 s run, on the tube of
benchmarks/robust_mpc.py (the known model's linearization, the text's 0.5 N input disturbance, the
stiff ancillary LQR, the cart travel ±0.5 m); the exported init refuses a first state where the
tightened problem is infeasible, as the Python one does; a changed tube law is refused by name."""

from __future__ import annotations

import ctypes

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


def test_exported_init_refuses_where_the_tightened_problem_is_infeasible(pendulum):
    """A cart 0.49 m out, moving outwards at 2 m/s: Python's feasibility LP refuses it, and so does the C."""
    python = tube_mpc(pendulum)
    compiled = export_linear_mpc(python, "tube_far").load()
    far = np.array([0.49, 0.0, 2.0, 0.0])
    with pytest.raises(ValueError, match="the tightened problem is infeasible"):
        python.initial_state(far)
    with pytest.raises(ValueError, match=r"init returned 3 \(QP infeasible\)"):
        compiled.initial_state(far, [0.0])
    np.testing.assert_allclose(compiled.initial_state(START, [0.0]), python.initial_state(START), atol=0, rtol=0)


def test_a_tube_mpc_whose_law_is_changed_is_not_exported(pendulum):
    class Clipped(TubeMPC):
        def step(self, xc, y, r=None):
            xc_next, u = super().step(xc, y, r)
            return xc_next, np.clip(u, -1.0, 1.0)

    _, _, model, tube, _ = pendulum
    changed = Clipped(model, tube, horizon=5, state_weight=COST[0], input_weight=COST[1], name="clipped tube")
    with pytest.raises(UnsupportedExport, match=r"clipped tube: Clipped overrides TubeMPC\.step; the export writes"):
        export_linear_mpc(changed, "clipped")


def test_the_exported_qp_is_the_python_one(pendulum):
    """name_solve_qp against TubeMPC.solve from states inside and at the edge of the tightened set."""
    python = tube_mpc(pendulum)
    library = ctypes.CDLL(
        str(mc.build_library(export_linear_mpc(python, "qp").files(), (*mc.FLAGS, *build_flags()), fallback=False))
    )
    library.qp_state_size.restype = ctypes.c_ulong
    memory = ctypes.create_string_buffer(library.qp_state_size())
    library.qp_solve_qp.argtypes = [ctypes.c_void_p] * 3
    rng = np.random.default_rng(5)
    for z0 in [START, np.zeros(4), *rng.uniform(-0.2, 0.2, (6, 4)) * [1.0, 0.5, 1.0, 1.0]]:
        plan, success, _, _ = python.solve(z0)
        z0 = np.ascontiguousarray(z0, dtype=float)
        out = np.zeros(python.qp.n)
        code = library.qp_solve_qp(ctypes.addressof(memory), z0.ctypes.data, out.ctypes.data)
        assert (code == 0) == success
        if success:
            np.testing.assert_allclose(out, plan.ravel(), atol=1e-9, rtol=0)
