"""Plants with first-order states beside (or instead of) Lagrangian coordinates, against
hand derivations, closed forms and exact discretizations.

State order x = (q, q̇, s): coordinates, their rates, then the first-order states.
"""

import casadi as ca
import numpy as np
import pytest
import scipy.linalg

import models
from models.simulate import simulate

MOTOR = {"J": 0.01, "b": 0.1, "K": 0.05, "R": 1.0, "L": 0.5}


def _motor_declaration(arm_mass=0.0):
    """DC motor with armature inductance: L di/dt = v − R i − K ω, J dω/dt = K i − b ω, angle θ.

    With `arm_mass` > 0 the motor also lifts a uniform rod of that mass and length 0.3 m
    (θ from level), so holding an angle needs current.
    """
    params = [models.Param(k, v, "SI") for k, v in MOTOR.items()]
    params.append(models.Param("m", arm_mass, "kg", positive=False))

    @models.declare(
        name="dc_motor",
        title="DC motor with inductance",
        coordinates=("theta",),
        inputs=("v",),
        first_order=("i",),
        params=tuple(params),
        input_limit=12.0,
        register=False,
    )
    def motor(q, dq, u, p, s):
        rod = p.m * 0.3**2 / 3
        return models.Physics(
            kinetic=(p.J + rod) * dq.theta**2 / 2,
            potential=p.m * 9.81 * 0.15 * ca.sin(q.theta),
            forces=[p.K * s.i - p.b * dq.theta],
            rates={"i": (u.v - p.R * s.i - p.K * dq.theta) / p.L},
            outputs={"theta": q.theta, "omega": dq.theta, "current": s.i},
        )

    return motor


@pytest.fixture(scope="module")
def motor():
    return models.Plant(_motor_declaration())


@models.declare(
    name="first_order_lag",
    title="x' = -b x + u",
    coordinates=(),
    inputs=("u",),
    first_order=("x",),
    params=(models.Param("b", 2.0, "1/s"),),
    input_limit=10.0,
    register=False,
)
def _lag(q, dq, u, p, s):
    return models.Physics(rates={"x": -p.b * s.x + u.u}, outputs={"x": s.x})


@pytest.fixture(scope="module")
def lag():
    return models.Plant(_lag)


def test_state_order_is_coordinates_rates_then_first_order_states(motor, lag):
    assert motor.state_names == ("theta", "dtheta", "i") and motor.nx == 3 and motor.nq == 1
    assert motor.n_first_order == 1 and motor.first_order_names == ("i",)
    assert lag.state_names == ("x",) and lag.nx == 1 and lag.nq == 0


def test_dc_motor_linearization_equals_the_hand_derivation(motor):
    J, b, K, R, L = (MOTOR[k] for k in ("J", "b", "K", "R", "L"))
    lin = motor.linearize()
    np.testing.assert_array_equal(lin.xe, [0, 0, 0])
    np.testing.assert_array_equal(lin.ue, [0])
    np.testing.assert_allclose(lin.A, [[0, 1, 0], [0, -b / J, K / J], [0, -K / L, -R / L]], rtol=1e-14, atol=0)
    np.testing.assert_allclose(lin.B, [[0], [0], [1 / L]], rtol=1e-14, atol=0)
    np.testing.assert_array_equal(lin.C, np.eye(3))  # outputs read the angle, the rate and the current


def test_dc_motor_transfer_function_is_the_textbook_one(motor):
    """Θ/V = K / (s ((J s + b)(L s + R) + K²))."""
    J, b, K, R, L = (MOTOR[k] for k in ("J", "b", "K", "R", "L"))
    G = motor.linearize().tf("theta", "v")
    den = np.polymul([1, 0], np.polyadd(np.polymul([J, b], [L, R]), [K**2]))
    num, got = np.ravel(G.num[0][0]), np.ravel(G.den[0][0])
    np.testing.assert_allclose(num / got[0], [K / den[0]], rtol=1e-10)
    np.testing.assert_allclose(got / got[0], den / den[0], rtol=1e-10, atol=1e-14)


def test_motor_lifting_an_arm_holds_an_angle_with_the_current_gravity_asks(motor):
    """At rest at θ: K i = m g ℓ/2 cos θ, v = R i; about it ω' gains m g ℓ/2 sin θ / J_total per rad."""
    plant = models.Plant(_motor_declaration(arm_mass=0.2))
    J, b, K, R, L = (MOTOR[k] for k in ("J", "b", "K", "R", "L"))
    theta, weight = 0.4, 0.2 * 9.81 * 0.15
    xe, ue = plant.equilibrium(theta=theta)
    current = weight * np.cos(theta) / K
    np.testing.assert_allclose(xe, [theta, 0.0, current], rtol=1e-12)
    np.testing.assert_allclose(ue, [R * current], rtol=1e-12)
    assert plant.equilibrium_input([theta])[0] == pytest.approx(R * current, rel=1e-12)
    J_total = J + 0.2 * 0.3**2 / 3
    lin = plant.linearize(xe, ue)
    np.testing.assert_allclose(
        lin.A,
        [[0, 1, 0], [weight * np.sin(theta) / J_total, -b / J_total, K / J_total], [0, -K / L, -R / L]],
        rtol=1e-12,
    )


def test_power_balance_of_the_motor(motor):
    """E = J ω²/2 (the mechanical part: the current stores none of it), dE/dt = ω (K i − b ω)."""
    rng = np.random.default_rng(4)
    K, b = MOTOR["K"], MOTOR["b"]
    for _ in range(10):
        x, u = rng.uniform(-1, 1, 3), rng.uniform(-12, 12, 1)
        assert motor.energy(x) == pytest.approx(MOTOR["J"] * x[1] ** 2 / 2, rel=1e-14)
        h = 1e-6
        xdot = motor.f(x, u)
        dE = (motor.energy(x + h * xdot) - motor.energy(x - h * xdot)) / (2 * h)
        assert dE == pytest.approx(x[1] * (K * x[2] - b * x[1]), rel=1e-7, abs=1e-12)


