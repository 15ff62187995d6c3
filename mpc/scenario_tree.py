"""Robust nonlinear MPC by a scenario tree, solved by the real-time iteration.

The known model's parameters p are uncertain; the tree carries S branches with parameter
vectors p¹ ... pˢ (the corners of a box, `models.uncertainty.corner_params`, or chosen samples)
and probabilities w₁ ... wₛ (Σ wᵢ = 1). Every branch predicts its own trajectory from the same
estimate under its own inputs, and the problem at each sample is

    minimize    Σᵢ wᵢ [ Σ_{k<N} ‖xᵢ_k − xᵢ_s‖²_Q + ‖uᵢ_k − uᵢ_s‖²_R + ‖xᵢ_N − xᵢ_s‖²_{Pᵢ} ]
                + Σᵢ Σ_k (w_σ ᵀ σᵢ_k + σᵢ_kᵀ diag(ρ) σᵢ_k)
    subject to  xᵢ_0 = x̂,   xᵢ_{k+1} = F(xᵢ_k, uᵢ_k + d̂, pⁱ)                 every branch i
                −u_max ≤ uᵢ_k ≤ u_max,  |uᵢ_k − uᵢ_{k−1}| ≤ Δ                 every branch i
                g_lo − σᵢ_k ≤ G xᵢ_{k+1} ≤ g_hi + σᵢ_k,  σᵢ_k ≥ 0            every branch i
                uᵢ_k = u¹_k                                  k < N_r (non-anticipativity)

with (xᵢ_s, uᵢ_s) the equilibrium of branch i at the reference and Pᵢ the Riccati solution of its
linearization there. N_r, the robust horizon (1 ≤ N_r ≤ N), is how many moves all branches share:
with N_r = 1 the later moves of each branch react to that branch's model (the recourse of a
multi-stage MPC), with N_r = N one open-loop plan must serve every branch.

It is the nominal NMPC's problem (`mpc.nonlinear.mpc_problem`) on a plant whose state stacks
the branches' states (`stacked_plant`: S copies of the known plant's equations, each with its
own parameters), with the branches' weights in Q, R and P and the non-anticipativity rows added;
the same `mpc.nonlinear.NonlinearMPCProblem` transcribes it by multiple shooting and solves it
by the same real-time iteration (`mpc.rti`). The controller (`ScenarioTreeMPC`) is
`mpc.NonlinearMPC` with that problem: the same estimator, targets, fallback and interface.

What the construction guarantees, and what it does not:

- the first move is the same on every branch (the QP holds the equality rows to its
  tolerance), so the command applied is one that every branch's prediction was planned with;
- with one branch (weight 1, the known parameters) the problem is the nominal NMPC's, and so are
  its moves (to rounding);
- at a converged solve (``iteration="sqp"``) the state bounds hold on every branch's prediction
  (soft bounds: their slacks are 0 when the hard problem is feasible and the penalty exceeds
  the multipliers).

It does not guarantee that the true plant stays within the bounds: a parameter vector inside the
box but not on a branch, an input disturbance other than the estimated one, estimation error and
a single real-time iteration per sample (not a converged solve) are not covered; nor recursive
feasibility (the soft bounds keep every problem feasible instead). The corners' predictions need not
bound those of the parameters inside the box: past one step the predicted state is not affine in
the parameters, even for a linear model. The Monte Carlo of `benchmarks/robust_mpc.py` measures
what happens on the true plant.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from models import Param, Physics, Plant, declare
from models.checks import integer, real_array, weight_matrix

from .controller import NonlinearMPC
from .linear import SoftBound, riccati_terminal_cost
from .nonlinear import NLPSolution, NonlinearMPCProblem
from .settings import MPCSettings, design_arguments

__all__ = ["ScenarioTreeMPC", "ScenarioTreeProblem", "scenario_tree_mpc", "stacked_plant"]

#: Largest |Σ w − 1| accepted for the branches' probabilities.
WEIGHT_SUM_TOLERANCE = 1e-9


def branch_parameters(known: Plant, branches) -> np.ndarray:
    """The branches as parameter vectors (S, n_params): rows of an array, dicts of overrides of
    `known`'s values, or Plants of the same declaration; each checked by `Plant.param_vector`.

    Raises ValueError for no branch, a row of the wrong size or a value out of its range.
    """
    if isinstance(branches, np.ndarray):
        rows = list(np.atleast_2d(branches)) if branches.size else []
    else:
        rows = list(branches)
    if not rows:
        raise ValueError(f"{known.name}: a scenario tree needs at least one branch, got none")
    out = []
    for i, row in enumerate(rows):
        if isinstance(row, Plant):
            if row.declaration is not known.declaration:
                raise ValueError(f"branch {i + 1} is the plant {row.name!r}, not {known.name!r}")
            row = row.param_vector()
        try:
            out.append(known.param_vector(row))
        except (ValueError, TypeError) as err:
            raise ValueError(f"{known.name}: branch {i + 1}: {err}") from None
    return np.array(out)


def branch_weights(weights, count: int) -> np.ndarray:
    """The branches' probabilities (count,): uniform for None; else finite, >= 0, summing to 1."""
    if weights is None:
        return np.full(count, 1.0 / count)
    w = real_array(weights, "weights").reshape(-1)
    if w.size != count:
        raise ValueError(f"weights must have one entry per branch ({count}), got {w.size}")
    if not np.all(np.isfinite(w)) or np.any(w < 0):
        raise ValueError(f"weights must be finite and >= 0, got {w}")
    if abs(float(w.sum()) - 1.0) > WEIGHT_SUM_TOLERANCE:
        raise ValueError(f"weights must sum to 1, got {w.sum():.12g} ({w})")
    return w


