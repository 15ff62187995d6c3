"""The global layer over open-loop co-design, on a landscape with three known local optima.

A mass on a spring, m s'' = −k s + u, moved in T = 2 s from rest at s = −d to rest at s = +d with the least
energy ½∫u² dt, plus a price c·k on the stiffness, k chosen in [0.5, 70] N/m. For a fixed k the problem is
the minimum-energy transfer of a linear system, whose answer is the controllability Gramian's
(x' = A x + B u, W(T) = ∫₀ᵀ e^{Aτ} B Bᵀ e^{Aᵀτ} dτ):

    E*(k) = ½ rᵀ W(T)⁻¹ r,   r = x_T − e^{AT} x_0,   u*(t) = Bᵀ e^{Aᵀ(T−t)} W(T)⁻¹ r.

The free motion takes −d to +d at rest whenever ωT is an odd multiple of π (k = (2n+1)² π² m / T²,
about 2.47, 22.2 and 61.7 N/m), where E* vanishes; with the price c·k, J*(k) = E*(k) + c k has a local
minimum just below each, the first the global one. The scan below finds them on the closed form, W(T)
computed by Van Loan's matrix exponential, independently of the transcription. The input stays far inside
the plant's limit |u| <= 1 N (checked), so the limit plays no part.
"""

import dask
import numpy as np
import pytest
from scipy.linalg import expm
from scipy.optimize import minimize_scalar

import models
import mpc
from models import catalog
from mpc import global_search

MASS, FINAL_TIME, DISTANCE, PRICE, K_RANGE = 1.0, 2.0, 0.05, 1e-3, (0.5, 70.0)
TRANSCRIPTION = mpc.Collocation(intervals=80)


def gramian_energy(k, with_input=False):
    """E*(k) of the continuous-time minimum-energy transfer, by the Gramian; with_input: (E*, max |u*|)."""
    A = np.array([[0.0, 1.0], [-k / MASS, 0.0]])
    B = np.array([[0.0], [1.0 / MASS]])
    van_loan = np.zeros((4, 4))
    van_loan[:2, :2], van_loan[:2, 2:], van_loan[2:, 2:] = -A, B @ B.T, A.T
    E = expm(van_loan * FINAL_TIME)
    W = E[2:, 2:].T @ E[:2, 2:]
    r = np.array([DISTANCE, 0.0]) - expm(A * FINAL_TIME) @ np.array([-DISTANCE, 0.0])
    nu = np.linalg.solve(W, r)
    energy = 0.5 * float(r @ nu)
    if not with_input:
        return energy
    u = [(B.T @ expm(A.T * (FINAL_TIME - t)) @ nu).item() for t in np.linspace(0, FINAL_TIME, 41)]
    return energy, max(abs(np.array(u)))


def total(k):
    return gramian_energy(k) + PRICE * k


@pytest.fixture(scope="module")
def scan_minima():
    """Every local minimum of J*(k) on a fine scan, polished by a bounded Brent search between neighbours."""
    ks = np.linspace(*K_RANGE, 4001)
    js = np.array([total(k) for k in ks])
    assert max(gramian_energy(k, True)[1] for k in ks[::100]) < 0.8  # the actuator limit (1 N) never binds
    inner = np.flatnonzero((js[1:-1] < js[:-2]) & (js[1:-1] < js[2:])) + 1
    minima = []
    for i in inner:
        found = minimize_scalar(total, bounds=(ks[i - 1], ks[i + 1]), method="bounded", options={"xatol": 1e-10})
        minima.append((float(found.x), float(found.fun)))
    return sorted(minima, key=lambda m: m[1])


def transfer(guess=None):
    ocp = mpc.OptimalControlProblem(models.Plant(catalog.spring_mass), FINAL_TIME)
    k = ocp.choose("k", *K_RANGE, guess=guess)
    ocp.minimize(ocp.integral(ocp.u.u**2 / 2) + PRICE * k)
    ocp.subject_to(ocp.at_start(ocp.state) == [-DISTANCE, 0])
    ocp.subject_to(ocp.at_end(ocp.state) == [DISTANCE, 0])
    return ocp


def close(answer_k, answer_j, k, j):
    """The transcription's accuracy: the held input's O(h²) in J (relative 2e-3) and k to 1 %."""
    return abs(answer_k - k) <= 0.01 * k and abs(answer_j - j) <= 2e-3 * abs(j)


def test_the_scan_finds_three_minima_below_the_resonances(scan_minima):
    ks = [k for k, _ in scan_minima]
    resonances = [(2 * n + 1) ** 2 * np.pi**2 * MASS / FINAL_TIME**2 for n in range(3)]
    assert len(ks) == 3
    assert all(r * 0.7 < k < r for k, r in zip(sorted(ks), resonances))
    assert scan_minima[0][0] == min(ks)


@pytest.mark.parametrize("method", global_search.METHODS)
@pytest.mark.parametrize("guess", [None, 15.0, 35.0, 50.0, 70.0])
def test_from_every_start_the_global_layer_returns_the_global_optimum(method, guess, scan_minima):
    """guess None is the plant's nominal stiffness; the plain nested method from 15 N/m stops elsewhere."""
    result = global_search.codesign(transfer(guess), TRANSCRIPTION, method=method)
    k, j = scan_minima[0]
    assert result.converged and result.best.success
    assert close(result.best.params["k"], result.best.objective, k, j)
    assert result.answer is not None and result.answer.success


