"""Per-plant state-space designs: placed poles, the text's numbers, and the nonlinear closed loops."""

import control
import numpy as np
import pytest
from case_designs import DESIGNED, case_of, statespace_answers, statespace_controllers, statespace_design

import models
from designs import statespace as ss
from designs.statespace_design import LABELS
from studies.cases import pendulum

PLANTS = DESIGNED
INTEGRAL_ACTION = ["pole placement + integrator", "disturbance observer", "LQR", "LQR + Kalman"]
SUBSTEPS = 2  # RK4 at 5 ms: far finer than every closed-loop time constant here


@pytest.fixture(scope="module")
def plants():
    return {name: models.get(name) for name in PLANTS}


@pytest.fixture(scope="module")
def designs(plants):
    return {name: statespace_design(name, plants[name]) for name in PLANTS}


def _step(design):
    case = case_of(design.plant)
    return models.signals.step(case.step, 0.0, design.model.tracked_equilibrium), case


# ------------------------------------------------------------ pole checks
@pytest.mark.parametrize("name", PLANTS)
def test_every_placed_pole_is_where_it_was_asked(designs, name):
    d = designs[name]
    A, B, nx = d.model.linear.A, d.model.linear.B, d.model.nx
    C = d.model.linear.C[d.observer_rows]
    A_I, B_I = ss.augment_integrator(A, B, d.model.C_r)
    A_d, _, C_d = ss.augment_disturbance(A, B, C)
    checks = [
        (A - B @ d.K, d.poles),
        (A_I - B_I @ np.hstack([d.K_integral, [[-d.ki]]]), np.append(d.poles, d.integrator_pole)),
        (A - d.L @ C, d.observer_poles),
        (A_d - d.L_disturbance @ C_d, d.disturbance_observer_poles),
    ]
    for matrix, requested in checks:
        assert ss.pole_mismatch(np.linalg.eigvals(matrix), requested) < 1e-8
    disc = d.model.discrete(d.observer_sample_period)
    assert (
        ss.pole_mismatch(
            np.linalg.eigvals(disc.A - d.L_discrete @ C), np.exp(d.observer_poles * d.observer_sample_period)
        )
        < 1e-8
    )
    # The text's .17(c) / IV-VI.15(c) demand: the compensator eig(A - B K - L C) in the left half plane.
    assert np.all(d.controller_poles.real < 0)
    assert d.controllability_rank == nx and d.observability_rank == nx


def test_arm_gains_are_the_pd_gains_of_I8(plants, designs):
    # I.15(f): K = (kp, kd). kp saturates the torque left over by gravity on the 50 deg step;
    # J theta'' = tau - b theta'  with J = m ell^2 / 3  =>  wn^2 = kp / J,  kd = 2 zeta wn J - b.
    p = plants["arm"].params
    J = p["m"] * p["ell"] ** 2 / 3
    kp = (1.0 - p["m"] * p["g"] * p["ell"] / 2) / np.deg2rad(50)
    wn = np.sqrt(kp / J)
    kd = 2 * 0.707 * wn * J - p["b"]
    np.testing.assert_allclose(designs["arm"].K, [[kp, kd]], rtol=1e-10)
    assert designs["arm"].kr == pytest.approx(kp, rel=1e-10)  # no gravity stiffness at theta = 0


def test_pendulum_and_satellite_poles_follow_the_successive_loop_rule(plants, designs):
    p = plants["pendulum"].params
    # theta'' = (m1 + m2) g / (m2 ell) theta - F / (m2 ell): wn^2 = F_max / (m2 ell A_th) - (m1 + m2) g / (m2 ell)
    wn = np.sqrt(5.0 / (p["m2"] * p["ell"] * np.deg2rad(10)) - (p["m1"] + p["m2"]) * p["g"] / (p["m2"] * p["ell"]))
    expected = np.roots(np.polymul([1, 2 * 0.707 * wn, wn**2], [1, 2 * 0.707 * wn / 5, (wn / 5) ** 2]))
    assert ss.pole_mismatch(designs["pendulum"].poles, expected) < 1e-10
    p = plants["satellite"].params
    wn = np.sqrt((p["k"] + 5.0 / np.deg2rad(30)) / p["Js"])
    expected = np.roots(np.polymul([1, 2 * 0.707 * wn, wn**2], [1, 2 * 0.707 * wn / 5, (wn / 5) ** 2]))
    assert ss.pole_mismatch(designs["satellite"].poles, expected) < 1e-10


