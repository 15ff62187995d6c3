"""The Monte Carlo's compiled kernel (`models.mc_kernel`): a batch of N is N batches of one bit for bit, a
sample's numbers are the same in every lane and group, its sine and cosine are the C library's to rounding, it
agrees with CasADi's run of the same closed loop, and where it cannot be built the CasADi map runs and the
plan says why."""

import math

import casadi as ca
import numpy as np
import pytest

import models
from models import mc_kernel
from models.monte_carlo_batch import MonteCarloPlan
from models.run_setup import RunSetup


class FixtureBlock(models.Block):
    """The test controllers' common declaration: Ts = 0.01 s, one reference, one command."""

    def __init__(self, gains: dict, n_state: int, n_measured: int, measures: str = "outputs"):
        super().__init__(
            sample_period=0.01,
            n_state=n_state,
            n_measured=n_measured,
            n_reference=1,
            n_input=1,
            gains=gains,
            measures=measures,
        )


class PendulumPI(FixtureBlock):
    """Reads the pendulum's two outputs: u = -kp y_0 ... with a clamped integral of the angle's error and a
    filtered angle (a test fixture with state, a conditional and every comparison the designs use)."""

    def __init__(self, remainder: bool = False):
        super().__init__({"K": np.array([-4.0, 40.0]), "ki": 2.0, "a": 0.6}, n_state=2, n_measured=2)
        self.remainder = remainder

    def expr(self, xc, y, r, g):
        e = r[0] - y[0]
        integral = ca.if_else(ca.fabs(xc[0] + 0.01 * e) < 1.0, xc[0] + 0.01 * e, xc[0])
        filtered = g["a"] * xc[1] + (1 - g["a"]) * y[1]
        u = -g["K"][0] * e + g["K"][1] * filtered + g["ki"] * integral
        if self.remainder:  # an operation the kernel's generator does not write
            u = u + 1e-3 * ca.remainder(y[1], 0.5)
        return ca.vertcat(integral, filtered), u


def _pendulum_runs(samples, **kw):
    pend = models.get("pendulum")
    block = PendulumPI()
    args = dict(noise_std=1e-3, seed=21, input_disturbance=0.1, substeps=2)
    return pend, block, models.monte_carlo(pend, block, 0.3, 2.0, samples, **(args | kw))


def _require_kernel(plant, block, substeps=2):
    try:
        mc_kernel.kernel(plant, block, substeps)
    except mc_kernel.KernelUnavailable as err:
        pytest.skip(f"no compiled kernel here: {err}")


FIELDS = ("x", "xc", "y", "u", "measured")


def test_a_batch_of_n_is_n_batches_of_one_bit_for_bit_whatever_the_threads_and_chunks():
    """11 samples (one full block of 8 lanes, one of 3 padded with copies) against each alone (lane 0, a
    block of 1): the same bits, for 1 and 2 threads and chunks of 4."""
    pend = models.get("pendulum")
    _require_kernel(pend, PendulumPI())
    samples = models.sample_params(pend, 11, seed=8)
    _, _, whole = _pendulum_runs(samples, jit=True, threads=2)
    _, _, chunked = _pendulum_runs(samples, jit=True, threads=1, chunk_size=4)
    for i in range(len(samples)):
        _, _, alone = _pendulum_runs(samples[i : i + 1], jit=True, threads=1, first_sample=i)
        for name in FIELDS:
            np.testing.assert_array_equal(getattr(whole, name)[i], getattr(alone, name)[0], err_msg=name)
            np.testing.assert_array_equal(getattr(chunked, name)[i], getattr(alone, name)[0], err_msg=name)
    assert not np.allclose(whole.x[0], whole.x[1])  # the samples differ


