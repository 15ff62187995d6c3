"""A Monte Carlo split into parts (as `studies.distributed` sends them to other processes) is the whole one,
and a plant survives pickling by its registry name."""

import pickle

import casadi as ca
import numpy as np
import pytest

import models
from models.monte_carlo_batch import MonteCarloPlan
from models.run_setup import RunSetup


class StateFeedback(models.Block):
    """u = -K x + kr r, reading the full state (a test fixture, not a design)."""

    def __init__(self, K, kr):
        super().__init__(
            sample_period=0.01,
            n_state=0,
            n_measured=len(K),
            n_reference=1,
            n_input=1,
            gains={"K": np.asarray(K, dtype=float), "kr": kr},
            measures="state",
        )

    def expr(self, xc, y, r, g):
        return xc, -ca.dot(g["K"], y) + g["kr"] * r[0]


def test_parts_with_their_first_sample_are_the_whole_monte_carlo_noise_included():
    arm = models.get("arm")
    block = StateFeedback([0.6, 0.05], 0.6)
    samples = models.sample_params(arm, 9, seed=2)
    kw = dict(noise_std=1e-3, seed=5, substeps=2)
    whole = models.monte_carlo(arm, block, 0.3, 1.0, samples, **kw)
    parts = [
        models.monte_carlo(arm, block, 0.3, 1.0, samples[a:b], first_sample=a, **kw)
        for a, b in ((0, 4), (4, 5), (5, 9))
    ]
    for name in ("x", "u", "measured"):
        np.testing.assert_array_equal(np.concatenate([getattr(p, name) for p in parts]), getattr(whole, name))
    assert [p.first_sample for p in parts] == [0, 4, 5]
    # Without its first_sample a later part would replay the first samples' noise.
    replay = models.monte_carlo(arm, block, 0.3, 1.0, samples[4:5], **kw)
    assert not np.array_equal(replay.measured, whole.measured[4:5])
    with pytest.raises(ValueError, match="first_sample"):
        models.monte_carlo(arm, block, 0.3, 1.0, samples, first_sample=-1, **kw)


def test_a_plant_pickles_by_name_with_its_parameters_and_limit():
    plant = models.get("pendulum", m1=0.3, input_limit=7.0)
    back = pickle.loads(pickle.dumps(plant))
    assert back.name == "pendulum" and back.params == plant.params and list(back.input_limit) == [7.0]
    x, u = np.array([0.1, 0.2, -0.1, 0.3]), np.array([1.5])
    np.testing.assert_array_equal(back.f(x, u), plant.f(x, u))


def test_an_unregistered_plant_says_it_cannot_be_rebuilt(blow_up_plant):
    with pytest.raises(TypeError, match="'blowup' is not the registered declaration"):
        pickle.dumps(blow_up_plant)


def test_the_plans_chunks_hold_the_most_samples_within_the_step_budget_and_cover_every_sample():
    # The arm under state feedback: nx = 2, no controller state, nu = 1, 2 measurements, 1 reference;
    # 1 s at 10 ms is N = 100 steps. Without noise a chunk's call holds 8 N (3 (nx + nc) + 2 nu + 2 nm + nr)
    # = 800 * 13 bytes per sample, so the step budget (2**16 // 100 = 655 samples) binds before the byte one.
    arm = models.get("arm")
    block = StateFeedback([0.6, 0.05], 0.6)
    setup = RunSetup.build(arm, block, 0.3, 1.0)
    samples = np.tile(arm.param_vector(), (1000, 1))
    plan = MonteCarloPlan.build(arm, block, setup, samples)
    assert plan.chunk == 655 and plan.chunk_bytes == 655 * 800 * 13
    assert list(plan.chunks()) == [(0, 655), (655, 1000)]
    given = MonteCarloPlan.build(arm, block, setup, samples, chunk_size=300)
    assert list(given.chunks()) == [(0, 300), (300, 600), (600, 900), (900, 1000)]
    # One sample's results: x, xc, y over 101 samples (2 + 0 + 1 numbers), u and measured over 100 (1 + 2), diverged_at.
    assert plan.sample_bytes() == 8 * (101 * 3 + 100 * 3 + 1)


def test_a_monte_carlo_needs_an_integer_seed_and_valid_parameter_rows():
    arm = models.get("arm")
    block = StateFeedback([0.6, 0.05], 0.6)
    samples = models.sample_params(arm, 3, seed=2)
    with pytest.raises(TypeError, match="seed must be an integer"):
        models.monte_carlo(arm, block, 0.3, 1.0, samples, seed=None)
    bad = samples.copy()
    bad[1, 0] = -1.0
    with pytest.raises(ValueError, match="param_samples row 1"):
        models.monte_carlo(arm, block, 0.3, 1.0, bad)
    with pytest.raises(TypeError, match="monte_carlo batches Blocks"):
        models.monte_carlo(arm, object(), 0.3, 1.0, samples)


class HeldMeasurement(models.Block):
    """x_c starts at the first measurement and is held; u = k (r - y) + 0.1 x_c (a test fixture)."""

    def __init__(self):
        super().__init__(sample_period=0.01, n_state=1, n_measured=1, n_reference=1, n_input=1, gains={"k": 2.0})

    def initial_state(self, y0, r0):
        return np.array([y0[0] + 0.5 * r0[0]])

    def expr(self, xc, y, r, g):
        return xc, g["k"] * (r[0] - y[0]) + 0.1 * xc[0]


def test_one_chunk_of_a_plan_runs_its_samples_as_separate_runs_with_their_own_noise_and_start():
    """A chunk from the middle of the sample set, run alone, equals `simulate_closed_loop` of each of its
    samples (one unmapped Function per run) with the noise seeded by (seed, index): the first state of
    each comes from its own noisy first measurement."""
    arm = models.get("arm")
    block = HeldMeasurement()
    setup = RunSetup.build(arm, block, 0.2, 0.5, noise_std=1e-2, seed=9, substeps=2)
    samples = models.sample_params(arm, 6, seed=4)
    plan = MonteCarloPlan.build(arm, block, setup, samples, chunk_size=2, first_sample=10)
    out = plan.allocate(2)
    plan.run_chunk(2, 4, out)
    chunk = plan.result(out, 2, 4)
    assert chunk.first_sample == 12 and len(chunk) == 2
    for j, i in enumerate((2, 3)):
        single = models.simulate_closed_loop(
            arm,
            block,
            0.2,
            0.5,
            params=samples[i],
            noise_std=1e-2,
            substeps=2,
            seed=np.random.SeedSequence([9, 10 + i]),
        )
        assert single.xc[0, 0] == single.measured[0, 0] + 0.1  # x_c0 = y_0 (noisy) + 0.5 r_0
        for name in ("x", "u", "xc", "measured"):
            np.testing.assert_array_equal(getattr(chunk[j], name), getattr(single, name), err_msg=name)
