"""The case studies' optimal trajectories against independent answers.

- every problem: `verify()` (CVODES re-simulation of the held input) below the tolerance;
- arm: the minimum time against the exact bang-bang with one switch, found by shooting on the
  hand-derived equation J θ̈ = τ − m g ℓ/2 cos θ − b θ̇ (J = m ℓ²/3) with SciPy;
- crane: the minimum time between a lower bound from the momentum of car and loads and the
  settling time of the text's VI.14 pole placement on the same step (an upper bound);
  the ZV shaper on crane1 against the unshaped command;
- pendulum: the swing-up tracked under the ±5 % parameter error stays up, within the actuator
  and near the travel bound, where the feedforward alone falls.

The default suite solves each case once on its --quick meshes (a few seconds each).
"""

import html
import math
import re
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

import models
import mpc
import studies
from designs import input_shaping
from models import metrics
from studies import trajectories
from studies.cases import crane as crane_case

CASES = [name for name in studies.names() if studies.get(name).trajectories]


@pytest.fixture(scope="module")
def solved():
    cache = {}

    def get(name):
        if name not in cache:
            cache[name] = trajectories.solve_case(studies.get(name), quick=True, strict=True)
        return cache[name]

    return get


def test_the_three_cases_declare_trajectories():
    assert {"pendulum", "crane", "arm"} <= set(CASES)


@pytest.mark.parametrize("name", CASES)
def test_every_trajectory_solves_and_verifies(name, solved):
    result = solved(name)
    case = studies.get(name)
    assert list(result.solved) == [p.key for p in case.trajectories]
    assert not result.notes
    for key, done in result.solved.items():
        assert done.solution.success, (key, done.solution.status)
        v = done.verification
        assert v.max_interval_defect < trajectories.DEFECT_TOLERANCE, (key, v)
        assert v.max_defect < 10 * trajectories.DEFECT_TOLERANCE, (key, v)  # from x(0), over the whole horizon
        assert done.verified
        limit = result.plant.input_limit[0]
        assert np.max(np.abs(done.solution.inputs)) <= limit * (1 + 1e-6)


# ------------------------------------------------------------------------------------------- arm
def arm_exact_minimum_time(params, limit, target):
    """Bang-bang, one switch: +limit until t_s, then −limit until θ̇ = 0; t_s such that θ stops at the target."""
    m, ell, g, b = params["m"], params["ell"], params["g"], params["b"]
    inertia = m * ell**2 / 3

    def rhs(torque):
        return lambda t, s: [s[1], (torque - m * g * ell / 2 * math.cos(s[0]) - b * s[1]) / inertia]

    stopped = lambda t, s: s[1]
    stopped.terminal, stopped.direction = True, -1

    def stop(switch):
        first = solve_ivp(rhs(limit), (0, switch), [0.0, 0.0], rtol=1e-12, atol=1e-12)
        second = solve_ivp(rhs(-limit), (switch, switch + 5), first.y[:, -1], events=stopped, rtol=1e-12, atol=1e-12)
        return second.t_events[0][0], second.y_events[0][0][0]

    switch = brentq(lambda s: stop(s)[1] - target, 0.05, 1.0, xtol=1e-13)
    return stop(switch)[0], switch


def test_arm_minimum_time_is_the_one_switch_bang_bang(solved):
    result = solved("arm")
    solution = result.solved["point_to_point_time"].solution
    plant = result.plant
    exact, switch = arm_exact_minimum_time(plant.params, float(plant.input_limit[0]), studies.get("arm").step)
    h = solution.final_time / len(solution.inputs)
    # The held input can only switch on a mesh point: T is at most about one interval above the exact time,
    # never below it (to the transcription's accuracy).
    assert exact - 1e-6 <= solution.final_time <= exact + h
    before, after = solution.t[1:] <= switch - h, solution.t[:-1] >= switch + h
    np.testing.assert_allclose(solution.inputs[before, 0], 1.0, atol=1e-6)
    np.testing.assert_allclose(solution.inputs[after, 0], -1.0, atol=1e-6)


# ------------------------------------------------------------------------------------------- crane
def momentum_lower_bound(mass, damping, force, distance):
    """A lower bound on any rest-to-rest move of the car by `distance` that never goes behind its start.

    With X the centre of mass of car and loads, M Ẍ = F − b ẋ. Let w = M Ẋ + b (x − x₀): ẇ = F,
    w(0) = 0 and w(T) = b d. Since x ≥ x₀, M d = ∫ M Ẋ dt ≤ ∫ w dt, and the largest ∫ w under |ẇ| ≤ F
    is the tent rising at F then falling at F: F/2 (T² − (T − δ)²/2), δ = b d / F. T must make it
    reach M d. Without friction (δ = 0) this is the rigid body's bang-bang time 2 √(M d / F).
    """
    delta = damping * distance / force
    reach = lambda T: force / 2 * (T**2 - (T - delta) ** 2 / 2) - mass * distance
    return brentq(reach, delta, 100.0)


