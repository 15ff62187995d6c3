"""A single run longer than `models.closed_loop.RUN_BLOCK_STEPS` runs a block of steps per call: the same
bits as the whole run's Function in one call."""

import casadi as ca
import numpy as np

import models
from models import closed_loop
from models.run_setup import RunSetup


class ClampedPI(models.Block):
    """u = kp e + ki x_c with the integral clamped to |x_c| < 1 (a test fixture with state and a switch)."""

    def __init__(self):
        super().__init__(
            sample_period=0.01, n_state=1, n_measured=2, n_reference=1, n_input=1, gains={"kp": 4.0, "ki": 2.0}
        )

    def expr(self, xc, y, r, g):
        e = r[0] - y[0]
        integral = ca.if_else(ca.fabs(xc[0] + 0.01 * e) < 1.0, xc[0] + 0.01 * e, xc[0])
        return integral, g["kp"] * e + g["ki"] * integral + 40.0 * y[1]


def test_a_run_in_blocks_is_the_whole_runs_function_bit_for_bit(monkeypatch):
    """53 steps in blocks of 7 (the last one padded), noise and disturbance included, against the whole
    run's `closed_loop_function` called once on the same inputs."""
    pend = models.get("pendulum")
    block = ClampedPI()
    kw = dict(noise_std=1e-3, seed=3, input_disturbance=0.1, substeps=2)
    monkeypatch.setattr(closed_loop, "RUN_BLOCK_STEPS", 7)
    blocked = models.simulate_closed_loop(pend, block, 0.3, 0.53, allow_divergence=True, **kw)
    assert blocked.u.shape == (53, 1) and np.ptp(blocked.u) > 0.1
    noise = RunSetup.build(pend, block, 0.3, 0.53, **kw).noise()
    whole = closed_loop.closed_loop_function(pend, block, 53, 2)
    X, XC, U, _ = (
        np.asarray(a)
        for a in whole(
            blocked.x[0],
            blocked.xc[0],
            blocked.r[:-1].T,
            noise.T,
            blocked.d.T,
            pend.param_vector(),
            block.gain_vector(),
        )
    )
    np.testing.assert_array_equal(blocked.x[1:], X.T)
    np.testing.assert_array_equal(blocked.xc[1:], XC.T)
    np.testing.assert_array_equal(blocked.u, U.T)
    monkeypatch.setattr(closed_loop, "RUN_BLOCK_STEPS", 1024)
    one_call = models.simulate_closed_loop(pend, block, 0.3, 0.53, allow_divergence=True, **kw)
    for name in ("x", "xc", "u", "measured", "y"):
        np.testing.assert_array_equal(getattr(blocked, name), getattr(one_call, name), err_msg=name)