def test_ranges_taken_in_turn_by_two_threads_give_one_threads_bits(monkeypatch):
    """Three blocks and five samples more, as a range per block taken in turn by two threads and as one
    range on one thread: the same bits."""
    pend = models.get("pendulum")
    block = PendulumPI()
    _require_kernel(pend, block)
    samples = models.sample_params(pend, 3 * mc_kernel.kernel(pend, block, 2).block + 5, seed=5)
    monkeypatch.setattr(mc_kernel, "PARTS_PER_THREAD", 2)
    _, _, one = _pendulum_runs(samples, jit=True, threads=1)
    _, _, two = _pendulum_runs(samples, jit=True, threads=2)
    for name in FIELDS:
        np.testing.assert_array_equal(getattr(two, name), getattr(one, name), err_msg=name)


def test_a_samples_numbers_are_the_same_in_every_lane_and_group():
    """Two blocks and three samples more of one parameter row, without noise: every lane of every group
    (and the padding of the last block) computes the same bits."""
    pend = models.get("pendulum")
    block = PendulumPI()
    _require_kernel(pend, block)
    size = mc_kernel.kernel(pend, block, 2).block
    assert size % mc_kernel.GROUPS == 0 and size >= 2 * mc_kernel.GROUPS
    row = models.sample_params(pend, 1, seed=4)
    batch = models.monte_carlo(
        pend, block, 0.3, 2.0, np.repeat(row, 2 * size + 3, axis=0), input_disturbance=0.1, substeps=2, jit=True
    )
    for name in FIELDS:
        values = getattr(batch, name)
        for i in range(1, values.shape[0]):
            np.testing.assert_array_equal(values[i], values[0], err_msg=f"{name}, sample {i}")
    assert np.ptp(batch.x[0, :, 1]) > 0.01  # the angle moves: the sines matter


def test_the_kernels_sine_and_cosine_are_the_c_librarys_to_rounding():
    """Against Python's math.sin and math.cos (the C library): within 2 units in the last place and
    2.3e-16 over [-1e5, 1e5], exact zeros' signs; beyond 1e5 and for infinities and NaN, the C library's
    own values (the kernel calls it there), lanes of either kind mixed in one vector."""
    pend = models.get("pendulum")
    _require_kernel(pend, PendulumPI())
    kernel = mc_kernel.kernel(pend, PendulumPI(), 2)
    rng = np.random.default_rng(2)
    x = np.concatenate([rng.uniform(-4.0, 4.0, 20000), rng.uniform(-1e5, 1e5, 20000)])
    x = np.concatenate([x, np.nextafter(np.arange(-2000, 2000) * (np.pi / 2), np.inf), [0.0, -0.0, 1e-300, -5e-324]])
    sine, cosine = kernel.sincos(x)
    for got, fun in ((sine, math.sin), (cosine, math.cos)):
        want = np.array([fun(v) for v in x])
        assert np.max(np.abs(got - want)) <= 2.3e-16
        assert np.max(np.abs(got - want) / np.spacing(np.abs(want))) <= 2.0
        assert np.mean(got == want) > 0.75  # most are the same bits
    np.testing.assert_array_equal(np.signbit(sine[-4:]), np.signbit(x[-4:]))  # sin(-0.) = -0.
    far = np.array([1.0, 1e5, -np.nextafter(1e5, 2e5), 3e7, 1.0, 1e300, np.inf, -np.inf, np.nan, 0.5, -1e6])
    beyond = ~(np.abs(far) <= 1e5)
    sine, cosine = kernel.sincos(far)
    for got, fun in ((sine, math.sin), (cosine, math.cos)):
        want = np.array([fun(v) if math.isfinite(v) else math.nan for v in far])
        np.testing.assert_array_equal(got[beyond], want[beyond])  # the C library's bits
        np.testing.assert_allclose(got[~beyond], want[~beyond], rtol=0, atol=2.3e-16)