def test_momentum_bound_without_friction_is_the_rigid_body_bang_bang():
    assert momentum_lower_bound(2200.0, 0.0, 5000.0, 10.0) == pytest.approx(2 * math.sqrt(2200 * 10 / 5000))
    # Friction lets w end above zero, so the bound is lower (weaker) than the frictionless one.
    assert momentum_lower_bound(2200.0, 200.0, 5000.0, 10.0) < 2 * math.sqrt(2200 * 10 / 5000)


@pytest.fixture(scope="module")
def pole_placement_step():
    """The text's VI.14 pole placement (designed on the +5 % model) on the 10 m step, nonlinear crane."""
    from studies import homework

    case = studies.get("crane")
    plant = models.get("crane")
    block = homework.statespace_controllers(case, case.known_plant(plant))["pole placement"]
    return models.simulate_closed_loop(plant, block, case.step, case.duration, substeps=case.substeps)


def test_crane_minimum_time_lies_between_the_bounds(solved, pole_placement_step):
    result = solved("crane")
    solution = result.solved["transfer_time"].solution
    plant, case = result.plant, studies.get("crane")
    x = solution.state("x")
    assert np.min(x) >= -1e-6  # the bound's premise: the car never goes behind its start
    mass, damping = crane_case.rigid_body(plant)
    lower = momentum_lower_bound(mass, damping, float(plant.input_limit[0]), case.step)
    run = pole_placement_step
    upper = metrics.step_metrics(run.t, run.state("x"), initial=0.0, target=case.step)["settling_time_s"]
    assert lower < solution.final_time < upper
    # Both loads at rest and the swing bound held on the re-simulation (not only at the NLP's nodes).
    simulated = result.solved["transfer_time"].verification.simulated
    assert np.max(np.abs(simulated[:, 1:3])) <= crane_case.TRANSFER_SWING + 1e-4
    np.testing.assert_allclose(simulated[-1], [case.step, 0, 0, 0, 0, 0], atol=1e-4)


def test_crane_step_comparison_lists_the_open_loop_commands(solved):
    rows = {c.label: c.row for c in solved("crane").compared["transfer_time"]}
    optimal = next(r for label, r in rows.items() if label.startswith("optimal"))
    shaped = rows["ZV-ZV, bang-bang within the swing bound"]
    # The shaped command honours the swing bound it was sized for, and is slower than the optimum.
    assert shaped["max_abs_theta1"] <= crane_case.TRANSFER_SWING + 1e-6
    assert shaped["move_time_s"] > optimal["move_time_s"]
    assert optimal["residual_theta1"] < 1e-4 and optimal["residual_theta2"] < 1e-4


def test_zv_shaper_on_crane1_removes_the_residual_swing():
    """On the one-load crane the ZV-shaped bang-bang leaves a tenth of the unshaped one's swing, or less."""
    crane1 = models.get("crane1")
    omega, zeta = crane_case.swing_modes(crane1)[0]
    residual = {}
    for label, shaper in (
        ("shaped", input_shaping.zero_vibration(omega, zeta)),
        ("unshaped", input_shaping.Shaper([0.0], [1.0])),
    ):
        command = crane_case.shaped_bang_bang(crane1, shaper, 2000.0, label)
        padded = np.vstack([command.inputs, np.zeros((2000, 1))])
        run = models.simulate(crane1, np.zeros(4), padded, command.sample_period, substeps=2)
        after = run.t >= command.sample_period * len(command.inputs)
        residual[label] = np.max(np.abs(run.state("theta")[after]))
    assert residual["unshaped"] > 0.02
    assert residual["shaped"] < 0.1 * residual["unshaped"]


@pytest.mark.slow
def test_crane_minimum_time_by_multiple_shooting_agrees():
    case = studies.get("crane")
    plant = models.get("crane")
    setup = crane_case.transfer_time(plant, False, {})
    collocation = setup.problem.solve(setup.transcription)
    shooting = crane_case.transfer_time(plant, False, {}).problem.solve(
        mpc.MultipleShooting(intervals=80), guess=collocation
    )
    assert collocation.success and shooting.success
    assert shooting.final_time == pytest.approx(collocation.final_time, rel=0.01)
    assert case.trajectories[0].key == "transfer_time"


