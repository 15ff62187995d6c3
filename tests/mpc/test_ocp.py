"""The optimal-control layer against closed forms: bang-bang minimum time, minimum energy, LQ/Riccati,
collocation order, and the plant's own RK4; plus its API: warm starts, parameters, guesses, errors."""

import casadi as ca
import numpy as np
import pytest
from scipy.integrate import solve_ivp

import models
import mpc
from models.simulate import radau_matrices
from mpc.transcription import collocation_coefficients, rk4_interval


def point_mass(mass=2.0, limit=3.0):
    """The double integrator: kinetic energy m v²/2, force f, |f| <= limit (acceleration limit / m)."""

    @models.declare(
        name="point_mass",
        title="point mass",
        coordinates=("s",),
        inputs=("f",),
        params=(models.Param("m", mass, "kg"),),
        input_limit=limit,
        register=False,
    )
    def declaration(q, dq, u, p):
        return models.Physics(kinetic=p.m * dq.s**2 / 2, potential=0, forces=[u.f], outputs={"s": q.s})

    return models.Plant(declaration)


def spring_mass(mass=1.0, stiffness=4.0, damping=0.0, limit=1.0):
    """m s'' = -k s - b s' + f."""

    @models.declare(
        name="spring_mass",
        title="spring mass damper",
        coordinates=("s",),
        inputs=("f",),
        params=(
            models.Param("m", mass, "kg"),
            models.Param("k", stiffness, "N/m"),
            models.Param("b", damping, "N s/m", positive=False),
        ),
        input_limit=limit,
        register=False,
    )
    def declaration(q, dq, u, p):
        return models.Physics(
            kinetic=p.m * dq.s**2 / 2, potential=p.k * q.s**2 / 2, forces=[u.f - p.b * dq.s], outputs={"s": q.s}
        )

    return models.Plant(declaration)


def rest_to_rest(plant, final_time, distance):
    ocp = mpc.OptimalControlProblem(plant, final_time)
    ocp.subject_to(ocp.at_start(ocp.state) == 0)
    ocp.subject_to(ocp.at_end(ocp.state) == [distance, 0])
    return ocp


TRANSCRIPTIONS = [
    mpc.Collocation(intervals=20),
    mpc.Collocation(intervals=20, degree=2, points="legendre"),
    mpc.MultipleShooting(intervals=20),
]


# --------------------------------------------------------------------------- closed forms
@pytest.mark.parametrize("transcription", TRANSCRIPTIONS, ids=["radau3", "legendre2", "shooting"])
def test_minimum_time_rest_to_rest_is_bang_bang_in_two_sqrt_d_over_a(transcription):
    """|s''| <= a, rest to rest over d: full push to half way, full brake, T* = 2 sqrt(d / a).

    With an even number of intervals the switch falls on a mesh point, so the held input
    is exact and both transcriptions integrate s'' = const exactly: T* to solver tolerance.
    """
    plant, distance = point_mass(mass=2.0, limit=3.0), 1.5
    accel = 3.0 / 2.0
    ocp = rest_to_rest(plant, mpc.FreeTime(0.1, 10.0, guess=1.0), distance)
    ocp.minimize(ocp.final_time)
    solution = ocp.solve(transcription)
    assert solution.success, solution.status
    assert solution.final_time == pytest.approx(2 * np.sqrt(distance / accel), rel=1e-6)
    half = transcription.intervals // 2
    np.testing.assert_allclose(solution.inputs[:half, 0], 3.0, rtol=1e-5)
    np.testing.assert_allclose(solution.inputs[half:, 0], -3.0, rtol=1e-5)