def test_configuration_is_recovered_from_the_outputs_that_depend_on_it_alone(motor):
    y = motor.output([0.7, -2.0, 0.3])
    np.testing.assert_allclose(y, [0.7, -2.0, 0.3])
    assert float(motor.casadi_configuration(y, motor.param_vector())) == pytest.approx(0.7, abs=1e-15)


@pytest.mark.parametrize("method", ["rk4", "adaptive", "collocation"])
def test_first_order_plant_matches_its_closed_form(lag, method):
    """x' = −b x + u with u held over each sample: x_{k+1} = e^{−b Ts} x_k + (1 − e^{−b Ts}) u_k / b."""
    b, ts = 2.0, 0.01
    u = np.sin(0.05 * np.arange(300))[:, None]
    phi = np.exp(-b * ts)
    exact = [0.7]
    for uk in u[:, 0]:
        exact.append(phi * exact[-1] + (1 - phi) / b * uk)
    run = simulate(lag, [0.7], u, ts, method=method)
    np.testing.assert_allclose(run.x[:, 0], exact, rtol=0, atol=1e-9)  # CVODES at 1e-12 drifts to ~1e-10


def test_first_order_plant_equilibria_and_linearization(lag):
    xe, ue = lag.equilibrium(x=1.5)
    np.testing.assert_allclose([xe[0], ue[0]], [1.5, 3.0], rtol=1e-12)
    xe, ue = lag.equilibrium(u=1.0)
    np.testing.assert_allclose(xe, [0.5], rtol=1e-12)
    lin = lag.linearize(xe, ue)
    np.testing.assert_array_equal(lin.A, [[-2.0]])
    np.testing.assert_array_equal(lin.B, [[1.0]])
    assert lag.energy([3.0]) == 0.0


class Proportional(models.Block):
    """u = k (r − y), reading the plant's first output."""

    def __init__(self, k, n_measured=1, measures="outputs"):
        super().__init__(
            sample_period=0.01,
            n_state=0,
            n_measured=n_measured,
            n_reference=1,
            n_input=1,
            gains={"k": k},
            measures=measures,
        )

    def expr(self, xc, y, r, g):
        return xc, g["k"] * (r[0] - y[0])


@pytest.mark.parametrize("compiled", [True, False])
def test_first_order_closed_loop_is_the_exact_sampled_recursion(lag, compiled):
    """u_k = clip(k (r − x_k), ±10): x_{k+1} = φ x_k + γ u_k, saturating on the first samples."""
    k, r, ts = 40.0, 1.0, 0.01
    res = models.simulate_closed_loop(lag, Proportional(k), r, 2.0, x0=[0.0], compiled=compiled)
    phi = np.exp(-2.0 * ts)
    gamma = (1 - phi) / 2.0
    x = 0.0
    for step in range(200):
        u = np.clip(k * (r - x), -10, 10)
        assert res.u[step, 0] == pytest.approx(k * (r - x), abs=1e-9)
        x = phi * x + gamma * u
        assert res.x[step + 1, 0] == pytest.approx(x, abs=1e-10)
    assert res.u[0, 0] > 10  # the actuator did saturate


def test_dc_motor_under_state_feedback_is_the_exact_discrete_recursion(motor):
    """The motor is linear: the closed loop on the nonlinear-plant path equals expm's ZOH recursion."""
    lin = motor.linearize()
    Ts = 0.01
    nx = 3
    block = np.zeros((4, 4))
    block[:nx, :nx], block[:nx, nx:] = lin.A, lin.B
    phi = scipy.linalg.expm(block * Ts)
    Ad, Bd = phi[:nx, :nx], phi[:nx, nx:]
    K = np.array([20.0, 1.0, 2.0])

    class StateFeedback(models.Block):
        def __init__(self):
            super().__init__(
                sample_period=Ts,
                n_state=0,
                n_measured=3,
                n_reference=1,
                n_input=1,
                gains={"K": K, "kr": 20.0},
                measures="state",
            )

        def expr(self, xc, y, r, g):
            return xc, -ca.dot(g["K"], y) + g["kr"] * r[0]

    res = models.simulate_closed_loop(motor, StateFeedback(), 0.5, 2.0)
    x = np.zeros(3)
    for k in range(200):
        u = np.clip(-K @ x + 20.0 * 0.5, -12, 12)
        x = Ad @ x + Bd[:, 0] * u
        np.testing.assert_allclose(res.x[k + 1], x, atol=1e-9)
    np.testing.assert_allclose(res.output("current"), res.state("i"))


def test_monte_carlo_of_a_first_order_plant_equals_single_runs(lag):
    samples = np.array([[1.0], [2.0], [3.0]])
    batch = models.monte_carlo(lag, Proportional(5.0), 1.0, 1.0, samples, x0=[0.0], noise_std=0.01, seed=3)
    for i, row in enumerate(samples):
        single = models.simulate_closed_loop(
            lag, Proportional(5.0), 1.0, 1.0, x0=[0.0], params=row, noise_std=0.01, seed=np.random.SeedSequence([3, i])
        )
        np.testing.assert_array_equal(batch[i].x, single.x)
    # At rest x = k r / (k + b): the larger b, the lower.
    assert batch.x[0, -1, 0] > batch.x[1, -1, 0] > batch.x[2, -1, 0]