# ------------------------------------------------------------------------------------------- pendulum
def test_swing_up_tracking_stays_up_under_the_parameter_error(solved):
    result = solved("pendulum")
    tracked = result.tracking["swing_up_effort"]
    spec = studies.get("pendulum").trajectories[0].tracking
    assert len(tracked.rows) == 1 + spec.samples
    for row in tracked.rows:
        # Stays up: within 1° of upright and 5 cm of the middle through the last second.
        assert row["held"], row
        assert row["final_dev_theta"] <= math.radians(1.0) and row["final_dev_z"] <= 0.05
        assert row["peak_u"] <= 5.0 + 1e-9
        assert row["max_abs_z"] <= 0.55  # the planned ±0.5 m travel plus 5 cm of tracking error
    # The catch: the last sample's state is upright and at rest.
    np.testing.assert_allclose(tracked.nominal.x[-1], 0.0, atol=0.01)
    # The feedback does the work: the planned input alone, open loop on the nominal plant, does not stay up.
    planned = tracked.planned
    alone = models.simulate(
        result.plant, planned.states[0], planned.inputs, planned.final_time / len(planned.inputs), method="adaptive"
    )
    assert abs(alone.state("theta")[-1]) > math.radians(5)


def test_minimum_time_swing_up_is_bang_bang_and_faster(solved):
    result = solved("pendulum")
    fastest = result.solved["swing_up_time"].solution
    effort = result.solved["swing_up_effort"].solution
    assert fastest.final_time < effort.final_time
    at_limit = np.abs(fastest.inputs[:, 0]) >= 0.99 * 5.0
    assert at_limit.mean() > 0.7
    assert np.max(np.abs(fastest.state("z"))) <= 0.5 + 1e-6


# ------------------------------------------------------------------------------------------- files
def test_write_leaves_the_tables_figures_and_animations(solved, tmp_path):
    result = solved("crane")
    files = trajectories.write(result, tmp_path)
    folder = tmp_path / "crane"
    for name in (
        "trajectories.md",
        "trajectories.csv",
        "trajectory_transfer_time.png",
        "trajectory_transfer_time.gif",
        "trajectory_transfer_time.html",
        "trajectory_transfer_time_comparison.png",
        "trajectory_transfer_time_comparison.csv",
    ):
        assert (folder / name).stat().st_size > 0, name
        assert name in files
    table = pd.read_csv(folder / "trajectories.csv")
    solution = result.solved["transfer_time"].solution
    assert table.final_time_s.iloc[0] == pytest.approx(solution.final_time, rel=1e-9)
    text = (folder / "trajectories.md").read_text()
    assert f"{solution.final_time:.4g}" in text and "ZV-ZV" in text
    assert "not run with these trajectories" in text  # no study result was given
    page = (folder / "trajectory_transfer_time.html").read_text()
    title = re.search(r"<title>(.*)</title>", page).group(1)
    problem_title = result.solved["transfer_time"].problem.title
    assert title == html.escape(f"{result.plant.title}: {problem_title}") and "text's step" not in title


def test_the_study_writes_its_trajectories_beside_its_table(arm_study):
    _, out = arm_study
    text = (out / "arm" / "trajectories.md").read_text()
    assert "Against the study's step responses" in text
    comparison = pd.read_csv(out / "arm" / "trajectory_point_to_point_time_comparison.csv")
    assert comparison.command.str.startswith("closed loop: ").sum() >= 1


def test_bad_declarations_are_named():
    build = studies.get("arm").trajectories[0].build
    with pytest.raises(ValueError, match="key must be an identifier"):
        trajectories.TrajectoryProblem("point to point", "x", build)
    with pytest.raises(ValueError, match="headroom must be in"):
        trajectories.TrajectoryProblem("p", "x", build, tracking=trajectories.Tracking({}, (1.0,), headroom=1.0))


def test_the_plant_title_is_shown_literally_in_the_trajectories_heading():
    """trajectories.md's heading escapes the plant's title (free text) as table.md's does."""
    result = SimpleNamespace(
        case=SimpleNamespace(input_unit="N m"), plant=SimpleNamespace(title="<b>Arm</b> & co"), solved={}, quick=False
    )
    text = trajectories.report.markdown(result, {}, [])
    assert text.splitlines()[0] == r"# \<b\>Arm\</b\> \& co: optimized trajectories"