@pytest.mark.parametrize("transcription", TRANSCRIPTIONS, ids=["radau3", "legendre2", "shooting"])
def test_minimum_energy_rest_to_rest_matches_closed_form(transcription):
    """min ∫ u² dt, u = s'' (unit mass), rest to rest over d in T: u linear in t, J = 12 d² / T³.

    Held on N intervals, the least-norm input u = Aᵀ(AAᵀ)⁻¹b with rows A = [h, h²(N - k - 1/2)]
    and b = (0, d) gives det(AAᵀ) = h⁶ N²(N² - 1)/12 and J_N = 12 d² / T³ · N² / (N² - 1)
    exactly, with u_k on the line through the continuous optimum at the interval middles.
    """
    plant, distance, final_time = point_mass(mass=1.0, limit=100.0), 1.5, 2.0
    ocp = rest_to_rest(plant, final_time, distance)
    ocp.minimize(ocp.integral(ocp.u.f**2))
    solution = ocp.solve(transcription)
    assert solution.success, solution.status
    N = transcription.intervals
    continuous = 12 * distance**2 / final_time**3
    assert solution.objective == pytest.approx(continuous * N**2 / (N**2 - 1), rel=1e-8)
    middles = (solution.t[:-1] + solution.t[1:]) / 2
    slope_line = 6 * distance / final_time**2 * (1 - 2 * middles / final_time)  # the continuous optimum
    np.testing.assert_allclose(solution.inputs[:, 0], slope_line * N**2 / (N**2 - 1), atol=1e-7)


def test_a_sum_is_the_discrete_stage_cost():
    """Σ u_k² (no interval length) has the same minimizer as ∫ u² dt and the value J_N / h."""
    plant, distance, final_time, N = point_mass(mass=1.0, limit=100.0), 1.5, 2.0, 20
    ocp = rest_to_rest(plant, final_time, distance)
    ocp.minimize(ocp.sum(ocp.u.f**2))
    solution = ocp.solve(mpc.MultipleShooting(intervals=N))
    assert solution.success, solution.status
    h = final_time / N
    assert solution.objective == pytest.approx(12 * distance**2 / final_time**3 * N**2 / (N**2 - 1) / h, rel=1e-8)


def test_an_extra_control_softens_a_terminal_constraint():
    """min ∫u² + w e² with s(T) = d - e: J(e) = c (d - e)² + w e², c = 12/T³ · N²/(N² - 1),
    so e* = c d / (c + w)."""
    plant, distance, final_time, N, weight = point_mass(mass=1.0, limit=100.0), 1.5, 2.0, 10, 3.0
    ocp = mpc.OptimalControlProblem(plant, final_time)
    shortfall = ocp.control("e")
    ocp.minimize(ocp.integral(ocp.u.f**2) + weight * ocp.at_end(shortfall) ** 2)
    ocp.subject_to(ocp.at_start(ocp.state) == 0)
    ocp.subject_to(ocp.at_end(ocp.x.s + shortfall) == distance)
    ocp.subject_to(ocp.at_end(ocp.x.ds) == 0)
    solution = ocp.solve(mpc.Collocation(intervals=N))
    assert solution.success, solution.status
    c = 12 / final_time**3 * N**2 / (N**2 - 1)
    assert solution.controls[-1, 0] == pytest.approx(c * distance / (c + weight), rel=1e-7)


def test_a_path_constraint_on_an_output_holds_at_every_collocation_point():
    """The satellite's measured twist y = phi - theta kept within 0.02 rad while it turns 1 rad
    rest to rest in 40 s; checked at the collocation nodes. The spring carries the panel, so
    its acceleration is at most k 0.02 / Jp = 0.003 rad/s²: feasible in 2 sqrt(1 / 0.003) = 36.5 s;
    the least-effort turn without the bound peaks near 6/40² rad/s², a twist of 0.025 rad."""
    ocp = mpc.OptimalControlProblem(models.get("satellite"), 40.0)
    ocp.minimize(ocp.integral(ocp.u.tau**2))
    ocp.subject_to(ocp.at_start(ocp.state) == 0)
    ocp.subject_to(ocp.at_end(ocp.state) == [1.0, 1.0, 0, 0])
    ocp.subject_to(ocp.bounded(-0.02, ocp.y.phi_minus_theta, 0.02))
    solution = ocp.solve(mpc.Collocation(intervals=40, degree=2, points="legendre"))
    assert solution.success, solution.status
    twist = np.concatenate(
        [
            solution.states[:, 1] - solution.states[:, 0],
            (solution.collocation_states[:, :, 1] - solution.collocation_states[:, :, 0]).ravel(),
        ]
    )
    assert np.max(np.abs(twist)) <= 0.02 + 1e-7
    assert np.max(np.abs(twist)) >= 0.02 - 1e-6  # active: without it the twist is larger
    free = mpc.OptimalControlProblem(models.get("satellite"), 40.0)
    free.minimize(free.integral(free.u.tau**2))
    free.subject_to(free.at_start(free.state) == 0)
    free.subject_to(free.at_end(free.state) == [1.0, 1.0, 0, 0])
    unconstrained = free.solve(mpc.Collocation(intervals=40, degree=2, points="legendre"))
    assert np.max(np.abs(unconstrained.states[:, 1] - unconstrained.states[:, 0])) > 0.02
    assert solution.objective > unconstrained.objective