def test_the_kernel_agrees_with_casadis_run_of_the_same_closed_loop():
    """The kernel's runs against the CasADi map in its virtual machine (jit=False) over the whole 2 s run,
    noise and disturbance included: within 1e-9 (rounding alone: the compiler may fuse a multiply and
    an add), and the divergence times the same."""
    pend = models.get("pendulum")
    _require_kernel(pend, PendulumPI())
    samples = models.sample_params(pend, 10, seed=3)
    _, _, kernel = _pendulum_runs(samples, jit=True)
    _, _, casadi = _pendulum_runs(samples, jit=False)
    for name in FIELDS:
        np.testing.assert_allclose(getattr(kernel, name), getattr(casadi, name), rtol=0, atol=1e-9, err_msg=name)
    np.testing.assert_array_equal(kernel.diverged_at, casadi.diverged_at)
    assert np.ptp(kernel.u) > 1.0  # the run does something (the step and the saturation's range)


class EveryOperation(FixtureBlock):
    """State feedback plus 1e-3 times a sum of every function, comparison and logic operation the kernel's
    generator writes, of bounded arguments v in (-1, 1) and w in (0.25, 0.75), and a filtered state."""

    def __init__(self):
        super().__init__({"K": np.array([-4.0, 40.0, -6.0, 6.0])}, n_state=1, n_measured=4, measures="state")

    def expr(self, xc, y, r, g):
        v, w = ca.tanh(y[1] + 0.1 * ca.sin(y[0])), 0.5 + 0.25 * ca.cos(y[2])
        terms = [ca.sqrt(w), ca.floor(3 * v), ca.ceil(3 * v), ca.sign(v), ca.tan(v), ca.asin(0.9 * v), ca.acos(w)]
        terms += [ca.atan(v), ca.exp(v), ca.log(w), ca.sinh(v), ca.cosh(v), ca.asinh(v), ca.acosh(1 + w)]
        terms += [ca.atanh(0.9 * v), ca.erf(v), ca.log1p(w), ca.expm1(v), w**v, ca.fmin(v, w), ca.fmax(v, w)]
        terms += [ca.atan2(v, w), ca.fmod(3 * v, w), ca.copysign(w, v), ca.hypot(v, w), 1 / w, ca.fabs(v), v**2, -v]
        terms += [ca.if_else(ca.logic_and(v < w, v >= -w), v, w), ca.if_else(ca.logic_or(v == w, v != 0.5), w, v)]
        terms += [ca.logic_not(v > 0)]
        return 0.5 * xc + v, -ca.dot(g["K"], y) + 1e-3 * sum(terms) + 1e-3 * xc[0]


def test_every_operation_the_generator_writes_agrees_with_casadi():
    """The C library's functions lane by lane (exp and log on libmvec's vector variants), the comparisons
    and logic as masks, sign, fmod, copysign...: 19 samples (one block and a part), 1 s with noise, against
    CasADi's virtual machine, within 1e-12 in u (which spans hundreds)."""
    pend = models.get("pendulum")
    block = EveryOperation()
    _require_kernel(pend, block)
    fun = mc_kernel.closed_loop_step(pend, block, 2).expand()
    used = {fun.instruction_id(k) for k in range(fun.n_instructions())}
    names = "SQRT FLOOR CEIL SIGN TAN ASIN ACOS ATAN EXP LOG SINH COSH TANH ASINH ACOSH ATANH ERF LOG1P EXPM1 POW FMIN"
    names += " FMAX ATAN2 FMOD COPYSIGN HYPOT INV FABS LT LE EQ NE AND OR NOT IF_ELSE_ZERO SQ NEG TWICE SIN COS DIV"
    assert {getattr(ca, f"OP_{name}") for name in names.split()} <= used
    samples = models.sample_params(pend, 19, seed=5)
    kernel = models.monte_carlo(pend, block, 0.3, 1.0, samples, substeps=2, jit=True, noise_std=1e-3)
    casadi = models.monte_carlo(pend, block, 0.3, 1.0, samples, substeps=2, jit=False, noise_std=1e-3)
    for name in FIELDS:
        np.testing.assert_allclose(getattr(kernel, name), getattr(casadi, name), rtol=0, atol=1e-12, err_msg=name)
    assert np.ptp(kernel.u) > 100.0


