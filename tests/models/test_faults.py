"""Faults of the models package, injected: each asserts the exact behaviour.

Three classes: a NaN is never turned into a number (the run is reported as
diverged at the sample where the non-finite command or state appeared, on
every path); resources are checked before the work (a request above
`models.checks.MEMORY_LIMIT_BYTES` is refused at once, naming its size and
the limit); bad input gets a one-line error naming the argument, its value
and what is allowed.
"""

import casadi as ca
import numpy as np
import pytest

import models
import models.checks
import models.closed_loop
import models.plant
from models.monte_carlo_batch import MonteCarloPlan
from models.run_setup import RunSetup
from models.simulate import radau_matrices, simulate


# --------------------------------------------------------------------------- fixtures
class CountingBlock(models.Block):
    """u = k (r - y); the command becomes `command` from sample `bad_step` on, the state `state` then.

    The state counts samples, so the fault's sample is known exactly.
    """

    def __init__(self, bad_step, command=np.nan, state=None, n_measured=1, k=0.5):
        self.bad_step, self.command, self.bad_state = bad_step, command, state
        super().__init__(
            sample_period=0.01,
            n_state=1,
            n_measured=n_measured,
            n_reference=1,
            n_input=1,
            gains={"k": k},
            name="counting",
        )

    def expr(self, xc, y, r, g):
        late = xc[0] >= self.bad_step
        u = ca.if_else(late, self.command, g["k"] * (r[0] - y[0])) if self.bad_state is None else g["k"] * (r[0] - y[0])
        xc_next = xc + 1 if self.bad_state is None else ca.if_else(late, self.bad_state, xc + 1)
        return xc_next, u


class ThresholdBlock(models.Block):
    """u = k (r - θ), NaN once θ passes `threshold`: the fault's time depends on the plant's parameters."""

    def __init__(self, threshold, k=2.0):
        self.threshold = threshold
        super().__init__(sample_period=0.01, n_state=0, n_measured=1, n_reference=1, n_input=1, gains={"k": k})

    def expr(self, xc, y, r, g):
        return xc, ca.if_else(y[0] > self.threshold, np.nan, g["k"] * (r[0] - y[0]))


class PythonNaN:
    """A controller in Python (as MPC is): u = k (r - y) until sample `bad_step`, then NaN."""

    sample_period, measures, n_reference, name = 0.01, "outputs", 1, "python nan"

    def __init__(self, bad_step):
        self.bad_step = bad_step

    def initial_state(self, y0, r0):
        return np.zeros(1)

    def step(self, xc, y, r):
        u = np.nan if xc[0] >= self.bad_step else 0.5 * (r[0] - y[0])
        return xc + 1, np.array([u])


@pytest.fixture
def arm():
    return models.get("arm")


@pytest.fixture
def private_registry(monkeypatch):
    """The registry as a copy, so a test may declare or replace plants without touching other tests."""
    monkeypatch.setattr(models.plant, "_REGISTRY", dict(models.plant._REGISTRY))
    monkeypatch.setattr(models.plant, "_SYMBOLIC_CACHE", dict(models.plant._SYMBOLIC_CACHE))


def _declare(physics, *, name="user", coordinates=("q1", "q2"), first_order=(), **kwargs):
    decl = models.declare(
        name=name,
        title="user plant",
        coordinates=coordinates,
        inputs=("u",),
        params=(models.Param("m", 1.0, "kg"),),
        input_limit=1.0,
        first_order=first_order,
        register=False,
        **kwargs,
    )(physics)
    return models.Plant(decl)


# --------------------------------------------------------------------------- NaN never becomes a number
@pytest.mark.parametrize("compiled", [True, False])
def test_a_nan_command_is_a_divergence_at_its_sample_on_both_paths(arm, compiled):
    block = CountingBlock(bad_step=50)
    with pytest.raises(
        models.SimulationError,
        match=r"arm under counting: closed loop diverged at t = 0\.5 s \(the command u = \[nan\]",
    ):
        models.simulate_closed_loop(arm, block, 0.1, 1.0, compiled=compiled)
    res = models.simulate_closed_loop(arm, block, 0.1, 1.0, compiled=compiled, allow_divergence=True)
    assert res.diverged_at == 0.5
    assert np.isnan(res.u[50, 0]) and np.all(np.isfinite(res.u[:50]))
    # The plant's input is undefined after a NaN command: no state is made up for it.
    assert np.all(np.isnan(res.x[51:])) and np.all(np.isfinite(res.x[:51]))
    # Before the fault the run is the ordinary one: an arm under u = k (r - θ) from rest.
    clean = models.simulate_closed_loop(arm, CountingBlock(bad_step=10**6), 0.1, 0.5, compiled=compiled)
    np.testing.assert_array_equal(res.x[:51], clean.x)


