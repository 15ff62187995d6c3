"""The global layer over closed-loop co-design, on the first-order problem with a rippled plant price.

x' = −b x + u under u = −k x sampled at Ts (zero-order hold), cost Σ Ts (q x² + r u²) from x = 1, plus the
plant price w b + a cos(2π b / P): the closed form of the sampled loop (`sampled_psi`, as in
tests/designs/test_codesign.py) minimized over k at each b on a fine scan gives Ψ*(b), whose four local
minima in b ∈ [0.1, 2] the layer must list, and whose least it must return, from either method.
"""

import pickle

import casadi as ca
import numpy as np
import pytest
import scipy.optimize

import models
from designs.codesign import Codesign, check_ranges, codesign
from designs.codesign_global import GLOBAL_METHODS, ClosedLoopWork, codesign_globally
from designs.tuning import Cost, Scenario, SolveOptions, TuningSetup, checked_options
from studies import distributed

Q, R, W, RIPPLE, PERIOD, TS = 1.0, 1.0, 0.5, 0.05, 0.5, 0.1
B_RANGE, K_BOUNDS = (0.1, 2.0), (0.0, 10.0)


@models.declare(
    name="lag_b_global",
    title="x' = -b x + u",
    coordinates=(),
    inputs=("u",),
    first_order=("x",),
    params=(models.Param("b", 1.0, "1/s"),),
    input_limit=1e6,
    register=False,
)
def _lag(q, dq, u, p, s):
    return models.Physics(rates={"x": -p.b * s.x + u.u}, outputs={"x": s.x})


class Proportional(models.Block):
    """u = −k x (reads the state, no reference)."""

    def __init__(self, k, sample_period):
        super().__init__(
            sample_period=sample_period,
            n_state=0,
            n_measured=1,
            n_reference=0,
            n_input=1,
            gains={"k": k},
            measures="state",
        )

    def expr(self, xc, y, r, g):
        return xc, -g["k"] * y[0]


def price(p):
    return W * p["b"] + RIPPLE * ca.cos(2 * np.pi * p["b"] / PERIOD)


def sampled_star(b):
    """min over k of the sampled loop's cost (x⁺ = φ x + γ u, φ = e^{−b Ts}, γ = (1 − φ)/b), plus the price."""

    def psi(k):
        lam = np.exp(-b * TS) - (1 - np.exp(-b * TS)) / b * k
        return TS * (Q + R * k**2) / (1 - lam**2)

    found = scipy.optimize.minimize_scalar(psi, bounds=K_BOUNDS, method="bounded", options={"xatol": 1e-12})
    return found.fun + W * b + RIPPLE * np.cos(2 * np.pi * b / PERIOD)


@pytest.fixture(scope="module")
def scan_minima():
    bs = np.linspace(*B_RANGE, 1901)
    js = np.array([sampled_star(b) for b in bs])
    minima = []
    for i in np.flatnonzero((js[1:-1] < js[:-2]) & (js[1:-1] < js[2:])) + 1:
        found = scipy.optimize.minimize_scalar(sampled_star, bounds=(bs[i - 1], bs[i + 1]), method="bounded")
        minima.append((float(found.x), float(found.fun)))
    return sorted(minima, key=lambda m: m[1])


def setup():
    scenario = Scenario(reference=None, duration=20.0, x0=[1.0], name="regulation from x = 1")
    cost = Cost(kind=None, state_weights={"x": Q}, input_weights={"u": R})
    return TuningSetup(models.Plant(_lag), Proportional(1.0, TS), scenario, cost=cost, bounds={"k": K_BOUNDS})


def test_the_scan_has_four_minima(scan_minima):
    assert len(scan_minima) == 4


@pytest.mark.parametrize("method", GLOBAL_METHODS)
def test_the_global_layer_lists_the_scans_minima_and_returns_the_least(method, scan_minima):
    """b to 1 % and the objective to 1e-4 relative: the 20 s run against the infinite sum, IPOPT's tolerance.

    The nested refinement stays in its sweep cell and finds all four; IPOPT's simultaneous steps may leave a
    cell for a neighbouring minimum, so it lists a subset of them, the global one first."""
    result = codesign_globally(
        setup(), {"b": B_RANGE}, method=method, plant_cost=price, options=SolveOptions(tol=1e-10), samples=16, keep=4
    )
    assert result.converged and len(result.optima) == (4 if method == "nested" else len(result.optima))
    for optimum in result.optima:
        b, j = min(scan_minima, key=lambda m: abs(m[0] - optimum.params["b"]))
        assert optimum.success and optimum.params["b"] == pytest.approx(b, rel=0.01)
        assert optimum.objective == pytest.approx(j, rel=1e-4)
    b, j = scan_minima[0]
    assert result.best.params["b"] == pytest.approx(b, rel=0.01) and result.best.objective == pytest.approx(j, rel=1e-4)
    assert result.answer.params["b"] == result.best.params["b"] and result.answer.feasible
    assert "grid of 16 points" in result.design


def test_a_plain_simultaneous_solve_from_the_middle_stops_on_a_local_optimum(scan_minima):
    """What the layer is for: the plain simultaneous method, started mid-range, is not on the global optimum."""
    plain = codesign(
        setup(), {"b": B_RANGE}, plant_cost=price, options=SolveOptions(tol=1e-10), methods=["simultaneous"]
    )
    found = plain["simultaneous"].params["b"]
    assert any(found == pytest.approx(b, rel=0.01) for b, _ in scan_minima[1:])


def test_a_sweep_beyond_the_budget_is_refused_before_it_runs():
    with pytest.raises(ValueError, match="samples = 1000"):
        codesign_globally(setup(), {"b": B_RANGE}, plant_cost=price, samples=1000, max_seconds=1.0)


def _arm_work():
    """The layer's work on the arm's length ℓ in [0.2, 0.4] m with a PD (a registered plant: it travels)."""
    from tests.designs.test_tuning import ArmPD  # deferred: a test module, imported only by the tests using it

    arm = models.get("arm")
    scenario = Scenario(reference=np.deg2rad(50), duration=2.0, tracked="theta")
    setup = TuningSetup(
        arm, ArmPD(arm, kp=2.0, kd=0.2), scenario, cost=Cost("itae"), bounds={"kp": (0, 5), "kd": (0, 1)}
    )
    return setup


def test_the_sweeps_work_travels_by_pickle_with_the_same_numbers():
    """What a worker process receives: the work pickled (the joint problem left out and built again on
    arrival) gives the tuning at a point bit for bit."""
    setup = _arm_work()
    problem = Codesign(setup, check_ranges(setup.plant, {"ell": (0.2, 0.4)}), None, None, checked_options(None))
    work = ClosedLoopWork(problem, "nested", 1e-3, np.array([0.1]))
    travelled = pickle.loads(pickle.dumps(work.evaluate))
    assert travelled.__self__.problem is not problem
    assert travelled((0.3,)) == work.evaluate((0.3,))


@pytest.mark.slow
def test_the_closed_loop_layer_on_two_worker_processes_equals_the_one_process_run_bit_for_bit():
    """The sweep on a Dask LocalCluster of two processes (`studies.distributed`) and in this one: the same
    sweep, optima and answer."""
    here = codesign_globally(_arm_work(), {"ell": (0.2, 0.4)}, samples=4, keep=1)
    with distributed.connect(workers=2) as executor:
        there = codesign_globally(_arm_work(), {"ell": (0.2, 0.4)}, samples=4, keep=1, map=executor.map)
    assert here.sweep == there.sweep and here.optima == there.optima
    assert here.answer.params == there.answer.params and here.answer.objective == there.answer.objective
