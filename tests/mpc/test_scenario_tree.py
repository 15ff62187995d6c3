"""The scenario-tree NMPC: non-anticipativity, the one-branch tree against the nominal NMPC, the state
bounds on every branch (checked by rolling each branch's inputs through its own model), refusals."""

import numpy as np
import pytest

import models
import studies
from models.uncertainty import corner_params
from mpc import SoftBound, nonlinear_mpc
from mpc.scenario_tree import ScenarioTreeMPC, scenario_tree_mpc, stacked_plant

CASE = studies.get("pendulum")
PLANT = models.get("pendulum")
KNOWN = CASE.known_plant(PLANT)
#: The cart's travel as a soft bound, the quantity the tree must hold on every branch.
TRAVEL = SoftBound.on(KNOWN, {"z": 1.0}, -0.5, 0.5, linear_weight=1e3, quadratic_weight=1e2, name="cart travel")
#: Four branches: the corners of ±10 % in the pendulum's mass and length.
BRANCHES = corner_params(PLANT, rel=0.1, names=["m2", "ell"])
#: The cart 0.4 m out and moving outwards at 0.6 m/s: the 5 N limit barely stops it within 0.5 m.
START = np.array([0.4, 0.0, 0.6, 0.0])


def one_step(controller, x0):
    """The controller's first step from the state x0 (its estimate set to x0): the plan (N, nu)."""
    xc = controller.initial_state(KNOWN.output(x0), [0.0])
    xc[: KNOWN.nx] = x0
    xc_next, _ = controller.step(xc, KNOWN.output(x0), np.array([0.0]))
    return xc_next[KNOWN.nx + KNOWN.nu :].reshape(-1, KNOWN.nu)


def largest_travel(inputs, params) -> float:
    """Largest z along the model with `params` from START under `inputs` (N, nu): a rollout independent
    of the controller's own prediction."""
    step = KNOWN.step_function(CASE.mpc.sample_period, CASE.mpc.substeps)
    x, largest = START.copy(), -np.inf
    for u in inputs:
        x = np.asarray(step(x, u, params)).ravel()
        largest = max(largest, x[0])
    return largest


def tree(branches=BRANCHES, **overrides):
    arguments = dict(tracked="z", compiled=False, horizon=30) | overrides
    return scenario_tree_mpc(KNOWN, CASE.mpc, branches, **arguments)


@pytest.fixture(scope="module")
def solved():
    """A converged solve from START of the tree with robust horizon 3 and the cart-travel bound, and the
    nominal NMPC's plan from there with the same settings: (controller, inputs (N, S, nu), nominal plan)."""
    converged = dict(iteration="sqp", soft_bounds=(TRAVEL,))
    nominal = nonlinear_mpc(KNOWN, CASE.mpc, tracked="z", compiled=False, horizon=30, **converged)
    controller = tree(robust_horizon=3, **converged)
    one_step(controller, START)
    return controller, controller.nlp.branch_inputs(controller.nlp.last), one_step(nominal, START)


def test_first_move_is_the_same_on_every_branch_and_later_moves_react(solved):
    controller, inputs, _ = solved
    assert controller.step_info()["success"]
    spread = np.ptp(inputs, axis=1).max(axis=1)
    assert spread[:3].max() < 1e-9  # shared moves: non-anticipativity
    assert spread[3:].max() > 1e-3  # after the robust horizon each branch plans for its own model


@pytest.mark.slow  # builds a second tree: about 10 s
def test_robust_horizon_equal_to_the_horizon_shares_every_move():
    controller = tree(robust_horizon=30)
    one_step(controller, START)
    inputs = controller.nlp.branch_inputs(controller.nlp.last)
    assert np.ptp(inputs, axis=1).max() < 1e-9


def test_one_branch_equals_the_nominal_nmpc_in_closed_loop():
    nominal = nonlinear_mpc(KNOWN, CASE.mpc, tracked="z", compiled=False, horizon=30)
    single = tree([KNOWN.param_vector()])
    x0 = np.array([0.1, 0.05, 0.0, 0.0])
    a = models.simulate_closed_loop(PLANT, nominal, 0.3, 0.5, x0=x0, input_disturbance=0.5)
    b = models.simulate_closed_loop(PLANT, single, 0.3, 0.5, x0=x0, input_disturbance=0.5)
    assert np.max(np.abs(a.u)) > 1.0  # the run does something
    np.testing.assert_allclose(b.u, a.u, rtol=0, atol=1e-9)
    np.testing.assert_allclose(b.x, a.x, rtol=0, atol=1e-9)