def test_a_nan_command_is_not_clipped_to_the_limit(arm):
    """Before, fmin/fmax turned NaN into -limit: the arm was driven at -1 N m and no divergence was seen."""
    res = models.simulate_closed_loop(arm, CountingBlock(bad_step=0), 0.0, 1.0, allow_divergence=True)
    assert res.diverged_at == 0.0
    saturated = simulate(arm, arm.equilibrium()[0], np.full((100, 1), -1.0), 0.01)
    assert not np.any(np.isclose(res.x[1:], saturated.x[1:]))
    assert np.isnan(models.saturate(np.nan, 1.0))
    u = ca.SX.sym("u")
    assert np.isnan(float(ca.Function("clip", [u], [models.saturate(u, 1.0)])(np.nan)))


def test_an_infinite_command_is_a_divergence_although_the_actuator_would_clip_it(arm):
    res = models.simulate_closed_loop(arm, CountingBlock(bad_step=20, command=np.inf), 0.1, 1.0, allow_divergence=True)
    assert res.diverged_at == pytest.approx(0.2) and np.isposinf(res.u[20, 0])


@pytest.mark.parametrize("compiled", [True, False])
def test_a_nan_controller_state_is_a_divergence_at_its_sample(arm, compiled):
    """The state x_c becomes NaN at sample 31 (after the step at sample 30); the command is still finite."""
    block = CountingBlock(bad_step=30, state=np.nan)
    with pytest.raises(models.SimulationError, match=r"diverged at t = 0\.31 s \(the controller's state"):
        models.simulate_closed_loop(arm, block, 0.1, 1.0, compiled=compiled)
    res = models.simulate_closed_loop(arm, block, 0.1, 1.0, compiled=compiled, allow_divergence=True)
    assert res.diverged_at == pytest.approx(0.31)
    assert np.all(np.isfinite(res.u[:31])) and np.isnan(res.xc[31, 0])


def test_a_nan_initial_controller_state_is_a_divergence_at_time_zero(arm):
    class NanStart(CountingBlock):
        def initial_state(self, y0, r0):
            return np.array([np.nan])

    for compiled in (True, False):
        res = models.simulate_closed_loop(arm, NanStart(10**6), 0.1, 1.0, compiled=compiled, allow_divergence=True)
        assert res.diverged_at == 0.0


def test_a_python_controller_commanding_nan_is_reported_not_raised(arm):
    with pytest.raises(models.SimulationError, match=r"diverged at t = 0\.4 s \(the command u = \[nan\]"):
        models.simulate_closed_loop(arm, PythonNaN(40), 0.1, 1.0)
    res = models.simulate_closed_loop(arm, PythonNaN(40), 0.1, 1.0, allow_divergence=True)
    assert res.diverged_at == pytest.approx(0.4) and np.all(np.isnan(res.x[41:]))
    # Compiled and Python paths of the same law agree up to the fault.
    block = models.simulate_closed_loop(arm, CountingBlock(bad_step=40), 0.1, 1.0, allow_divergence=True)
    np.testing.assert_allclose(res.x[:41], block.x[:41], atol=1e-12)


def test_monte_carlo_reports_each_sample_diverged_at_its_own_time(arm):
    """θ passes 0.2 rad sooner for a lighter arm, never for the 0.8 kg arm that 1 N m cannot lift;
    every sample agrees with its own Python-loop run."""
    block = ThresholdBlock(0.2)
    samples = np.array([arm.param_vector({"m": m}) for m in (0.3, 0.4, 0.5, 0.8)])
    batch = models.monte_carlo(arm, block, 0.5, 3.0, samples, chunk_size=3)
    assert batch.diverged_at[0] < batch.diverged_at[1] < batch.diverged_at[2] and np.isnan(batch.diverged_at[3])
    for i, row in enumerate(samples):
        single = models.simulate_closed_loop(arm, block, 0.5, 3.0, params=row, compiled=False, allow_divergence=True)
        assert batch[i].diverged_at == single.diverged_at
        if single.diverged_at is not None:
            k = int(round(single.diverged_at / 0.01))
            assert np.isnan(batch.u[i, k, 0]) and np.all(np.isnan(batch.x[i, k + 1 :]))
    assert batch[3].diverged_at is None and np.all(np.isfinite(batch.x[3]))


# --------------------------------------------------------------------------- resources checked first
def test_a_monte_carlo_beyond_the_memory_limit_is_refused_before_any_work(arm):
    samples = np.broadcast_to(arm.param_vector(), (2_000_000, arm.n_params))
    with pytest.raises(
        models.ResourceLimitError,
        match=r"monte_carlo of 2000000 samples x 2000 steps .* needs about \d+ GiB, above the "
        r"limit of 1 GiB \(models.checks.MEMORY_LIMIT_BYTES\); run them with "
        r"models.monte_carlo_chunks",
    ):
        models.monte_carlo(arm, CountingBlock(10**9), 0.1, 20.0, samples)


