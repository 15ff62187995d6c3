"""Gain tuning through the compiled nonlinear closed loop, with exact derivatives.

The decision variables are a block's gains; the cost is a time-domain
criterion of the nonlinear closed loop (`models.closed_loop_function`, one
CasADi mapaccum, so its gradient is exact) over a weighted set of scenarios
(a step, a series of steps, an input disturbance, measurement noise, a
regulation from an initial state) and parameter samples; the constraints are
each scenario's specs on every parameter sample. IPOPT solves it from the
hand design.

    result = tune(plant, block, [Scenario(0.8, 5.0, tracked="theta", name="step"),
                                 Scenario(0.8, 5.0, input_disturbance=0.2, tracked="theta")],
                  specs=Specs(max_overshoot=0.05, settling_time=2.0))
    result.block          # the tuned block; result.converged, result.status, result.violations

Saturation, conditional integration and anti-windup make the closed-loop
cost piecewise smooth in the gains (its gradient jumps wherever a sample
enters or leaves a limit). `tune` therefore solves a continuation of smoothed
problems (`models.smooth`: every switch blended over a band of relative width
w, w = 0.01, 0.001, ..., each solve warm-started from the last and solved to
`STAGE_TOL_FACTOR` times the tolerance, the last one to the tolerance itself) and stops when
IPOPT has converged on a stage where the exact nonsmooth loop's objective
agrees with the smoothed one to `AGREEMENT` with the same specs violated, and
whose answer either no longer moves the exact objective (the change from the
previous stage's answer is within `AGREEMENT`, relative) or has every switch
outside its band (smoothed and exact objectives equal: near that answer the
two problems are one). An intermediate stage stopped at IPOPT's iteration cap
hands its last point to the next width, cold (the verdict rests on the last
stage); two capped stages in a row end the continuation, unconverged. The choice
was measured (`python benchmarks/tuning.py --compare`) on the saturating 2 m
pendulum step against the exact loop in single shooting, which stops at
IPOPT's iteration limit because quasi-Newton steps stall on the kinks, and
multiple shooting of the exact loop, which makes each interval's
gradient local but keeps every kink, adds (n_x + n_c) variables and
constraints per interval, and was slower to a worse cost. A complementarity
reformulation needs each switch of each sample as a variable pair with a
complementarity constraint, which IPOPT handles only through a relaxation
driven to zero, the same continuation on a problem a thousand times larger,
and needs every switch exposed by the blocks, which write them inside their
CasADi step: not measured, for that reason.

On a problem without specs the continuation runs twice: first on the same loop
integrated coarsely (`COARSE_SUBSTEPS` RK4 steps per sample, every stage
loose), then on the problem's own loop from the coarse answer, starting at the
width where the coarse one settled; only the second decides convergence. Most
quasi-Newton iterations go to the first, widest stage, and there a coarse run
costs a fraction of a fine one (measured in `COARSE_SUBSTEPS`). Skipped where the
coarse loop's objective at the start is off by more than `COARSE_AGREEMENT`.

Only the switches are blended, not the criteria's |e|: blending |e| over
w |e_0| as well (tried) biased the settled tail, so the smoothed and exact
objectives agreed only to about 20 w and the continuation had to go below
w = 1e-5, where IPOPT stalled. The criteria carry their own fixed resolution
instead (`Cost.resolution`), part of the objective's definition.

A spec on a run is one inequality per sample (``paths="pointwise"``, the
default). With ``paths="aggregated"`` the smoothed stages replace each spec's
inequalities on one run by one: a soft maximum of their relative excesses,
``m + τ log(mean exp((v - m)/τ))`` with τ = w / max(log n, 1), which lies between
max v − w and max v, so the relaxation shrinks with the width and the exact
pointwise specs still judge every stage. Measured on the satellite's stored-gains
problem (16 parameter corners, two runs, 336,256 inequalities for 5 gains): with
zero-overshoot bounds thousands of them approach activity together in the settled
tail, and IPOPT crept (cost 23.7 → 21.0 over 300 iterations of its first stage,
3-5 s each, 60 % of it in MUMPS). Aggregated, L-BFGS hovered (170 iterations of the
first stage without meeting its tolerance); aggregated with ``hessian="exact"`` (5
gains, so second derivatives are cheap) it converged: six stages, 225 iterations.

With ``phase=True`` a start that misses a spec is first moved by a phase one (`phase_one`: minimize
the largest relative excess of the specs, a problem every decision is feasible
for), and the tuning starts from its answer. Measured on the arm's PD with zero
overshoot and 0.8 s settling from gains that miss both: IPOPT's own restoration
from the start wandered to its 3000-iteration cap (70 s); after a phase one (286
iterations) the tuning converged (12 s in all). A phase one that converges with
the specs still missed is a local certificate of infeasibility
(`TuningResult.stopped_on_test`).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import casadi as ca
import numpy as np

import models
from models import Block, Plant
from models.checks import as_matrix, as_vector, boolean, integer, positive, real, real_array, weight_matrix
from models.signals import sample

COSTS = ("itae", "iae", "ise")
ROBUST = ("mean", "worst")
PATHS = ("pointwise", "aggregated")
METHODS = ("smooth", "exact")
HESSIANS = ("limited-memory", "exact")
#: Relative smoothing widths of the continuation (see `models.smooth`), largest first. A start far from
#: the answer may need a wider first stage: on two pendulum corners, starting at 1e-2 hovered for 200+
#: IPOPT iterations without meeting its test, starting at 0.1 converged in 155 over four stages.
WIDTHS = (1e-2, 1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8)
#: The continuation stops when the exact and smoothed objectives agree to this, relative.
AGREEMENT = 1e-6
#: IPOPT statuses that mean it converged (to `tol`, or to 100 `tol` held for 10 iterations).
CONVERGED = ("Solve_Succeeded", "Solved_To_Acceptable_Level")
#: IPOPT's status at its iteration cap.
CAPPED = "Maximum_Iterations_Exceeded"
#: IPOPT's verdict of local infeasibility (its restoration converged outside the constraints).
INFEASIBLE = "Infeasible_Problem_Detected"
#: IPOPT iterations per solve: a safety cap, not the stopping rule (a stop here is reported).
MAX_ITER = 3000
#: IPOPT's default convergence tolerance here (scaled NLP error). Measured on the saturating 2 m
#: pendulum step (`benchmarks/tuning.py`): with 1e-8 the third stage (width 1e-4) stopped at the
#: 3000-iteration cap, its L-BFGS steps stalled on the narrow blends; with 1e-6 every stage
#: converged (104 iterations in all), at an exact objective equal to Nelder-Mead's to 1e-7.
TOL = 1e-6
#: The continuation's intermediate stages only start the next one: solved to this times `tol`, and the
#: stage that ends the continuation is finished at `tol` from where it stopped. Measured on the saturating
#: 2 m pendulum step (`benchmarks/tuning.py`, one loaded run each): factor 1 reached Nelder-Mead's cost
#: after 12.4 s (125 iterations in all), 100 after 9.7 s, 1000 after 8.9 s (92), 10^4 after 8.7 s, all
#: at the same converged answer (exact cost equal to 1e-10).
STAGE_TOL_FACTOR = 1000.0
#: RK4 sub-steps per sample of the coarser level `solve` runs first (its whole continuation, loosely, every
#: stage to `STAGE_TOL_FACTOR` x tol), whose answer starts the problem's own continuation at the width where
#: the coarser one settled. Measured on the saturating 2 m pendulum step (`benchmarks/tuning.py`): one
#: sub-step instead of ten makes an objective 4.2x and a gradient about as much cheaper, and the coarse
#: level's answer is already within 1e-7 of the fine optimum on the fine loop; the first stage's 60
#: quasi-Newton iterations, most of the work, are then spent on the cheap loop. Only on problems without
#: specs: the coarse answer sits on the coarse loop's spec boundary, which the fine loop may place a hair
#: away, and from there the arm's zero-overshoot tuning crept to IPOPT's 3000-iteration cap (a test).
COARSE_SUBSTEPS = 1
#: The coarser level runs only where its objective at the start is within this (relative) of the problem's:
#: a sample period too long for one RK4 step (a fast or stiff plant) fails it and is tuned at full fidelity.
COARSE_AGREEMENT = 1e-2
#: IPOPT options of every solve (`tol` sets tol and acceptable_tol = 100 tol).
#: MUMPS orders the KKT system by QAMD (approximate minimum degree that detects quasi-dense rows): every
#: constraint depends on every gain, so the system has a few dense columns, and MUMPS's automatic choice
#: took 237 s for the symbolic factorization of a 336,256-constraint tuning problem (16 parameter corners,
#: two runs), once per IPOPT solve; QAMD took 0.3 s.
IPOPT_OPTIONS = {"print_level": 0, "sb": "yes", "acceptable_iter": 10, "mumps_pivot_order": 6}
#: IPOPT's constraint tolerances (unscaled) on aggregated specs, whose values are relative excesses: well
#: inside the 1e-6 the exact specs are judged to. With IPOPT's defaults (1e-4, and 1e-2 for an acceptable
#: stop) the arm's aggregated tuning ended 1e-6 outside its overshoot spec, and the stages at widths 1e-7
#: and 1e-8 took no iteration.
AGGREGATED_IPOPT_OPTIONS = {"constr_viol_tol": 1e-8, "acceptable_constr_viol_tol": 1e-8}
#: IPOPT statuses of a numerical failure, retried once from the failed solve's last point.
RETRIED = ("Error_In_Step_Computation", "Restoration_Failed", "Search_Direction_Becomes_Too_Small")
#: IPOPT options of the continuation's later stages, which start at the last answer and multipliers.
WARM_START = {
    "warm_start_init_point": "yes",
    "mu_init": 1e-6,
    "warm_start_bound_push": 1e-9,
    "warm_start_slack_bound_push": 1e-9,
    "warm_start_mult_bound_push": 1e-9,
}


# ----------------------------------------------------------------- records
def _optional_time(value, what: str) -> float | None:
    return None if value is None else positive(value, what)


@dataclass(frozen=True)
class Specs:
    """Time-domain specs of one scenario, enforced at every sample of every parameter sample.

    max_overshoot : fraction (>= 0) of the step the tracked output may pass the final reference
    settling_time : s after which |e| <= settling_band * |step|
    settling_band : fraction of the step, in (0, 1)
    rise_time : s by which the output has covered 90 % of the step, and stays beyond
        (sufficient for a 10-90 % rise time below it)
    max_spectral_abscissa : 1/s, bound on the closed-loop linearization's slowest mode
        at the final state, log(spectral radius) / Ts; checked at the solution, not
        enforced during the search (eigenvalues are not smooth)
    state_bounds : dict state name -> bound b > 0 (|x_i| <= b) or (low, high) with low < high
        (either may be infinite), at every sample after the start (a crane's swing angle)
    final_values : dict state name -> (value, tolerance > 0): |x_i(t_N) − value| <= tolerance
        at the scenario's last sample

    The first three need a step (a constant reference different from the initial
    tracked value); the others hold for any scenario.
    """

    max_overshoot: float | None = None
    settling_time: float | None = None
    settling_band: float = 0.02
    rise_time: float | None = None
    max_spectral_abscissa: float | None = None
    state_bounds: Mapping = field(default_factory=dict)
    final_values: Mapping = field(default_factory=dict)

    def __post_init__(self):
        if self.max_overshoot is not None:
            value = real(self.max_overshoot, "max_overshoot")
            if value < 0:
                raise ValueError(f"max_overshoot must be a fraction >= 0, got {value}")
        _optional_time(self.settling_time, "settling_time (s)")
        _optional_time(self.rise_time, "rise_time (s)")
        band = real(self.settling_band, "settling_band")
        if not 0 < band < 1:
            raise ValueError(f"settling_band must be a fraction in (0, 1), got {band}")
        if self.max_spectral_abscissa is not None:
            real(self.max_spectral_abscissa, "max_spectral_abscissa (1/s)")
        if not isinstance(self.state_bounds, Mapping):
            raise TypeError(f"state_bounds must be a dict state name -> bound, got {self.state_bounds!r}")
        for name, bound in self.state_bounds.items():
            state_bound(bound, f"state_bounds[{name!r}]")
        if not isinstance(self.final_values, Mapping):
            raise TypeError(f"final_values must be a dict state name -> (value, tolerance), got {self.final_values!r}")
        for name, pair in self.final_values.items():
            final_value(pair, f"final_values[{name!r}]")

    @property
    def step_specs(self) -> tuple[str, ...]:
        """Names of the specs set here that need a step."""
        return tuple(
            name for name in ("max_overshoot", "settling_time", "rise_time") if getattr(self, name) is not None
        )


def state_bound(bound, what: str) -> tuple[float, float]:
    """(low, high) from a bound b > 0 (meaning |x| <= b) or a pair low < high (NaN refused)."""
    arr = real_array(bound, what)
    if arr.ndim == 0:
        b = float(arr)
        if not (np.isfinite(b) and b > 0):
            raise ValueError(f"{what} must be a finite bound > 0 or a pair (low, high), got {bound!r}")
        return -b, b
    if arr.shape != (2,) or np.any(np.isnan(arr)) or not arr[0] < arr[1]:
        raise ValueError(f"{what} must be a finite bound > 0 or a pair (low, high) with low < high, got {bound!r}")
    return float(arr[0]), float(arr[1])


def final_value(pair, what: str) -> tuple[float, float]:
    """(value, tolerance) with a finite value and a finite tolerance > 0."""
    arr = real_array(pair, what)
    if arr.shape != (2,) or not np.all(np.isfinite(arr)) or arr[1] <= 0:
        raise ValueError(f"{what} must be a pair (value, tolerance > 0) of finite numbers, got {pair!r}")
    return float(arr[0]), float(arr[1])


@dataclass(frozen=True)
class Cost:
    """A closed-loop cost: a criterion of one signal plus quadratic terms, summed over k = 0..N-1.

        J = Ts Σ_k w(t_k) ρ(s_k) + energy_weight Ts Σ_k |u_k|²
            + Ts Σ_k [(x_k − x*)ᵀ Q (x_k − x*) + (u_k − u*)ᵀ R (u_k − u*) + (y_k − y*)ᵀ Q_y (y_k − y*)]
            + (x_N − x*)ᵀ P (x_N − x*)

    kind : "itae" (w = t, ρ = |s|), "iae" (ρ = |s|), "ise" (ρ = s²), or None for no criterion term
    signal : what the criterion measures: "error" (reference − tracked coordinate), or the
        name of a state, output or input (measured from its target)
    energy_weight : weight (>= 0) on Σ u² Ts
    smoothing, resolution : |s| is evaluated as sqrt(s² + δ²), δ = max(smoothing, resolution × S),
        so the criterion is differentiable with a curvature a quasi-Newton method can follow;
        `smoothing` in units of the signal (> 0), `resolution` relative (>= 0) to the signal's
        scale S (its size at the start, or the reference's largest change for "error"; 0 where
        both are zero). The criterion exceeds the exact Σ w|s| Ts by at most δ Σ w Ts (ITAE:
        δ T² / 2). Measured on the saturating 2 m pendulum step: with δ = 1e-6 m IPOPT stalls on
        the sign changes of the settled error (each a kink of curvature 1/δ) without meeting its
        tolerance; with resolution 1e-4 (δ = 0.2 mm) it converges in about 100 iterations.
    state_weights, output_weights, input_weights, terminal_weights : Q, Q_y, R and P: a
        symmetric positive semidefinite matrix, a vector of its diagonal, or a dict
        name -> weight (diagonal, the others zero); None for no term
    target : x*, a dict state name -> value or a full state vector; default the plant's
        standard equilibrium with the tracked coordinate at the final reference (when the
        scenario has one); y* = h(x*)
    input_target : u*, a dict input name -> value or a vector; default zero
    """

    kind: str | None = "itae"
    energy_weight: float = 0.0
    smoothing: float = 1e-6
    resolution: float = 1e-4
    signal: str = "error"
    state_weights: object = None
    input_weights: object = None
    output_weights: object = None
    terminal_weights: object = None
    target: object = None
    input_target: object = None

    def __post_init__(self):
        if self.kind is not None and self.kind not in COSTS:
            raise ValueError(f"unknown cost {self.kind!r}; choose one of {', '.join(COSTS)} or None")
        weight = real(self.energy_weight, "energy_weight", finite=False)
        if not np.isfinite(weight) or weight < 0:
            raise ValueError(f"energy_weight must be finite and >= 0, got {self.energy_weight}")
        positive(self.smoothing, "smoothing")
        resolution = real(self.resolution, "resolution", finite=False)
        if not np.isfinite(resolution) or resolution < 0:
            raise ValueError(f"resolution must be finite and >= 0, got {self.resolution}")
        if not isinstance(self.signal, str):
            raise TypeError(f"signal must be 'error' or a state, output or input name, got {self.signal!r}")
        terms = (self.kind, self.state_weights, self.input_weights, self.output_weights, self.terminal_weights)
        if all(term is None for term in terms) and weight == 0:
            raise ValueError("the cost has no term: give kind, energy_weight or a weight matrix")


def _named_vector(value, names: Sequence[str], default: np.ndarray, what: str) -> np.ndarray:
    if value is None:
        return np.array(default, dtype=float)
    if isinstance(value, Mapping):
        out = np.array(default, dtype=float)
        for k, v in value.items():
            if k not in names:
                raise ValueError(f"{what}: no signal named {k!r}; the names are {', '.join(names)}")
            out[list(names).index(k)] = real(v, f"{what}[{k!r}]")
        return out
    return as_vector(value, len(names), what)


@dataclass(frozen=True)
class Scenario:
    """One closed-loop run of a tuning problem.

    reference : constant, callable t -> r, or array (N+1, n_reference): the block's reference
        (absolute tracked value); None for a regulation (the block's reference held at zero)
    duration : s
    x0 : initial plant state (nx,), default the plant's standard equilibrium
    input_disturbance : constant, callable or array (N, nu), added at the plant input
    tracked : state name of the coordinate that follows the reference (needed by the
        "error" signal and the step specs; keyword only)
    noise_std : standard deviation of Gaussian measurement noise, one number or one per
        measurement; parameter sample j draws it from the generator seeded (seed, j)
    seed : integer >= 0, the noise seed
    weight : > 0, the scenario's weight in the objective
    specs, cost : this scenario's own specs and cost (default: the problem's)
    name : label in violation messages
    """

    reference: object
    duration: float
    x0: np.ndarray | None = None
    input_disturbance: object = 0.0
    tracked: str | None = field(default=None, kw_only=True)
    noise_std: object = field(default=0.0, kw_only=True)
    seed: int = field(default=0, kw_only=True)
    weight: float = field(default=1.0, kw_only=True)
    specs: Specs | None = field(default=None, kw_only=True)
    cost: Cost | None = field(default=None, kw_only=True)
    name: str = field(default="", kw_only=True)

    def __post_init__(self):
        positive(self.duration, "duration (s)")
        positive(self.weight, "scenario weight")
        integer(self.seed, "seed", minimum=0)
        if self.tracked is not None and not isinstance(self.tracked, str):
            raise TypeError(f"tracked must be a state name, got {self.tracked!r}")
        if self.specs is not None and not isinstance(self.specs, Specs):
            raise TypeError(f"specs must be a designs.tuning.Specs, got {type(self.specs).__name__}")
        if self.cost is not None and not isinstance(self.cost, Cost):
            raise TypeError(f"cost must be a designs.tuning.Cost, got {type(self.cost).__name__}")
        if not isinstance(self.name, str):
            raise TypeError(f"name must be a string, got {self.name!r}")


@dataclass
class TuningResult:
    """What `tune` found.

    block : the block with the tuned gains (or the best feasible point found)
    cost, initial_cost : the objective on the exact (nonsmooth) closed loop
    improvement : 1 − cost / initial_cost
    feasible : every spec holds at `block`'s gains (exact loop)
    converged : the last IPOPT solve met its tolerance (`CONVERGED`) and, with smoothing,
        the exact and smoothed objectives agree to `AGREEMENT` at its answer
    success : converged, feasible, and the answer is IPOPT's (not a fallback)
    status : IPOPT's return status of the last solve
    message : one line saying what happened, including any fallback
    violations : the specs violated at the returned gains, by name
    phase_one : the `PhaseOne` run first when the start missed a spec (None otherwise)
    stages : one dict per solve: width (None for the exact loop), status, iterations,
        smoothed (the objective IPOPT saw) and exact objective at its answer
    smoothing_gap : |exact − smoothed| / |exact| at the last stage's answer (0 for "exact")
    history : [(seconds since the call began, the objective IPOPT saw)] per IPOPT iteration
        (smoothed at that stage's width)
    iterates : the decision vector of each `history` entry (evaluate the exact objective
        there with `TuningProblem.values`)
    """

    block: Block
    gains: dict
    initial_gains: dict
    cost: float
    initial_cost: float
    improvement: float
    feasible: bool
    success: bool
    status: str
    message: str
    violations: list = field(default_factory=list)
    iterations: int = 0
    wall_time: float = 0.0
    decision: np.ndarray | None = None
    history: list = field(default_factory=list)
    converged: bool = False
    stages: list = field(default_factory=list)
    smoothing_gap: float = 0.0
    method: str = "smooth"
    iterates: list = field(default_factory=list)
    phase_one: PhaseOne | None = None

    @property
    def stopped_on_test(self) -> bool:
        """Converged, or the specs were proved locally infeasible (IPOPT's restoration converged, or the
        phase one converged outside them) and no point returned meets them: not a cap, and not a claim of
        infeasibility a feasible answer contradicts."""
        proved = self.status == INFEASIBLE or (self.phase_one is not None and self.phase_one.infeasible)
        return self.converged or (proved and not self.feasible)


class _Log:
    """The iterates of one `solve` call: (x, f, perf_counter) each, reported to `progress` as they come."""

    def __init__(self, progress=None, started=None):
        self.progress = progress
        self.started = time.perf_counter() if started is None else started
        self.iterates: list[tuple[np.ndarray, float, float]] = []

    def add(self, x: np.ndarray, value: float) -> None:
        self.iterates.append((x, value, time.perf_counter()))
        if self.progress is not None:
            self.progress(len(self.iterates) - 1, value, self.iterates[-1][2] - self.started)


class _Recorder(ca.Callback):
    """IPOPT iteration callback passing every iterate and the objective IPOPT saw there to `log`.

    A solver keeps its callback for life; a cached solver (`_cached`) serves one `solve` call after
    another, each pointing `log` at its own `_Log`.
    """

    def __init__(self, nx: int, ng: int, n_p: int):
        ca.Callback.__init__(self)
        self.log: _Log | None = None
        self.sizes = {"x": nx, "lam_x": nx, "g": ng, "lam_g": ng, "p": n_p, "lam_p": n_p, "f": 1}
        self.construct("recorder", {})

    def get_n_in(self):
        return ca.nlpsol_n_out()

    def get_n_out(self):
        return 1

    def get_name_in(self, i):
        return ca.nlpsol_out(i)

    def get_name_out(self, i):
        return "ret"

    def get_sparsity_in(self, i):
        return ca.Sparsity.dense(self.sizes[ca.nlpsol_out(i)], 1)

    def eval(self, arg):
        if self.log is not None:
            self.log.add(np.asarray(arg[0]).ravel().copy(), float(arg[1]))
        return [0]


def _frozen(value):
    """`value` (nested dicts, lists, scalars, callables) as a hashable key."""
    if isinstance(value, Mapping):
        return tuple(sorted((k, _frozen(v)) for k, v in value.items()))
    if isinstance(value, (list, tuple)):
        return tuple(_frozen(v) for v in value)
    return value


def _cached(problem: TuningProblem, key: tuple, make: Callable[[], Any]) -> Any:
    """`make()`, built once per problem and key: building an IPOPT solver with exact second derivatives
    (and generating its C code) takes minutes on a long horizon, and a nested co-design solves one
    problem once per outer evaluation."""
    key = _frozen(key)
    if key not in problem._solvers:
        problem._solvers[key] = make()
    return problem._solvers[key]


# ----------------------------------------------------------------- the problem
@dataclass
class _Run:
    """One scenario's numbers, ready to build: times, signals, specs and cost."""

    scenario: Scenario
    specs: Specs
    cost: Cost
    n: int
    t: np.ndarray
    x0: np.ndarray
    r: np.ndarray
    d: np.ndarray
    noise: list
    tracked_index: int | None
    step: float | None
    target: np.ndarray
    input_target: np.ndarray
    weights: dict
    label: str
    signal_size: float = 0.0


def _scenarios(value) -> tuple[Scenario, ...]:
    if isinstance(value, Scenario):
        return (value,)
    if isinstance(value, (str, bytes)) or not isinstance(value, Sequence):
        raise TypeError(f"scenarios must be a Scenario or a sequence of them, got {type(value).__name__}")
    found = tuple(value)
    if not found:
        raise ValueError("scenarios is empty: give at least one Scenario")
    bad = [type(s).__name__ for s in found if not isinstance(s, Scenario)]
    if bad:
        raise TypeError(f"scenarios must all be designs.tuning.Scenario, got {bad}")
    return found


class TuningProblem:
    """The closed-loop cost and spec constraints as CasADi expressions of the free gains.

    Parameters
    ----------
    plant : Plant, simulated with each row of `samples`
    block : Block, the starting design; its gains not in `free` stay fixed
    scenarios : Scenario or a sequence of them; the objective is the weighted sum of
        the scenarios' costs, per parameter sample
    specs : Specs for the scenarios that have none of their own (default none)
    cost : Cost for the scenarios that have none of their own (default ITAE of the error)
    samples : (M, n_params) actual parameter vectors, M >= 1, default the plant's own
    robust : "mean" or "worst" over the samples of the per-sample weighted total
    free : names of the gains to tune (default all)
    substeps : RK4 sub-steps per sample
    extra_params : names of plant parameters to decide together with the gains
        (co-design); they become decision variables after the gains
    paths : "pointwise" (one inequality per sample of each spec on each run) or
        "aggregated" (on the smoothed problem, one soft-maximum inequality per spec and
        run; see the module docstring); the exact problem is always pointwise
    """

    def __init__(
        self,
        plant: Plant,
        block: Block,
        scenarios,
        *,
        specs: Specs | None = None,
        cost: Cost | None = None,
        samples=None,
        robust: str = "mean",
        free=None,
        substeps: int = 10,
        extra_params=(),
        paths: str = "pointwise",
    ):
        if not isinstance(plant, Plant):
            raise TypeError(f"plant must be a models.Plant, got {type(plant).__name__}")
        if not isinstance(block, Block):
            raise TypeError(
                f"block must be a models.Block (a controller written in CasADi), got {type(block).__name__}"
            )
        if robust not in ROBUST:
            raise ValueError(f"robust must be 'mean' or 'worst', got {robust!r}")
        if paths not in PATHS:
            raise ValueError(f"paths must be 'pointwise' or 'aggregated', got {paths!r}")
        self.paths = paths
        self._arguments = dict(
            specs=specs, cost=cost, samples=samples, robust=robust, free=free, extra_params=extra_params, paths=paths
        )
        if specs is not None and not isinstance(specs, Specs):
            raise TypeError(f"specs must be a designs.tuning.Specs, got {type(specs).__name__}")
        if cost is not None and not isinstance(cost, Cost):
            raise TypeError(f"cost must be a designs.tuning.Cost, got {type(cost).__name__}")
        self.plant, self.block = plant, block
        self.scenarios = _scenarios(scenarios)
        self.scenario = self.scenarios[0]
        self.specs = specs or Specs()
        self.cost = cost or Cost()
        self.robust = robust
        self.substeps = integer(substeps, "substeps", minimum=1)
        if samples is None:
            self.samples = plant.param_vector()[None]
        else:
            self.samples = as_matrix(samples, plant.n_params, "samples")
            if self.samples.shape[0] == 0:
                raise ValueError("samples has no rows; give at least one parameter vector")
        for i, row in enumerate(self.samples):
            try:
                plant.param_vector(row)
            except (TypeError, ValueError) as err:
                raise ValueError(f"samples row {i}: {err}") from None
        if free is not None and (isinstance(free, str) or not isinstance(free, Sequence)):
            raise TypeError(f"free must be a sequence of gain names, got {free!r}")
        self.free = tuple(block.gain_names if free is None else free)
        unknown = [g for g in self.free if g not in block.gains]
        if unknown:
            raise ValueError(f"{block.name} has no gain {unknown}; gains are {', '.join(block.gain_names)}")
        if isinstance(extra_params, str) or not isinstance(extra_params, Sequence):
            raise TypeError(f"extra_params must be a sequence of parameter names, got {extra_params!r}")
        self.extra_params = tuple(extra_params)
        names = list(plant.params)
        bad = [n for n in self.extra_params if n not in names]
        if bad:
            raise ValueError(f"{plant.name} has no parameter {bad}; its parameters are {', '.join(names)}")
        if not self.free and not self.extra_params:
            raise ValueError("nothing to decide: free names no gain and there are no extra_params")
        self.runs = [self._prepare(s, i) for i, s in enumerate(self.scenarios)]
        self.free_index = self._free_index()
        self.n_gains = self.free_index.size
        self.decision = ca.MX.sym("decision", self.n_gains + len(self.extra_params))
        self.width = ca.MX.sym("width")
        costs, self.g, u_runs, self.lbg, self.ubg, self.constraint_names = self._build(smooth=False)
        self.scenario_costs = costs  # (S, M)
        self.costs = self._per_sample(costs)  # (M, 1) weighted totals
        self.objective = self.aggregate(self.costs)
        self.evaluate = ca.Function("tuning_problem", [self.decision], [self.costs, self.g, ca.horzcat(*u_runs), costs])
        self._smooth: tuple[ca.MX, ca.MX] | None = None
        #: (lbg, ubg, names) of the smoothed problem's constraints, set by `smoothed()`
        self.smooth_bounds: tuple[np.ndarray, np.ndarray, list[tuple[str, slice]]] | None = None
        self._solvers: dict[Any, Any] = {}  # built solvers and levels by options (see `_cached`)
        # Back-compatible single-scenario attributes.
        first = self.runs[0]
        self.x0, self.reference, self.n_steps = first.x0, first.r, first.n
        self.step = first.step if first.step is not None else 0.0
        self.tracked = first.scenario.tracked

    def without_specs(self) -> TuningProblem:
        """The same problem with no specs (built once): what `solve(relaxed=True)` solves first."""

        def make() -> TuningProblem:
            scenarios = tuple(replace(sc, specs=None if sc.specs is None else Specs()) for sc in self.scenarios)
            return TuningProblem(
                self.plant, self.block, scenarios, substeps=self.substeps, **(self._arguments | {"specs": None})
            )

        return _cached(self, ("without specs",), make)

    def with_substeps(self, substeps: int) -> TuningProblem:
        """The same problem integrated with `substeps` RK4 sub-steps per sample (built once per value)."""
        return _cached(
            self,
            ("substeps", substeps),
            lambda: TuningProblem(self.plant, self.block, self.scenarios, substeps=substeps, **self._arguments),
        )

    # ------------------------------------------------------------ building
    def _free_index(self) -> np.ndarray:
        idx: list[int] = []
        i = 0
        for name, g in self.block.gains.items():
            if name in self.free:
                idx.extend(range(i, i + g.size))
            i += g.size
        return np.array(idx, dtype=int)

    def _prepare(self, sc: Scenario, index: int) -> _Run:
        plant, block = self.plant, self.block
        label = sc.name or (f"scenario {index}" if len(self.scenarios) > 1 else "")
        specs = sc.specs if sc.specs is not None else self.specs
        cost = sc.cost if sc.cost is not None else self.cost
        ts = block.sample_period
        n = int(round(sc.duration / ts))
        if n < 1:
            raise ValueError(f"{label or 'scenario'}: duration {sc.duration} s is shorter than one sample ({ts} s)")
        t = ts * np.arange(n + 1)
        x0 = plant.equilibrium()[0] if sc.x0 is None else as_vector(sc.x0, plant.nx, f"{plant.name} initial state x0")
        if sc.reference is None:
            r = np.zeros((n + 1, block.n_reference))
        else:
            r = sample(sc.reference, t, block.n_reference, "reference")
        d = sample(sc.input_disturbance, t[:-1], plant.nu, "input disturbance")
        n_meas = block.n_measured
        std = real_array(sc.noise_std, "noise_std")
        if std.ndim > 1 or std.size not in (1, n_meas) or not np.all(np.isfinite(std)) or np.any(std < 0):
            raise ValueError(f"noise_std must be one number or {n_meas} numbers >= 0, got {sc.noise_std!r}")
        std = np.broadcast_to(std, (n_meas,))
        noise = [
            np.random.default_rng(np.random.SeedSequence([sc.seed, j])).standard_normal((n, n_meas)) * std
            if np.any(std)
            else np.zeros((n, n_meas))
            for j in range(self.samples.shape[0])
        ]
        k = None
        if sc.tracked is not None:
            if sc.tracked not in plant.state_names:
                raise ValueError(f"{plant.name} has no state {sc.tracked!r}; states are {plant.state_names}")
            k = plant.state_names.index(sc.tracked)
        step = None
        if sc.reference is not None and k is not None and n_meas and block.n_reference:
            constant = np.all(r[1:, 0] == r[-1, 0])
            if constant and r[-1, 0] != x0[k]:
                step = float(r[-1, 0] - x0[k])
        where = f" ({label})" if label else ""
        if specs.step_specs and step is None:
            reason = (
                "it regulates (reference None)"
                if sc.reference is None
                else "it names no tracked state"
                if k is None
                else "its reference is not constant"
                if not np.all(r[1:, 0] == r[-1, 0])
                else "its final reference equals the initial tracked value"
            )
            raise ValueError(f"{', '.join(specs.step_specs)} need a step, and the scenario{where} has none: {reason}")
        for name, when in (("settling_time", specs.settling_time), ("rise_time", specs.rise_time)):
            if when is not None and when > t[-1]:
                raise ValueError(
                    f"{name} = {when:g} s is after the end of the scenario{where} ({t[-1]:g} s): "
                    "the spec would constrain nothing"
                )
        for what, table in (("state_bounds", specs.state_bounds), ("final_values", specs.final_values)):
            for name in table:
                if name not in plant.state_names:
                    raise ValueError(f"{what}: {plant.name} has no state {name!r}; states are {plant.state_names}")
        if cost.kind is not None and cost.signal == "error" and (k is None or sc.reference is None):
            raise ValueError(
                f"the cost's signal 'error' needs a reference and a tracked state; the scenario"
                f"{where} has {'no reference' if sc.reference is None else 'no tracked state'} "
                "(give Cost(signal=...) a state, output or input name)"
            )
        signals = plant.state_names + plant.output_names + plant.input_names
        if cost.kind is not None and cost.signal != "error" and cost.signal not in signals:
            raise ValueError(
                f"the cost's signal {cost.signal!r} is not 'error' nor a state, output or input of "
                f"{plant.name} ({', '.join(signals)})"
            )
        weights = {}
        for key, names in (
            ("state_weights", plant.state_names),
            ("input_weights", plant.input_names),
            ("output_weights", plant.output_names),
            ("terminal_weights", plant.state_names),
        ):
            value = getattr(cost, key)
            if value is not None:
                weights[key] = weight_matrix(value, len(names), key, names=names)
        default_target = plant.equilibrium()[0].copy()
        if step is not None:
            default_target[k] = r[-1, 0]
        target = _named_vector(cost.target, plant.state_names, default_target, "target")
        input_target = _named_vector(cost.input_target, plant.input_names, np.zeros(plant.nu), "input_target")
        size = 0.0  # the criterion signal's scale (see Cost.resolution; inputs: unknown before the run)
        if cost.kind is not None:
            if cost.signal == "error":
                size = max(abs(r[0, 0] - x0[k]), float(np.max(np.abs(r[:, 0] - r[0, 0]))))
            elif cost.signal in plant.state_names:
                i = plant.state_names.index(cost.signal)
                size = abs(x0[i] - target[i])
            elif cost.signal in plant.output_names:
                i = plant.output_names.index(cost.signal)
                size = abs(plant.output(x0, self.samples[0])[i] - plant.output(target, self.samples[0])[i])
        return _Run(
            sc,
            specs,
            cost,
            n,
            t,
            x0,
            r,
            d,
            noise,
            k,
            step,
            target,
            input_target,
            weights,
            label,
            float(size),
        )

    def _params(self, j: int, param_index) -> ca.MX:
        p = ca.MX(ca.DM(self.samples[j]))
        for i, pi in enumerate(param_index):
            p[pi] = self.decision[self.n_gains + i]
        return p

    def _build(self, smooth: bool):
        """(scenario costs (S, M), constraints, commands, lbg, ubg, names) on the exact or smoothed loop."""
        plant, block = self.plant, self.block
        gains = ca.MX(ca.DM(block.gain_vector()))
        for j, i in enumerate(self.free_index):
            gains[int(i)] = self.decision[j]
        param_index = [list(plant.params).index(name) for name in self.extra_params]
        m = self.samples.shape[0]
        rows: list[ca.MX] = []
        constraints: list[ca.MX] = []
        lower: list[np.ndarray] = []
        upper: list[np.ndarray] = []
        u_runs: list[ca.MX] = []
        names: list[tuple[str, slice]] = []

        def add(name, expr, lo, hi):
            expr = ca.vec(expr)
            if smooth and self.paths == "aggregated":
                expr, lo, hi = _soft_max_excess(expr, lo, hi, self.width), -np.inf, 0.0
            start = sum(c.numel() for c in constraints)
            constraints.append(expr)
            lower.append(np.broadcast_to(lo, (expr.numel(),)))
            upper.append(np.broadcast_to(hi, (expr.numel(),)))
            names.append((name, slice(start, start + expr.numel())))

        for run_data in self.runs:
            sp, n, k = run_data.specs, run_data.n, run_data.tracked_index
            run = models.closed_loop_function(plant, block, n, self.substeps, smooth=smooth)
            extra = [self.width] if smooth else []
            row = []
            for j in range(m):
                p = self._params(j, param_index)
                y0 = plant.output(run_data.x0, self.samples[j]) if block.measures == "outputs" else run_data.x0
                xc0 = block.initial_state(y0 + run_data.noise[j][0], run_data.r[0])
                X, _, U, _ = run(
                    run_data.x0, xc0, run_data.r[:-1].T, run_data.noise[j].T, run_data.d.T, p, gains, *extra
                )
                states = ca.horzcat(ca.DM(run_data.x0), X)  # x_0 .. x_N
                row.append(self._cost(run_data, states, U, p, self.width if smooth else None))
                tags = [t for t in (run_data.label, f"sample {j}" if m > 1 else "") if t]
                tag = f" ({', '.join(tags)})" if tags else ""
                if run_data.step is not None:
                    assert k is not None, "a step scenario has a tracked state (checked in _prepare)"
                    y = X[k, :]
                    r_final, amp, sign = run_data.r[-1, 0], abs(run_data.step), np.sign(run_data.step)
                    t1 = run_data.t[1:]
                    if sp.max_overshoot is not None:
                        add(
                            f"overshoot <= {100 * sp.max_overshoot:g} %{tag}",
                            sign * (y - r_final),
                            -np.inf,
                            sp.max_overshoot * amp,
                        )
                    if sp.settling_time is not None:
                        late = np.flatnonzero(t1 >= sp.settling_time)
                        add(
                            f"within {100 * sp.settling_band:g} % after {sp.settling_time:g} s{tag}",
                            y[:, late] - r_final,
                            -sp.settling_band * amp,
                            sp.settling_band * amp,
                        )
                    if sp.rise_time is not None:
                        late = np.flatnonzero(t1 >= sp.rise_time)
                        add(
                            f"90 % of the step by {sp.rise_time:g} s{tag}",
                            sign * (y[:, late] - run_data.x0[k]),
                            0.9 * amp,
                            np.inf,
                        )
                for name, bound in sp.state_bounds.items():
                    lo, hi = state_bound(bound, name)
                    text = f"|{name}| <= {hi:g}" if lo == -hi else f"{lo:g} <= {name} <= {hi:g}"
                    add(f"{text}{tag}", X[plant.state_names.index(name), :], lo, hi)
                for name, pair in sp.final_values.items():
                    value, tol = final_value(pair, name)
                    add(
                        f"{name}(t_N) = {value:g} ± {tol:g}{tag}",
                        X[plant.state_names.index(name), -1],
                        value - tol,
                        value + tol,
                    )
                u_runs.append(U)
            rows.append(ca.horzcat(*row))
        g = ca.vertcat(*constraints) if constraints else ca.MX(0, 1)
        lbg = np.concatenate(lower) if lower else np.zeros(0)
        ubg = np.concatenate(upper) if upper else np.zeros(0)
        return ca.vertcat(*rows), g, u_runs, lbg, ubg, names

    def _cost(self, run: _Run, states: ca.MX, U: ca.MX, p, width=None) -> ca.MX:
        """The scenario's cost of one run: states (nx, N+1), commands U (nu, N)."""
        plant, cost, n = self.plant, run.cost, run.n
        ts = self.block.sample_period
        X = states[:, :n]
        total = ca.MX(0)
        outputs: list[ca.MX] = []

        def output_rows():
            if not outputs:
                outputs.append(_outputs(plant, X, p))
            return outputs[0]

        if cost.kind is not None:
            if cost.signal == "error":
                k = run.tracked_index
                assert k is not None, "the 'error' signal needs a tracked state (checked in _prepare)"
                s = ca.DM(run.r[:-1, 0]).T - X[k, :]
            elif cost.signal in plant.state_names:
                i = plant.state_names.index(cost.signal)
                s = X[i, :] - run.target[i]
            elif cost.signal in plant.output_names:
                i = plant.output_names.index(cost.signal)
                s = output_rows()[i, :] - float(plant.output(run.target, self.samples[0])[i])
            else:
                i = plant.input_names.index(cost.signal)
                s = U[i, :] - run.input_target[i]
            if cost.kind == "ise":
                per_sample = s**2
            else:
                floor = max(cost.smoothing, cost.resolution * run.signal_size)
                per_sample = ca.sqrt(s**2 + floor**2)
                if cost.kind == "itae":
                    per_sample = ca.DM(run.t[:-1]).T * per_sample
            total += ts * ca.sum2(per_sample)
        if cost.energy_weight:
            total += cost.energy_weight * ts * ca.sum2(ca.sum1(U**2))
        w = run.weights
        if "state_weights" in w:
            dx = X - run.target
            total += ts * ca.sum2(ca.sum1(dx * ca.mtimes(ca.DM(w["state_weights"]), dx)))
        if "input_weights" in w:
            du = U - run.input_target
            total += ts * ca.sum2(ca.sum1(du * ca.mtimes(ca.DM(w["input_weights"]), du)))
        if "output_weights" in w:
            dy = output_rows() - plant.output(run.target, self.samples[0])
            total += ts * ca.sum2(ca.sum1(dy * ca.mtimes(ca.DM(w["output_weights"]), dy)))
        if "terminal_weights" in w:
            dn = states[:, n] - run.target
            total += ca.dot(dn, ca.mtimes(ca.DM(w["terminal_weights"]), dn))
        return total

    def _per_sample(self, costs: ca.MX) -> ca.MX:
        weights = ca.DM([run.scenario.weight for run in self.runs])
        return ca.mtimes(costs.T, weights)

    def aggregate(self, per_sample):
        """The objective from per-sample totals: their mean or their largest."""
        if self.robust == "mean":
            return ca.sum1(per_sample) / self.samples.shape[0]
        return ca.mmax(per_sample)

    def smoothed(self) -> tuple[ca.MX, ca.MX]:
        """(per-sample totals (M, 1), constraints) on the smoothed loop, functions of decision and `width`."""
        if self._smooth is None:
            costs, g, _, lbg, ubg, names = self._build(smooth=True)
            assert [n for n, _ in names] == [n for n, _ in self.constraint_names]
            self._smooth = (self._per_sample(costs), g)
            self.smooth_bounds = (lbg, ubg, names)
        return self._smooth

    # ------------------------------------------------------------ numbers
    def start(self) -> np.ndarray:
        """The decision vector of the starting design (and the plant's parameter values)."""
        extra = [self.plant.params[n] for n in self.extra_params]
        return np.concatenate([self.block.gain_vector()[self.free_index], extra])

    def values(self, decision) -> tuple[float, np.ndarray, list[str]]:
        """(objective, per-sample weighted totals (M,), violated spec names) at a decision vector, exact loop.

        The actuator limit is checked here rather than constrained in the NLP:
        blocks saturate their own command, so it never binds during the search.
        """
        costs, g, u, _ = (np.asarray(v) for v in self.evaluate(decision))
        costs = costs.ravel()
        obj = float(np.mean(costs)) if self.robust == "mean" else float(np.max(costs))
        violations = self.violated(g.ravel())
        limit = self.plant.input_limit[:, None]
        if not np.all(np.abs(u) <= limit):
            violations.append(
                f"|u| <= {', '.join(f'{v:g}' for v in self.plant.input_limit)} "
                f"(commanded up to {np.max(np.abs(u)):.4g})"
            )
        return obj, costs, violations

    def scenario_values(self, decision) -> np.ndarray:
        """Unweighted cost of each scenario on each sample, (S, M), exact loop."""
        return np.asarray(self.evaluate(decision)[3])

    def excess(self, g: np.ndarray, bounds=None) -> np.ndarray:
        """Each constraint's violation relative to 1 + |its bound| (<= 0 where it holds; inf if non-finite).
        bounds : (lbg, ubg) of `g` when it is not the exact problem's (the smoothed problem's)"""
        lbg, ubg = (self.lbg, self.ubg) if bounds is None else bounds
        scale = _bound_scale(lbg, ubg)
        with np.errstate(invalid="ignore"):
            out = np.maximum(lbg - g, g - ubg) / scale
        return np.where(np.isfinite(g), out, np.inf)

    def violated(self, g: np.ndarray, tol: float = 1e-6) -> list[str]:
        """The violated specs, each with its largest relative excess."""
        excess = self.excess(g)
        return [
            f"{name} (violated by {np.max(excess[sl]):.3g} relative)"
            for name, sl in self.constraint_names
            if np.any(excess[sl] > tol)
        ]

    def violated_names(self, g: np.ndarray, tol: float = 1e-6, smoothed: bool = False) -> list[str]:
        """The names of the violated specs; smoothed: `g` is the smoothed problem's constraints."""
        if smoothed:
            self.smoothed()
            assert self.smooth_bounds is not None, "set by smoothed()"
            lbg, ubg, names = self.smooth_bounds
            excess = self.excess(g, (lbg, ubg))
        else:
            names, excess = self.constraint_names, self.excess(g)
        return [name for name, sl in names if np.any(excess[sl] > tol)]

    def block_at(self, decision) -> Block:
        gains = self.block.gain_vector().copy()
        gains[self.free_index] = np.asarray(decision)[: self.n_gains]
        return self.block.with_gains(**self.block.gains_from_vector(gains))


def _outputs(plant: Plant, X: ca.MX, p) -> ca.MX:
    """Plant outputs of each column of X (nx, N) with parameters p: (ny, N)."""
    x, q = ca.MX.sym("x", plant.nx), ca.MX.sym("p", plant.n_params)
    h = ca.Function("outputs", [x, q], [plant.casadi_h(x, q)])
    return h.map(X.shape[1])(X, p)


def _bound_scale(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """What a constraint's violation is measured relative to: 1 + max(|lo|, |hi|) when both bounds are
    finite, else 1."""
    scale = 1 + np.maximum(np.abs(lo), np.abs(hi))
    return np.where(np.isfinite(scale), scale, 1.0)


def _relative_excess(g: ca.MX, lbg: np.ndarray, ubg: np.ndarray) -> ca.MX:
    """Each finite bound's excess relative to its scale (as `TuningProblem.excess`), <= 0 where it holds."""
    scale = _bound_scale(lbg, ubg)
    up, low = np.flatnonzero(np.isfinite(ubg)), np.flatnonzero(np.isfinite(lbg))
    parts = [(g[up.tolist()] - ca.DM(ubg[up])) / ca.DM(scale[up])] if up.size else []
    if low.size:
        parts.append((ca.DM(lbg[low]) - g[low.tolist()]) / ca.DM(scale[low]))
    return ca.vertcat(*parts) if parts else ca.MX(0, 1)


def _soft_max_excess(expr: ca.MX, lo, hi, width: ca.MX) -> ca.MX:
    """One smooth inequality (<= 0) for ``lo <= expr <= hi`` elementwise: the soft maximum of the
    relative excesses v (as in `TuningProblem.excess`), m + τ log(mean exp((v - m)/τ)), m = max v,
    τ = width / max(log n, 1): between max v - width and max v, exact as the width goes to 0."""
    n = expr.numel()
    lo, hi = np.broadcast_to(lo, (n,)).astype(float), np.broadcast_to(hi, (n,)).astype(float)
    scale = _bound_scale(lo, hi)
    sides = []
    upper, lower = np.flatnonzero(np.isfinite(hi)), np.flatnonzero(np.isfinite(lo))
    if upper.size:
        sides.append((expr[upper.tolist()] - hi[upper]) / scale[upper])
    if lower.size:
        sides.append((lo[lower] - expr[lower.tolist()]) / scale[lower])
    if not sides:
        return ca.MX(-1.0)  # no finite bound: always holds
    v = ca.vertcat(*sides)
    tau = width / max(np.log(v.numel()), 1.0)
    m = ca.mmax(v)  # shift for the exponentials; its derivative cancels exactly
    return m + tau * ca.log(ca.sum1(ca.exp((v - m) / tau)) / v.numel())


# ----------------------------------------------------------------- solving
def _check_options(max_iter, tol, hessian, jit, progress, method, widths):
    max_iter = integer(max_iter, "max_iter", minimum=1)
    tol = positive(tol, "tol")
    if hessian not in HESSIANS:
        raise ValueError(f"hessian must be 'limited-memory' or 'exact', got {hessian!r}")
    jit = boolean(jit, "jit")
    if progress is not None and not callable(progress):
        raise TypeError(f"progress must be callable(iteration, objective, seconds) or None, got {progress!r}")
    if method not in METHODS:
        raise ValueError(f"method must be 'smooth' or 'exact', got {method!r}")
    return max_iter, tol, jit, check_widths(widths)


def check_widths(widths) -> tuple[float, ...]:
    """The continuation's widths as a tuple; ValueError unless a non-empty, strictly decreasing
    sequence of finite numbers > 0."""
    values = real_array(widths, "widths")
    if (
        values.ndim != 1
        or values.size == 0
        or not np.all(np.isfinite(values))
        or np.any(values <= 0)
        or np.any(np.diff(values) >= 0)
    ):
        raise ValueError(
            f"widths must be a non-empty, strictly decreasing sequence of numbers > 0, got {values.tolist()}"
        )
    return tuple(float(w) for w in values)


def tune(
    plant: Plant,
    block: Block,
    scenarios,
    *,
    specs: Specs | None = None,
    cost: Cost | None = None,
    samples=None,
    robust: str = "mean",
    free=None,
    bounds=None,
    substeps: int = 10,
    max_iter: int = MAX_ITER,
    tol: float = TOL,
    hessian: str = "limited-memory",
    jit: bool = False,
    progress=None,
    method: str = "smooth",
    widths=WIDTHS,
    ipopt_options=None,
    paths: str = "pointwise",
    phase: bool = False,
    until_feasible: bool = False,
    coarse_substeps: int | None = COARSE_SUBSTEPS,
    relaxed: bool = False,
) -> TuningResult:
    """Tune `block`'s gains on the nonlinear closed loop with IPOPT, from its current gains.

    Parameters
    ----------
    plant, block, scenarios, specs, cost, samples, robust, free, substeps, paths
        As in `TuningProblem`.
    bounds : dict gain name -> (low, high), optional box bounds on the free gains
        (scalars or arrays shaped like the gain; ±inf for none)
    max_iter : IPOPT iterations per solve, >= 1: a cap that is reported when hit
        (`converged` False), never the intended stop
    tol : IPOPT's convergence tolerance (it also stops at 100 tol held for 10 iterations)
    hessian : "limited-memory" (L-BFGS, one gradient per iteration) or "exact"
        (CasADi's second derivatives; fewer iterations, each costlier)
    jit : compile the NLP's functions to machine code (pays off for long runs)
    progress : optional callable(iteration, objective, seconds) after each IPOPT iteration
    method : "smooth" (continuation over `widths`, see the module docstring) or "exact"
        (one solve on the exact loop)
    widths : the continuation's relative smoothing widths, strictly decreasing
    phase : run a phase one first when the start misses a spec (see `solve`); off by default: on
        the README's two-scenario, four-sample PID tuning it ran for over 28 minutes
    until_feasible : with `phase`, a feasibility verdict rather than a tuning (see `solve`)
    relaxed : solve without the specs first and keep that answer if it meets them (see `solve`)
    coarse_substeps : RK4 sub-steps per sample of a coarser problem whose continuation runs first and
        starts this one's (`COARSE_SUBSTEPS`; skipped where it disagrees at the start, see
        `COARSE_AGREEMENT`); None: none
    ipopt_options : dict of further IPOPT options (for example ``{"print_level": 5}``); they
        override `IPOPT_OPTIONS` and the ones set from the arguments above

    Returns
    -------
    TuningResult
        When IPOPT fails or the closed loop diverges on the way, the best
        feasible iterate (or the start, if it is feasible and better) is
        returned and `message` says so; an infeasible spec set is reported
        with the violated specs named.
    """
    max_iter, tol, jit, widths = _check_options(max_iter, tol, hessian, jit, progress, method, widths)
    problem = TuningProblem(
        plant,
        block,
        scenarios,
        specs=specs,
        cost=cost,
        samples=samples,
        robust=robust,
        free=free,
        substeps=substeps,
        paths=paths,
    )
    lbx, ubx = gain_bounds(problem, bounds)
    return solve(
        problem,
        lbx,
        ubx,
        max_iter,
        jit,
        tol=tol,
        hessian=hessian,
        progress=progress,
        method=method,
        widths=widths,
        ipopt_options=ipopt_options,
        phase=phase,
        until_feasible=until_feasible,
        coarse_substeps=coarse_substeps,
        relaxed=relaxed,
    )


def gain_bounds(problem: TuningProblem, bounds) -> tuple[np.ndarray, np.ndarray]:
    """(lower, upper) decision bounds from {gain name: (low, high)} (unbounded where not given).

    Raises ValueError naming the gain when a bound is NaN, has the wrong shape or has low > high.
    """
    n = problem.decision.numel()
    lbx, ubx = np.full(n, -np.inf), np.full(n, np.inf)
    if bounds is None:
        return lbx, ubx
    if not isinstance(bounds, Mapping):
        raise TypeError(f"bounds must be a dict gain name -> (low, high), got {bounds!r}")
    offsets, i = {}, 0
    for name, g in problem.block.gains.items():
        if name in problem.free:
            offsets[name] = (i, g)
            i += g.size
    for name, pair in bounds.items():
        if name not in offsets:
            raise ValueError(f"bounds given for {name!r}, which is not a free gain ({', '.join(problem.free)})")
        if isinstance(pair, (str, bytes)) or not isinstance(pair, Sequence) or len(pair) != 2:
            raise ValueError(f"bounds[{name!r}] must be a pair (low, high), got {pair!r}")
        start, g = offsets[name]
        try:
            lo = np.broadcast_to(real_array(pair[0], f"bounds[{name!r}] low"), g.shape).ravel(order="F")
            hi = np.broadcast_to(real_array(pair[1], f"bounds[{name!r}] high"), g.shape).ravel(order="F")
        except ValueError:
            raise ValueError(
                f"bounds[{name!r}] must be numbers or arrays shaped like the gain {g.shape}, got {pair!r}"
            ) from None
        if np.any(np.isnan(lo)) or np.any(np.isnan(hi)):
            raise ValueError(f"bounds[{name!r}] must not be NaN, got {pair!r}")
        if np.any(lo > hi):
            raise ValueError(f"bounds[{name!r}] has low > high: {pair!r}")
        lbx[start : start + g.size], ubx[start : start + g.size] = lo, hi
    return lbx, ubx


def _status_converged(status: str) -> bool:
    return status in CONVERGED


#: Phase one stops improving once every spec holds with this relative margin (its lower bound on s).
PHASE_ONE_MARGIN = 1e-3


@dataclass
class PhaseOne:
    """What `phase_one` found.

    decision : the decision vector it ended at (n_decision,)
    excess : the largest relative excess of the exact specs there (<= 0: every spec holds)
    status : IPOPT's return status of its last solve;  converged : that status is in `CONVERGED`
    iterations : IPOPT iterations over its stages
    """

    decision: np.ndarray
    excess: float
    status: str
    converged: bool
    iterations: int

    @property
    def infeasible(self) -> bool:
        """Converged with the specs still missed: a local certificate that no decision near it meets them."""
        return self.converged and self.excess > AGREEMENT


def _largest_excess(problem: TuningProblem, decision) -> float:
    """The largest relative excess of the exact specs at a decision (<= 0: all hold; -inf: no specs)."""
    return float(np.max(problem.excess(np.asarray(problem.evaluate(decision)[1]).ravel()), initial=-np.inf))


def _decision_scale(start: np.ndarray) -> np.ndarray:
    """IPOPT works on z = x / scale, each decision scaled by its own start, so gains of different
    magnitudes (a crane cascade's 0.2 outer and 8000 inner) all move on the order of one; a zero
    start takes 1e-3 of the largest."""
    magnitude = np.abs(start)
    floor = 1e-3 * np.max(magnitude) if np.any(magnitude > 0) else 1.0
    return np.where(magnitude > 0, magnitude, floor)


def phase_one(
    problem: TuningProblem,
    lbx,
    ubx,
    start,
    *,
    method: str = "smooth",
    widths=WIDTHS,
    tol: float = TOL,
    max_iter: int = MAX_ITER,
    jit: bool = False,
) -> PhaseOne:
    """Gains meeting the specs, or a converged local certificate that none near `start` do.

    minimize s over (decision, s >= -`PHASE_ONE_MARGIN`) subject to every spec's relative
    excess (as `TuningProblem.excess` measures it) <= s, on the smoothed loop through the
    continuation's widths, each stage from the last one's answer; it stops at the first
    stage whose answer meets the exact specs. The problem is feasible for every decision
    (s large), so IPOPT has no restoration phase to fail in and stops on its convergence
    test (a local minimum of the largest excess), where the tuning problem itself, started
    outside its specs, can end in Restoration_Failed.
    """
    max_iter, tol, jit, widths = _check_options(max_iter, tol, "limited-memory", jit, None, method, widths)
    lbx, ubx = np.asarray(lbx, dtype=float), np.asarray(ubx, dtype=float)
    start = np.clip(as_vector(start, problem.decision.numel(), "start"), lbx, ubx)
    smooth = method == "smooth"
    if smooth:
        g = problem.smoothed()[1]
        assert problem.smooth_bounds is not None, "set by smoothed()"
        lbg, ubg, _ = problem.smooth_bounds
    else:
        g, lbg, ubg = problem.g, problem.lbg, problem.ubg
    width = problem.width if smooth else ca.MX.sym("unused", 0)
    excess = _relative_excess(g, lbg, ubg)
    scale = _decision_scale(start)
    n = start.size
    z, s, scaling = ca.MX.sym("z", n), ca.MX.sym("s"), ca.MX.sym("scale", n)  # a parameter, as in `solve`
    excess_of = ca.Function("excess", [problem.decision, width], [excess])
    rows = excess_of(scaling * z, width) - s
    ipopt = IPOPT_OPTIONS | {"max_iter": int(max_iter), "tol": tol, "acceptable_tol": 100 * tol}
    options: dict[str, Any] = {"ipopt": ipopt, "print_time": False, "error_on_fail": False}
    nlp: dict[str, Any] = {"x": ca.vertcat(z, s), "p": ca.vertcat(width, scaling), "f": s, "g": rows}
    solver = _cached(
        problem,
        ("phase one", smooth, jit, options),
        lambda: (
            models.compile.jit_nlpsols("ipopt", nlp, {"phase_one": options})["phase_one"]
            if jit
            else ca.nlpsol("phase_one", "ipopt", nlp, options)
        ),
    )

    decision, worst = start, np.inf  # widths is never empty: the loop sets both
    status, iterations = "not solved", 0
    z_now = start / scale
    for w in widths if smooth else (None,):
        for _ in range(2):
            # A numerical failure is retried once from where it stopped, as the tuning's stages are.
            s0 = float(ca.mmax(excess_of(scale * z_now, [] if w is None else w)))
            sol = solver(
                x0=np.concatenate([z_now, [max(s0, 0.0)]]),
                lbx=np.concatenate([lbx / scale, [-PHASE_ONE_MARGIN]]),
                ubx=np.concatenate([ubx / scale, [np.inf]]),
                lbg=-np.inf,
                ubg=0.0,
                p=np.concatenate([[] if w is None else [w], scale]),
            )
            stats = solver.stats()
            status, iterations = stats["return_status"], iterations + int(stats.get("iter_count", 0))
            z_now = np.asarray(sol["x"]).ravel()[:n]
            if status not in RETRIED:
                break
        decision = np.clip(scale * z_now, lbx, ubx)
        worst = _largest_excess(problem, decision)
        if worst <= 0 or not _status_converged(status):
            break
    return PhaseOne(decision, worst, status, _status_converged(status), iterations)


def _feasible_answer(problem: TuningProblem, start, found: PhaseOne | None, total, started, method) -> TuningResult:
    """`solve`'s answer with `until_feasible`: the start, or the phase one's answer, meeting the specs."""
    decision = start if found is None else np.asarray(found.decision)
    start_value = float(total(start))
    value = start_value if found is None else float(total(decision))
    block = problem.block_at(decision)
    where = "the start meets the specs" if found is None else (
        f"phase one (IPOPT: {found.status}, {found.iterations} iterations) met the specs"
    )  # fmt: skip
    return TuningResult(
        block=block,
        gains={k: v.copy() for k, v in block.gains.items()},
        initial_gains={k: v.copy() for k, v in problem.block.gains.items()},
        cost=value,
        initial_cost=start_value,
        improvement=1 - value / start_value if start_value else 0.0,
        feasible=True,
        success=True,
        status=found.status if found is not None else "not solved: the start meets the specs",
        message=f"{where}; stopped there (until_feasible: a verdict on the specs, the cost not tuned)",
        iterations=0 if found is None else found.iterations,
        wall_time=time.perf_counter() - started,
        decision=np.array(decision),
        converged=True,
        method=method,
        phase_one=found,
    )


def solve(
    problem: TuningProblem,
    lbx,
    ubx,
    max_iter: int = MAX_ITER,
    jit: bool = False,
    plant_cost=None,
    tol: float = TOL,
    hessian: str = "limited-memory",
    progress=None,
    method: str = "smooth",
    widths=WIDTHS,
    start=None,
    cost_weight: float = 1.0,
    ipopt_options=None,
    phase: bool = False,
    until_feasible: bool = False,
    coarse_substeps: int | None = COARSE_SUBSTEPS,
    relaxed: bool = False,
) -> TuningResult:
    """IPOPT on cost_weight × the problem's objective (+ plant_cost(decision)), smoothed by continuation.

    Parameters
    ----------
    problem : TuningProblem
    lbx, ubx : decision bounds (n_decision,)
    plant_cost : optional callable MX decision -> MX scalar added to the objective
    start : decision vector to start from (default `problem.start()`), clipped to the bounds
    cost_weight : >= 0, the closed-loop objective's weight (0: the plant cost alone, under the specs)
    ipopt_options : as in `tune`
    phase : (opt-in) when the start misses a spec, run `phase_one` first and tune from its answer; if it
        ends outside the specs, tune from its answer and from the start and keep the better
        (feasible first, then converged, then cost)
    until_feasible : with `phase`, stop at the first decision that meets the specs: the start itself
        (no solve) or the phase one's answer, returned as converged (the feasibility problem's test);
        when the phase one ends outside the specs, as `phase`. A verdict on the specs, not a tuned
        cost: what an outer search over the plant needs when only feasibility decides (`size_actuator`)
    coarse_substeps : RK4 sub-steps of a coarser level solved first (see `COARSE_SUBSTEPS`), None for none
    relaxed : (opt-in) on a problem with specs, first solve it without them from `start`; a converged answer
        that meets every spec on the exact loop is returned: a local minimum over the bounds alone that
        meets the specs is a local minimum under them too. Otherwise the problem is solved as usual. For
        specs inactive at the answer: on the satellite's panel-stiffness problem IPOPT wandered for
        thousands of iterations with its two aggregated specs (both 1 % or more inside their bounds),
        and converged in 15 without them
    max_iter, jit, tol, hessian, progress, method, widths : as in `tune`
    """
    max_iter, tol, jit, widths = _check_options(max_iter, tol, hessian, jit, progress, method, widths)
    phase = boolean(phase, "phase")
    until_feasible = boolean(until_feasible, "until_feasible")
    if coarse_substeps is not None:
        coarse_substeps = integer(coarse_substeps, "coarse_substeps", minimum=1)
    relaxed = boolean(relaxed, "relaxed")
    if until_feasible and not phase:
        raise ValueError("until_feasible needs phase=True: the verdict comes from the phase one")
    if ipopt_options is not None and not isinstance(ipopt_options, Mapping):
        raise TypeError(f"ipopt_options must be a dict of IPOPT options, got {ipopt_options!r}")
    start_time = time.perf_counter()
    x = problem.decision
    n = x.numel()
    lbx, ubx = np.asarray(lbx, dtype=float), np.asarray(ubx, dtype=float)
    start = np.clip(problem.start() if start is None else as_vector(start, n, "start"), lbx, ubx)
    cost_weight = real(cost_weight, "cost_weight")
    if cost_weight < 0:
        raise ValueError(f"cost_weight must be >= 0, got {cost_weight}")
    extra_cost = ca.MX(0) if plant_cost is None else plant_cost(x)
    exact_total = ca.Function("total", [x], [cost_weight * problem.objective + extra_cost])
    smooth = method == "smooth"
    # What a further solve from another start (of this problem, or of it without its specs) passes on.
    again = dict(
        max_iter=max_iter, jit=jit, plant_cost=plant_cost, tol=tol, hessian=hessian, progress=progress,
        method=method, widths=widths, cost_weight=cost_weight, ipopt_options=ipopt_options,
        coarse_substeps=coarse_substeps,
    )  # fmt: skip

    def violated(decision) -> list[str]:
        """The specs a decision misses on the exact loop, the spectral bound included."""
        return problem.values(decision)[2] + _spectral_violation(problem, decision)

    prefix = ""
    if relaxed and not until_feasible and problem.g.numel():
        free = solve(problem.without_specs(), lbx, ubx, start=start, **again)
        assert free.decision is not None, "solve always returns its decision vector"
        missed = violated(free.decision)
        if free.converged and np.isfinite(free.cost) and not missed:
            worst_excess = _largest_excess(problem, free.decision)
            return replace(
                free,
                wall_time=time.perf_counter() - start_time,
                message=f"solved without the specs: the answer meets them (largest relative excess "
                f"{worst_excess:.3g}), so it is a local minimum under them too; {free.message}",
            )
        prefix = (
            f"without the specs: {free.status}, {'converged' if free.converged else 'not converged'}"
            f"{', missing ' + '; '.join(missed) if missed else ''}; then with them: "
        )
    # Started outside the specs: a phase one first (see `phase_one`), and the tuning from its answer.
    found, begin = None, start
    if phase and _largest_excess(problem, start) > AGREEMENT:
        found = phase_one(problem, lbx, ubx, start, method=method, widths=widths, tol=tol, max_iter=max_iter, jit=jit)
    if until_feasible and (found is None or found.excess <= AGREEMENT):
        return _feasible_answer(problem, start, found, exact_total, start_time, method)
    if found is not None:
        if found.excess > AGREEMENT:
            # A local verdict only: IPOPT's own restoration from the start may still find the specs (the arm's
            # sizing from its holding limit did, where the phase one stopped 0.77 outside), or not where the
            # phase one's answer leads it on (the UUV's). Both starts; the better answer is kept.
            tries = [solve(problem, lbx, ubx, start=point, phase=False, **again) for point in (found.decision, start)]
            best = max(tries, key=lambda r: (r.feasible, r.converged, -r.cost if np.isfinite(r.cost) else -np.inf))
            initial = tries[1].initial_cost
            return replace(
                best,
                phase_one=found,
                initial_cost=initial,
                initial_gains=tries[1].initial_gains,
                improvement=1 - best.cost / initial if initial else 0.0,
                iterations=sum(r.iterations for r in tries),
                wall_time=time.perf_counter() - start_time,
                message=f"{prefix}started outside the specs; phase one (IPOPT: {found.status}, {found.iterations} "
                f"iterations) ended {found.excess:.3g} relative outside them; tuned from its answer and from "
                f"the start, kept the one from {'its answer' if best is tries[0] else 'the start'}: {best.message}",
            )
        begin = found.decision
    scale = _decision_scale(begin)
    worst = problem.robust == "worst"
    m = problem.samples.shape[0]
    width = problem.width if smooth else ca.MX.sym("unused", 0)
    # The levels of fidelity: a coarser integration first where it agrees with the problem's at the start,
    # on problems without specs (see `COARSE_SUBSTEPS`).
    levels = [problem]
    if smooth and coarse_substeps is not None and coarse_substeps < problem.substeps and not problem.g.numel():
        lower = problem.with_substeps(coarse_substeps)
        fine_value, coarse_value = problem.values(begin)[0], lower.values(begin)[0]
        if abs(coarse_value - fine_value) <= COARSE_AGREEMENT * abs(fine_value):
            levels.insert(0, lower)
    if worst:
        totals = ca.Function("c", [x, width], [problem.smoothed()[0] if smooth else problem.costs])
        tau0 = float(ca.mmax(totals(begin, widths[0] if smooth else [])))
        start_z = np.concatenate([begin, [tau0]])
        scale = np.concatenate([scale, [max(abs(tau0), 1e-12)]])
        lbz, ubz = np.concatenate([lbx, [-np.inf]]), np.concatenate([ubx, [np.inf]])
    else:
        start_z, lbz, ubz = begin, lbx, ubx
    log = _Log(progress, start_time)
    ipopt: dict[str, Any] = (
        IPOPT_OPTIONS
        | (AGGREGATED_IPOPT_OPTIONS if smooth and problem.paths == "aggregated" else {})
        | {"max_iter": int(max_iter), "tol": tol, "acceptable_tol": 100 * tol, "hessian_approximation": hessian}
        | dict(ipopt_options or {})
    )
    opts: dict[str, Any] = {"ipopt": ipopt, "print_time": False, "error_on_fail": False}
    continuation = smooth and len(widths) > 1
    # Solvers by (warm, loose). Later stages start at the last answer and its multipliers, with the
    # barrier already small; the continuation's intermediate stages are solved loosely.
    variants = {(False, False): ("tuning", ipopt)}
    loose: dict[str, float] = {}
    if continuation:
        loose = {"tol": STAGE_TOL_FACTOR * ipopt["tol"], "acceptable_tol": STAGE_TOL_FACTOR * ipopt["acceptable_tol"]}
        for warm, tight, name in (
            (False, False, "tuning_loose"),
            (True, True, "tuning_warm"),
            (True, False, "tuning_warm_loose"),
        ):
            variants[warm, not tight] = (name, ipopt | (WARM_START if warm else {}) | ({} if tight else loose))
    elif len(levels) > 1:  # one width: the problem's own level starts warm from the coarse level's answer
        variants[True, False] = ("tuning_warm", ipopt | WARM_START)
    options = {name: dict(opts, ipopt=settings) for name, settings in variants.values()}

    def build(level: TuningProblem) -> dict[str, Any]:
        """The level's solvers by (warm, loose), its bounds on g, and its total, smoothed total and smoothed g."""
        xl = level.decision
        per_sample, g = level.smoothed() if smooth else (level.costs, level.g)
        if smooth:
            assert level.smooth_bounds is not None, "set by smoothed()"
            lbg, ubg, _ = level.smooth_bounds
        else:
            lbg, ubg = level.lbg, level.ubg
        extra = ca.MX(0) if plant_cost is None else plant_cost(xl)
        if worst:
            # Epigraph: minimize τ subject to every sample's total <= τ (max is not smooth).
            tau = ca.MX.sym("tau")
            variables, objective = ca.vertcat(xl, tau), cost_weight * tau + extra
            g = ca.vertcat(g, per_sample - tau)
            lbg, ubg = np.concatenate([lbg, np.full(m, -np.inf)]), np.concatenate([ubg, np.zeros(m)])
        else:
            variables, objective = xl, cost_weight * level.aggregate(per_sample) + extra

        def make() -> tuple[_Recorder, dict[str, Any]]:
            f_of = ca.Function("objective", [variables, level.width], [objective])
            g_of = ca.Function("constraints", [variables, level.width], [g])
            z, scaling = ca.MX.sym("z", start_z.size), ca.MX.sym("scale", start_z.size)
            decision = scaling * z
            nlp = {"x": z, "p": ca.vertcat(width, scaling), "f": f_of(decision, width), "g": g_of(decision, width)}
            recorder = _Recorder(start_z.size, g.numel(), width.numel() + start_z.size)
            with_recorder = {name: o | {"iteration_callback": recorder} for name, o in options.items()}
            # Compiled once without a shell and cached (models.compile); CasADi's virtual machine when impossible.
            if jit:
                return recorder, models.compile.jit_nlpsols("ipopt", nlp, with_recorder)
            return recorder, {name: ca.nlpsol(name, "ipopt", nlp, o) for name, o in with_recorder.items()}

        # The scale is a parameter of the NLP, not a constant in it, so the problem solved again from another
        # start (each evaluation of a nested co-design) reuses the solvers built here.
        recorder, built = _cached(level, ("tuning", smooth, worst, cost_weight, plant_cost, jit, options), make)
        recorder.log = log
        total = cost_weight * level.aggregate(per_sample) + extra
        spec_rows = level.smoothed()[1] if smooth else level.g
        return {
            "problem": level,
            "solvers": {key: built[name] for key, (name, _) in variants.items()},
            "lbg": lbg,
            "ubg": ubg,
            "exact_total": ca.Function("total", [xl], [cost_weight * level.objective + extra]),
            "smoothed_total": ca.Function("smoothed_total", [xl, level.width], [total]),
            "smoothed_g": ca.Function("smoothed_constraints", [xl, level.width], [spec_rows]),
        }

    z_now = start_z / scale
    multipliers: dict[str, ca.DM] = {}

    def run_stage(level: dict, w, tight: bool, warm: bool) -> tuple[str, int]:
        """One IPOPT solve at width w from z_now (warm: with its multipliers, barrier small); (status, iterations)."""
        nonlocal z_now, multipliers
        done, status = 0, "not solved"
        for attempt in range(2):
            # A numerical failure (not an iteration cap) is retried once from its last point, cold, to the
            # stage's own tolerance: a fresh quasi-Newton memory often gets past it. A verdict of local
            # infeasibility that one of the solve's own iterates contradicts (it meets the specs on the
            # exact loop) is retried once from the last such iterate, cold.
            warm_now = warm and attempt == 0
            mark = len(log.iterates)
            this = level["solvers"][warm_now, not tight]
            sol = this(
                x0=z_now,
                lbx=lbz / scale,
                ubx=ubz / scale,
                lbg=level["lbg"],
                ubg=level["ubg"],
                p=np.concatenate([[] if w is None else [w], scale]),
                **(multipliers if warm_now else {}),
            )
            stats = this.stats()
            status = stats["return_status"]
            done += int(stats.get("iter_count", 0))
            z_now = np.asarray(sol["x"]).ravel()
            multipliers = {"lam_x0": sol["lam_x"], "lam_g0": sol["lam_g"]}
            if status == INFEASIBLE and attempt == 0:
                at = level["problem"]
                met = (
                    zz
                    for zz, _, _ in reversed(log.iterates[mark:])
                    if not at.values(np.clip(scale[:n] * zz[:n], lbx, ubx))[2]
                )
                witness = next(met, None)
                if witness is None:
                    break
                z_now = witness
                continue
            if status not in RETRIED:
                break
        return status, done

    def judge_stage(level: dict, w) -> tuple[float, float, float, bool]:
        """At z_now: (exact objective, smoothed objective, their relative gap, same specs violated)."""
        decision = np.clip(scale[:n] * z_now[:n], lbx, ubx)
        exact = float(level["exact_total"](decision))
        seen = float(level["smoothed_total"](decision, [] if w is None else w))
        gap = abs(exact - seen) / max(abs(exact), 1e-300) if np.isfinite(exact) and np.isfinite(seen) else np.inf
        same = True
        at = level["problem"]
        if smooth and at.g.numel():
            g_exact = np.asarray(at.evaluate(decision)[1]).ravel()
            g_smooth = np.asarray(level["smoothed_g"](decision, [] if w is None else w)).ravel()
            same = at.violated_names(g_exact) == at.violated_names(g_smooth, smoothed=True)
        return exact, seen, gap, same

    stages: list[dict[str, Any]] = []
    iterations = 0
    status, gap, settled = "not solved", 0.0, not continuation
    first = 0  # the width a level starts at: where the coarser one settled
    for number, at in enumerate(levels):
        level, last = build(at), number == len(levels) - 1
        own: list[dict[str, Any]] = []
        for w in widths[first:] if smooth else (None,):
            # Intermediate stages only start the next one: solved to STAGE_TOL_FACTOR x tol; the stage
            # that ends the continuation is then finished at tol from where it stopped (a coarser
            # level's never: it only gives the next level its start).
            tight, warm = not continuation, bool(multipliers)
            status, stage_iterations = run_stage(level, w, tight, warm)
            while True:
                exact, seen, gap, same = judge_stage(level, w)
                # Settled: the exact objective no longer moved from the previous stage's answer, or gap
                # exactly 0: every switch at the answer lies outside its band, so near it the smoothed
                # problem is the exact one and IPOPT's convergence on it is convergence on the exact problem.
                moved = abs(own[-1]["exact"] - exact) if own and np.isfinite(exact) else np.inf
                settled = not continuation or gap == 0.0 or moved <= AGREEMENT * abs(exact)
                ends = gap <= AGREEMENT and same and settled
                if (
                    tight
                    or not last
                    or not (np.isfinite(exact) and _status_converged(status))
                    or not (ends or w == widths[-1])
                ):
                    break
                # This stage ends the continuation: finished at tol from where it stopped, started as the
                # stage was. A cold stage's loose answer is centred for a large barrier; warm from it
                # (barrier 1e-6), a case's simultaneous sizing crept for 1141 iterations (3000 with one
                # BLAS thread), cold: 112.
                tight = True
                status, more = run_stage(level, w, tight, warm)
                stage_iterations += more
            iterations += stage_iterations
            own.append(
                {
                    "width": w,
                    "substeps": at.substeps,
                    "status": status,
                    "tol": ipopt["tol"] if tight else loose["tol"],
                    "iterations": stage_iterations,
                    "smoothed": seen,
                    "exact": exact,
                    "gap": gap,
                }
            )
            if not np.isfinite(exact):
                break  # no closed-loop run to go on from: reported, not hidden
            if not _status_converged(status):
                if status == CAPPED and w != widths[-1] and not (len(own) > 1 and own[-2]["status"] == CAPPED):
                    # An intermediate stage only gives the next one its start: one stopped at its cap hands
                    # its last point on, cold (the verdict rests on the last stage alone, which must
                    # converge); two capped stages in a row end the continuation.
                    multipliers = {}
                    continue
                break  # a numerical failure ends the continuation: reported, not hidden
            if ends:
                break
        stages += own
        if not last:
            if not (np.isfinite(exact) and _status_converged(status)):
                z_now, multipliers = start_z / scale, {}  # the coarse level failed: the next starts afresh
            else:
                first = widths.index(own[-1]["width"])
    converged = _status_converged(status) and gap <= AGREEMENT and settled
    final = np.clip(scale[:n] * z_now[:n], lbx, ubx)  # IPOPT relaxes bounds by ~1e-8

    def judge(decision):
        return float(exact_total(decision)), violated(decision)

    initial_cost, _ = judge(start)
    message = f"IPOPT: {status}"
    if found is not None:
        message = (
            f"started outside the specs; phase one (IPOPT: {found.status}, {found.iterations} iterations) "
            f"met them; {message}"
        )
    message = prefix + message  # in the order the solves ran
    if smooth:
        message += (
            f"; smoothing continuation in {len(stages)} stage{'s' if len(stages) > 1 else ''} down to "
            f"width {stages[-1]['width']:g}, exact and smoothed objectives agree to {gap:.1e}"
        )
        if gap > AGREEMENT:
            message += f" (not within {AGREEMENT:g})"
        if not settled:
            message += "; the exact objective still changed at the last width"
    chosen = None
    value, violations = judge(final)
    if np.isfinite(value):
        chosen = (value, violations, final, "final")
    # Other iterates matter only when clearly better than IPOPT's answer, or when
    # that answer is infeasible: judge them lazily, lowest objective IPOPT saw first.
    threshold = value - 1e-6 * abs(value) if chosen and not violations else np.inf
    others = sorted(
        ((f, scale[:n] * zz[:n], "iterate") for zz, f, _ in log.iterates if np.isfinite(f) and f < threshold),
        key=lambda item: item[0],
    )
    others.append((initial_cost, start, "start"))
    if found is not None and found.excess <= AGREEMENT:
        others.append((float(exact_total(found.decision)), found.decision, "phase one's answer"))
    for _, cand, label in others:
        cand = np.clip(cand, lbx, ubx)
        cand_value, cand_violations = judge(cand)
        if np.isfinite(cand_value) and not cand_violations and cand_value < threshold:
            chosen = (cand_value, cand_violations, cand, label)
            break
    if chosen is None:
        chosen = (np.inf, ["no finite closed-loop run"], start, "start")
        message += "; no iterate gave a finite closed-loop run"
    elif chosen[1]:
        message += "; infeasible: " + "; ".join(chosen[1])
    elif chosen[3] != "final":
        message += f"; returning the best feasible point found (the {chosen[3]})"
    value, violations, decision, label = chosen
    block = problem.block_at(decision)
    return TuningResult(
        block=block,
        gains={k: v.copy() for k, v in block.gains.items()},
        initial_gains={k: v.copy() for k, v in problem.block.gains.items()},
        cost=float(value),
        initial_cost=initial_cost,
        improvement=1 - float(value) / initial_cost if initial_cost else 0.0,
        feasible=not violations,
        success=converged and label == "final" and not violations,
        status=status,
        message=message,
        violations=list(violations),
        iterations=iterations,
        wall_time=time.perf_counter() - start_time,
        decision=np.array(decision),
        history=[(stamp - start_time, f) for _, f, stamp in log.iterates],
        iterates=[np.clip(scale[:n] * zz[:n], lbx, ubx) for zz, _, _ in log.iterates],
        converged=converged,
        stages=stages,
        smoothing_gap=float(gap),
        method=method,
        phase_one=found,
    )


def closed_loop_spectral_abscissa(plant: Plant, block: Block, x, xc, r, params=None, substeps: int = 10) -> float:
    """Slowest mode of the sampled closed loop linearized at (x, xc, r), in 1/s.

    log(spectral radius of ∂(x⁺, x_c⁺)/∂(x, x_c)) / Ts: negative when the loop is
    locally stable; a saturated input makes the loop open there.
    """
    s = ca.SX.sym("s", plant.nx + block.n_state)
    p = plant.param_vector(params)
    xs, xcs = s[: plant.nx], s[plant.nx :]
    y = plant.casadi_h(xs, p) if block.measures == "outputs" else xs
    xc_next, u = block.casadi_step(xcs, y, np.atleast_1d(r), block.gain_vector())
    u = ca.fmin(ca.fmax(u, -plant.input_limit), plant.input_limit)
    x_next = plant.step_function(block.sample_period, substeps)(xs, u, p)
    jac = ca.Function("closed_loop_jacobian", [s], [ca.jacobian(ca.vertcat(x_next, xc_next), s)])
    eig = np.linalg.eigvals(np.asarray(jac(np.concatenate([x, xc]))))
    return float(np.log(np.max(np.abs(eig))) / block.sample_period)


def _spectral_violation(problem: TuningProblem, decision) -> list[str]:
    found = []
    block = None
    for run in problem.runs:
        bound = run.specs.max_spectral_abscissa
        if bound is None:
            continue
        block = block or problem.block_at(decision)
        sc = run.scenario
        where = f" ({run.label})" if run.label else ""
        res = models.simulate_closed_loop(
            problem.plant,
            block,
            run.r,
            sc.duration,
            x0=run.x0,
            params=problem.samples[0],
            input_disturbance=run.d,
            substeps=problem.substeps,
            allow_divergence=True,
        )
        if res.diverged_at is not None:
            found.append(
                f"spectral abscissa <= {bound:g} 1/s{where} (the closed loop diverged at t = {res.diverged_at:.3g} s)"
            )
            continue
        assert res.xc is not None, "a Block controller's states are recorded"
        alpha = closed_loop_spectral_abscissa(
            problem.plant, block, res.x[-1], res.xc[-1], res.r[-1], problem.samples[0], problem.substeps
        )
        if alpha > bound:
            found.append(f"spectral abscissa <= {bound:g} 1/s{where} (got {alpha:.3g} 1/s)")
    return found