def test_uuv_meets_IV14_rise_time_and_overshoot(designs):
    d = designs["uuv"]
    A, B = d.model.linear.A, d.model.linear.B
    closed = control.ss(A - B @ d.K, B * d.kr, d.model.C_r, 0)
    t = np.linspace(0, 8, 80001)
    info = control.step_info(closed, T=t)
    assert info["RiseTime"] == pytest.approx(1.0, abs=t[1])
    assert info["Overshoot"] == pytest.approx(5.0, rel=1e-3)


def test_ballbeam_and_crane_use_the_texts_poles(designs):
    assert ss.pole_mismatch(designs["ballbeam"].poles, [-4.5 + 4.5j, -4.5 - 4.5j, -6 + 1.5j, -6 - 1.5j]) == 0
    assert ss.pole_mismatch(designs["crane1"].poles, [-0.6, -1.5, -0.55 + 0.75j, -0.55 - 0.75j]) == 0
    assert designs["crane"].K.shape == (1, 6)  # the two-load crane is designed on its 6 states


@pytest.mark.parametrize("name", PLANTS)
def test_dc_gain_from_reference_to_tracked_output_is_one(designs, name):
    d = designs[name]
    A, B = d.model.linear.A, d.model.linear.B
    assert control.dcgain(control.ss(A - B @ d.K, B * d.kr, d.model.C_r, 0)) == pytest.approx(1.0, rel=1e-10)
    # Sampled: the ZOH model keeps the continuous DC gain.
    disc = d.model.discrete(d.sample_period)
    dc = d.model.C_r @ np.linalg.solve(np.eye(d.model.nx) - disc.A + disc.B @ d.K, disc.B * d.kr)
    assert dc.item() == pytest.approx(1.0, rel=1e-9)


@pytest.mark.parametrize("name", PLANTS)
def test_lqr_gain_solves_the_riccati_equation(designs, name):
    d = designs[name]
    A_I, B_I = ss.augment_integrator(d.model.linear.A, d.model.linear.B, d.model.C_r)
    K_aug = np.hstack([d.K_lqr, [[-d.ki_lqr]]])
    assert ss.riccati_residual(A_I, B_I, d.Q, d.R, d.P_lqr) < 1e-9
    np.testing.assert_allclose(K_aug, np.linalg.solve(d.R, B_I.T @ d.P_lqr), rtol=1e-10)
    # The return-difference equality at s -> 0, where the integrator's 1/s dominates both sides,
    # gives |ki| = sqrt(q_I / r) (the scalar S = sqrt(Q R) form): input room / (step * horizon).
    assert abs(d.ki_lqr) == pytest.approx(np.sqrt(d.Q[-1, -1] / d.R[0, 0]), rel=1e-8)


@pytest.mark.parametrize("name", ["arm", "uuv", "crane1"])
def test_discrete_lqr_record_equals_the_converged_recursion(designs, name):
    d = designs[name]
    Ts = d.sample_period
    disc = d.model.discrete(Ts)
    nx = d.model.nx
    A = np.block([[disc.A, np.zeros((nx, 1))], [-Ts * d.model.C_r, np.eye(1)]])
    B = np.vstack([disc.B, [[0.0]]])
    Q, R = d.Q * Ts, d.R * Ts
    P = Q.copy()
    for _ in range(200000):
        K = np.linalg.solve(R + B.T @ P @ B, B.T @ P @ A)
        P_next = Q + A.T @ P @ (A - B @ K)
        if np.max(np.abs(P_next - P)) <= 1e-13 * np.max(np.abs(P_next)):
            break
        P = (P_next + P_next.T) / 2
    np.testing.assert_allclose(d.K_dlqr, K, rtol=1e-7)


# ------------------------------------------------- nonlinear closed loops
@pytest.mark.parametrize("name", PLANTS)
def test_state_feedback_tracks_the_step_on_the_nonlinear_plant(plants, name):
    plant = plants[name]
    block = statespace_controllers(name, plant)["pole placement"]
    reference, case = _step(statespace_design(name, plant))
    res = models.simulate_closed_loop(plant, block, reference, case.duration, substeps=SUBSTEPS)
    tracked = res.x[:, block.model.tracked_state]
    assert abs(res.r[-1, 0] - tracked[-1]) < 1e-5
    assert np.max(np.abs(res.u)) <= plant.input_limit[0] + 1e-12