def test_plant_input_feeds_a_disturbance_estimate_to_the_plant():
    """The plant gets v = u + δ (δ a parameter, as an MPC's disturbance estimate). Rest to rest,
    ∫v dt = 0, so ∫u² = ∫v² + δ² T: the optimal v is the undisturbed one and J grows by δ² T."""
    plant, distance, final_time, N, offset = point_mass(mass=1.0, limit=100.0), 1.5, 2.0, 10, 0.4
    ocp = rest_to_rest(plant, final_time, distance)
    disturbance = ocp.parameter("d_hat", 1, value=0.0)
    ocp.plant_input(ocp.input + disturbance)
    ocp.minimize(ocp.integral(ocp.u.f**2))
    solver = ocp.solver(mpc.MultipleShooting(intervals=N))
    calm, pushed = solver.solve(), solver.solve(params={"d_hat": offset})
    assert calm.success and pushed.success, pushed.status
    assert pushed.objective == pytest.approx(calm.objective + offset**2 * final_time, rel=1e-8)
    np.testing.assert_allclose(pushed.plant_inputs, calm.inputs, atol=1e-7)
    np.testing.assert_allclose(pushed.inputs, calm.inputs - offset, atol=1e-7)
    assert pushed.verify().max_defect < 1e-8


def riccati_cost(A, B, Q, R, S, final_time, x0):
    """x0ᵀ P(0) x0 with -P' = AᵀP + PA - PBR⁻¹BᵀP + Q, P(T) = S, integrated backwards by scipy."""
    n = A.shape[0]

    def rde(t, p):
        P = p.reshape(n, n)
        return -(A.T @ P + P @ A - P @ B @ np.linalg.solve(R, B.T) @ P + Q).ravel()

    run = solve_ivp(rde, (final_time, 0.0), S.ravel(), rtol=1e-12, atol=1e-12)
    return float(x0 @ run.y[:, -1].reshape(n, n) @ x0)


def test_finite_horizon_lq_converges_to_the_riccati_cost_at_second_order():
    """Spring-mass-damper (A, B written by hand from m s'' = -k s - b s' + f), quadratic cost:
    the optimum with held inputs tends to the Riccati value, the error falling as h² (the
    input's hold), so halving h divides it by about four."""
    m, k, b = 1.0, 2.0, 0.3
    plant = spring_mass(mass=m, stiffness=k, damping=b)
    A = np.array([[0, 1], [-k / m, -b / m]])
    B = np.array([[0], [1 / m]])
    Q, R, S = np.diag([1.0, 0.5]), np.array([[0.1]]), np.diag([2.0, 1.0])
    final_time, x0 = 3.0, np.array([1.0, 0.0])
    exact = riccati_cost(A, B, Q, R, S, final_time, x0)
    errors = []
    for N in (40, 80):
        ocp = mpc.OptimalControlProblem(plant, final_time, actuator_limit=False)
        x, u = ocp.x, ocp.u
        ocp.minimize(ocp.integral(x.s**2 + 0.5 * x.ds**2 + 0.1 * u.f**2) + ocp.at_end(2 * x.s**2 + x.ds**2))
        ocp.subject_to(ocp.at_start(ocp.state) == x0)
        solution = ocp.solve(mpc.Collocation(intervals=N))
        assert solution.success, solution.status
        errors.append(solution.objective - exact)
    assert abs(errors[1]) < 1e-3 * exact
    assert 3.5 < errors[0] / errors[1] < 4.5