def stacked_plant(known: Plant, parameters: np.ndarray) -> Plant:
    """A plant whose state stacks S copies of `known`'s state, each moved by `known`'s equations
    with its own parameter row of `parameters` (S, n_params) and its own inputs.

    States (first-order) ``<state>_<i>``, inputs ``<input>_<i>``, parameters ``<param>_<i>``,
    i = 1..S, in branch order: x = (x¹, ..., xˢ), u = (u¹, ..., uˢ). Its standard operating point
    is each branch's own (`Plant.equilibrium` of `known` with that branch's parameters).
    """
    S = len(parameters)
    nx, nu = known.nx, known.nu
    states = tuple(f"{n}_{i + 1}" for i in range(S) for n in known.state_names)
    inputs = tuple(f"{n}_{i + 1}" for i in range(S) for n in known.input_names)
    params = tuple(
        Param(f"{p.name}_{i + 1}", float(parameters[i][j]), p.unit, p.description, p.positive)
        for i in range(S)
        for j, p in enumerate(known.param_info)
    )
    n_params = known.n_params
    operating = [known.equilibrium(params=row)[0] for row in parameters]

    def physics(q, dq, u, p, s):
        # The branches' rates: known's f on each block of the stacked state.
        rates = []
        outputs = {}
        for i in range(S):
            x_i = ca.vertcat(*[getattr(s, states[i * nx + j]) for j in range(nx)])
            u_i = ca.vertcat(*[getattr(u, inputs[i * nu + j]) for j in range(nu)])
            p_i = ca.vertcat(*[getattr(p, params[i * n_params + j].name) for j in range(n_params)])
            xdot = known.casadi_f(x_i, u_i, p_i)
            rates += [xdot[j] for j in range(nx)]
            y = known.casadi_h(x_i, p_i)
            outputs |= {f"{n}_{i + 1}": y[j] for j, n in enumerate(known.output_names)}
        return Physics(outputs=outputs, rates=rates)

    def operating_point(p):  # the branches' own equilibria, whatever the namespace p
        return {states[i * nx + j]: float(operating[i][j]) for i in range(S) for j in range(nx)}

    decl = declare(
        name=f"{known.name}_tree",
        title=f"{S} branches of {known.name}",
        coordinates=(),
        inputs=inputs,
        params=params,
        input_limit=tuple(np.tile(known.input_limit, S)),
        operating_point=operating_point,
        first_order=states,
        register=False,
    )(physics)
    return Plant(decl)


