"""The tuning problem: the closed-loop cost and the spec constraints as CasADi expressions of the gains."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any, cast

import casadi as ca
import numpy as np

import models
from models import Block, Plant
from models.checks import as_matrix, as_vector, integer, real, real_array, weight_matrix
from models.metrics import FINAL_WINDOW, segments
from models.signals import sample

from .excess import Constraints, bound_scale
from .scenarios import Cost, Scenario, Specs, final_value, state_bound
from .settings import PATHS, ROBUST


@dataclass
class ScenarioRun:
    """One scenario's numbers, ready to build: times, signals, specs and cost.

    n : samples of the run;  t : (n+1,) s;  x0 : (nx,);  r : (n+1, n_reference);  d : (n, nu)
    noise : one (n, n_measured) array per parameter sample
    tracked_index : index of the tracked state (None without one)
    step : final reference − initial tracked value, when the reference is one constant step (else None)
    segments : the run's steps as `models.metrics.segments` splits them, (start index, end index
        (exclusive), level before, commanded level) over the samples 0..n, only those with a step: the step
        specs hold on each (a series of steps is judged by its worst step, as the tables judge it)
    target, input_target : x* (nx,) and u* (nu,) of the cost
    weights : the cost's weight matrices by name ("state_weights", ...), only those given
    label : the scenario's name in messages ("" for the only unnamed one)
    signal_size : the criterion signal's scale S (see `Cost.resolution`)
    """

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
    segments: tuple = ()


def _scenarios(value) -> tuple[Scenario, ...]:
    """One Scenario or a non-empty sequence of them, as a tuple (TypeError, ValueError otherwise)."""
    if isinstance(value, Scenario):
        return (value,)
    if isinstance(value, (str, bytes)) or not isinstance(value, Sequence):
        raise TypeError(f"scenarios must be a Scenario or a sequence of them, got {type(value).__name__}")
    found = tuple(value)
    if not found:
        raise ValueError("scenarios is empty: give at least one Scenario")
    bad = [type(s).__name__ for s in found if not isinstance(s, Scenario)]
    if bad:
        raise TypeError(f"scenarios must all be models.scenario.Scenario, got {bad}")
    for s in found:
        if s.cost is not None and not isinstance(s.cost, Cost):
            raise TypeError(f"cost must be a designs.tuning.Cost, got {type(s.cost).__name__}")
    return found


def _named_vector(value, names: Sequence[str], default: np.ndarray, what: str) -> np.ndarray:
    """A vector over `names` from None (the default), a dict name -> value (the default elsewhere) or a vector."""
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


def _frozen(value):
    """`value` (nested dicts, lists, scalars, callables) as a hashable key."""
    if isinstance(value, Mapping):
        return tuple(sorted((k, _frozen(v)) for k, v in value.items()))
    if isinstance(value, (list, tuple)):
        return tuple(_frozen(v) for v in value)
    return value


def _tagged(tag: str, more: str) -> str:
    """The tag " (scenario, sample 2)" with `more` added inside its parentheses (" (more)" when `tag` is empty)."""
    return f"{tag[:-1]}, {more})" if tag else f" ({more})"


def _late(t: np.ndarray, after: float, skip: int) -> np.ndarray:
    """Indices k >= skip of the samples with t_k > after, or the last one when none is (a segment shorter
    than the spec: the table then needs its last sample inside, or its time is inf)."""
    late = np.flatnonzero((t > after) & (np.arange(t.size) >= skip))
    return late if late.size else np.array([t.size - 1])


def _outputs(plant: Plant, X: ca.MX, p) -> ca.MX:
    """Plant outputs of each column of X (nx, N) with parameters p: (ny, N)."""
    x, q = ca.MX.sym("x", plant.nx), ca.MX.sym("p", plant.n_params)
    h = ca.Function("outputs", [x, q], [plant.casadi_h(x, q)])
    return h.map(X.shape[1])(X, p)


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
        run, `excess.soft_max_excess`); the exact problem is always pointwise

    Attributes
    ----------
    decision : MX (n_gains + len(extra_params),), the free gains (column-major) then the parameters
    width : MX scalar, the smoothing width of `smoothed()`
    costs : MX (M, 1), per-sample weighted totals;  objective : their mean or largest
    g, lbg, ubg : the exact loop's spec constraints and bounds;  constraint_names : [(name, rows)]
    evaluate : Function decision -> (costs (M, 1), g, commands (nu, Σ N), scenario costs (S, M))
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
            raise TypeError(f"specs must be a models.specs.Specs, got {type(specs).__name__}")
        if cost is not None and not isinstance(cost, Cost):
            raise TypeError(f"cost must be a designs.tuning.Cost, got {type(cost).__name__}")
        self.plant, self.block = plant, block
        self.scenarios = _scenarios(scenarios)
        self.scenario = self.scenarios[0]
        self.specs = specs or Specs()
        self.cost = cost or Cost()
        self.robust = robust
        self.substeps = integer(substeps, "substeps", minimum=1)
        self.samples = self._checked_samples(samples)
        self.free = self._checked_free(free)
        self.extra_params = self._checked_extra_params(extra_params)
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
        self._solvers: dict[Any, Any] = {}  # built solvers and levels by options (see `cached`)
        # The first scenario's numbers, for single-scenario callers.
        first = self.runs[0]
        self.x0, self.reference, self.n_steps = first.x0, first.r, first.n
        self.step = first.step if first.step is not None else 0.0
        self.tracked = first.scenario.tracked

    def _checked_samples(self, samples) -> np.ndarray:
        """(M, n_params) parameter rows, each one the plant accepts; the plant's own values by default."""
        plant = self.plant
        if samples is None:
            rows = plant.param_vector()[None]
        else:
            rows = as_matrix(samples, plant.n_params, "samples")
            if rows.shape[0] == 0:
                raise ValueError("samples has no rows; give at least one parameter vector")
        for i, row in enumerate(rows):
            try:
                plant.param_vector(row)
            except (TypeError, ValueError) as err:
                raise ValueError(f"samples row {i}: {err}") from None
        return rows

    def _checked_free(self, free) -> tuple[str, ...]:
        """The names of the gains to tune, each one of the block's (all of them by default)."""
        block = self.block
        if free is not None and (isinstance(free, str) or not isinstance(free, Sequence)):
            raise TypeError(f"free must be a sequence of gain names, got {free!r}")
        names = tuple(block.gain_names if free is None else free)
        unknown = [g for g in names if g not in block.gains]
        if unknown:
            raise ValueError(f"{block.name} has no gain {unknown}; gains are {', '.join(block.gain_names)}")
        return names

    def _checked_extra_params(self, extra_params) -> tuple[str, ...]:
        """The names of the plant parameters decided with the gains, each one of the plant's."""
        if isinstance(extra_params, str) or not isinstance(extra_params, Sequence):
            raise TypeError(f"extra_params must be a sequence of parameter names, got {extra_params!r}")
        names = list(self.plant.params)
        bad = [n for n in extra_params if n not in names]
        if bad:
            raise ValueError(f"{self.plant.name} has no parameter {bad}; its parameters are {', '.join(names)}")
        return tuple(extra_params)

    def cached(self, key: tuple, make: Callable[[], Any]) -> Any:
        """`make()`, built once per problem and key: building an IPOPT solver with exact second derivatives
        (and generating its C code) takes minutes on a long horizon, and a nested co-design solves one
        problem once per outer evaluation."""
        key = _frozen(key)
        if key not in self._solvers:
            self._solvers[key] = make()
        return self._solvers[key]

    def without_specs(self) -> TuningProblem:
        """The same problem with no specs (built once): what `solve` with `relaxed` solves first."""

        def make() -> TuningProblem:
            scenarios = tuple(replace(sc, specs=None if sc.specs is None else Specs()) for sc in self.scenarios)
            return TuningProblem(
                self.plant, self.block, scenarios, substeps=self.substeps, **(self._arguments | {"specs": None})
            )

        return self.cached(("without specs",), make)

    def with_substeps(self, substeps: int) -> TuningProblem:
        """The same problem integrated with `substeps` RK4 sub-steps per sample (built once per value)."""
        return self.cached(
            ("substeps", substeps),
            lambda: TuningProblem(self.plant, self.block, self.scenarios, substeps=substeps, **self._arguments),
        )

    # ------------------------------------------------------------ one scenario's numbers
    def _free_index(self) -> np.ndarray:
        """Indices of the free gains' entries in the block's gain vector (n_gains,)."""
        idx: list[int] = []
        i = 0
        for name, g in self.block.gains.items():
            if name in self.free:
                idx.extend(range(i, i + g.size))
            i += g.size
        return np.array(idx, dtype=int)

    def _prepare(self, sc: Scenario, index: int) -> ScenarioRun:
        """Scenario `index`'s numbers, its specs and cost checked against what the run can judge."""
        label = sc.name or (f"scenario {index}" if len(self.scenarios) > 1 else "")
        specs = sc.specs if sc.specs is not None else self.specs
        cost = sc.cost if sc.cost is not None else self.cost
        n, t, x0, r, d, noise = self._signals(sc, label)
        k = None
        if sc.tracked is not None:
            if sc.tracked not in self.plant.state_names:
                raise ValueError(f"{self.plant.name} has no state {sc.tracked!r}; states are {self.plant.state_names}")
            k = self.plant.state_names.index(sc.tracked)
        step, steps = None, cast(tuple, ())
        if sc.reference is not None and k is not None and self.block.n_measured and self.block.n_reference:
            constant = np.all(r[1:, 0] == r[-1, 0])
            if constant and r[-1, 0] != x0[k]:
                step = float(r[-1, 0] - x0[k])
            steps = tuple(
                (a, b, before, after)
                for a, b, before, after in segments(t, np.full(n + 1, x0[k]), r[:, 0])
                if after != before and b - a >= 2
            )
        where = f" ({label})" if label else ""
        self._check_specs(sc, specs, r, t, k, steps, where)
        self._check_cost(sc, cost, k, where)
        weights, target, input_target, size = self._cost_terms(cost, r, x0, k, step)
        return ScenarioRun(
            sc, specs, cost, n, t, x0, r, d, noise, k, step, target, input_target, weights, label, size, steps
        )

    def _signals(self, sc: Scenario, label: str) -> tuple:
        """(n, t, x0, r, d, noise) of a scenario: samples, times (n+1,) s, initial state (nx,), reference
        (n+1, n_reference), input disturbance (n, nu), and one (n, n_measured) noise draw per parameter sample."""
        plant, block = self.plant, self.block
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
        return n, t, x0, r, d, noise

    def _check_specs(self, sc: Scenario, specs: Specs, r, t, k, steps, where: str) -> None:
        """ValueError for a spec the run cannot judge: a step spec without a step, a time after the run's
        end, a bound or limit on a state the plant does not have, a limit whose bound is a decided parameter,
        and a frequency field (margins, bandwidth: measures of a linearized loop, not of the run, which
        these constraints do not impose)."""
        plant = self.plant
        if specs.frequency_specs:
            raise ValueError(
                f"{', '.join(specs.frequency_specs)}{where}: the tuning constrains the runs, not the linearized "
                "loop's margins or bandwidth; judge those on the tuned design (studies.judging.judge_run)"
            )
        if specs.step_specs and not steps:
            reason = (
                "it regulates (reference None)"
                if sc.reference is None
                else "it names no tracked state"
                if k is None
                else "its reference never changes from the initial tracked value"
            )
            raise ValueError(f"{', '.join(specs.step_specs)} need a step, and the scenario{where} has none: {reason}")
        for name, when in (
            ("max_settling_time_s", specs.max_settling_time_s),
            ("max_rise_time_s", specs.max_rise_time_s),
        ):
            # The table's rule (`models.specs.Specs.validate`): a time after the run's end is refused. A step
            # shorter than the time is judged: the table needs its last sample settled (else its time is inf).
            if when is not None and when > t[-1] - t[0]:
                raise ValueError(
                    f"{name} = {when:g} s is after the end of the scenario{where} ({t[-1]:g} s): "
                    "the spec would constrain nothing"
                )
        for what, table in (("state_bounds", specs.state_bounds), ("final_values", specs.final_values)):
            for name in table:
                if name not in plant.state_names:
                    raise ValueError(f"{what}: {plant.name} has no state {name!r}; states are {plant.state_names}")
        for limit in specs.state_limits:
            missing = [name for name in limit.states if name not in plant.state_names]
            if missing:
                raise ValueError(
                    f"state_limits {limit.name!r}: {plant.name} has no state {missing[0]!r}; states are "
                    f"{plant.state_names}"
                )
            if limit.upper_parameter is not None and limit.upper_parameter in self.extra_params:
                raise ValueError(
                    f"state_limits {limit.name!r}: its bound is the parameter {limit.upper_parameter!r}, which "
                    "this problem decides (extra_params): a limit that moves with the design is not supported"
                )

    def _check_cost(self, sc: Scenario, cost: Cost, k, where: str) -> None:
        """ValueError for a criterion signal the run does not have."""
        plant = self.plant
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

    def _cost_terms(self, cost: Cost, r, x0, k, step) -> tuple[dict, np.ndarray, np.ndarray, float]:
        """(weight matrices by name, x* (nx,), u* (nu,), the criterion signal's scale S) of a cost on a run."""
        plant = self.plant
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
        return weights, target, input_target, float(size)

    # ------------------------------------------------------------ building
    def _params(self, j: int, param_index) -> ca.MX:
        """Parameter sample j (n_params,), the designed parameters at `param_index` replaced by the decision's."""
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
        u_runs: list[ca.MX] = []
        constraints = Constraints(self.width if smooth and self.paths == "aggregated" else None)
        for run_data in self.runs:
            run = models.closed_loop_function(plant, block, run_data.n, self.substeps, smooth=smooth)
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
                self._add_specs(constraints, run_data, X, f" ({', '.join(tags)})" if tags else "", j)
                u_runs.append(U)
            rows.append(ca.horzcat(*row))
        g, lbg, ubg, names = constraints.stacked()
        return ca.vertcat(*rows), g, u_runs, lbg, ubg, names

    def _add_specs(self, constraints: Constraints, run: ScenarioRun, X: ca.MX, tag: str, sample: int) -> None:
        """The specs of one run on parameter sample `sample`, X (nx, N) its states x_1 .. x_N.

        Each `models.specs.Specs` field becomes inequalities on the samples that imply the table's
        verdict for the same run (`models.metrics.step_metrics`, at the same sample times). The step
        specs hold on every step of the run (`ScenarioRun.segments`, the table's worst step), y_0 the
        level before that step, r the commanded one, t_k counted from the step:

        - overshoot: sign·(y_k − r) <= max_overshoot_pct/100 · |step| at every sample: the table's
          largest excursion past the reference, exactly;
        - settling time: |y_k − r| <= band · |step| at every sample with t_k > T_s − Ts: then the
          last sample outside the band is at or before T_s − Ts, and the table's interpolated exit
          from the band is at or before T_s (sufficient; equal to within one sample; a step shorter
          than T_s: its last sample);
        - rise time: sign·(y_k − y_0) >= 0.9 |step| at every sample with t_k > T_r − Ts (the output
          has covered 90 % by T_r, at a sample, and stays): the table's 10-90 % rise time is then at
          most T_r minus its 10 % crossing (sufficient, conservative by that crossing's time);
        - steady-state error: |mean of y over the table's final window − r| <= max_ss_error_pct/100 ·
          |step|: the table's definition, exactly;
        - state bounds at every sample, and final values as the mean over the table's final window
          (`models.metrics.final_values`): exactly the table's;
        - physical limits (`Specs.state_limits`) at every sample, on the limited quantity (a state, or the
          difference of two), a bound read from a parameter taken from this sample's row: exactly the
          table's (`models.state_limits.check_state_limits` on the plant the run simulated).

        `input_limit` holds by construction (a block clips its command at the actuator limit);
        `limit_cycle` is not a constraint (`max_spectral_abscissa` is checked at the solution).
        """
        sp, k = run.specs, run.tracked_index
        ts = self.block.sample_period
        n_final = max(1, int(np.ceil(FINAL_WINDOW * len(run.t))))  # the table's final window of x_0 .. x_N
        window = slice(max(0, X.shape[1] - n_final), X.shape[1])
        if k is not None:
            states = ca.horzcat(ca.DM(run.x0), X)  # x_0 .. x_N, indexed as the table's samples
            for number, (a, b, before, after) in enumerate(run.segments):
                where = tag if len(run.segments) == 1 else _tagged(tag, f"step {number + 1}")
                y, t = states[k, a:b], run.t[a:b] - run.t[a]
                self._add_step_specs(constraints, sp, y, t, (before, after), ts, where, int(a == 0))
        names = self.plant.state_names
        for name, interval in sp.state_bounds.items():
            lo, hi = state_bound(interval, name)
            text = f"|{name}| <= {hi:g}" if lo == -hi else f"{lo:g} <= {name} <= {hi:g}"
            constraints.add(f"{text}{tag}", X[names.index(name), :], lo, hi)
        params = dict(zip(self.plant.params, self.samples[sample]))
        for limit in sp.state_limits:
            at = limit.at(params)
            limited = X[names.index(at.state), :]
            if at.relative_to is not None:
                limited = limited - X[names.index(at.relative_to), :]
            constraints.add(f"{at.describe()}{tag}", limited, at.lower, at.upper)
        for name, pair in sp.final_values.items():
            value, tol = final_value(pair, name)
            mean = ca.sum2(X[names.index(name), window]) / n_final
            constraints.add(f"final {name} = {value:g} ± {tol:g}{tag}", mean, value - tol, value + tol)

    @staticmethod
    def _add_step_specs(constraints: Constraints, sp: Specs, y: ca.MX, t: np.ndarray, levels, ts, tag, skip: int):
        """The step specs on one segment: y (1, L) the tracked samples from the step on, t (L,) their times
        after it (s), levels (the level before the step, the commanded one), Ts (s); the first `skip` samples
        (the run's given initial state, a constant) carry no constraint (see `_add_specs`)."""
        before, after = levels
        amp, sign = abs(after - before), np.sign(after - before)
        if sp.max_overshoot_pct is not None:
            constraints.add(
                f"overshoot <= {sp.max_overshoot_pct:g} %{tag}",
                sign * (y[:, skip:] - after),
                -np.inf,
                sp.max_overshoot_pct / 100 * amp,
            )
        if sp.max_settling_time_s is not None:
            late = _late(t, sp.max_settling_time_s - ts, skip)
            constraints.add(
                f"within {sp.settling_band_pct:g} % after {sp.max_settling_time_s:g} s{tag}",
                y[:, late] - after,
                -sp.settling_band * amp,
                sp.settling_band * amp,
            )
        if sp.max_rise_time_s is not None:
            late = _late(t, sp.max_rise_time_s - ts, skip)
            constraints.add(
                f"90 % of the step by {sp.max_rise_time_s:g} s{tag}", sign * (y[:, late] - before), 0.9 * amp, np.inf
            )
        if sp.max_ss_error_pct is not None:
            bound = sp.max_ss_error_pct / 100 * amp
            n_final = max(1, int(np.ceil(FINAL_WINDOW * len(t))))  # the table's window of the segment
            constraints.add(
                f"ss error <= {sp.max_ss_error_pct:g} %{tag}", ca.sum2(y[:, -n_final:]) / n_final - after, -bound, bound
            )

    def _cost(self, run: ScenarioRun, states: ca.MX, U: ca.MX, p, width=None) -> ca.MX:
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
        """Per-sample weighted totals (M, 1) from the scenario costs (S, M) and the scenarios' weights."""
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
        obj = self._robust(costs)
        violations = self.violated(g.ravel())
        limit = self.plant.input_limit[:, None]
        if not np.all(np.abs(u) <= limit):
            violations.append(
                f"|u| <= {', '.join(f'{v:g}' for v in self.plant.input_limit)} "
                f"(commanded up to {np.max(np.abs(u)):.4g})"
            )
        return obj, costs, violations

    def _robust(self, costs: np.ndarray) -> float:
        """The objective of the per-sample totals (M,): their mean or their worst, as `robust` says."""
        return float(np.mean(costs)) if self.robust == "mean" else float(np.max(costs))

    def merit(self, decision) -> tuple[float, float]:
        """(the objective, the exact specs' largest relative excess) at a decision: `values` and
        `largest_excess` from one evaluation of the exact loop."""
        costs, g, _, _ = (np.asarray(v) for v in self.evaluate(decision))
        return self._robust(costs.ravel()), float(np.max(self.excess(g.ravel()), initial=-np.inf))

    def scenario_values(self, decision) -> np.ndarray:
        """Unweighted cost of each scenario on each sample, (S, M), exact loop."""
        return np.asarray(self.evaluate(decision)[3])

    def excess(self, g: np.ndarray, bounds=None) -> np.ndarray:
        """Each constraint's violation relative to 1 + |its bound| (<= 0 where it holds; inf if non-finite).
        bounds : (lbg, ubg) of `g` when it is not the exact problem's (the smoothed problem's)"""
        lbg, ubg = (self.lbg, self.ubg) if bounds is None else bounds
        scale = bound_scale(lbg, ubg)
        with np.errstate(invalid="ignore"):
            out = np.maximum(lbg - g, g - ubg) / scale
        return np.where(np.isfinite(g), out, np.inf)

    def largest_excess(self, decision) -> float:
        """The largest relative excess of the exact specs at a decision (<= 0: all hold; -inf: no specs)."""
        return float(np.max(self.excess(np.asarray(self.evaluate(decision)[1]).ravel()), initial=-np.inf))

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
        """The block with the free gains of `decision` (its first `n_gains` entries)."""
        gains = self.block.gain_vector().copy()
        gains[self.free_index] = np.asarray(decision)[: self.n_gains]
        return self.block.with_gains(**self.block.gains_from_vector(gains))


def gain_bounds(problem: TuningProblem, bounds) -> tuple[np.ndarray, np.ndarray]:
    """(lower, upper) decision bounds (n_decision,) from {gain name: (low, high)} (unbounded where not given).

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
