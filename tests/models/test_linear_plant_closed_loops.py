"""A python-control StateSpace plant with actuator limits (`models.LinearPlant`) gets a PID, an LQR and a linear
MPC whose closed loops on the true pendulum match, to 1e-9, those of the same designs on the declared plant it
is the linearization of; and python-control's own closed loop of the user's LQR has the design's poles."""

import control
import numpy as np

import models
from designs import statespace_design as ssd
from designs.loops import cascade_plants
from designs.pid import PID, pd_design
from mpc import LinearMPC

TS = 0.01
POLES = np.array([-1.5 + 1j, -1.5 - 1j, -0.4 + 0.3j, -0.4 - 0.3j])
Q = np.diag([10.0, 10.0, 1.0, 1.0, 5.0])
R = np.array([[1.0]])
#: Every closed loop starts off the equilibrium and is asked to move the cart.
X0 = np.array([0.0, 0.05, 0.0, 0.0])
REFERENCE = 0.2


def closed_loops(truth, controllers, reference, duration):
    """One run of each controller on `truth` from X0 (about its equilibrium)."""
    x0 = truth.linearize().xe + X0
    return [models.simulate_closed_loop(truth, c, reference, duration, x0=x0) for c in controllers]


def assert_same_runs(runs):
    a, b = runs
    assert a.diverged_at is None and b.diverged_at is None
    np.testing.assert_allclose(b.u, a.u, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(b.x, a.x, rtol=1e-9, atol=1e-9)
    assert np.max(np.abs(a.u)) > 1e-2  # the loops did something


def test_the_pid_closed_loops_match(pendulum_plants):
    pds = [pd_design(cascade_plants(p, "theta", "z").inner, zeta=0.7, wn=4.0) for p in pendulum_plants]
    blocks = [
        PID(p, "theta", kp=pd.kp, kd=pd.kd, ki=0.5, sample_period=TS, sigma=0.05, output_limit=5.0)
        for p, pd in zip(pendulum_plants, pds)
    ]
    assert_same_runs(closed_loops(pendulum_plants[0], blocks, 0.0, 2.0))


def test_the_lqr_closed_loops_match_and_python_control_has_its_poles(pendulum_plants):
    designs = [ssd.design(p, "z", poles=POLES, Q=Q, R=R, sample_period=TS) for p in pendulum_plants]
    assert_same_runs(closed_loops(pendulum_plants[0], [ssd.controllers(d)["LQR"] for d in designs], REFERENCE, 3.0))
    # The user's model and gain closed in python-control: the integrator-augmented loop's poles.
    user = pendulum_plants[1].linearize()
    i = user.state_names.index("z")
    A = np.block([[user.A, np.zeros((4, 1))], [np.eye(4)[[i]], np.zeros((1, 1))]])
    B = np.vstack([user.B, np.zeros((1, 1))])
    K = np.hstack([np.atleast_2d(designs[1].K_lqr), np.atleast_2d(designs[1].ki_lqr)])
    poles = control.poles(control.ss(A - B @ K, B, np.eye(5), 0))
    np.testing.assert_allclose(np.sort_complex(poles), np.sort_complex(designs[0].lqr_poles), rtol=1e-8, atol=1e-9)


def test_the_linear_mpc_closed_loops_match(pendulum_plants):
    kwargs = dict(sample_period=0.05, horizon=20, state_weight=[10.0, 10.0, 1.0, 1.0], input_weight=0.1, tracked="z")
    controllers = [LinearMPC(p, **kwargs) for p in pendulum_plants]
    assert_same_runs(closed_loops(pendulum_plants[0], controllers, REFERENCE, 2.0))
