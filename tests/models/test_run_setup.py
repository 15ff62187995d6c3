"""The run inputs every closed-loop simulator shares (`models.run_setup.RunSetup`), checked against their
definitions: the grid t_k = k Ts, the signals sampled on it, the noise drawn by numpy's own generator."""

import casadi as ca
import numpy as np
import pytest

import models
from models.run_setup import RunSetup, check_seed


class StateFeedback(models.Block):
    """u = -K x + kr r, reading the full state (a test fixture, not a design)."""

    def __init__(self, K, kr, sample_period=0.01):
        K = np.atleast_1d(np.asarray(K, dtype=float))
        super().__init__(
            sample_period=sample_period,
            n_state=0,
            n_measured=K.size,
            n_reference=1,
            n_input=1,
            gains={"K": K, "kr": kr},
            measures="state",
        )

    def expr(self, xc, y, r, g):
        return xc, -ca.dot(g["K"], y) + g["kr"] * r[0]


@pytest.fixture
def arm():
    return models.get("arm")


def test_the_grid_is_k_times_the_sample_period_and_the_signals_are_sampled_on_it(arm):
    block = StateFeedback([0.6, 0.05], 0.6, sample_period=0.02)
    setup = RunSetup.build(arm, block, lambda t: np.sin(t), 1.0, input_disturbance=lambda t: 0.1 * t)
    k = np.arange(51)
    np.testing.assert_array_equal(setup.t, 0.02 * k)  # k Ts, not accumulated
    assert setup.n_steps == 50 and setup.r.shape == (51, 1) and setup.d.shape == (50, 1)
    np.testing.assert_array_equal(setup.r[:, 0], np.sin(0.02 * k))
    np.testing.assert_array_equal(setup.d[:, 0], 0.1 * (0.02 * k[:-1]))  # held on [t_k, t_k+1): no value at t_N
    np.testing.assert_array_equal(setup.x0, [0.0, 0.0])  # the arm hangs at rest at theta = 0
    assert setup.substeps == 10 and setup.seed == 0


def test_the_number_of_samples_is_the_duration_over_the_period_rounded(arm):
    block = StateFeedback([0.6, 0.05], 0.6)
    assert RunSetup.build(arm, block, 0.0, 1.004).n_steps == 100
    assert RunSetup.build(arm, block, 0.0, 1.006).n_steps == 101
    with pytest.raises(ValueError, match="shorter than one sample"):
        RunSetup.build(arm, block, 0.0, 0.004)


def test_one_noise_level_is_every_measurements_and_the_noise_is_numpys_draw(arm):
    block = StateFeedback([0.6, 0.05], 0.6)
    setup = RunSetup.build(arm, block, 0.0, 0.5, noise_std=0.2, seed=7)
    np.testing.assert_array_equal(setup.noise_std, [0.2, 0.2])
    assert setup.n_measured == 2 and setup.noisy
    expected = np.random.default_rng(7).standard_normal((50, 2)) * 0.2
    np.testing.assert_array_equal(setup.noise(), expected)
    # A Monte Carlo sample's noise depends on (seed, its index) alone.
    sample_3 = np.random.default_rng(np.random.SeedSequence([7, 3])).standard_normal((50, 2)) * 0.2
    np.testing.assert_array_equal(setup.noise(sample=3), sample_3)
    per_measurement = RunSetup.build(arm, block, 0.0, 0.5, noise_std=[0.0, 0.1], seed=7)
    np.testing.assert_array_equal(per_measurement.noise()[:, 0], 0.0)


def test_without_noise_the_noise_is_zeros_and_the_seed_is_not_used(arm):
    block = StateFeedback([0.6, 0.05], 0.6)
    generator = np.random.default_rng(1)
    state = generator.bit_generator.state
    setup = RunSetup.build(arm, block, 0.0, 0.5, seed=generator)
    assert not setup.noisy
    np.testing.assert_array_equal(setup.noise(), np.zeros((50, 2)))
    assert generator.bit_generator.state == state


@pytest.mark.parametrize(
    "kwargs,error,message",
    [
        (dict(noise_std=[0.1, 0.1, 0.1]), ValueError, "one number or 2 numbers"),
        (dict(noise_std=-0.1), ValueError, "finite and >= 0"),
        (dict(noise_std=np.nan), ValueError, "finite and >= 0"),
        (dict(substeps=0), ValueError, "substeps must be an integer >= 1"),
        (dict(substeps=2.5), ValueError, "substeps must be an integer"),
        (dict(seed=-1), ValueError, "seed must be an integer >= 0"),
        (dict(seed="one"), TypeError, "seed must be an integer"),
        (dict(x0=[0.0]), ValueError, "arm initial state must have 2 entries"),
    ],
)
def test_each_bad_argument_is_named(arm, kwargs, error, message):
    with pytest.raises(error, match=message):
        RunSetup.build(arm, StateFeedback([0.6, 0.05], 0.6), 0.0, 0.5, **kwargs)


def test_seeds_numpy_takes_pass_and_an_integral_float_becomes_an_int():
    sequence = np.random.SeedSequence(4)
    assert check_seed(None) is None and check_seed(sequence) is sequence
    assert check_seed(3.0) == 3 and isinstance(check_seed(3.0), int)