@pytest.mark.parametrize("name", PLANTS)
def test_observer_error_decays_on_the_nonlinear_plant(plants, name):
    plant = plants[name]
    block = statespace_controllers(name, plant)["observer-based"]
    reference, case = _step(statespace_design(name, plant))
    x0 = plant.equilibrium()[0]
    xc0 = block.initial_state(plant.output(x0), reference(0.0))
    xc0[plant.nq : plant.nx] += 0.01  # wrong initial velocity estimates (5 times this drops the ball)
    res = models.simulate_closed_loop(plant, block, reference, case.duration, xc0=xc0, substeps=SUBSTEPS)
    error = np.abs(res.x - block.state_estimate(res.xc))
    assert np.max(error[0]) > 0.01 - 1e-12
    assert np.max(error[-1]) < 1e-4 * 0.01
    assert abs(res.r[-1, 0] - res.x[-1, block.model.tracked_state]) < 1e-3 * abs(case.step)


@pytest.mark.parametrize("sign", [1, -1])
@pytest.mark.parametrize("name", PLANTS)
def test_integral_action_removes_the_error_that_plain_state_feedback_leaves(plants, name, sign):
    plant = plants[name]
    known = models.perturbed(plant, 0.05, sign)
    blocks = statespace_controllers(name, known)
    reference, case = _step(statespace_design(name, known))
    labels = INTEGRAL_ACTION + (["observer-based"] if name in ("arm", "pendulum", "satellite") else [])
    errors = {}
    for label in labels + ["pole placement"]:
        res = models.simulate_closed_loop(
            plant, blocks[label], reference, case.duration, input_disturbance=case.input_disturbance, substeps=SUBSTEPS
        )
        errors[label] = abs(res.r[-1, 0] - res.x[-1, blocks[label].model.tracked_state])
    assert all(errors[label] < 1e-3 for label in labels), errors
    assert errors["pole placement"] > 1e-3


@pytest.mark.parametrize("name", PLANTS)
def test_disturbance_estimate_converges_to_the_disturbance(plants, name):
    plant = plants[name]
    case = case_of(name)
    d_true = case.input_disturbance
    for known in (plant, models.perturbed(plant, 0.05, 1)):
        block = statespace_controllers(name, known)["disturbance observer"]
        reference, _ = _step(statespace_design(name, known))
        res = models.simulate_closed_loop(
            plant, block, reference, case.duration, input_disturbance=d_true, substeps=SUBSTEPS
        )
        d_hat = block.disturbance_estimate(res.xc)[-1]
        # At rest the true plant needs u + d = u_e,true(q); the known model explains u_e,known(q) - u,
        # so d̂ settles at d + u_e,known(q) - u_e,true(q): d itself when the model is right.
        q = res.x[-1, : plant.nq]
        expected = d_true + (known.equilibrium_input(q) - plant.equilibrium_input(q))[0]
        assert d_hat == pytest.approx(expected, abs=1e-4 * d_true)
        if known is plant:
            assert abs(d_hat - d_true) < 0.05 * d_true


# ---------------------------------------------------------- records, API
@pytest.mark.parametrize("name", PLANTS)
def test_answers_list_the_design_numbers_by_homework_item(designs, name):
    answers = statespace_answers(name, models.get(name))
    d = designs[name]
    numeral = case_of(name).numeral
    if numeral in ("I", "II", "III"):
        feedback, integrator = answers[f"{numeral}.15(f)"], answers[f"{numeral}.16"]
        observer, dob = answers[f"{numeral}.17(c)"], answers[f"{numeral}.17(e)"]
    else:
        feedback = answers[{"IV": "IV.14(d)", "V": "V.14(c)", "VI": "VI.14(c)"}[numeral]]
        integrator, dob = answers["integrator"], answers["disturbance observer"]
        observer = answers[f"{numeral}.15(c)"]
    A, B = d.model.linear.A, d.model.linear.B
    K = np.array(feedback["K"])
    assert ss.pole_mismatch(np.linalg.eigvals(A - B @ K), np.array(feedback["poles"])) < 1e-8
    assert isinstance(integrator["ki"], float) and integrator["ki"] == d.ki
    C = d.model.linear.C[d.observer_rows]
    assert ss.pole_mismatch(np.linalg.eigvals(A - np.array(observer["L"]) @ C), observer["observer_poles"]) < 1e-8
    assert np.all(np.real(observer["controller_poles"]) < 0)
    assert len(dob["observer_poles"]) == d.model.nx + 1
    lqr = answers["LQR"]
    assert set(lqr) >= {"K", "ki", "Q", "R", "poles"}
    assert np.array(lqr["Q"]).shape == (d.model.nx + 1, d.model.nx + 1)