def test_a_closed_loop_of_a_billion_steps_is_refused_before_any_work(arm):
    with pytest.raises(
        models.ResourceLimitError,
        match=r"closed loop of 1000000000 samples .* needs about \d+ GiB, above the limit of 1 GiB",
    ):
        models.simulate_closed_loop(arm, CountingBlock(10**9), 0.1, 1e7)


def test_a_collocation_system_beyond_the_limit_is_refused(arm):
    crane = models.get("crane")
    with pytest.raises(models.ResourceLimitError, match=r"simulate \(collocation\) of crane over 200000 samples"):
        simulate(crane, crane.equilibrium()[0], np.zeros((200_000, 1)), 0.01, method="collocation", degree=9)


def test_the_limit_is_an_overridable_constant(arm, monkeypatch):
    block = CountingBlock(10**9)
    monkeypatch.setattr(models.checks, "MEMORY_LIMIT_BYTES", 10_000)
    with pytest.raises(models.ResourceLimitError, match=r"above the limit of 9.77 KiB"):
        models.simulate_closed_loop(arm, block, 0.1, 1.0)
    monkeypatch.setattr(models.checks, "MEMORY_LIMIT_BYTES", 2**30)
    assert models.simulate_closed_loop(arm, block, 0.1, 1.0).x.shape == (101, 2)


def test_the_kernels_default_chunks_hold_their_results_within_the_chunk_budget(arm, monkeypatch):
    """With the C kernel a chunk's results are its memory: `monte_carlo_chunks` without a chunk size runs
    what `monte_carlo` refuses (the crane's 60,000-step runs once asked for one 1.7 GiB chunk)."""
    block = CountingBlock(10**9, n_measured=1)
    samples = models.sample_params(arm, 10, seed=2)
    setup = RunSetup.build(arm, block, 0.2, 1.0)
    plan = MonteCarloPlan.build(arm, block, setup, samples, jit=True)
    if plan.kernel is None:
        pytest.skip(f"no C kernel here: {plan.engine}")
    whole = models.monte_carlo(arm, block, 0.2, 1.0, samples, jit=True)
    monkeypatch.setattr(models.monte_carlo_batch, "MONTE_CARLO_CHUNK_BYTES", int(3.5 * plan.sample_bytes()))
    monkeypatch.setattr(models.checks, "MEMORY_LIMIT_BYTES", int(8 * plan.sample_bytes()))
    with pytest.raises(models.ResourceLimitError, match="monte_carlo of 10 samples"):
        models.monte_carlo(arm, block, 0.2, 1.0, samples, jit=True)
    chunks = list(models.monte_carlo_chunks(arm, block, 0.2, 1.0, samples, jit=True))
    assert [len(c) for c in chunks] == [3, 3, 3, 1]
    for field in ("x", "u", "xc"):
        np.testing.assert_array_equal(np.concatenate([getattr(c, field) for c in chunks]), getattr(whole, field))


def test_monte_carlo_chunks_run_what_monte_carlo_refuses_with_the_same_numbers(arm, monkeypatch):
    block = CountingBlock(10**9, n_measured=1)
    samples = models.sample_params(arm, 10, seed=2)
    whole = models.monte_carlo(arm, block, 0.2, 1.0, samples, noise_std=1e-3, seed=5)
    # About 168 kB for all ten samples at once, 50 kB for a chunk of three.
    monkeypatch.setattr(models.checks, "MEMORY_LIMIT_BYTES", 64 * 1024)
    with pytest.raises(models.ResourceLimitError, match="monte_carlo of 10 samples"):
        models.monte_carlo(arm, block, 0.2, 1.0, samples, noise_std=1e-3, seed=5)
    chunks = list(models.monte_carlo_chunks(arm, block, 0.2, 1.0, samples, noise_std=1e-3, seed=5, chunk_size=3))
    assert [c.first_sample for c in chunks] == [0, 3, 6, 9] and [len(c) for c in chunks] == [3, 3, 3, 1]
    for field in ("x", "u", "xc", "measured", "params"):
        np.testing.assert_array_equal(np.concatenate([getattr(c, field) for c in chunks]), getattr(whole, field))
    with pytest.raises(models.ResourceLimitError, match="a Monte Carlo chunk of 10 samples"):
        models.monte_carlo_chunks(arm, block, 0.2, 1.0, samples, chunk_size=10)


def test_sample_params_beyond_the_limit_is_refused(arm):
    with pytest.raises(models.ResourceLimitError, match=r"sample_params of 100000000000 samples"):
        models.sample_params(arm, 10**11)


