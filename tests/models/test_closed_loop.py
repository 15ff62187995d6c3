"""The closed-loop simulator against independent references: the exact discrete
recursion of a linear plant, open-loop runs, and its own two execution paths."""

import dataclasses

import casadi as ca
import numpy as np
import pytest

import models
from models.simulate import simulate


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


class Constant(models.Block):
    def __init__(self, value, n_measured=1):
        super().__init__(
            sample_period=0.01, n_state=0, n_measured=n_measured, n_reference=1, n_input=1, gains={"value": value}
        )

    def expr(self, xc, y, r, g):
        return xc, g["value"]


class Proportional(models.Block):
    """u = k (r - y[index]); one state counting samples so Cascade has a state to carry."""

    def __init__(self, k, index, n_measured):
        self.index = index
        super().__init__(sample_period=0.01, n_state=1, n_measured=n_measured, n_reference=1, n_input=1, gains={"k": k})

    def expr(self, xc, y, r, g):
        return xc + 1, g["k"] * (r[0] - y[self.index])


def test_linear_plant_matches_exact_discrete_recursion():
    sat = models.get("satellite")
    lin = sat.linearize()
    disc = lin.discretize(0.01)
    K = np.array([2.0, 1.0, 6.0, 0.5])
    ctrl = StateFeedback(K, 3.0)
    res = models.simulate_closed_loop(sat, ctrl, 0.1, 5.0)
    x = np.zeros(4)
    for k in range(500):
        u = -K @ x + 3.0 * 0.1
        assert res.u[k, 0] == pytest.approx(u, abs=1e-9)
        x = disc.A @ x + disc.B[:, 0] * np.clip(u, -5, 5)
        np.testing.assert_allclose(res.x[k + 1], x, atol=1e-9)


def test_compiled_and_python_paths_agree():
    arm = models.get("arm")
    ctrl = StateFeedback([0.6, 0.05], 0.6)
    kw = dict(x0=[0.1, 0.0], input_disturbance=0.05, noise_std=1e-3, seed=4)
    a = models.simulate_closed_loop(arm, ctrl, 0.4, 2.0, **kw)
    b = models.simulate_closed_loop(arm, ctrl, 0.4, 2.0, compiled=False, **kw)
    for field in ("x", "y", "u", "measured"):
        np.testing.assert_allclose(getattr(a, field), getattr(b, field), atol=1e-12)
    assert a.u.shape == (200, 1) and a.x.shape == (201, 2) and a.r.shape == (201, 1)


def test_actuator_saturates_and_disturbance_adds_at_the_plant_input():
    arm = models.get("arm")
    res = models.simulate_closed_loop(arm, Constant(10.0), 0.0, 1.0, x0=[0.0, 0.0], input_disturbance=-0.25)
    assert np.all(res.u == 10.0)  # the command is recorded as commanded
    # The plant sees clip(10, ±1) - 0.25 = 0.75 N m.
    ref = simulate(arm, [0.0, 0.0], np.full((100, 1), 0.75), 0.01)
    np.testing.assert_allclose(res.x, ref.x, atol=1e-12)


def test_noise_is_seeded_and_has_the_requested_spread():
    uuv = models.get("uuv")
    ctrl = Constant(0.0)
    a = models.simulate_closed_loop(uuv, ctrl, 0.0, 20.0, noise_std=0.01, seed=7)
    b = models.simulate_closed_loop(uuv, ctrl, 0.0, 20.0, noise_std=0.01, seed=7)
    c = models.simulate_closed_loop(uuv, ctrl, 0.0, 20.0, noise_std=0.01, seed=8)
    np.testing.assert_array_equal(a.measured, b.measured)
    assert not np.allclose(a.measured, c.measured)
    noise = a.measured[:, 0] - a.y[:-1, 0]
    assert np.std(noise) == pytest.approx(0.01, rel=0.1)  # 2000 samples: ~1.6 % standard error


def test_monte_carlo_equals_single_runs():
    pend = models.get("pendulum")
    lin = pend.linearize()
    import control

    K = control.place(lin.A, lin.B, [-3, -3.5, -4, -4.5])[0]
    kr = -1.0 / (np.array([1, 0, 0, 0]) @ np.linalg.solve(lin.A - lin.B @ K[None], lin.B))[0]
    ctrl = StateFeedback(K, kr)
    samples = models.sample_params(pend, 4, seed=3)
    batch = models.monte_carlo(pend, ctrl, 0.5, 3.0, samples, noise_std=1e-3, seed=11)
    for i, res in enumerate(batch):
        single = models.simulate_closed_loop(
            pend, ctrl, 0.5, 3.0, params=samples[i], noise_std=1e-3, seed=np.random.SeedSequence([11, i])
        )
        np.testing.assert_allclose(res.x, single.x, atol=1e-12)
        np.testing.assert_allclose(res.u, single.u, atol=1e-12)
    assert not np.allclose(batch[0].x, batch[1].x)