def test_state_feedback_runs_on_the_kernel_with_the_plans_engine_saying_so():
    pend = models.get("pendulum")
    lin = pend.linearize()
    import control

    K = control.place(lin.A, lin.B, [-3, -3.5, -4, -4.5])[0]

    class StateFeedback(FixtureBlock):
        def __init__(self):
            super().__init__({"K": K}, n_state=0, n_measured=4, measures="state")

        def expr(self, xc, y, r, g):
            return xc, -ca.dot(g["K"], y) + 2.0 * r[0]

    block = StateFeedback()
    _require_kernel(pend, block)
    setup = RunSetup.build(pend, block, 0.3, 2.0, substeps=2)
    samples = models.sample_params(pend, 5, seed=1)
    plan = MonteCarloPlan.build(pend, block, setup, samples, jit=True)
    assert plan.engine == "C kernel" and plan.kernel is not None
    kernel = models.monte_carlo(pend, block, 0.3, 2.0, samples, substeps=2, jit=True)
    casadi = models.monte_carlo(pend, block, 0.3, 2.0, samples, substeps=2, jit=False)
    for name in FIELDS:
        np.testing.assert_allclose(getattr(kernel, name), getattr(casadi, name), rtol=0, atol=1e-9, err_msg=name)


def test_without_a_kernel_the_casadi_map_runs_and_the_plan_names_the_operation():
    pend = models.get("pendulum")
    block = PendulumPI(remainder=True)
    setup = RunSetup.build(pend, block, 0.3, 1.0, substeps=2)
    samples = models.sample_params(pend, 3, seed=1)
    plan = MonteCarloPlan.build(pend, block, setup, samples, jit=True)
    assert plan.kernel is None and "OP_REMAINDER" in plan.engine and plan.engine.startswith("CasADi map")
    with pytest.raises(mc_kernel.KernelUnavailable, match="OP_REMAINDER"):
        mc_kernel.kernel(pend, block, 2)
    batch = models.monte_carlo(pend, block, 0.3, 1.0, samples, substeps=2, jit=True)
    single = models.simulate_closed_loop(pend, block, 0.3, 1.0, params=samples[1], substeps=2)
    np.testing.assert_allclose(batch[1].u, single.u, rtol=0, atol=1e-12)  # the compiled map: rounding alone


def test_a_diverging_sample_diverges_at_the_same_time_on_the_kernel(blow_up_plant):
    """q'' = 4 q^3 from q = 1 escapes at about 0.93 s whatever the (zero) command: the kernel's run goes
    non-finite like CasADi's, and the fault rule gives the same sample time."""

    class Zero(FixtureBlock):
        def __init__(self):
            super().__init__({"k": 0.0}, n_state=0, n_measured=1)

        def expr(self, xc, y, r, g):
            return xc, g["k"] * y[0]

    block = Zero()
    _require_kernel(blow_up_plant, block, 10)
    samples = np.array([[1.0], [0.5]])
    kw = dict(x0=[1.0, 0.0], substeps=10)
    kernel = models.monte_carlo(blow_up_plant, block, 0.0, 2.0, samples, jit=True, **kw)
    casadi = models.monte_carlo(blow_up_plant, block, 0.0, 2.0, samples, jit=False, **kw)
    assert np.all(np.isfinite(kernel.diverged_at))
    np.testing.assert_array_equal(kernel.diverged_at, casadi.diverged_at)