# --------------------------------------------------------------------------- clear errors: parameters and plants
@pytest.mark.parametrize(
    "value,error,message",
    [
        ("0.6", TypeError, r"arm: parameter m \(kg\) must be a real number, got str '0.6'"),
        ([0.5], TypeError, r"arm: parameter m \(kg\) must be a real number, got list \[0.5\]"),
        (True, TypeError, r"arm: parameter m \(kg\) must be a real number, got bool True"),
        (np.array([0.5, 0.6]), TypeError, r"arm: parameter m \(kg\) must be a real number, got ndarray"),
        (None, TypeError, r"arm: parameter m \(kg\) must be a real number, got NoneType"),
        (complex(0.5, 0), TypeError, r"arm: parameter m \(kg\) must be a real number, got complex"),
    ],
)
def test_a_parameter_must_be_a_real_number(value, error, message):
    with pytest.raises(error, match=message):
        models.get("arm", m=value)
    with pytest.raises(error, match=message):
        models.get("arm").with_params(m=value)


def test_numpy_and_integer_parameters_are_accepted():
    assert models.get("arm", m=np.float32(0.5), ell=1).params["ell"] == 1.0
    assert models.get("arm", m=np.array(0.6)).params["m"] == 0.6


@pytest.mark.parametrize(
    "call,error,message",
    [
        (
            lambda: models.get("arm", input_limit=[1, 2]),
            ValueError,
            r"arm: input_limit must be one number for every input or one per input \('tau',\), got \[1, 2\]",
        ),
        (lambda: models.get("arm", input_limit="1"), TypeError, r"arm: input_limit must hold real numbers"),
        (
            lambda: models.get("arm", input_limit=np.inf),
            ValueError,
            r"arm: input_limit must be finite and > 0, got inf",
        ),
        (lambda: models.get("arm").with_input_limit([0.5, -1]), ValueError, r"arm: input_limit must be one number"),
        (lambda: models.get(["arm"]), TypeError, r"plant name must be a non-empty string, got \['arm'\]"),
        (
            lambda: models.get("arm").param_vector(["0.5", 0.3, 9.8, 0.01]),
            TypeError,
            r"arm parameter vector must hold real numbers",
        ),
        (lambda: models.get("arm").f(["0", "0"], [0.0]), TypeError, r"arm state \('theta', 'dtheta'\) must hold real"),
        (lambda: models.get("arm").f([True, False], [0.0]), TypeError, r"arm state .* must hold real numbers"),
        (
            lambda: models.get("arm").equilibrium(theta="0.5"),
            TypeError,
            r"arm: fixed value theta must be a real number",
        ),
        (
            lambda: models.get("arm").equilibrium(theta=0.1, tau=0.0),
            ValueError,
            r"arm: equilibrium\(theta=0.1, tau=0\) fixes every coordinate and input, leaving nothing to solve for",
        ),
        (
            lambda: models.get("pendulum").equilibrium(z=0.0, theta=0.0, F=0.0),
            ValueError,
            r"pendulum: equilibrium\(z=0, theta=0, F=0\) fixes every coordinate and input",
        ),
        (
            lambda: models.get("arm").equilibrium(tol=-1.0),
            ValueError,
            r"arm: equilibrium tol must be a finite number > 0",
        ),
        (lambda: models.get("arm").linearize(check="no"), TypeError, r"check must be True or False, got str 'no'"),
        (lambda: models.get("arm").step_function(0.01, 2.7), ValueError, r"substeps must be an integer, got 2.7"),
        (lambda: models.get("arm").step_function(0.01, 0), ValueError, r"substeps must be an integer >= 1, got 0"),
        (lambda: models.get("arm").step_function("0.01"), TypeError, r"sample_period \(s\) must be a real number"),
        (lambda: models.Plant("arm"), TypeError, r"Plant needs a declaration made by models.declare, got str 'arm'"),
    ],
)
def test_plant_arguments(call, error, message):
    with pytest.raises(error, match=message):
        call()


def test_declaring_a_registered_name_is_refused_unless_replace(private_registry):
    original = models.get("arm")

    def physics(q, dq, u, p):
        return models.Physics(kinetic=p.m * dq.theta**2 / 2, potential=0, forces=[u.tau], outputs={"theta": q.theta})

    spec = dict(
        name="arm",
        title="my arm",
        coordinates=("theta",),
        inputs=("tau",),
        params=(models.Param("m", 2.0, "kg"),),
        input_limit=1.0,
    )
    with pytest.raises(
        ValueError,
        match=r"a plant named 'arm' is already registered \(Single link robot arm "
        r"\(case study I\)\); pass replace=True",
    ):
        models.declare(**spec)(physics)
    assert models.get("arm").title == original.title and models.get("arm").params == original.params
    models.declare(**spec, replace=True)(physics)
    assert models.get("arm").title == "my arm" and models.get("arm").params == {"m": 2.0}
    models.declare(**spec | {"name": "my_new_plant"})(physics)  # a new name needs no permission
    assert "my_new_plant" in models.names()