def test_a_plain_local_solve_stops_on_a_local_optimum(scan_minima):
    """What the layer is for: started at 15 N/m the nested method ends on the second minimum."""
    local = mpc.solve_nested(transfer(15.0), TRANSCRIPTION)
    k, j = scan_minima[1]
    assert local.success and close(local.params["k"], local.objective, k, j)


@pytest.mark.parametrize("method", global_search.METHODS)
def test_the_listed_local_optima_are_the_scans_minima(method, scan_minima):
    result = global_search.codesign(transfer(), TRANSCRIPTION, method=method)
    assert len(result.optima) == len(scan_minima)
    for optimum, (k, j) in zip(result.optima, scan_minima):
        assert optimum.success and close(optimum.params["k"], optimum.objective, k, j)
    assert "grid of 12 points" in result.design and "least objective" in result.how


def dask_threads(function, items):
    return list(dask.compute(*[dask.delayed(function)(item) for item in items], scheduler="threads"))


def test_the_dask_run_equals_the_one_process_run_bit_for_bit():
    """Dask's threads scheduler, two workers: each sweep point and each refinement starts from the same
    start, so neither the order nor the thread changes a bit."""
    here = global_search.codesign(transfer(35.0), TRANSCRIPTION, samples=8)
    with dask.config.set(num_workers=2):
        there = global_search.codesign(transfer(35.0), TRANSCRIPTION, samples=8, map=dask_threads)
    assert here.sweep == there.sweep
    assert here.optima == there.optima
    assert np.array_equal(here.answer.decision, there.answer.decision)


def test_a_sweep_beyond_the_budget_is_refused_before_it_runs():
    with pytest.raises(ValueError, match="samples = 400"):
        global_search.codesign(transfer(), TRANSCRIPTION, samples=400, max_seconds=1.0)
    with pytest.raises(ValueError, match="samples = 50"):
        global_search.codesign(transfer(), TRANSCRIPTION, samples=50, max_memory=1e3)


# ----------------------------------------------------------------- the generic layer
def bumps(values):
    """A 2-D landscape with four local minima at (±1, ±1), the global one at (1, −1)."""
    x, y = values
    depth = {(1, -1): 1.0, (-1, -1): 0.8, (1, 1): 0.6, (-1, 1): 0.4}
    return -sum(d * np.exp(-4 * ((x - a) ** 2 + (y - b) ** 2)) for (a, b), d in depth.items())


def evaluate_bumps(values):
    return float(bumps(values)), True


def refine_bumps(values):
    from scipy.optimize import minimize

    found = minimize(bumps, values, method="L-BFGS-B", bounds=[(-2, 2)] * 2, options={"ftol": 1e-14, "gtol": 1e-10})
    return global_search.LocalOptimum(
        {"x": float(found.x[0]), "y": float(found.x[1])}, float(found.fun), bool(found.success), "", {}
    )


def test_a_grid_of_two_parameters_finds_all_four_minima_and_the_global_one():
    result = global_search.search(evaluate_bumps, refine_bumps, {"x": (-2, 2), "y": (-2, 2)}, samples=9, keep=4)
    found = sorted((round(o.params["x"]), round(o.params["y"])) for o in result.optima)
    assert found == [(-1, -1), (-1, 1), (1, -1), (1, 1)]
    assert (round(result.best.params["x"]), round(result.best.params["y"])) == (1, -1)
    assert len(result.sweep) == 81 and "9 × 9" in result.design


def test_more_parameters_use_a_seeded_space_filling_design():
    ranges = {"a": (0, 1), "b": (0, 2), "c": (-1, 1)}
    first, text = global_search.sweep_points(ranges, 16, seed=3)
    again, _ = global_search.sweep_points(ranges, 16, seed=3)
    other, _ = global_search.sweep_points(ranges, 16, seed=4)
    assert np.array_equal(first, again) and not np.array_equal(first, other)
    assert first.shape == (16, 3) and np.all(first >= [0, 0, -1]) and np.all(first <= [1, 2, 1])
    assert "Sobol" in text and "seed 3" in text


def failing_at_the_best(values):
    answer = refine_bumps(values)
    return (
        answer
        if answer.objective > -0.9
        else global_search.LocalOptimum(answer.params, answer.objective, False, "x", {})
    )


def test_converged_means_converged_at_the_best():
    """A failed refinement below the best converged one is listed, not chosen, and the answer is then not
    converged: nothing proves the best converged optimum is the global one."""
    result = global_search.search(evaluate_bumps, failing_at_the_best, {"x": (-2, 2), "y": (-2, 2)}, samples=9, keep=4)
    assert result.best.success and not result.converged
    assert (round(result.best.params["x"]), round(result.best.params["y"])) == (-1, -1)
    assert [o.success for o in result.optima].count(False) == 1
    assert "not converged" in result.how