@pytest.mark.parametrize(
    "points, degree, intervals, order",
    [
        ("legendre", 1, (16, 32), 2),
        ("legendre", 2, (16, 32), 4),
        ("legendre", 3, (8, 16), 6),
        ("radau", 1, (64, 128), 1),
        ("radau", 2, (16, 32), 3),
        ("radau", 3, (16, 32), 5),
    ],
)
def test_collocation_error_falls_at_the_order_of_its_points(points, degree, intervals, order):
    """Free oscillation s'' = -ω² s from s = 1 (input fixed at zero): s(T) = cos ωT and
    ∫ s² dt = T/2 + sin 2ωT / 4ω. Gauss collocation is of order 2d, Radau IIA of 2d - 1."""
    omega, final_time = 2.0, 2.0
    plant = spring_mass(mass=1.0, stiffness=omega**2)
    errors = []
    for N in intervals:
        ocp = mpc.OptimalControlProblem(plant, final_time)
        ocp.minimize(ocp.integral(ocp.x.s**2))
        ocp.subject_to(ocp.at_start(ocp.state) == [1.0, 0.0])
        ocp.subject_to(ocp.u.f == 0)
        solution = ocp.solve(
            mpc.Collocation(intervals=N, degree=degree, points=points), solver_options={"tolerance": 1e-14}
        )
        assert solution.success, solution.status
        errors.append(
            [
                abs(solution.states[-1, 0] - np.cos(omega * final_time)),
                abs(solution.objective - (final_time / 2 + np.sin(2 * omega * final_time) / (4 * omega))),
            ]
        )
    observed = np.log2(np.array(errors[0]) / np.array(errors[1]))
    np.testing.assert_allclose(observed, order, atol=0.25)


def test_multiple_shooting_uses_the_plants_rk4_map():
    """The shooting interval's state is `Plant.step_function`'s RK4 (substeps included), and
    its quadrature of a constant integrand is exact."""
    plant = models.get("pendulum")
    x, u, c, t, p, T = (ca.SX.sym(n, size) for n, size in (("x", 4), ("u", 1), ("c", 0), ("t", 1), ("p", 5), ("T", 1)))
    integrands = ca.Function("integrands", [x, u, c, t, p, T], [ca.vertcat(u**2, t)])
    step = rk4_interval(plant, integrands, 3)
    reference = plant.step_function(0.2, 3)
    rng = np.random.default_rng(3)
    p_value = plant.param_vector()
    for _ in range(5):
        x0, u0 = rng.normal(size=4), rng.normal(size=1)
        x_next, integrals = step(x0, u0, u0, np.zeros(0), 0.4, 0.2, p_value, 1.0)
        np.testing.assert_allclose(
            np.asarray(x_next).ravel(), np.asarray(reference(x0, u0, p_value)).ravel(), rtol=1e-13, atol=1e-13
        )
        np.testing.assert_allclose(np.asarray(integrals).ravel(), [0.2 * u0[0] ** 2, (0.6**2 - 0.4**2) / 2], rtol=1e-13)


def test_radau_coefficients_match_the_simulators():
    tau, deriv = radau_matrices(3)
    coefficients = collocation_coefficients(3, "radau")
    np.testing.assert_allclose(coefficients.tau, tau, atol=1e-14)
    np.testing.assert_allclose(coefficients.derivative, deriv, atol=1e-12)


@pytest.mark.parametrize("points", ["radau", "legendre"])
@pytest.mark.parametrize("degree", [1, 2, 3, 5])
def test_collocation_coefficients_differentiate_and_integrate_polynomials_exactly(points, degree):
    c = collocation_coefficients(degree, points)
    exact_to = 2 * degree - 1 if points == "legendre" else 2 * degree - 2
    for power in range(exact_to + 1):  # ∫₀¹ τ^k dτ = 1/(k+1)
        assert c.quadrature @ c.tau[1:] ** power == pytest.approx(1 / (power + 1), abs=1e-13)
    for power in range(degree + 1):  # d/dτ τ^k = k τ^(k-1) at the points; τ^k at 1 is 1
        np.testing.assert_allclose(
            c.tau**power @ c.derivative, power * c.tau[1:] ** max(power - 1, 0) * (power > 0), atol=1e-11
        )
        assert c.tau**power @ c.continuity == pytest.approx(1.0, abs=1e-12)