def test_a_singular_static_balance_is_an_error_not_a_nan_feedforward():
    """x' = -b x + u + 1 rests wherever u = b x - 1: no unique input, and the symbolic least-squares
    solve of the static balance gives NaN, which was returned as the feedforward."""

    def physics(q, dq, u, p, s):
        return models.Physics(rates={"x": -p.m * s.x + u.u + 1.0}, outputs={"x": s.x})

    lag = _declare(physics, coordinates=(), first_order=("x",))
    with pytest.raises(
        ValueError,
        match=r"user: no unique input holds the plant at rest at q = \[\] \(the static "
        r"balance is singular there\); use equilibrium\(\) instead",
    ):
        lag.equilibrium_input([])
    np.testing.assert_allclose(lag.equilibrium(x=2.0)[1], [1.0])


def test_an_operating_point_that_is_not_a_dict_is_named():
    def physics(q, dq, u, p):
        return models.Physics(kinetic=p.m * dq.q1**2 / 2, forces=[u.u], outputs={"q1": q.q1})

    plant = _declare(physics, coordinates=("q1",), operating_point=lambda p: None)
    with pytest.raises(TypeError, match=r"user: operating_point must return a dict of fixed values, got None"):
        plant.equilibrium()


def test_solve_spd_names_a_zero_pivot():
    from models.lagrangian import solve_spd

    with pytest.raises(ValueError, match=r"structurally zero pivot in row 0"):
        solve_spd(ca.SX(np.array([[0.0, 1.0], [1.0, 2.0]])), ca.SX.sym("b", 2))


def test_a_coordinate_without_kinetic_energy_is_named():
    """Today's KeyError (0, 0) from the elimination: q1 has no inertia."""

    def physics(q, dq, u, p):
        return models.Physics(kinetic=p.m * dq.q2**2 / 2, potential=q.q1**2, forces=[u.u, 0], outputs={"q1": q.q1})

    with pytest.raises(
        ValueError,
        match=r"user: the kinetic energy has no term in the velocity of coordinate 'q1' "
        r"\(zero mass-matrix diagonal\).*declare it as a first-order state",
    ):
        _declare(physics)


def test_a_singular_mass_matrix_is_named_with_its_massless_combination():
    def physics(q, dq, u, p):
        return models.Physics(
            kinetic=p.m * (dq.q1 + dq.q2) ** 2 / 2, potential=0, forces=[u.u, 0], outputs={"q1": q.q1}
        )

    with pytest.raises(
        ValueError,
        match=r"user: the mass matrix is singular: the velocity combination "
        r"-?0.707 dq1 \+ -?0.707 dq2 has no kinetic energy",
    ):
        _declare(physics)


def test_an_indefinite_mass_matrix_is_named():
    def physics(q, dq, u, p):
        return models.Physics(
            kinetic=p.m * (dq.q1**2 - dq.q2**2) / 2, potential=0, forces=[u.u, 0], outputs={"q1": q.q1}
        )

    with pytest.raises(
        ValueError,
        match=r"user: the mass matrix is not positive definite at q = \[0. 0.\] "
        r"\(eigenvalue -1\)",
    ):
        _declare(physics)


@pytest.mark.parametrize(
    "returned,error,message",
    [
        (None, TypeError, r"user: the physics function 'physics' must return models.Physics, got NoneType None"),
        ({"kinetic": 0}, TypeError, r"user: the physics function 'physics' must return models.Physics, got dict"),
        (
            models.Physics(kinetic="T", forces=[0, 0]),
            TypeError,
            r"user: Physics.kinetic must be a CasADi SX expression or a number, got str 'T'",
        ),
        (
            models.Physics(kinetic=1.0, forces=[0]),
            ValueError,
            r"user: Physics.forces needs one generalized force per coordinate \('q1', 'q2'\) \(2\), got 1",
        ),
        (models.Physics(kinetic=1.0, forces=[0, None]), TypeError, r"user: generalized force of 'q2' must be"),
        (models.Physics(kinetic=1.0, forces="F"), TypeError, r"user: Physics.forces must be a list"),
        (
            models.Physics(kinetic=1.0, forces=[0, 0], outputs=[1.0]),
            TypeError,
            r"user: Physics.outputs must be a mapping name -> expression",
        ),
        (
            models.Physics(kinetic=1.0, forces=[0, 0], outputs={"y": ca.SX.sym("a", 2)}),
            ValueError,
            r"user: output 'y' must be one scalar expression, got shape \(2, 1\)",
        ),
    ],
)
def test_a_wrong_physics_return_is_named(returned, error, message):
    def physics(q, dq, u, p):
        return returned

    with pytest.raises(error, match=message):
        _declare(physics)