def _stacked_bounds(bounds, nx: int, S: int) -> tuple[SoftBound, ...]:
    """Each soft bound on the known state, once per branch on that branch's block of the stacked state."""
    out = []
    for i in range(S):
        for b in bounds:
            row = np.zeros(S * nx)
            row[i * nx : (i + 1) * nx] = b.row
            name = b.name if S == 1 else f"{b.name} (branch {i + 1})"
            out.append(SoftBound(name, row, b.lower, b.upper, b.linear_weight, b.quadratic_weight))
    return tuple(out)


class ScenarioTreeProblem:
    """The scenario tree's optimal control problem (see the module docstring), transcribed and prepared
    for real-time iteration once: a `NonlinearMPCProblem` on `stacked_plant`.

    Parameters
    ----------
    known : Plant, the controller's model (its equations; the branches give the parameters)
    parameters : (S, n_params) the branches' parameter vectors;  weights : (S,) > 0, summing to 1
    robust_horizon : N_r, 1 <= N_r <= horizon, the moves all branches share
    sample_period, horizon, state_weight, input_weight, soft_bounds, rate_limit, substeps, iteration,
        max_iterations, tolerance, compiled : as `NonlinearMPCProblem`, on the known plant's state
        (the soft bounds and the rate limit hold on every branch)

    Raises
    ------
    ValueError
        For no branch, weights that are not > 0 or do not sum to 1, a robust horizon < 1 or > horizon,
        and what `NonlinearMPCProblem` refuses.
    """

    def __init__(
        self,
        known: Plant,
        parameters,
        weights,
        robust_horizon: int,
        sample_period: float,
        horizon: int,
        state_weight,
        input_weight,
        *,
        soft_bounds=(),
        rate_limit=None,
        **options,
    ):
        self.parameters = branch_parameters(known, parameters)
        S = self.branches = len(self.parameters)
        self.weights = branch_weights(weights, S)
        if np.any(self.weights <= 0):
            raise ValueError(f"weights must be > 0 (a branch of weight 0 is no branch), got {self.weights}")
        N = integer(horizon, "horizon", minimum=1)
        Nr = self.robust_horizon = integer(robust_horizon, "robust_horizon", minimum=1)
        if Nr > N:
            raise ValueError(f"robust_horizon must be at most the horizon N = {N}, got {Nr}")
        nx, nu = known.nx, known.nu
        self.known, self.nx, self.nu, self.horizon = known, nx, nu, N
        Q = weight_matrix(state_weight, nx, "state_weight Q")
        R = weight_matrix(input_weight, nu, "input_weight R", definite=True)
        self.soft_bounds = tuple(soft_bounds)
        self.plant = stacked_plant(known, self.parameters)
        Ts = float(sample_period)

        def non_anticipativity(ocp) -> None:
            # u of every branch equals branch 1's on the intervals k < N_r (t_k = k Ts < (N_r - 1/2) Ts).
            first, shared = ocp.input[:nu], ocp.t < (Nr - 0.5) * Ts
            for i in range(1, S):
                gap = ocp.input[i * nu : (i + 1) * nu] - first
                ocp.subject_to(
                    (gap if Nr == N else ca.if_else(shared, gap, ca.SX.zeros(nu))) == 0,
                    label=f"non-anticipativity of branch {i + 1}",
                    include_end=False,
                )

        self.inner = NonlinearMPCProblem(
            self.plant,
            sample_period,
            N,
            np.kron(np.diag(self.weights), Q),
            np.kron(np.diag(self.weights), R),
            soft_bounds=_stacked_bounds(self.soft_bounds, nx, S),
            rate_limit=None if rate_limit is None else np.tile(np.broadcast_to(rate_limit, (nu,)), S),
            constrain=non_anticipativity,
            **options,
        )
        self.iteration, self.qp_solver = self.inner.iteration, self.inner.qp_solver
        self.sample_period = self.inner.sample_period
        self.last: NLPSolution | None = None

    def reset(self) -> None:
        """Forget the warm start (of `solve`)."""
        self.inner.reset()

    def reset_many(self, count: int) -> None:
        """Forget every warm start and keep one per sample for `solve_many` on `count` samples."""
        self.inner.reset_many(count)

    def branch_inputs(self, solution: NLPSolution) -> np.ndarray:
        """The stacked solution's inputs per branch, (N, S, nu)."""
        return np.asarray(solution.inputs).reshape(self.horizon, self.branches, self.nu)

    def branch_states(self, solution: NLPSolution) -> np.ndarray:
        """The stacked solution's predicted states per branch, (N + 1, S, nx)."""
        return np.asarray(solution.states).reshape(self.horizon + 1, self.branches, self.nx)

    def _first_branch(self, solution: NLPSolution) -> NLPSolution:
        """`solution` of the stacked problem as the known plant's: branch 1's inputs and states (the
        first N_r moves every branch's), every branch's slacks."""
        return NLPSolution(
            solution.inputs[:, : self.nu],
            solution.states[:, : self.nx],
            solution.slacks,
            solution.success,
            solution.status,
            solution.iterations,
            solution.solve_time,
            solution.preparation_time,
            solution.feedback_time,
            solution.qp_status,
        )

    def solve(self, x_hat, d_hat, x_target, u_target, terminal_weight, u_previous, plan) -> NLPSolution:
        """One sample of the tree (`NonlinearMPCProblem.solve` on the stacked problem); the stacked
        answer is kept as `last`.

        Parameters
        ----------
        x_hat : (nx,) estimate, every branch's start;  d_hat : (nu,) input-disturbance estimate
        x_target, u_target : (S nx,), (S nu,) the branches' steady states (u_target excludes d̂)
        terminal_weight : (S nx, S nx) the stacked terminal weight (the branches' weights applied)
        u_previous : (nu,) input applied last;  plan : (N, nu) the plan followed, every branch's first guess
        """
        S = self.branches
        self.last = self.inner.solve(
            np.tile(x_hat, S),
            np.tile(d_hat, S),
            x_target,
            u_target,
            terminal_weight,
            np.tile(u_previous, S),
            np.tile(np.reshape(plan, (self.horizon, self.nu)), (1, S)),
        )
        return self._first_branch(self.last)

    def solve_many(
        self, index, x_hat, d_hat, x_target, u_target, terminal_weight, u_previous, plans
    ) -> list[NLPSolution]:
        """`solve` of the samples `index` of the `reset_many` batch at once (`NonlinearMPCProblem.solve_many`).

        x_hat (m, nx), d_hat (m, nu), u_target (m, S nu), u_previous (m, nu), plans (m, N, nu);
        x_target (S nx,) and terminal_weight (S nx, S nx) shared.
        """
        S = self.branches
        solutions = self.inner.solve_many(
            index,
            np.tile(x_hat, (1, S)),
            np.tile(d_hat, (1, S)),
            x_target,
            u_target,
            terminal_weight,
            np.tile(u_previous, (1, S)),
            np.tile(plans, (1, 1, S)),
        )
        return [self._first_branch(s) for s in solutions]