# --------------------------------------------------------------------------- solution and check
def test_dense_state_is_the_plants_trajectory_between_the_mesh_points():
    """With the input held, s is quadratic in t on each interval: the degree-2 collocation
    polynomial is exact, so it matches CVODES at off-mesh times to the integrator's tolerance."""
    plant = point_mass(mass=1.0, limit=100.0)
    ocp = rest_to_rest(plant, 2.0, 1.0)
    ocp.minimize(ocp.integral(ocp.u.f**2))
    solution = ocp.solve(mpc.Collocation(intervals=10, degree=2, points="legendre"))
    fine = np.linspace(0, 2.0, 41)
    held = solution.input_at((fine[:-1] + fine[1:]) / 2)
    simulated = mpc.resimulate(plant, fine, solution.states[0], held)
    np.testing.assert_allclose(solution.state_at(fine), simulated, atol=1e-8)
    shooting = ocp.solve(mpc.MultipleShooting(intervals=10))
    np.testing.assert_allclose(shooting.state_at(fine), simulated, atol=1e-8)  # cubic Hermite, exact here


def swing_up(final_time=4.0, travel=0.5):
    """The pendulum from hanging (theta = pi) to upright at rest, minimum ∫F² dt, |z| <= travel."""
    ocp = mpc.OptimalControlProblem(models.get("pendulum"), final_time)
    x, u = ocp.x, ocp.u
    ocp.minimize(ocp.integral(u.F**2))
    ocp.subject_to(ocp.at_start(ocp.state) == [0, np.pi, 0, 0])
    ocp.subject_to(ocp.at_end(ocp.state) == 0)
    ocp.subject_to(ocp.bounded(-travel, x.z, travel))
    return ocp


def test_pendulum_swing_up_meets_its_constraints_and_verifies():
    """The optimal input re-simulated interval by interval on the nonlinear plant (CVODES)
    lands within 1e-4 of the collocated states; the limits hold."""
    ocp = swing_up()
    solution = ocp.solve(mpc.Collocation(intervals=80), guess_input=lambda t: [2 * np.sin(2 * np.pi * t / 4.0)])
    assert solution.success, solution.status
    assert np.max(np.abs(solution.inputs)) <= 5.0 + 1e-6
    assert np.max(np.abs(solution.state("z"))) <= 0.5 + 1e-6
    np.testing.assert_allclose(solution.states[-1], 0, atol=1e-8)
    check = solution.verify()
    assert check.max_interval_defect < 1e-4
    # The objective is the Radau quadrature of the held input: Σ h F².
    assert solution.objective == pytest.approx(np.sum(np.diff(solution.t) * solution.inputs[:, 0] ** 2), rel=1e-10)


def test_mesh_refinement_meets_its_tolerance_and_verifies():
    """The arm swung from hanging to upright with least effort: refinement adds intervals until
    every collocation defect is below the tolerance, and the re-simulated input agrees."""
    ocp = mpc.OptimalControlProblem(models.get("arm"), 2.0)
    ocp.minimize(ocp.integral(ocp.u.tau**2))
    ocp.subject_to(ocp.at_start(ocp.state) == [-np.pi / 2, 0])
    ocp.subject_to(ocp.at_end(ocp.state) == [np.pi / 2, 0])
    solution = ocp.solve(mpc.Collocation(intervals=10), refine_tolerance=1e-4)
    assert solution.success, solution.status
    intervals, defects = zip(*solution.refinement)
    assert defects[-1] <= 1e-4 < defects[0]
    assert intervals[-1] > intervals[0]
    assert np.max(mpc.collocation_defects(solution)) == pytest.approx(defects[-1])
    assert solution.verify().max_interval_defect < 1e-4


@pytest.mark.slow
def test_mesh_refinement_of_the_swing_up():
    ocp = swing_up()
    solution = ocp.solve(
        mpc.Collocation(intervals=40), refine_tolerance=1e-5, guess_input=lambda t: [2 * np.sin(2 * np.pi * t / 4.0)]
    )
    assert solution.success, solution.status
    assert solution.refinement[-1][1] <= 1e-5 < solution.refinement[0][1]
    assert solution.verify().max_interval_defect < 1e-5


