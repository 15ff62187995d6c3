"""Gain tuning through the compiled nonlinear closed loop, with exact derivatives.

The decision variables are a block's gains; the cost is a time-domain
criterion of the nonlinear closed loop (`models.closed_loop_function`, one
CasADi mapaccum, so its gradient is exact); the constraints are time-domain
specs on every parameter sample. IPOPT solves it from the hand design.

    result = tune(plant, block, Scenario(reference=0.8, duration=5.0, tracked="theta"),
                  specs=Specs(max_overshoot=0.05, settling_time=2.0))
    result.block          # the tuned block; result.improvement, result.violations
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

import models
from models import Block, Plant
from models.checks import as_matrix, positive
from models.signals import sample

COSTS = ("itae", "iae", "ise")


@dataclass(frozen=True)
class Scenario:
    """The closed-loop run a tuning problem is judged on.

    reference : constant, callable t -> r, or array (N+1, 1): absolute tracked value
    duration : s
    x0 : initial plant state (nx,), default the plant's standard equilibrium
    input_disturbance : constant, callable or array (N, nu), added at the plant input
    tracked : state name of the coordinate that follows the reference (keyword only)
    """

    reference: object
    duration: float
    x0: np.ndarray | None = None
    input_disturbance: object = 0.0
    tracked: str = field(kw_only=True)


@dataclass(frozen=True)
class Specs:
    """Time-domain specs, enforced at every sample of every parameter sample.

    max_overshoot : fraction of the step the tracked output may pass the final reference
    settling_time : s after which |e| <= settling_band * |step|
    rise_time : s by which the output has covered 90 % of the step, and stays beyond
        (sufficient for a 10-90 % rise time below it)
    max_spectral_abscissa : 1/s, bound on the closed-loop linearization's slowest mode
        at the final state, log(spectral radius) / Ts; checked at the solution, not
        enforced during the search (eigenvalues are not smooth)
    state_bounds : dict state name -> bound, |x_i| <= bound at every sample (for example
        a crane's swing angle)
    """

    max_overshoot: float | None = None
    settling_time: float | None = None
    settling_band: float = 0.02
    rise_time: float | None = None
    max_spectral_abscissa: float | None = None
    state_bounds: dict = field(default_factory=dict)


@dataclass(frozen=True)
class Cost:
    """Σ_k w(t_k) ρ(e_k) Ts + energy_weight Σ_k u_k² Ts over k = 0..N-1.

    kind : "itae" (w = t, ρ = |e|), "iae" (|e|) or "ise" (e²)
    smoothing : |e| is evaluated as sqrt(e² + smoothing²) so the cost is differentiable;
        in units of the tracked coordinate
    """

    kind: str = "itae"
    energy_weight: float = 0.0
    smoothing: float = 1e-6

    def __post_init__(self):
        if self.kind not in COSTS:
            raise ValueError(f"unknown cost {self.kind!r}; choose one of {', '.join(COSTS)}")
        if not np.isfinite(self.energy_weight) or self.energy_weight < 0:
            raise ValueError(f"energy_weight must be finite and >= 0, got {self.energy_weight}")

    def __call__(self, t, e, u, sample_period):
        """The cost of error samples e (1, N) and commands u (nu, N) at times t (1, N)."""
        if self.kind == "ise":
            per_sample = e**2
        else:
            per_sample = ca.sqrt(e**2 + self.smoothing**2)
            if self.kind == "itae":
                per_sample = t * per_sample
        return sample_period * (ca.sum2(per_sample) + self.energy_weight * ca.sum2(ca.sum1(u**2)))


@dataclass
class TuningResult:
    """What `tune` found.

    block : the block with the tuned gains (or the best feasible point found)
    cost, initial_cost : the tuning cost (mean or worst over the samples)
    improvement : 1 − cost / initial_cost
    feasible : every spec holds at `block`'s gains
    success : IPOPT converged and the result is feasible
    status : IPOPT's return status
    message : one line saying what happened, including any fallback
    violations : the specs violated at the returned gains, by name
    history : [(seconds since the call began, IPOPT's objective)] per iteration
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


class _Recorder(ca.Callback):
    """IPOPT iteration callback keeping every iterate, for the best-feasible fallback."""

    def __init__(self, nx: int, ng: int, n_p: int, progress=None):
        ca.Callback.__init__(self)
        self.progress, self.started = progress, time.perf_counter()
        self.sizes = {"x": nx, "lam_x": nx, "g": ng, "lam_g": ng, "p": n_p, "lam_p": n_p, "f": 1}
        self.iterates: list[tuple[np.ndarray, float, float]] = []  # (x, f, perf_counter)
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
        self.iterates.append((np.asarray(arg[0]).ravel().copy(), float(arg[1]), time.perf_counter()))
        if self.progress is not None:
            self.progress(len(self.iterates) - 1, float(arg[1]), self.iterates[-1][2] - self.started)
        return [0]


class TuningProblem:
    """The closed-loop cost and spec constraints as CasADi expressions of the free gains.

    Parameters
    ----------
    plant : Plant, simulated with each row of `samples`
    block : Block, the starting design; its gains not in `free` stay fixed
    scenario : Scenario
    specs : Specs or None
    cost : Cost
    samples : (M, n_params) actual parameter vectors, default the plant's own
    robust : "mean" or "worst" over the samples
    free : names of the gains to tune (default all)
    substeps : RK4 sub-steps per sample
    extra_params : names of plant parameters to decide together with the gains
        (co-design); they become decision variables after the gains
    """

    def __init__(self, plant: Plant, block: Block, scenario: Scenario, *, specs: Specs | None = None,
                 cost: Cost | None = None, samples=None, robust: str = "mean", free=None,
                 substeps: int = 10, extra_params=()):
        if robust not in ("mean", "worst"):
            raise ValueError(f"robust must be 'mean' or 'worst', got {robust!r}")
        self.plant, self.block, self.scenario = plant, block, scenario
        self.specs = specs or Specs()
        self.cost = cost or Cost()
        self.robust = robust
        self.tracked = scenario.tracked
        if self.tracked not in plant.state_names:
            raise ValueError(f"{plant.name} has no state {self.tracked!r}; states are {plant.state_names}")
        self.samples = (plant.param_vector()[None] if samples is None
                        else as_matrix(samples, plant.n_params, "samples"))
        for row in self.samples:
            plant.param_vector(row)
        self.free = tuple(block.gain_names if free is None else free)
        unknown = [g for g in self.free if g not in block.gains]
        if unknown:
            raise ValueError(f"{block.name} has no gain {unknown}; gains are {', '.join(block.gain_names)}")
        self.extra_params = tuple(extra_params)
        names = list(plant.params)
        bad = [n for n in self.extra_params if n not in names]
        if bad:
            raise ValueError(f"{plant.name} has no parameter {bad}; its parameters are {', '.join(names)}")
        self._build(substeps)

    # ------------------------------------------------------------ building
    def _free_index(self) -> np.ndarray:
        idx, i = [], 0
        for name, g in self.block.gains.items():
            if name in self.free:
                idx.extend(range(i, i + g.size))
            i += g.size
        return np.array(idx, dtype=int)

    def _build(self, substeps: int) -> None:
        plant, block, sc = self.plant, self.block, self.scenario
        ts = block.sample_period
        n = int(round(positive(sc.duration, "duration (s)") / ts))
        self.n_steps = n
        t = ts * np.arange(n + 1)
        x0 = plant.equilibrium()[0] if sc.x0 is None else np.asarray(sc.x0, dtype=float)
        r = sample(sc.reference, t, block.n_reference, "reference")
        d = sample(sc.input_disturbance, t[:-1], plant.nu, "input disturbance")
        k = plant.state_names.index(self.tracked)
        self.step = float(r[-1, 0] - x0[k])
        if self.step == 0 and (self.specs.max_overshoot is not None or self.specs.rise_time is not None
                               or self.specs.settling_time is not None):
            raise ValueError("the specs need a step: the final reference equals the initial tracked value")
        g0 = block.gain_vector()
        self.free_index = self._free_index()
        self.n_gains = self.free_index.size
        decision = ca.MX.sym("decision", self.n_gains + len(self.extra_params))
        gains = ca.MX(ca.DM(g0))
        for j, i in enumerate(self.free_index):
            gains[int(i)] = decision[j]
        param_index = [list(plant.params).index(name) for name in self.extra_params]
        run = models.closed_loop_function(plant, block, n, substeps)
        m = self.samples.shape[0]
        costs, constraints, lower, upper, u_runs = [], [], [], [], []
        self.constraint_names: list[tuple[str, slice]] = []

        def add(name, expr, lo, hi):
            expr = ca.vec(expr)
            start = sum(c.numel() for c in constraints)
            constraints.append(expr)
            lower.append(np.broadcast_to(lo, (expr.numel(),)))
            upper.append(np.broadcast_to(hi, (expr.numel(),)))
            self.constraint_names.append((name, slice(start, start + expr.numel())))

        sp, amp, sign = self.specs, abs(self.step), np.sign(self.step) or 1.0
        r_final = r[-1, 0]
        self.x0, self.reference = x0, r
        for i in range(m):
            p = ca.MX(ca.DM(self.samples[i]))
            for j, pi in enumerate(param_index):
                p[pi] = decision[self.n_gains + j]
            y0 = plant.output(x0, self.samples[i]) if block.measures == "outputs" else x0
            xc0 = block.initial_state(y0, r[0])
            X, _, U, _ = run(x0, xc0, r[:-1].T, np.zeros((block.n_measured, n)), d.T, p, gains)
            y = X[k, :]  # tracked value after each sample, k = 1..N
            y_cost = ca.horzcat(x0[k], y[:, :n - 1])  # k = 0..N-1
            costs.append(self.cost(ca.DM(t[:-1]).T, ca.DM(r[:-1, 0]).T - y_cost, U, ts))
            tag = f" (sample {i})" if m > 1 else ""
            if sp.max_overshoot is not None:
                add(f"overshoot <= {100 * sp.max_overshoot:g} %{tag}", sign * (y - r_final), -np.inf,
                    sp.max_overshoot * amp)
            if sp.settling_time is not None:
                late = np.flatnonzero(t[1:] >= sp.settling_time)
                if late.size:
                    add(f"within {100 * sp.settling_band:g} % after {sp.settling_time:g} s{tag}",
                        y[:, late] - r_final, -sp.settling_band * amp, sp.settling_band * amp)
            if sp.rise_time is not None:
                late = np.flatnonzero(t[1:] >= sp.rise_time)
                if late.size:
                    add(f"90 % of the step by {sp.rise_time:g} s{tag}", sign * (y[:, late] - x0[k]),
                        0.9 * amp, np.inf)
            for name, bound in sp.state_bounds.items():
                if name not in plant.state_names:
                    raise ValueError(f"state_bounds: {plant.name} has no state {name!r}; states are "
                                     f"{plant.state_names}")
                add(f"|{name}| <= {bound:g}{tag}", X[plant.state_names.index(name), :], -bound, bound)
            u_runs.append(U)
        self.decision = decision
        self.costs = ca.vertcat(*costs)
        self.g = ca.vertcat(*constraints) if constraints else ca.MX(0, 1)
        self.lbg = np.concatenate(lower) if lower else np.zeros(0)
        self.ubg = np.concatenate(upper) if upper else np.zeros(0)
        self.evaluate = ca.Function("tuning_problem", [decision], [self.costs, self.g, ca.horzcat(*u_runs)])
        self.objective = (ca.sum1(self.costs) / m) if self.robust == "mean" else ca.mmax(self.costs)

    # ------------------------------------------------------------ numbers
    def start(self) -> np.ndarray:
        """The decision vector of the starting design (and the plant's parameter values)."""
        extra = [self.plant.params[n] for n in self.extra_params]
        return np.concatenate([self.block.gain_vector()[self.free_index], extra])

    def values(self, decision) -> tuple[float, np.ndarray, list[str]]:
        """(objective, per-sample costs, violated spec names) at a decision vector.

        The actuator limit is checked here rather than constrained in the NLP:
        blocks saturate their own command, so it never binds during the search.
        """
        costs, g, u = (np.asarray(v) for v in self.evaluate(decision))
        costs = costs.ravel()
        obj = float(np.mean(costs)) if self.robust == "mean" else float(np.max(costs))
        violations = self.violated(g.ravel())
        limit = self.plant.input_limit[:, None]
        if not np.all(np.abs(u) <= limit):
            violations.append(f"|u| <= {', '.join(f'{v:g}' for v in self.plant.input_limit)} "
                              f"(commanded up to {np.max(np.abs(u)):.4g})")
        return obj, costs, violations

    def violated(self, g: np.ndarray, tol: float = 1e-6) -> list[str]:
        names = []
        for name, sl in self.constraint_names:
            scale = 1 + np.maximum(np.abs(self.lbg[sl]), np.abs(self.ubg[sl]))
            scale = np.where(np.isfinite(scale), scale, 1.0)
            excess = np.maximum(self.lbg[sl] - g[sl], g[sl] - self.ubg[sl]) / scale
            if not np.all(np.isfinite(g[sl])) or np.any(excess > tol):
                worst = np.nanmax(excess) if np.all(np.isfinite(g[sl])) else np.inf
                names.append(f"{name} (violated by {worst:.3g} relative)")
        return names

    def block_at(self, decision) -> Block:
        gains = self.block.gain_vector().copy()
        gains[self.free_index] = np.asarray(decision)[:self.n_gains]
        return self.block.with_gains(**self.block.gains_from_vector(gains))


def tune(plant: Plant, block: Block, scenario: Scenario, *, specs: Specs | None = None,
         cost: Cost | None = None, samples=None, robust: str = "mean", free=None, bounds=None,
         substeps: int = 10, max_iter: int = 200, tol: float = 1e-8,
         hessian: str = "limited-memory", jit: bool = False, progress=None) -> TuningResult:
    """Tune `block`'s gains on the nonlinear closed loop with IPOPT, from its current gains.

    Parameters
    ----------
    plant, block, scenario, specs, cost, samples, robust, free, substeps
        As in `TuningProblem`.
    bounds : dict gain name -> (low, high), optional box bounds on the free gains
        (scalars or arrays shaped like the gain)
    max_iter : IPOPT iteration limit
    tol : IPOPT's convergence tolerance (it also stops at 100 tol held for 10 iterations)
    hessian : "limited-memory" (L-BFGS, one gradient per iteration) or "exact"
        (CasADi's second derivatives; fewer iterations, each costlier)
    jit : compile the NLP's functions to machine code (pays off for long runs)
    progress : optional callable(iteration, objective, seconds) after each IPOPT iteration

    Returns
    -------
    TuningResult
        When IPOPT fails or the closed loop diverges on the way, the best
        feasible iterate (or the start, if it is feasible and better) is
        returned and `message` says so; an infeasible spec set is reported
        with the violated specs named.
    """
    problem = TuningProblem(plant, block, scenario, specs=specs, cost=cost, samples=samples,
                            robust=robust, free=free, substeps=substeps)
    lbx, ubx = gain_bounds(problem, bounds)
    if hessian not in ("limited-memory", "exact"):
        raise ValueError(f"hessian must be 'limited-memory' or 'exact', got {hessian!r}")
    return solve(problem, lbx, ubx, max_iter, jit, tol=tol, hessian=hessian, progress=progress)


def gain_bounds(problem: TuningProblem, bounds) -> tuple[np.ndarray, np.ndarray]:
    """(lower, upper) decision bounds from {gain name: (low, high)} (unbounded where not given)."""
    n = problem.decision.numel()
    lbx, ubx = np.full(n, -np.inf), np.full(n, np.inf)
    if not bounds:
        return lbx, ubx
    offsets, i = {}, 0
    for name, g in problem.block.gains.items():
        if name in problem.free:
            offsets[name] = (i, g)
            i += g.size
    for name, (lo, hi) in bounds.items():
        if name not in offsets:
            raise ValueError(f"bounds given for {name!r}, which is not a free gain ({', '.join(problem.free)})")
        start, g = offsets[name]
        lbx[start:start + g.size] = np.broadcast_to(lo, g.shape).ravel(order="F")
        ubx[start:start + g.size] = np.broadcast_to(hi, g.shape).ravel(order="F")
    return lbx, ubx


def solve(problem: TuningProblem, lbx, ubx, max_iter: int, jit: bool, plant_cost=None,
           tol: float = 1e-8, hessian: str = "limited-memory", progress=None) -> TuningResult:
    """IPOPT on the problem's objective (+ plant_cost(decision)), with the fallback logic."""
    start_time = time.perf_counter()
    x = problem.decision
    objective = problem.objective if plant_cost is None else problem.objective + plant_cost(x)
    start = np.clip(problem.start(), lbx, ubx)
    # IPOPT works on z = x / scale with each decision scaled by its own start, so
    # gains of different magnitudes (a crane cascade's 0.2 outer and 8000 inner)
    # all move on the order of one; a zero start takes 1e-3 of the largest.
    magnitude = np.abs(start)
    floor = 1e-3 * np.max(magnitude) if np.any(magnitude > 0) else 1.0
    scale = np.where(magnitude > 0, magnitude, floor)
    z = ca.MX.sym("z", x.numel())
    f_of_x = ca.Function("objective", [x], [objective])
    g_of_x = ca.Function("constraints", [x], [problem.g])
    recorder = _Recorder(x.numel(), problem.g.numel(), 0, progress)
    opts = {"ipopt": {"max_iter": int(max_iter), "print_level": 0, "tol": tol, "acceptable_tol": 100 * tol,
                      "acceptable_iter": 10, "hessian_approximation": hessian, "sb": "yes"},
            "print_time": False, "iteration_callback": recorder, "error_on_fail": False}
    nlp = {"x": z, "f": f_of_x(scale * z), "g": g_of_x(scale * z)}
    # Compiled without a shell and cached (models.compile); CasADi's virtual machine when impossible.
    build = models.compile.jit_nlpsol if jit else ca.nlpsol
    solver = build("tuning", "ipopt", nlp, opts)
    sol = solver(x0=start / scale, lbx=lbx / scale, ubx=ubx / scale, lbg=problem.lbg, ubg=problem.ubg)
    stats = solver.stats()
    status = stats["return_status"]
    total = ca.Function("total", [x], [objective])

    def judge(decision):
        value = float(total(decision))
        violations = problem.values(decision)[2] + _spectral_violation(problem, decision)
        return value, violations

    final = np.clip(scale * np.asarray(sol["x"]).ravel(), lbx, ubx)  # IPOPT relaxes bounds by ~1e-8
    initial_cost, _ = judge(start)
    message = f"IPOPT: {status}"
    chosen = None
    value, violations = judge(final)
    if np.isfinite(value):
        chosen = (value, violations, final, "final")
    # Other iterates matter only when clearly better than IPOPT's answer, or when
    # that answer is infeasible: judge them lazily, lowest recorded objective first.
    threshold = value - 1e-6 * abs(value) if chosen and not violations else np.inf
    others = sorted(((f, scale * z, "iterate") for z, f, _ in recorder.iterates
                     if np.isfinite(f) and f < threshold), key=lambda item: item[0])
    others.append((initial_cost, start, "start"))
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
        block=block, gains={k: v.copy() for k, v in block.gains.items()},
        initial_gains={k: v.copy() for k, v in problem.block.gains.items()},
        cost=float(value), initial_cost=initial_cost,
        improvement=1 - float(value) / initial_cost if initial_cost else 0.0,
        feasible=not violations, success=bool(stats["success"]) and label == "final" and not violations,
        status=status, message=message, violations=list(violations),
        iterations=int(stats.get("iter_count", 0)), wall_time=time.perf_counter() - start_time,
        decision=np.array(decision),
        history=[(stamp - start_time, value) for _, value, stamp in recorder.iterates])


def closed_loop_spectral_abscissa(plant: Plant, block: Block, x, xc, r, params=None, substeps: int = 10) -> float:
    """Slowest mode of the sampled closed loop linearized at (x, xc, r), in 1/s.

    log(spectral radius of ∂(x⁺, x_c⁺)/∂(x, x_c)) / Ts: negative when the loop is
    locally stable; a saturated input makes the loop open there.
    """
    s = ca.SX.sym("s", plant.nx + block.n_state)
    p = plant.param_vector(params)
    xs, xcs = s[:plant.nx], s[plant.nx:]
    y = plant.casadi_h(xs, p) if block.measures == "outputs" else xs
    xc_next, u = block.casadi_step(xcs, y, np.atleast_1d(r), block.gain_vector())
    u = ca.fmin(ca.fmax(u, -plant.input_limit), plant.input_limit)
    x_next = plant.step_function(block.sample_period, substeps)(xs, u, p)
    jac = ca.Function("closed_loop_jacobian", [s], [ca.jacobian(ca.vertcat(x_next, xc_next), s)])
    eig = np.linalg.eigvals(np.asarray(jac(np.concatenate([x, xc]))))
    return float(np.log(np.max(np.abs(eig))) / block.sample_period)


def _spectral_violation(problem: TuningProblem, decision) -> list[str]:
    bound = problem.specs.max_spectral_abscissa
    if bound is None:
        return []
    block = problem.block_at(decision)
    run = models.simulate_closed_loop(problem.plant, block, problem.reference, problem.scenario.duration,
                                      x0=problem.x0, params=problem.samples[0],
                                      input_disturbance=problem.scenario.input_disturbance,
                                      allow_divergence=True)
    if run.diverged_at is not None:
        return [f"spectral abscissa <= {bound:g} 1/s (the closed loop diverged at t = {run.diverged_at:.3g} s)"]
    alpha = closed_loop_spectral_abscissa(problem.plant, block, run.x[-1], run.xc[-1], run.r[-1],
                                          problem.samples[0])
    return [] if alpha <= bound else [f"spectral abscissa <= {bound:g} 1/s (got {alpha:.3g} 1/s)"]