def test_state_bound_holds_on_every_branch_where_the_nominal_plan_leaves_it(solved):
    controller, inputs, nominal_plan = solved
    # The nominal plan, rolled through the branches' models, leaves the travel on some branch ...
    assert max(largest_travel(nominal_plan, p) for p in BRANCHES) > 0.5 + 1e-3
    # ... the tree's plan for each branch, rolled through that branch's model, does not.
    for i, params in enumerate(BRANCHES):
        assert largest_travel(inputs[:, i], params) <= 0.5 + 1e-6
    assert controller.step_info()["soft_violation"] < 1e-6


def test_stacked_plant_moves_each_branch_by_its_own_parameters():
    stacked = stacked_plant(KNOWN, BRANCHES)
    x = np.tile(START, len(BRANCHES)) + 0.01 * np.arange(4 * len(BRANCHES))
    u = np.array([1.0, -2.0, 0.5, 3.0])
    xdot = stacked.f(x, u)
    for i, params in enumerate(BRANCHES):
        alone = KNOWN.f(x[4 * i : 4 * i + 4], u[i : i + 1], params)
        np.testing.assert_allclose(xdot[4 * i : 4 * i + 4], alone, rtol=1e-14, atol=1e-14)


@pytest.mark.parametrize(
    "arguments, message",
    [
        (dict(branches=np.zeros((0, 4))), "at least one branch"),
        (dict(branches=[]), "at least one branch"),
        (dict(robust_horizon=0), "robust_horizon"),
        (dict(robust_horizon=31), "at most the horizon"),
        (dict(weights=[0.5, 0.5, 0.5, 0.5]), "sum to 1"),
        (dict(weights=[0.5, 0.5]), "one entry per branch"),
        (dict(weights=[1.0, 0.5, -0.5, 0.0]), ">= 0"),
        (dict(weights=[1.0, 0.0, 0.0, 0.0]), "> 0"),
        (dict(branches=[[1.0, 2.0]]), "branch 1"),
        (dict(branches=[{"m2": -1.0}]), "branch 1"),
    ],
)
def test_bad_input_is_refused_at_construction(arguments, message):
    branches = arguments.pop("branches", BRANCHES)
    with pytest.raises(ValueError, match=message):
        ScenarioTreeMPC(
            KNOWN,
            branches,
            tracked="z",
            compiled=False,
            sample_period=CASE.mpc.sample_period,
            horizon=30,
            state_weight=np.array(CASE.mpc.state_weight),
            input_weight=CASE.mpc.input_weight,
            **arguments,
        )


def test_the_generated_condensing_of_the_stacked_plant_equals_casadis():
    """`mpc.condensing`'s C, which skips the updates whose multiplier is 0 (the stacked plant's A_k, B_k and
    rows are block diagonal by branch), against the CasADi expressions it replaces, entry by entry, on the
    tree's problem with the cart-travel bound and a rate limit at random points."""
    from mpc.rti import RealTimeIteration

    controller = tree(horizon=12, soft_bounds=(TRAVEL,), rate_limit=1.0)
    tr = controller.nlp.inner.transcription
    reference, generated = (RealTimeIteration(tr, compiled=c) for c in (False, True))
    assert generated.condensing is not None
    rng = np.random.default_rng(4)
    S, nx = len(BRANCHES), KNOWN.nx
    for _ in range(3):
        w = rng.normal(scale=0.2, size=tr.layout.size)
        x_hat = np.tile(START, S) + rng.normal(scale=0.01, size=S * nx)
        P = tr.parameter_values(x_hat)
        ours, theirs = generated.prepare(w, P), reference.prepare(w, P)
        same = ours == theirs
        np.testing.assert_allclose(ours[~same], theirs[~same], rtol=1e-12, atol=1e-12 * np.abs(theirs[~same]).max())