def test_crane_minimum_time_move_is_expressible_and_beats_no_bound():
    """crane1: 10 m rest to rest, |F| <= 5 kN, swing |theta| <= 0.1 rad, minimum time. The
    horizontal momentum of cart and load changes at most at F, so T >= 2 sqrt(d (mc + m) / F)."""
    plant = models.get("crane1")
    ocp = mpc.OptimalControlProblem(plant, mpc.FreeTime(2.0, 30.0, guess=10.0))
    x = ocp.x
    ocp.minimize(ocp.final_time)
    ocp.subject_to(ocp.at_start(ocp.state) == 0)
    ocp.subject_to(ocp.at_end(ocp.state) == [10.0, 0, 0, 0])
    ocp.subject_to(ocp.bounded(-0.1, x.theta, 0.1))
    ocp.scale(x=10.0, dx=2.0)
    solution = ocp.solve(mpc.Collocation(intervals=40))
    assert solution.success, solution.status
    lower_bound = 2 * np.sqrt(10.0 * (1500.0 + 500.0) / 5000.0)
    assert solution.final_time > lower_bound
    assert np.max(np.abs(solution.state("theta"))) <= 0.1 + 1e-6
    assert solution.verify().max_interval_defect < 1e-4


# --------------------------------------------------------------------------- build once, solve many
def parametrized_rest_to_rest():
    plant = point_mass(mass=1.0, limit=100.0)
    ocp = mpc.OptimalControlProblem(plant, 2.0)
    distance = ocp.parameter("distance", value=1.0)
    ocp.start_from([0.0, 0.0])
    ocp.minimize(ocp.integral(ocp.u.f**2))
    ocp.subject_to(ocp.at_end(ocp.state) == ca.vertcat(distance, 0))
    return ocp


def test_one_build_solves_new_parameters_and_initial_states():
    """J = 12 d² / T³ · N²/(N² - 1) for the distance left to go, from any start at rest."""
    solver = parametrized_rest_to_rest().solver(mpc.Collocation(intervals=10))
    factor = 12 / 2.0**3 * 100 / 99
    first = solver.solve()
    assert first.objective == pytest.approx(factor * 1.0**2, rel=1e-8)
    second = solver.solve(params={"distance": 3.0}, x0=[1.0, 0.0], warm_start=first)
    assert second.success, second.status
    assert second.objective == pytest.approx(factor * 2.0**2, rel=1e-8)
    cold = solver.solve(params={"distance": 3.0}, x0=[1.0, 0.0])
    np.testing.assert_allclose(second.states, cold.states, atol=1e-7)


def test_warm_start_from_the_answer_converges_at_once():
    solver = swing_up().solver(mpc.Collocation(intervals=40))
    first = solver.solve(guess_input=lambda t: [2 * np.sin(2 * np.pi * t / 4.0)])
    again = solver.solve(warm_start=first)
    assert again.success, again.status
    assert again.iterations <= 5 < first.iterations
    assert again.objective == pytest.approx(first.objective, rel=1e-7)


def test_the_nmpc_problem_posed_here_is_what_nonlinear_mpc_problem_solves():
    """mpc.NonlinearMPCProblem (this layer's OCP, Gauss-Newton SQP to convergence, condensed DAQP QPs)
    and IPOPT (exact Hessian) on the same NLP written by hand here: pendulum, N = 50, Ts = 0.01 s,
    stage cost Σ‖x - x_s‖²_Q + ‖u - u_s‖²_R, terminal ‖x_N - x_s‖²_P, x_0 = x̂, the plant fed u + d̂,
    |u| <= 5 N. Same KKT point."""
    plant = models.perturbed(models.get("pendulum"), 0.05)
    sample_period, horizon = 0.01, 50
    Q, R, P = np.diag([1.0, 10.0, 0.1, 0.1]), np.array([[1e-2]]), np.diag([10.0, 50.0, 5.0, 5.0])
    x_hat, d_hat, x_s, u_s = np.array([0.1, 0.15, -0.2, 0.3]), np.array([0.5]), np.array([0.6, 0, 0, 0]), np.zeros(1)
    problem = mpc.NonlinearMPCProblem(
        plant, sample_period, horizon, Q, R, iteration="sqp", tolerance=1e-11, compiled=False
    )
    ours = problem.solve(x_hat, d_hat, x_s, u_s, P, np.zeros(1), np.zeros((horizon, 1)))
    assert ours.success, ours.status
    assert 0 < np.sum(np.abs(ours.inputs) < 4.9) < horizon  # some inputs saturate, some do not

    ocp = mpc.OptimalControlProblem(plant, horizon * sample_period)
    ocp.start_from()
    disturbance, state_target = ocp.parameter("d_hat", 1), ocp.parameter("x_s", 4)
    input_target, terminal = ocp.parameter("u_s", 1), ocp.parameter("P", 16)
    ocp.plant_input(ocp.input + disturbance)
    stage = ca.bilin(ca.DM(Q), ocp.state - state_target) + ca.bilin(ca.DM(R), ocp.input - input_target)
    ocp.minimize(ocp.sum(stage) + ocp.at_end(ca.bilin(ca.reshape(terminal, 4, 4), ocp.state - state_target)))
    solver = ocp.solver(mpc.MultipleShooting(intervals=horizon), tolerance=1e-12)
    values = {"d_hat": d_hat, "x_s": x_s, "u_s": u_s, "P": P.T.ravel()}
    reference = solver.solve(x0=x_hat, params=values)
    assert reference.success, reference.status
    np.testing.assert_allclose(ours.inputs, reference.inputs, atol=1e-7)
    np.testing.assert_allclose(ours.states, reference.states, atol=1e-8)
    # One sample later, warm-started: fewer iterations than from scratch.
    later = solver.solve(x0=reference.states[1], params=values, warm_start=reference)
    cold = solver.solve(x0=reference.states[1], params=values)
    assert later.success and later.iterations < cold.iterations
    np.testing.assert_allclose(later.inputs, cold.inputs, atol=1e-6)