def test_sample_params_are_reproducible_and_within_five_percent():
    crane = models.get("crane")
    a = models.sample_params(crane, 200, seed=5)
    np.testing.assert_array_equal(a, models.sample_params(crane, 200, seed=5))
    ratio = a / crane.param_vector()
    moved = [list(crane.params).index(n) for n in crane.uncertain_params]
    assert np.all(np.abs(ratio[:, moved] - 1) <= 0.05) and np.all(ratio[:, list(crane.params).index("g")] == 1)
    assert models.corner_params(crane).shape == (2 ** len(crane.uncertain_params), crane.n_params)


def test_cascade_composes_outer_and_inner():
    outer = Proportional(0.2, index=0, n_measured=2)
    inner = Proportional(-30.0, index=1, n_measured=2)
    both = models.Cascade(outer, inner)
    assert both.gain_names == ("outer.k", "inner.k")
    xc, u = both.step([0, 0], [0.1, 0.05], [1.0])
    # theta_ref = 0.2 (1 - 0.1) = 0.18 ; u = -30 (0.18 - 0.05)
    assert u[0] == pytest.approx(-30.0 * (0.2 * 0.9 - 0.05))
    np.testing.assert_array_equal(xc, [1, 1])
    changed = both.with_gains(**{"outer.k": 0.5})
    assert changed.outer.gains["k"] == 0.5 and both.outer.gains["k"] == 0.2
    assert changed.step([0, 0], [0.1, 0.05], [1.0])[1][0] == pytest.approx(-30.0 * (0.5 * 0.9 - 0.05))


def test_gradient_of_a_closed_loop_cost_equals_finite_differences():
    arm = models.get("arm")
    ctrl = StateFeedback([0.6, 0.05], 0.6)
    run = models.closed_loop_function(arm, ctrl, 150)
    gains = ca.MX.sym("g", 3)
    X = run(
        np.zeros(2),
        np.zeros(0),
        0.3 * np.ones((1, 150)),
        np.zeros((2, 150)),
        np.zeros((1, 150)),
        arm.param_vector(),
        gains,
    )[0]
    cost = ca.Function("cost", [gains], [ca.sumsqr(X[0, :] - 0.3) * 0.01])
    grad = ca.Function("grad", [gains], [ca.gradient(cost(gains), gains)])
    g0 = ctrl.gain_vector()
    exact = np.asarray(grad(g0)).ravel()
    h = 1e-6
    fd = [(float(cost(g0 + h * e)) - float(cost(g0 - h * e))) / (2 * h) for e in np.eye(3)]
    np.testing.assert_allclose(exact, fd, rtol=1e-5)


def test_closed_loop_divergence_names_the_time(blow_up_plant):
    with pytest.raises(models.SimulationError, match=r"closed loop diverged at t = 0\.9"):
        models.simulate_closed_loop(blow_up_plant, Constant(0.0), 0.0, 2.0, x0=[1.0, 0.0])
    res = models.simulate_closed_loop(blow_up_plant, Constant(0.0), 0.0, 2.0, x0=[1.0, 0.0], allow_divergence=True)
    assert 0.92 <= res.diverged_at <= 0.95


@pytest.mark.parametrize(
    "kwargs,error,message",
    [
        ({"controller": Constant(0.0, n_measured=2)}, ValueError, "reads 2 measurements but arm provides 1"),
        ({"duration": -1.0}, ValueError, r"duration \(s\) must be a finite number > 0, got -1.0"),
        ({"reference": np.zeros((5, 1))}, ValueError, "reference must be a constant"),
        ({"noise_std": -0.1}, ValueError, "noise_std must be finite and >= 0"),
        ({"reference": lambda t: np.where(t > 0.5, np.nan, 0.0)}, ValueError, "reference is not finite at t = 0.51"),
        ({"controller": object()}, TypeError, "is not a controller"),
    ],
)
def test_closed_loop_bad_input(kwargs, error, message):
    args = {"controller": Constant(0.0), "reference": 0.0, "duration": 1.0} | kwargs
    with pytest.raises(error, match=message):
        models.simulate_closed_loop(
            models.get("arm"),
            args["controller"],
            args["reference"],
            args["duration"],
            noise_std=args.get("noise_std", 0.0),
        )


def test_block_rejects_bad_gains():
    with pytest.raises(ValueError, match="gain value is not finite"):
        Constant(np.nan)
    with pytest.raises(ValueError, match="has no gain"):
        Constant(1.0).with_gains(kp=1.0)