def test_outputs_may_not_depend_on_the_inputs():
    def physics(q, dq, u, p):
        return models.Physics(
            kinetic=p.m * (dq.q1**2 + dq.q2**2) / 2, forces=[u.u, 0], outputs={"q1": q.q1, "feedthrough": q.q2 + u.u}
        )

    with pytest.raises(ValueError, match=r"user: outputs must not depend on the inputs \(feedthrough do\)"):
        _declare(physics)


@pytest.mark.parametrize(
    "rates,error,message",
    [
        (
            {"i": ca.SX.sym("two", 2)},
            ValueError,
            r"user: first-order equation of 'i' must be one scalar expression, "
            r"got shape \(2, 1\)",
        ),
        ({}, ValueError, r"user: Physics.rates must give one equation per first-order state \('i',\), got \(\)"),
        ({"i": 0.0, "j": 0.0}, ValueError, r"user: Physics.rates must give one equation per first-order state"),
        ([0.0, 1.0], ValueError, r"user: Physics.rates needs one equation per first-order state \('i',\) \(1\), got 2"),
        ("di", TypeError, r"user: Physics.rates must map each first-order state to its derivative"),
        ({"i": "x"}, TypeError, r"user: first-order equation of 'i' must be a CasADi SX expression or a number"),
    ],
)
def test_a_wrong_first_order_equation_is_named(rates, error, message):
    def physics(q, dq, u, p, s):
        return models.Physics(kinetic=p.m * dq.q1**2 / 2, forces=[s.i], rates=rates, outputs={"q1": q.q1})

    with pytest.raises(error, match=message):
        _declare(physics, coordinates=("q1",), first_order=("i",))


def test_kinetic_energy_may_not_depend_on_a_first_order_state():
    def physics(q, dq, u, p, s):
        return models.Physics(
            kinetic=(p.m + s.i**2) * dq.q1**2 / 2, forces=[u.u], rates={"i": -s.i}, outputs={"q1": q.q1}
        )

    with pytest.raises(
        ValueError,
        match=r"user: the kinetic energy must not depend on the first-order states "
        r"\('i',\)",
    ):
        _declare(physics, coordinates=("q1",), first_order=("i",))


@pytest.mark.parametrize(
    "kwargs,error,message",
    [
        ({"coordinates": "theta"}, TypeError, r"user: coordinates must be a list or tuple of names, got 'theta'"),
        ({"first_order": ("q1",)}, ValueError, r"user: repeated state name in \('q1', 'dq1', 'q1'\)"),
        ({"first_order": ("dq1",)}, ValueError, r"user: repeated state name"),
        ({"coordinates": (), "first_order": ()}, ValueError, r"user: declare at least one coordinate or first-order"),
        ({"uncertain": ("mass",)}, ValueError, r"user: uncertain parameter 'mass' is not declared"),
        ({"params": (models.Param("m", "1", "kg"),)}, TypeError, r"user: Param m value must be a real number"),
        (
            {"params": (models.Param("m", 0.0, "kg"),)},
            ValueError,
            r"user: Param m \(kg\) must be finite and > 0, got 0",
        ),
        ({"params": ("m",)}, TypeError, r"user: params must be a sequence of models.Param"),
        ({"input_limit": [1.0, 2.0]}, ValueError, r"user: input_limit must be one number for every input"),
        ({"operating_point": {"q1": 0}}, TypeError, r"user: operating_point must be a callable"),
        ({"register": "yes"}, TypeError, r"register must be True or False, got str 'yes'"),
    ],
)
def test_declare_arguments(kwargs, error, message):
    spec = (
        dict(
            name="user",
            title="user plant",
            coordinates=("q1",),
            inputs=("u",),
            params=(models.Param("m", 1.0, "kg"),),
            input_limit=1.0,
            register=False,
        )
        | kwargs
    )
    with pytest.raises(error, match=message):
        models.declare(**spec)(lambda q, dq, u, p: models.Physics(kinetic=dq.q1**2, forces=[u.u]))