def test_an_interval_constraint_on_x_next_bounds_the_next_mesh_state():
    """On a double integrator, x_next.s <= 0.5 on every interval holds mesh states 1..N at or below
    0.5, as a path constraint without the start does (IPOPT on both, same answer)."""
    mass = point_mass(mass=1.0, limit=100.0)
    solutions = []
    for kind in ("interval", "path"):
        ocp = mpc.OptimalControlProblem(mass, 2.0)
        ocp.start_from([0.0, 0.0])
        ocp.minimize(ocp.sum((ocp.x.s - 1.0) ** 2 + 1e-3 * ocp.u.f**2))
        if kind == "interval":
            ocp.subject_to(ocp.x_next.s <= 0.5)
        else:
            ocp.subject_to(ocp.x.s <= 0.5, include_start=False)
        solution = ocp.solve(mpc.MultipleShooting(intervals=20), solver_options={"tolerance": 1e-12})
        assert solution.success, solution.status
        solutions.append(solution)
    assert np.max(solutions[0].states[:, 0]) == pytest.approx(0.5, abs=1e-7)
    np.testing.assert_allclose(solutions[0].states, solutions[1].states, atol=1e-7)
    ocp = mpc.OptimalControlProblem(mass, 1.0)
    ocp.minimize(ocp.sum(ocp.u.f**2))
    ocp.subject_to(ocp.u.f - ocp.u_previous.f <= 1.0)
    with pytest.raises(ValueError, match="u_previous: give the input before the first interval"):
        ocp.solve(mpc.MultipleShooting(intervals=5))
    with pytest.raises(ValueError, match="cannot use x_next or u_previous"):
        ocp.sum(ocp.x_next.s)


@pytest.mark.parametrize("kind", ["limited-memory", "trajectory", "simulated input"])
def test_hessian_option_and_guesses_reach_the_same_minimum_energy_answer(kind):
    plant = point_mass(mass=1.0, limit=100.0)
    ocp = rest_to_rest(plant, 2.0, 1.5)
    ocp.minimize(ocp.integral(ocp.u.f**2))
    reference = 12 * 1.5**2 / 8 * 400 / 399
    method = mpc.Collocation(intervals=20)
    if kind == "limited-memory":
        solution = ocp.solve(method, solver_options={"hessian": "limited-memory"})
    elif kind == "trajectory":
        run = models.simulate(plant, [0, 0], np.full((20, 1), 0.5), 0.1)
        solution = ocp.solve(method, guess=run)
    else:
        solution = ocp.solve(method, guess_input=lambda t: [1.0 if t < 1 else -1.0])
    assert solution.success, solution.status
    assert solution.objective == pytest.approx(reference, rel=1e-6)