@pytest.mark.parametrize("measures", ["state", "outputs"])
def test_monte_carlo_is_bit_identical_to_single_runs_whatever_the_chunking(measures):
    """Each sample of the batch equals a separate simulate_closed_loop run (another code path: one
    unmapped Function per run) exactly, with noise, for chunks of 1, 2 and the default size."""
    pend = models.get("pendulum")
    if measures == "state":
        lin = pend.linearize()
        import control

        K = control.place(lin.A, lin.B, [-3, -3.5, -4, -4.5])[0]
        ctrl = StateFeedback(K, -1.0 / (np.array([1, 0, 0, 0]) @ np.linalg.solve(lin.A - lin.B @ K[None], lin.B))[0])
    else:
        ctrl = models.Cascade(Proportional(0.1, index=0, n_measured=2), Proportional(-40.0, index=1, n_measured=2))
    samples = models.sample_params(pend, 5, seed=8)
    kw = dict(noise_std=1e-3, seed=21, input_disturbance=0.1, substeps=2)
    batches = [models.monte_carlo(pend, ctrl, 0.3, 2.0, samples, chunk_size=c, **kw) for c in (1, 2, None)]
    chunked = list(models.monte_carlo_chunks(pend, ctrl, 0.3, 2.0, samples, chunk_size=2, **kw))
    for i, row in enumerate(samples):
        single = models.simulate_closed_loop(
            pend,
            ctrl,
            0.3,
            2.0,
            params=row,
            noise_std=1e-3,
            substeps=2,
            seed=np.random.SeedSequence([21, i]),
            input_disturbance=0.1,
            allow_divergence=True,
        )
        chunk = chunked[i // 2][i % 2]
        for batch in batches:
            for field in ("x", "y", "u", "xc", "measured", "params", "t", "r", "d", "input_limit"):
                np.testing.assert_array_equal(getattr(batch[i], field), getattr(single, field), err_msg=field)
                np.testing.assert_array_equal(getattr(chunk, field), getattr(single, field), err_msg=field)
            assert batch[i].diverged_at == single.diverged_at
    assert not np.allclose(batches[0][0].x, batches[0][1].x)  # the samples differ


def test_monte_carlo_result_is_a_read_only_sequence_of_views():
    arm = models.get("arm")
    batch = models.monte_carlo(arm, StateFeedback([0.6, 0.05], 0.6), 0.3, 1.0, models.sample_params(arm, 4))
    assert len(batch) == 4 and batch.x.shape == (4, 101, 2) and batch.u.shape == (4, 100, 1)
    assert batch.y.shape == (4, 101, 1) and batch.xc.shape == (4, 101, 0)
    runs = list(batch)
    assert len(runs) == 4 and all(isinstance(r, models.ClosedLoopResult) for r in runs)
    np.testing.assert_array_equal(batch[-1].x, batch.x[3])
    assert np.shares_memory(batch[2].x, batch.x)  # a view, not a copy
    assert [r.diverged_at for r in batch[1:3]] == [None, None]
    with pytest.raises(ValueError, match="read-only"):
        batch[0].x[0, 0] = 1.0
    with pytest.raises(IndexError, match="sample 4 of a batch of 4"):
        batch[4]
    # Outputs are the plant's h of each sample's states (the arm measures θ).
    np.testing.assert_array_equal(batch.y[:, :, 0], batch.x[:, :, 0])


def test_a_batchs_sample_has_the_fields_its_dataclass_init_gives(blow_up_plant):
    """`MonteCarloResult` builds a sample without the dataclass's __init__: the same fields, the same
    objects, by index and by iteration, a diverged sample's time a float. From q = 1 at rest, q'' = 4 k q³
    escapes at 0.927 s / √k: within 1.5 s for k = 1 only."""
    pend = blow_up_plant
    batch = models.monte_carlo(pend, StateFeedback([0.0, 0.0], 0.0), 0.0, 1.5, [[0.01], [1.0], [0.02]], x0=[1, 0])
    assert np.isnan(batch.diverged_at[[0, 2]]).all() and 0.9 < batch.diverged_at[1] < 0.95
    for i, run in enumerate(batch):
        expected = models.ClosedLoopResult(
            t=batch.t,
            x=run.x,
            y=run.y,
            r=batch.r,
            u=run.u,
            d=batch.d,
            measured=run.measured,
            xc=run.xc,
            step_time=run.step_time,
            status=None,
            input_limit=batch.input_limit,
            state_names=pend.state_names,
            output_names=pend.output_names,
            input_names=pend.input_names,
            controller=batch.controller,
            diverged_at=None if i != 1 else float(batch.diverged_at[1]),
            params=run.params,
        )
        assert vars(run).keys() == vars(expected).keys() == {f.name for f in dataclasses.fields(expected)}
        for name, value in vars(expected).items():
            assert getattr(run, name) is value or getattr(run, name) == value, name
        for name in ("x", "y", "u", "measured", "xc", "params"):
            np.testing.assert_array_equal(getattr(run, name), getattr(batch[i], name))
            assert getattr(run, name).size == 0 or np.shares_memory(getattr(run, name), getattr(batch, name))
    assert type(batch[1].diverged_at) is float and batch[0].diverged_at is None