class Faulty(FixtureBlock):
    """On the pendulum at rest: u = b² with a state x_c_next = a x_c + 1. With a = 1e100 the state overflows
    at its fifth sample (0, 1, 1e100, 1e200, 1e300, inf) while x and u stay finite; with b = 1e300 the
    command is infinite from the first sample (saturated, the plant does not see it)."""

    def __init__(self, a: float, b: float):
        super().__init__({"a": a, "b": b}, n_state=1, n_measured=4, measures="state")

    def expr(self, xc, y, r, g):
        return g["a"] * xc + 1.0, g["b"] * g["b"] + 0.0 * y[0]


@pytest.mark.parametrize(("a", "b", "when"), [(1e100, 0.0, 0.05), (1.0, 1e300, 0.0), (1.0, 0.0, None)])
def test_the_kernel_flags_every_fault_the_rule_finds(a, b, when):
    """A controller state that overflows with x and u finite, a command that is not finite, and neither:
    the kernel's divergence times are CasADi's (the rule of `models.closed_loop.first_faults`, which runs on
    the samples the kernel flags), and the expected ones."""
    pend = models.get("pendulum")
    faulty = Faulty(a, b)
    _require_kernel(pend, faulty)
    samples = np.repeat(pend.param_vector()[None], 5, axis=0)
    kernel = models.monte_carlo(pend, faulty, 0.0, 0.3, samples, substeps=2, jit=True)
    casadi = models.monte_carlo(pend, faulty, 0.0, 0.3, samples, substeps=2, jit=False)
    np.testing.assert_array_equal(kernel.diverged_at, casadi.diverged_at)
    np.testing.assert_array_equal(kernel.diverged_at, np.nan if when is None else when)
    clean = models.monte_carlo(pend, PendulumPI(), 0.3, 0.3, samples, substeps=2, jit=True)
    assert np.all(np.isnan(clean.diverged_at))


def test_a_single_run_with_jit_is_its_monte_carlo_sample_bit_for_bit():
    """`simulate_closed_loop(..., jit=True)` runs the kernel as a batch of one: the numbers of the same
    sample in `monte_carlo(..., jit=True)`, its noise seeded by (seed, index)."""
    pend = models.get("pendulum")
    _require_kernel(pend, PendulumPI())
    samples = models.sample_params(pend, 3, seed=6)
    pend, block, batch = _pendulum_runs(samples, jit=True)
    for i, row in enumerate(samples):
        single = models.simulate_closed_loop(
            pend,
            block,
            0.3,
            2.0,
            params=row,
            noise_std=1e-3,
            substeps=2,
            input_disturbance=0.1,
            seed=np.random.SeedSequence([21, i]),
            jit=True,
            allow_divergence=True,
        )
        for name in FIELDS:
            np.testing.assert_array_equal(getattr(single, name), getattr(batch, name)[i], err_msg=name)


@pytest.mark.parametrize("noise", [0.0, 1e-3])
def test_outputs_and_measurements_that_repeat_the_state_are_read_off_it(noise):
    """The pendulum's outputs are its first two states: with the kernel, y is a view of x, and without
    noise so is what the block measured; their values are CasADi's run's (a separate computation of
    h(x) and of the measurement), and with noise the measurement is its own array."""
    pend = models.get("pendulum")
    assert models.monte_carlo_batch.output_states(pend) == slice(0, 2)
    assert models.monte_carlo_batch.output_states(models.get("satellite")) is None  # phi - theta is no state
    block = PendulumPI()
    _require_kernel(pend, block)
    samples = models.sample_params(pend, 3, rel=0.05, seed=2)
    args = dict(noise_std=noise, seed=21, substeps=2)
    fast = models.monte_carlo(pend, block, 0.3, 1.0, samples, jit=True, **args)
    vm = models.monte_carlo(pend, block, 0.3, 1.0, samples, jit=False, **args)
    assert np.shares_memory(fast.y, fast.x)
    assert np.shares_memory(fast.measured, fast.x) == (noise == 0.0)
    np.testing.assert_allclose(fast.y, vm.y, atol=1e-9, rtol=0)
    np.testing.assert_allclose(fast.measured, vm.measured, atol=1e-9, rtol=0)
