"""State-space blocks against exact recursions on the linear satellite and hand formulas on the arm and UUV."""

import numpy as np
import pytest

import models
from designs import statespace as ss
from designs.statespace_blocks import ObserverFeedback, StateFeedback, TrackingModel

TS = 0.01


@pytest.fixture(scope="module")
def satellite():
    plant = models.get("satellite")
    return plant, TrackingModel.from_plant(plant, "phi")


@pytest.fixture(scope="module")
def satellite_gains(satellite):
    _, model = satellite
    A, B = model.linear.A, model.linear.B
    K = ss.place(A, B, [-1 + 1j, -1 - 1j, -0.3 + 0.3j, -0.3 - 0.3j])
    return K, ss.reference_gain(A, B, K, model.C_r)[0]


def test_tracking_model_of_the_satellite(satellite):
    _, model = satellite
    assert model.tracked == "phi" and model.tracked_state == 1
    np.testing.assert_allclose(model.C_r, [[0, 1, 0, 0]])
    np.testing.assert_allclose(model.N_x, [1, 1, 0, 0], atol=1e-12)
    with pytest.raises(ValueError, match="satellite has no coordinate 'psi'"):
        TrackingModel.from_plant(models.get("satellite"), tracked="psi")


def test_state_feedback_on_the_linear_satellite_is_the_exact_sampled_recursion(satellite, satellite_gains):
    # The satellite is linear, u_e = 0, so u_k = sat(-K x_k + kr r) and x_{k+1} = A_d x_k + B_d u_k.
    plant, model = satellite
    K, kr = satellite_gains
    block = StateFeedback(model, K, kr, sample_period=TS)
    res = models.simulate_closed_loop(plant, block, 0.5, 8.0)
    disc = model.discrete(TS)
    x = np.zeros(4)
    for k in range(len(res.u)):
        u = np.clip(-K @ x + kr * 0.5, -5, 5)
        assert res.u[k, 0] == pytest.approx(u[0], abs=1e-9)
        x = disc.A @ x + disc.B @ u
        np.testing.assert_allclose(res.x[k + 1], x, atol=1e-9)
    assert np.any(np.abs(res.u) == 5.0)  # the run exercises the saturation


def _observer(model, K, kr, poles, disturbance=False, ki=None):
    disc = model.discrete(TS)
    A, C = disc.A, disc.C
    if disturbance:
        A = np.block([[A, disc.B], [np.zeros((1, 4)), np.eye(1)]])
        C = np.hstack([C, np.zeros((2, 1))])
    L = ss.discrete_observer_gain(A, C, np.exp(np.asarray(poles) * TS))
    block = ObserverFeedback(
        model, K, kr, ss.current_estimator_gain(A, L), ki, sample_period=TS, disturbance_observer=disturbance
    )
    return block, A - L @ C


def test_observer_prior_error_follows_the_designed_error_dynamics(satellite, satellite_gains):
    plant, model = satellite
    K, kr = satellite_gains
    block, error_matrix = _observer(model, K, kr, [-4, -5, -6 + 1j, -6 - 1j])
    x0 = np.array([0.05, -0.02, 0.01, 0.03])
    res = models.simulate_closed_loop(plant, block, 0.2, 5.0, x0=x0, xc0=np.zeros(4))
    error = res.x - block.state_estimate(res.xc)
    e = x0.copy()
    for k in range(len(res.t)):
        np.testing.assert_allclose(error[k], e, atol=1e-9)
        e = error_matrix @ e
    assert np.max(np.abs(error[-1])) < 1e-6 * np.max(np.abs(x0))


def test_disturbance_observer_recovers_a_constant_input_disturbance(satellite, satellite_gains):
    plant, model = satellite
    K, kr = satellite_gains
    block, error_matrix = _observer(model, K, kr, [-2, -2.5, -3 + 1j, -3 - 1j, -1.5], disturbance=True)
    d = 0.5
    res = models.simulate_closed_loop(plant, block, 0.3, 50.0, input_disturbance=d)
    # Augmented prior error (x - x̄, d - d̄) obeys the designed recursion from its initial value.
    error = np.hstack([res.x - block.state_estimate(res.xc), d - block.disturbance_estimate(res.xc)[:, None]])
    e = error[0]
    for k in range(len(res.t)):
        np.testing.assert_allclose(error[k], e, atol=1e-8)
        e = error_matrix @ e
    assert block.disturbance_estimate(res.xc)[-1] == pytest.approx(d, rel=1e-6)
    # With d̂ subtracted the plant holds phi at the reference despite the disturbance.
    assert res.state("phi")[-1] == pytest.approx(0.3, abs=1e-6)