# --------------------------------------------------------------------------- bad input
def test_infeasible_problem_says_so_and_names_the_worst_constraint():
    """A final time shorter than 2 sqrt(d / a) cannot be met within the force limit. The rows of
    the returned point are recomputed here from its states (Radau IIA, `radau_matrices`):
    the named row is the worst one, by the reported amount."""
    plant = point_mass(mass=1.0, limit=1.0)
    ocp = rest_to_rest(plant, 1.0, 1.0)  # needs T >= 2 s
    ocp.minimize(ocp.integral(ocp.u.f**2))
    solution = ocp.solve(mpc.Collocation(intervals=10, degree=3))
    assert not solution.success
    assert solution.status.startswith("infeasible")
    label, amount = solution.largest_violation
    assert label in solution.status
    _, deriv = radau_matrices(3)
    rows = {}
    for k, h in enumerate(np.diff(solution.t)):
        nodes = np.vstack([solution.states[k], solution.collocation_states[k]])  # (4, [s, ds])
        for j in range(3):
            rate = np.array([nodes[j + 1, 1], solution.inputs[k, 0]])  # s' = ds, ds' = f / m
            for i, name in enumerate(("s", "ds")):
                residual = h * rate[i] - nodes[:, i] @ deriv[:, j]
                rows[f"collocation of {name} on interval {k}, point {j + 1}"] = abs(residual)
        for i, name in enumerate(("s", "ds")):
            rows[f"continuity of {name} at mesh point {k + 1}"] = abs(solution.states[k + 1, i] - nodes[3, i])
    worst = max(rows, key=rows.get)
    assert (label, amount) == (worst, pytest.approx(rows[worst], rel=1e-6))
    assert amount > 1e-2
    assert np.max(np.abs(solution.inputs)) <= 1.0 + 1e-6  # bounds are kept; the dynamics give way


def test_errors_name_the_argument():
    plant = point_mass()
    ocp = mpc.OptimalControlProblem(plant, 1.0)
    with pytest.raises(ValueError, match="no state 'speed'.*states are s, ds"):
        _ = ocp.x.speed
    with pytest.raises(ValueError, match="no input 'F'"):
        ocp.u["F"]
    with pytest.raises(ValueError, match="no parameter 'k'"):
        ocp.choose("k", 1, 2)
    with pytest.raises(ValueError, match="lower bound must be finite and > 0"):
        mpc.FreeTime(0.0, 2.0)
    with pytest.raises(ValueError, match="lower bound must be finite and > 0"):
        mpc.FreeTime(-1.0, 2.0)
    with pytest.raises(ValueError, match="final_time must be finite and > 0"):
        mpc.OptimalControlProblem(plant, 0.0)
    for degree in (0, 6, 2.5):
        with pytest.raises(ValueError, match=f"degree must be an integer from 1 to 5, got {degree}"):
            mpc.Collocation(degree=degree)
    with pytest.raises(ValueError, match="intervals must be an integer >= 1, got 0"):
        mpc.Collocation(intervals=0)
    with pytest.raises(ValueError, match="intervals must be an integer >= 1, got 0"):
        mpc.MultipleShooting(intervals=0)
    with pytest.raises(ValueError, match="points must be one of legendre, radau"):
        mpc.Collocation(points="chebyshev")
    with pytest.raises(ValueError, match="objective depends on the path"):
        ocp.minimize(ocp.x.s)
    with pytest.raises(ValueError, match="needs a relation"):
        ocp.subject_to(ocp.x.s + 1)
    with pytest.raises(ValueError, match="mixes the path"):
        ocp.subject_to(ocp.x.s <= ocp.at_end(ocp.x.s))
    with pytest.raises(ValueError, match="no objective"):
        ocp.solver()
    ocp.minimize(ocp.integral(ocp.u.f**2))
    solver = ocp.solver(mpc.Collocation(intervals=4))
    with pytest.raises(ValueError, match="x0 given, but the problem has no start_from"):
        solver.solve(x0=[0, 0])
    with pytest.raises(ValueError, match="params: the problem has no parameter 'distance'"):
        solver.solve(params={"distance": 1.0})
    with pytest.raises(ValueError, match="plant_params: 'k' is not a fixed parameter"):
        solver.solve(plant_params={"k": 1.0})
    with pytest.raises(ValueError, match="hessian must be one of exact, limited-memory"):
        ocp.solver(hessian="bfgs")
