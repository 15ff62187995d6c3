"""models.LinearPlant: a python-control model with limits gets the same linear designs as the declared plant."""

import control
import numpy as np
import pytest

from designs import statespace_design as ssd
from designs.loops import cascade_plants
from designs.pid import PID, pd_design
from models.linear_plant import LinearPlant
from mpc import LinearMPC

TS = 0.01
POLES = np.array([-1.5 + 1j, -1.5 - 1j, -0.4 + 0.3j, -0.4 - 0.3j])
Q = np.diag([10.0, 10.0, 1.0, 1.0, 5.0])
R = np.array([[1.0]])


def test_the_adapter_answers_as_the_declared_plant(pendulum_plants):
    declared, user = pendulum_plants
    a, b = declared.linearize(), user.linearize()
    for key in ("A", "B", "C", "D", "xe", "ue", "ye"):
        np.testing.assert_array_equal(getattr(a, key), getattr(b, key))
    assert (user.coordinate_names, user.state_names, user.nq) == (
        declared.coordinate_names,
        declared.state_names,
        declared.nq,
    )
    np.testing.assert_array_equal(user.input_limit, declared.input_limit)
    y = declared.output(a.xe + np.array([0.3, -0.1, 0, 0]))
    q_user = np.asarray(user.casadi_configuration(y, user.param_vector())).ravel()
    q_declared = np.asarray(declared.casadi_configuration(y, declared.param_vector())).ravel()
    np.testing.assert_allclose(q_user, q_declared, atol=1e-12)


def test_a_transfer_function_becomes_a_state_space_plant():
    G = control.tf([2.0], [1.0, 0.5, 3.0])
    plant = LinearPlant(G, 1.5, name="oscillator")
    lin = plant.linearize()
    np.testing.assert_allclose(control.dcgain(lin.ss()), 2.0 / 3.0, rtol=1e-12)
    assert (plant.nq, plant.nu, plant.input_limit.tolist()) == (1, 1, [1.5])
    with pytest.raises(TypeError, match="StateSpace or TransferFunction"):
        LinearPlant(np.eye(2), 1.0)


def test_state_space_and_lqr_designs_match_the_declared_plant(pendulum_plants):
    designs = [ssd.design(p, "z", poles=POLES, Q=Q, R=R, sample_period=TS) for p in pendulum_plants]
    for key in (
        "K",
        "kr",
        "K_integral",
        "ki",
        "L",
        "L_discrete",
        "L_disturbance",
        "K_lqr",
        "ki_lqr",
        "P_lqr",
        "K_dlqr",
        "L_kalman",
    ):
        np.testing.assert_allclose(getattr(designs[1], key), getattr(designs[0], key), rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(np.sort_complex(designs[1].lqr_poles), np.sort_complex(designs[0].lqr_poles), atol=1e-9)
    # The LQR blocks command the same input on the same measurement (at the operating configuration,
    # where the declared plant's nonlinear remainder of the equilibrium input vanishes).
    blocks = [ssd.controllers(d)["LQR"] for d in designs]
    x = designs[0].model.linear.xe + np.array([0.0, 0.0, 0.2, -0.1])
    r = np.array([0.5])
    u = [blk.step(blk.initial_state(x, r), x, r)[1] for blk in blocks]  # the LQR block measures the state
    np.testing.assert_allclose(u[1], u[0], rtol=1e-9, atol=1e-12)
    assert abs(u[0][0]) > 1e-3


def test_linear_mpc_matches_the_declared_plant(pendulum_plants):
    kwargs = dict(sample_period=0.05, horizon=20, state_weight=[10.0, 10.0, 1.0, 1.0], input_weight=0.1, tracked="z")
    controllers = [LinearMPC(p, **kwargs) for p in pendulum_plants]
    for key in ("A", "B", "C"):
        np.testing.assert_allclose(getattr(controllers[1].model, key), getattr(controllers[0].model, key), rtol=1e-12)
    y0 = pendulum_plants[0].output(pendulum_plants[0].linearize().xe + np.array([0.1, 0.05, 0.0, 0.0]))
    commands = []
    for c in controllers:
        xc = c.initial_state(y0, np.array([0.0]))
        for r in (0.5, 0.5, 0.5):
            xc, u = c.step(xc, y0, np.array([r]))
            commands.append(u)
    n = len(commands) // 2
    np.testing.assert_allclose(np.array(commands[n:]), np.array(commands[:n]), rtol=1e-9, atol=1e-12)
    assert np.min(np.abs(commands[:n])) > 1e-3


def test_pd_loops_match_the_declared_plant(pendulum_plants):
    cascades = [cascade_plants(p, "theta", "z") for p in pendulum_plants]
    for part in ("inner", "outer"):
        for a, b in zip(control.tfdata(getattr(cascades[0], part)), control.tfdata(getattr(cascades[1], part))):
            np.testing.assert_allclose(np.asarray(b[0][0]), np.asarray(a[0][0]), rtol=1e-9, atol=1e-12)
    pds = [pd_design(c.inner, zeta=0.7, wn=4.0) for c in cascades]
    assert (pds[1].kp, pds[1].kd) == pytest.approx((pds[0].kp, pds[0].kd), rel=1e-9)
    blocks = [
        PID(p, "theta", kp=pd.kp, kd=pd.kd, sample_period=TS, sigma=0.05, output_limit=5.0)
        for p, pd in zip(pendulum_plants, pds)
    ]
    y = pendulum_plants[0].output(pendulum_plants[0].linearize().xe + np.array([0.2, 0.1, 0.0, 0.0]))
    r = np.array([0.3])
    u = [blk.step(blk.initial_state(y, r), y, r)[1] for blk in blocks]
    np.testing.assert_allclose(u[1], u[0], rtol=1e-9, atol=1e-12)
    assert abs(u[0][0]) > 1e-3