def test_integrator_is_trapezoidal_with_back_calculation(satellite, satellite_gains):
    plant, model = satellite
    A_I, B_I = ss.augment_integrator(model.linear.A, model.linear.B, model.C_r)
    K, ki = ss.split_integral_gain(ss.place(A_I, B_I, [-1 + 1j, -1 - 1j, -0.3 + 0.3j, -0.3 - 0.3j, -0.5]), 4)
    block = StateFeedback(model, K, 0.0, ki, sample_period=TS)
    res = models.simulate_closed_loop(plant, block, 1.0, 40.0, x0=[-1.0, -1.0, 0.0, 0.0])
    integral, error_prev = res.xc[:-1, 0], res.xc[:-1, 1]
    error = 1.0 - res.x[:-1, 1]
    trapezoid = integral + TS / 2 * (error + error_prev)
    unsaturated = -(res.x[:-1] @ K.ravel()) + ki[0] * trapezoid
    saturated = np.clip(unsaturated, -5, 5)
    np.testing.assert_allclose(res.u[:, 0], saturated, atol=1e-9)
    np.testing.assert_allclose(res.xc[1:, 0], trapezoid + TS / ki[0] * (saturated - unsaturated), atol=1e-9)
    np.testing.assert_allclose(res.xc[1:, 1], error, atol=1e-12)
    assert np.any(saturated != unsaturated)  # starting 2 rad away saturates: back-calculation acts
    assert res.state("phi")[-1] == pytest.approx(1.0, abs=1e-3)


def test_rate_gate_freezes_the_integrator_while_the_tracked_coordinate_moves(satellite):
    plant, model = satellite
    block = StateFeedback(model, [10, -5, 12, 20], 0.0, 0.5, sample_period=TS, rate_limit=0.01)
    res = models.simulate_closed_loop(plant, block, 0.2, 5.0, x0=[-0.5, -0.5, 0.0, 0.0])
    moving = np.abs(res.state("dphi")[:-1]) >= 0.01
    assert moving.sum() > 50
    np.testing.assert_array_equal(res.xc[1:, 0][moving], res.xc[:-1, 0][moving])


def test_arm_command_cancels_gravity_at_the_measured_angle():
    # u = (m g ell / 2) cos(theta) - K x + kr r: u_e + u_nl(q) = u_e(q) - G q with G = 0 at theta = 0.
    arm = models.get("arm")
    model = TrackingModel.from_plant(arm, "theta")
    np.testing.assert_allclose(model.static_input_jacobian, [[0.0]], atol=1e-15)
    block = StateFeedback(model, [0.3, 0.08], 0.3, sample_period=TS)
    m, ell, g = arm.params["m"], arm.params["ell"], arm.params["g"]
    for theta, dtheta, r in [(0.3, 0.1, 0.5), (1.0, -0.4, 0.9), (-0.2, 0.0, 1.5)]:
        _, u = block.step(np.zeros(0), [theta, dtheta], [r])
        expected = m * g * ell / 2 * np.cos(theta) - 0.3 * theta - 0.08 * dtheta + 0.3 * r
        assert u[0] == pytest.approx(np.clip(expected, -1, 1), abs=1e-12)


def test_uuv_command_cancels_the_restoring_moment_beyond_its_linearization():
    uuv = models.get("uuv")
    model = TrackingModel.from_plant(uuv, "phi")
    stiffness = uuv.params["m"] * uuv.params["g"] * uuv.params["L"]
    np.testing.assert_allclose(model.static_input_jacobian, [[stiffness]], rtol=1e-12)
    block = StateFeedback(model, [100.0, 80.0], 150.0, sample_period=TS)
    for phi, dphi, r in [(0.4, 0.2, 0.5), (-0.6, 0.1, -0.5)]:
        _, u = block.step(np.zeros(0), [phi, dphi], [r])
        expected = stiffness * (np.sin(phi) - phi) - 100 * phi - 80 * dphi + 150 * r
        assert u[0] == pytest.approx(np.clip(expected, -50, 50), abs=1e-9)