class ScenarioTreeMPC(NonlinearMPC):
    """Robust nonlinear MPC by a scenario tree (see the module docstring): `NonlinearMPC` whose
    problem predicts every branch of the tree and shares the first `robust_horizon` moves.

    Parameters
    ----------
    known : Plant, the controller's model: its equations, estimator and reference
    branches : the branches' parameters: an (S, n_params) array (`models.uncertainty.corner_params`,
        `sample_params`), dicts of overrides of known's values, or Plants of known's declaration
    weights : (S,) the branches' probabilities, > 0 and summing to 1 (default uniform)
    robust_horizon : N_r, the moves every branch shares, 1 <= N_r <= horizon
    sample_period, horizon, state_weight, input_weight, soft_bounds, rate_limit, tracked, substeps,
        iteration, max_iterations, tolerance, compiled, input_noise_std, disturbance_step_std,
        measurement_std : as `NonlinearMPC` (the soft bounds hold on every branch)
    name : str

    Raises
    ------
    ValueError
        For an empty branch list, a branch of the wrong size or out of range, weights not > 0 or not
        summing to 1, a robust horizon < 1 or > horizon, and what `NonlinearMPC` refuses.
    """

    nlp: ScenarioTreeProblem

    def __init__(
        self, known: Plant, branches, *, weights=None, robust_horizon: int = 1, name="scenario-tree NMPC", **arguments
    ):
        self.branch_params = branch_parameters(known, branches)
        self.weights = branch_weights(weights, len(self.branch_params))
        self.robust_horizon = integer(robust_horizon, "robust_horizon", minimum=1)
        if "horizon" in arguments and self.robust_horizon > integer(arguments["horizon"], "horizon", minimum=1):
            raise ValueError(
                f"robust_horizon must be at most the horizon N = {arguments['horizon']}, got {self.robust_horizon}"
            )
        keys = list(known.params)
        self.branch_plants = [known.with_params(**dict(zip(keys, row))) for row in self.branch_params]
        super().__init__(known, name=name, **arguments)

    def _problem(self, known: Plant, sample_period, horizon, Q, R, **options) -> ScenarioTreeProblem:
        return ScenarioTreeProblem(
            known, self.branch_params, self.weights, self.robust_horizon, sample_period, horizon, Q, R, **options
        )

    def target(self, reference: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The branches' stacked (x_s (S nx,), holding inputs (S nu,), terminal weight blockdiag(wᵢ Pᵢ))
        for an absolute reference: each branch's own equilibrium and Riccati solution there."""
        key = float(reference)
        if key not in self._targets:
            xs, vs, blocks = [], [], []
            for plant, w in zip(self.branch_plants, self.weights):
                x, v = plant.equilibrium(**{self.tracked: key})
                lin = plant.linearize(x, v).discretize(self.sample_period)
                P, _ = riccati_terminal_cost(lin.A, lin.B, self.Q, self.R)
                xs.append(x)
                vs.append(v)
                blocks.append(w * P)
            if len(self._targets) > 64:
                self._targets.clear()
            self._targets[key] = (np.concatenate(xs), np.concatenate(vs), _block_diagonal(blocks))
        return self._targets[key]


def _block_diagonal(blocks) -> np.ndarray:
    """The square blocks on the diagonal of one matrix."""
    n = sum(len(b) for b in blocks)
    out, at = np.zeros((n, n)), 0
    for b in blocks:
        out[at : at + len(b), at : at + len(b)] = b
        at += len(b)
    return out


def scenario_tree_mpc(
    known: Plant, settings: MPCSettings, branches, *, tracked: str, weights=None, robust_horizon: int = 1, **overrides
) -> ScenarioTreeMPC:
    """The scenario-tree NMPC designed on `known` with the case's `settings` (as `mpc.nonlinear_mpc`).

    Parameters
    ----------
    known : Plant, the controller's model;  settings : MPCSettings
    branches, weights, robust_horizon : as `ScenarioTreeMPC`
    tracked : coordinate whose absolute value the reference gives
    overrides : keyword arguments of `ScenarioTreeMPC` replacing the settings' values
    """
    arguments = {"substeps": settings.substeps} | design_arguments(known, settings) | overrides
    return ScenarioTreeMPC(
        known, branches, weights=weights, robust_horizon=robust_horizon, tracked=tracked, **arguments
    )
