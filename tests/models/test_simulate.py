"""Open-loop simulators: conservation of energy, agreement of three methods, exactness on
a linear plant, and divergence reporting."""

import numpy as np
import pytest

import models
from models.simulate import radau_matrices, simulate

UNDAMPED = {
    "arm": {"b": 0.0},
    "pendulum": {"b": 0.0},
    "satellite": {"b": 0.0},
    "uuv": {"b": 0.0},
    "ballbeam": {},
    "crane": {"b": 0.0},
    "crane1": {"b": 0.0},
}


@pytest.mark.parametrize("name", models.names())
def test_energy_is_conserved_without_damping_or_input(name):
    plant = models.get(name, **UNDAMPED[name])
    xe, _ = plant.equilibrium()
    x0 = xe.copy()
    x0[: plant.nq] += 0.2
    x0[plant.nq :] += 0.1
    run = simulate(plant, x0, np.zeros((100, plant.nu)), 0.05, method="adaptive")
    energy = np.array([plant.energy(x) for x in run.x])
    potential = np.array([plant.energy(np.concatenate([x[: plant.nq], np.zeros(plant.nq)])) for x in run.x])
    # Relative to the kinetic energy exchanged, not to T + V (whose offset is arbitrary).
    scale = np.max(energy - potential)
    assert scale > 1e-6
    assert np.max(np.abs(energy - energy[0])) / scale < 1e-8


# Stable plants run 10 s; unstable ones start 1e-3 off equilibrium and run while
# the state stays physical (ball on the beam, pendulum within 0.3 rad).
RUNS = {
    "arm": (0.0, 1000, 0.0),
    "satellite": (0.0, 1000, 0.5),
    "uuv": (0.0, 1000, 10.0),
    "crane": (0.0, 1000, 1000.0),
    "crane1": (0.0, 1000, 1000.0),
    "pendulum": (1e-3, 100, 0.0),
    "ballbeam": (1e-3, 100, 0.0),
}


@pytest.mark.parametrize("name", models.names())
def test_three_simulators_agree(name):
    plant = models.get(name)
    offset, n, du = RUNS[name]
    xe, ue = plant.equilibrium()
    x0 = xe.copy()
    x0[: plant.nq] += offset
    t = 0.01 * np.arange(n)
    u = ue + du * np.sin(t)[:, None] if name != "arm" else np.zeros((n, 1))
    runs = [simulate(plant, x0, u, 0.01, method=m) for m in ("rk4", "adaptive", "collocation")]
    if name == "pendulum":
        assert np.max(np.abs(runs[0].state("theta"))) < 0.3
    if name == "ballbeam":
        assert np.all((runs[0].state("z") > 0) & (runs[0].state("z") < plant.params["ell"]))
    assert np.max(np.abs(runs[0].x - x0)) > 1e-3  # something happened
    for other in runs[1:]:
        np.testing.assert_allclose(other.x, runs[0].x, rtol=0, atol=1e-4)
        assert other.t.shape == runs[0].t.shape and other.u.shape == runs[0].u.shape


@pytest.mark.parametrize("method", ["rk4", "adaptive", "collocation"])
def test_linear_plant_matches_matrix_exponential(method):
    """The satellite is linear: the zero-order-hold solution is exact by expm."""
    sat = models.get("satellite")
    disc = sat.linearize().discretize(0.01)
    x0 = np.array([0.01, -0.02, 0.0, 0.03])
    u = np.sin(0.01 * np.arange(500))[:, None]
    exact = [x0]
    for uk in u:
        exact.append(disc.A @ exact[-1] + disc.B @ uk)
    run = simulate(sat, x0, u, 0.01, method=method)
    np.testing.assert_allclose(run.x, np.array(exact), atol=1e-8)


def test_radau_differentiation_is_exact_for_polynomials():
    tau, deriv = radau_matrices(3)
    np.testing.assert_allclose(tau[1:], [(4 - np.sqrt(6)) / 10, (4 + np.sqrt(6)) / 10, 1.0], rtol=1e-14)
    values = tau**3 - 2 * tau
    np.testing.assert_allclose(values @ deriv, 3 * tau[1:] ** 2 - 2, atol=1e-12)


@pytest.mark.parametrize("method", ["rk4", "adaptive"])
def test_divergence_names_the_time(method, blow_up_plant):
    plant = blow_up_plant
    message = r"blowup: .*(diverged at|failed on the segment starting at) t = 0\.9"
    with pytest.raises(models.SimulationError, match=message):
        simulate(plant, [1.0, 0.0], np.zeros((200, 1)), 0.01, method=method)
    assert "blowup" not in models.names()


@pytest.mark.parametrize(
    "kwargs,message",
    [
        ({"method": "euler"}, "unknown method 'euler'"),
        ({"x0": [0.0]}, "initial state .* must have 2 entries"),
        ({"u": np.full((3, 1), np.nan)}, "input sequence has a non-finite entry at row 0"),
        ({"sample_period": -0.01}, r"sample_period \(s\) must be a finite number > 0, got -0.01"),
    ],
)
def test_simulate_bad_input(kwargs, message):
    args = {"x0": [0.0, 0.0], "u": np.zeros((3, 1)), "sample_period": 0.01} | kwargs
    with pytest.raises(ValueError, match=message):
        simulate(models.get("arm"), args.pop("x0"), args.pop("u"), args.pop("sample_period"), **args)


def test_discretize_double_integrator_closed_form():
    lin = models.LinearModel(
        A=np.array([[0.0, 1.0], [0.0, 0.0]]),
        B=np.array([[0.0], [1.0]]),
        C=np.eye(2),
        D=np.zeros((2, 1)),
        xe=np.zeros(2),
        ue=np.zeros(1),
        ye=np.zeros(2),
        state_names=("q", "dq"),
        input_names=("u",),
        output_names=("q", "dq"),
    )
    disc = lin.discretize(0.1)
    np.testing.assert_allclose(disc.A, [[1, 0.1], [0, 1]], atol=1e-15)
    np.testing.assert_allclose(disc.B, [[0.005], [0.1]], atol=1e-15)
    assert disc.ss().dt == 0.1


def test_transfer_function_of_the_arm():
    """I.6: Θ/τ = (3/(m ℓ²)) / (s² + 3b/(m ℓ²) s)."""
    arm = models.get("arm")
    p = arm.params
    G = arm.linearize().tf("theta", "tau")
    a = 3 / (p["m"] * p["ell"] ** 2)
    num, den = np.ravel(G.num[0][0]), np.ravel(G.den[0][0])
    np.testing.assert_allclose(num / den[0], [a], rtol=1e-12)
    np.testing.assert_allclose(den / den[0], [1, a * p["b"], 0], rtol=1e-12, atol=1e-15)