@pytest.mark.parametrize("name, reference", [("arm", np.deg2rad(50)), ("uuv", np.deg2rad(30))])
def test_closed_loop_linearized_at_the_reference_has_the_designed_poles(name, reference):
    # Cancelling the equilibrium input's nonlinearity at the measured configuration makes the
    # designed poles hold about every reference, not only about the operating point.
    plant = models.get(name)
    model = TrackingModel.from_plant(plant, plant.coordinate_names[0])
    poles = [-3 + 2j, -3 - 2j]
    K = ss.place(model.linear.A, model.linear.B, poles)
    kr = ss.reference_gain(model.linear.A, model.linear.B, K, model.C_r)[0]
    block = StateFeedback(model, K, kr, sample_period=TS)
    rest = np.array([reference, 0.0])

    def xdot(x):
        return plant.f(x, block.step(np.zeros(0), x, [reference])[1])

    np.testing.assert_allclose(xdot(rest), 0, atol=1e-12)  # the reference is an exact rest point
    h = 1e-6
    jac = np.column_stack([(xdot(rest + h * e) - xdot(rest - h * e)) / (2 * h) for e in np.eye(2)])
    assert ss.pole_mismatch(np.linalg.eigvals(jac), poles) < 1e-5


def test_observer_starts_from_the_measured_configuration():
    sat = models.get("satellite")
    model = TrackingModel.from_plant(sat, "phi")
    L = np.full((4, 2), 0.1)
    block = ObserverFeedback(model, np.ones(4), 1.0, L * 0.01, sample_period=TS)
    # y = (theta, phi - theta) = (0.2, 0.05)  =>  q = (0.2, 0.25)
    np.testing.assert_allclose(block.initial_state([0.2, 0.05], [0.0]), [0.2, 0.25, 0, 0], atol=1e-12)


def test_bad_block_inputs_name_the_culprit():
    model = TrackingModel.from_plant(models.get("satellite"), "phi")
    with pytest.raises(ValueError, match="satellite: K must have 4 entries"):
        StateFeedback(model, [1, 2, 3], 1.0, sample_period=TS)
    with pytest.raises(ValueError, match="rate_limit gates the integrator"):
        StateFeedback(model, [1, 2, 3, 4], 1.0, sample_period=TS, rate_limit=0.1)
    with pytest.raises(ValueError, match="gain K is not finite"):
        StateFeedback(model, [1, 2, np.nan, 4], 1.0, sample_period=TS)
    with pytest.raises(ValueError, match="observer error dynamics are unstable"):
        ObserverFeedback(model, [1, 2, 3, 4], 1.0, np.zeros((4, 2)), sample_period=TS)
    with pytest.raises(ValueError, match="has no output 'phi'"):
        ObserverFeedback(model, [1, 2, 3, 4], 1.0, np.zeros((4, 1)), sample_period=TS, measured_outputs=("phi",))
    with pytest.raises(ValueError, match="has no disturbance observer"):
        disc = model.discrete(TS)
        L = ss.discrete_observer_gain(disc.A, disc.C, [0.9, 0.91, 0.92, 0.93])
        ObserverFeedback(
            model, [1, 2, 3, 4], 1.0, ss.current_estimator_gain(disc.A, L), sample_period=TS
        ).disturbance_estimate(np.zeros((3, 4)))


def test_closed_loop_is_differentiable_in_the_gains():
    # Gradient of the final tracking error w.r.t. (K, kr, ki) through the compiled run, against
    # central finite differences of the numeric simulation.
    import casadi as ca

    from designs import statespace_design

    arm = models.get("arm")
    design = statespace_design.design(
        arm,
        "theta",
        poles=[-8 + 6j, -8 - 6j],
        Q=np.diag([1 / 0.87**2, 0.0, 1 / 0.2**2]),
        R=[[1 / 0.26**2]],
        sample_period=TS,
    )
    block = statespace_design.controllers(design)["LQR + Kalman"]
    n = 100
    run = models.closed_loop_function(arm, block, n, substeps=2)
    gains = ca.MX.sym("g", block.gain_vector().size)
    x0 = arm.equilibrium()[0]
    xc0 = block.initial_state(arm.output(x0), [0.5])
    X, *_ = run(x0, xc0, np.full((1, n), 0.5), np.zeros((1, n)), np.zeros((1, n)), arm.param_vector(), gains)
    cost = ca.Function("cost", [gains], [ca.sumsqr(X[0, :] - 0.5)])
    grad = np.asarray(ca.Function("grad", [gains], [ca.gradient(cost(gains), gains)])(block.gain_vector())).ravel()
    h = 1e-6
    for i, g0 in enumerate(block.gain_vector()):
        step = np.zeros_like(block.gain_vector())
        step[i] = h * max(1.0, abs(g0))
        fd = (float(cost(block.gain_vector() + step)) - float(cost(block.gain_vector() - step))) / (2 * step[i])
        assert grad[i] == pytest.approx(fd, rel=1e-4, abs=1e-8)