# --------------------------------------------------------------------------- clear errors: simulators
@pytest.mark.parametrize(
    "kwargs,error,message",
    [
        ({"method": "collocation", "degree": 0}, ValueError, r"degree must be an integer >= 1, got 0"),
        (
            {"method": "collocation", "degree": 12},
            ValueError,
            r"degree must be an integer from 1 to 9 \(Radau points\)",
        ),
        ({"method": "collocation", "degree": 2.5}, ValueError, r"degree must be an integer, got 2.5"),
        ({"method": "adaptive", "rtol": -1e-6}, ValueError, r"rtol must be a finite number > 0, got -1e-06"),
        ({"method": "adaptive", "atol": float("nan")}, ValueError, r"atol must be a finite number > 0, got nan"),
        ({"substeps": 2.7}, ValueError, r"substeps must be an integer, got 2.7"),
        ({"substeps": True}, TypeError, r"substeps must be an integer, got bool True"),
        ({"sample_period": "0.01"}, TypeError, r"sample_period \(s\) must be a real number, got str '0.01'"),
        ({"u": [["1"], ["2"]]}, TypeError, r"arm input sequence must hold real numbers"),
        ({"jit": "yes"}, TypeError, r"jit must be True or False, got str 'yes'"),
        ({"method": 4}, ValueError, r"unknown method 4; choose one of rk4, adaptive, collocation"),
        ({"plant": "arm"}, TypeError, r"plant must be a models.Plant, got str 'arm'"),
    ],
)
def test_simulate_arguments(kwargs, error, message):
    args = {"plant": models.get("arm"), "x0": [0.0, 0.0], "u": np.zeros((3, 1)), "sample_period": 0.01} | kwargs
    with pytest.raises(error, match=message):
        simulate(args.pop("plant"), args.pop("x0"), args.pop("u"), args.pop("sample_period"), **args)


def test_radau_matrices_refuse_degree_zero():
    with pytest.raises(ValueError, match=r"degree must be an integer >= 1, got 0"):
        radau_matrices(0)


@pytest.mark.parametrize(
    "kwargs,error,message",
    [
        ({"substeps": 2.7}, ValueError, r"substeps must be an integer, got 2.7"),
        ({"seed": -1}, ValueError, r"seed must be an integer >= 0, got -1"),
        ({"seed": "1"}, TypeError, r"seed must be an integer, got str '1'"),
        ({"duration": "1"}, TypeError, r"duration \(s\) must be a real number, got str '1'"),
        ({"duration": 0.001}, ValueError, r"duration 0.001 s is shorter than one sample \(0.01 s\)"),
        ({"noise_std": [0.1, 0.2]}, ValueError, r"noise_std must be one number or 1 numbers .* got shape \(2,\)"),
        ({"noise_std": "0.1"}, TypeError, r"noise_std must hold real numbers"),
        ({"xc0": [0.0, 1.0]}, ValueError, r"counting: initial controller state xc0 must have 1 entries"),
        ({"reference": "1.0"}, TypeError, r"reference must hold real numbers, got '1.0'"),
        ({"input_disturbance": lambda t: ["a"] * len(t)}, TypeError, r"input disturbance must hold real numbers"),
        ({"allow_divergence": 1}, TypeError, r"allow_divergence must be True or False, got int 1"),
        ({"compiled": "no"}, TypeError, r"compiled must be True or False, got str 'no'"),
        ({"x0": [0.0, np.nan]}, ValueError, r"arm initial state has non-finite entries"),
        ({"params": {"m": "0.5"}}, TypeError, r"arm: parameter m \(kg\) must be a real number"),
        ({"plant": "arm"}, TypeError, r"plant must be a models.Plant, got str 'arm'"),
    ],
)
def test_simulate_closed_loop_arguments(kwargs, error, message):
    args = {"plant": models.get("arm"), "controller": CountingBlock(10**6), "reference": 0.1, "duration": 1.0} | kwargs
    with pytest.raises(error, match=message):
        models.simulate_closed_loop(
            args.pop("plant"), args.pop("controller"), args.pop("reference"), args.pop("duration"), **args
        )


@pytest.mark.parametrize(
    "kwargs,error,message",
    [
        ({"threads": 0}, ValueError, r"threads must be an integer >= 1, got 0"),
        ({"threads": 2.5}, ValueError, r"threads must be an integer, got 2.5"),
        ({"seed": -3}, ValueError, r"seed must be an integer >= 0, got -3"),
        ({"chunk_size": 0}, ValueError, r"chunk_size must be an integer >= 1, got 0"),
        ({"substeps": 2.7}, ValueError, r"substeps must be an integer, got 2.7"),
        ({"param_samples": np.zeros((0, 4))}, ValueError, r"param_samples has no rows"),
        (
            {"param_samples": [[0.5, 0.3, 9.8, 0.01], [-0.5, 0.3, 9.8, 0.01]]},
            ValueError,
            r"param_samples row 1: arm: parameter m \(kg\) must be finite and > 0, got -0.5",
        ),
        ({"param_samples": [[0.5, 0.3, 9.8]]}, ValueError, r"param_samples must have shape \(N, 4\), got \(1, 3\)"),
        ({"param_samples": [["0.5", 0.3, 9.8, 0.01]]}, TypeError, r"param_samples must hold real numbers"),
        ({"controller": PythonNaN(3)}, TypeError, r"monte_carlo batches Blocks"),
    ],
)
def test_monte_carlo_arguments(kwargs, error, message):
    arm = models.get("arm")
    args = {"controller": CountingBlock(10**6), "param_samples": models.sample_params(arm, 2)} | kwargs
    with pytest.raises(error, match=message):
        models.monte_carlo(arm, args.pop("controller"), 0.1, 1.0, args.pop("param_samples"), **args)