def test_controllers_labels_and_sample_periods(plants):
    for name, observer_period in (("ballbeam", 0.001), ("crane1", 0.001), ("arm", 0.01)):
        blocks = statespace_controllers(name, plants[name])
        assert tuple(blocks) == LABELS
        assert blocks["observer-based"].sample_period == observer_period
        assert blocks["pole placement"].sample_period == 0.01
        assert blocks["pole placement"].measures == "state" and blocks["LQR"].measures == "state"
        assert blocks["observer-based"].measures == "outputs"
    assert statespace_controllers("ballbeam", plants["ballbeam"])["observer-based"].measured_outputs == ("z",)


def test_bad_requests_name_the_culprit(plants):
    with pytest.raises(ValueError, match="unknown plant 'rocket'"):
        statespace_design("rocket")
    with pytest.raises(ValueError, match="the known plant is 'uuv'; the arm designs take 'arm'"):
        statespace_design("arm", plants["uuv"])
    with pytest.raises(ValueError, match="pendulum: a step of 0.5 rad .* cannot stabilize"):
        pendulum.statespace_poles(plants["pendulum"], angle_step=0.5)


@pytest.mark.slow
@pytest.mark.parametrize("name", PLANTS)
def test_integral_designs_hold_zero_error_on_every_parameter_corner(plants, name):
    # The nominal design on every actual plant at the corners of the ±5 % box, with the disturbance.
    plant = plants[name]
    blocks = statespace_controllers(name, plant)
    reference, case = _step(statespace_design(name, plant))
    corners = models.corner_params(plant)
    for label in INTEGRAL_ACTION:
        runs = models.monte_carlo(
            plant,
            blocks[label],
            reference,
            case.duration,
            corners,
            substeps=SUBSTEPS,
            input_disturbance=case.input_disturbance,
            threads=1,
        )
        errors = [abs(run.r[-1, 0] - run.x[-1, blocks[label].model.tracked_state]) for run in runs]
        assert max(errors) < 1e-3, (label, max(errors))


def test_design_overrides_replace_the_default_poles_and_weights(plants):
    arm = plants["arm"]
    d = statespace_design(
        "arm", arm, poles=[-5.0, -6.0], integrator_pole=-7.0, observer_poles=[-20.0, -21.0], disturbance_pole=-9.0
    )
    # theta'' = -a theta' + b0 u: s^2 + (a + b0 k2) s + b0 k1 = (s + 5)(s + 6).
    a, b0 = -d.model.linear.A[1, 1], d.model.linear.B[1, 0]
    np.testing.assert_allclose(d.K, [[30 / b0, (11 - a) / b0]], rtol=1e-10)
    assert d.integrator_pole == -7.0 and d.disturbance_observer_poles[-1] == -9.0
    assert ss.pole_mismatch(d.observer_poles, [-20, -21]) == 0
    with pytest.raises(ValueError, match=r"arm \(integrator-augmented\): weight Q has non-finite"):
        statespace_design("arm", arm, Q=np.diag([1.0, np.nan, 1.0]))
    with pytest.raises(ValueError, match="requested 2 times"):
        statespace_controllers("arm", arm, poles=[-5.0, -5.0])


@pytest.mark.parametrize("name", ["arm", "satellite", "crane"])
def test_lqr_without_integrator_has_unit_dc_gain_and_solves_its_riccati_equation(designs, name):
    d = designs[name]
    A, B, nx = d.model.linear.A, d.model.linear.B, d.model.nx
    Q = d.Q[:nx, :nx]
    K, P = ss.lqr(A, B, Q, d.R)  # the record's gain is this solve on the states' block of Q
    np.testing.assert_allclose(d.K_lqr_plain, K, rtol=1e-12)
    assert ss.riccati_residual(A, B, Q, d.R, P) < 1e-9
    closed = control.ss(A - B @ d.K_lqr_plain, B * d.kr_lqr_plain, d.model.C_r, 0)
    assert control.dcgain(closed) == pytest.approx(1.0, rel=1e-10)