@pytest.mark.parametrize(
    "call,error,message",
    [
        (lambda: CountingBlock(10, k="1"), TypeError, r"counting: gain k must hold real numbers"),
        (lambda: CountingBlock(10, k=[np.nan]), ValueError, r"counting: gain k is not finite"),
        (
            lambda: models.Cascade(CountingBlock(1), CountingBlock(1)).with_gains(**{"outer.k": "2"}),
            TypeError,
            r"gain outer.k must hold real numbers",
        ),
        (lambda: models.signals.steps(["1", "2"], 1.0), TypeError, r"levels must hold real numbers"),
        (lambda: models.signals.steps([1.0, np.nan], 1.0), ValueError, r"levels must be finite"),
        (lambda: models.signals.step("2"), TypeError, r"amplitude must be a real number, got str '2'"),
        (lambda: models.signals.square(1.0, 0.0), ValueError, r"period \(s\) must be a finite number > 0, got 0.0"),
        (lambda: models.signals.ramp(np.inf), ValueError, r"slope must be finite, got inf"),
        (
            lambda: models.sample_params(models.get("arm"), True),
            TypeError,
            r"the number of samples n must be an integer",
        ),
        (lambda: models.sample_params(models.get("arm"), 10, seed=-1), ValueError, r"seed must be an integer >= 0"),
        (lambda: models.sample_params(models.get("arm"), 10, names="m"), TypeError, r"names must be a list"),
        (lambda: models.corner_params(models.get("arm"), rel=2.0), ValueError, r"rel must be in \[0, 1\), got 2.0"),
        (
            lambda: models.perturbed(models.get("arm"), rel=float("nan")),
            ValueError,
            r"rel must be in \[0, 1\), got nan",
        ),
        (lambda: models.perturbed(models.get("arm"), sign=0.0), ValueError, r"sign must be \+1 or -1, got 0.0"),
        (lambda: models.get("arm").linearize().discretize("0.01"), TypeError, r"sample_period \(s\) must be a real"),
        (
            lambda: models.closed_loop_function(models.get("arm"), CountingBlock(1), 10.5),
            ValueError,
            r"n_steps must be an integer, got 10.5",
        ),
        (
            lambda: models.closed_loop_function(models.get("arm"), CountingBlock(1), 10**9),
            models.ResourceLimitError,
            r"closed_loop_function of 1000000000 steps of arm needs about \d+ GiB",
        ),
        (
            lambda: models.closed_loop_function(models.get("arm"), PythonNaN(1), 10),
            TypeError,
            r"closed_loop_function needs a Block",
        ),
        (
            lambda: models.Cascade(CountingBlock(1), "inner"),
            TypeError,
            r"cascade: the inner controller must be a models.Block, got str",
        ),
    ],
)
def test_blocks_signals_and_uncertainty_arguments(call, error, message):
    with pytest.raises(error, match=message):
        call()


class _SizedBlock(models.Block):
    def expr(self, xc, y, r, g):
        return xc, g["k"] * y[0]


@pytest.mark.parametrize(
    "kwargs,error,message",
    [
        ({"n_state": 1.5}, ValueError, r"block: n_state must be an integer, got 1.5"),
        ({"n_input": 0}, ValueError, r"block: n_input must be an integer >= 1, got 0"),
        ({"sample_period": True}, TypeError, r"block: sample_period \(s\) must be a real number, got bool True"),
        ({"gains": [1.0]}, TypeError, r"block: gains must be a mapping name -> value"),
        ({"gains": {"k": np.ones((2, 2, 2))}}, ValueError, r"block: gain k must be a number, vector or matrix"),
        ({"measures": "everything"}, ValueError, r"block: measures must be one of \('outputs', 'state'\)"),
    ],
)
def test_block_arguments(kwargs, error, message):
    spec = (
        dict(sample_period=0.01, n_state=0, n_measured=1, n_reference=1, n_input=1, gains={"k": 1.0}, name="block")
        | kwargs
    )
    with pytest.raises(error, match=message):
        _SizedBlock(**spec)


def test_a_linear_model_of_inconsistent_shapes_names_the_matrix():
    lin = models.get("arm").linearize()
    with pytest.raises(ValueError, match=r"arm: B must have shape \(2, 1\) .* got \(3, 1\)"):
        models.LinearModel(**{**lin.__dict__, "B": np.zeros((3, 1))})
    with pytest.raises(ValueError, match=r"arm: C has non-finite entries"):
        models.LinearModel(**{**lin.__dict__, "C": np.array([[np.nan, 0.0]])})
