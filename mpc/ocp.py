"""Optimal control problems on any `models.Plant`, written like the math.

    minimize    Φ(x(0), x(T), p, T, ∫L dt, Σ ℓ)                 (`minimize`, `integral`, `sum`)
    subject to  ẋ = f(x, u, p)                                   (the plant, always)
                g_lo <= g(x(t), u(t), p, t) <= g_hi   on [0, T]    (path: `subject_to` on x, u, y, t)
                i_lo <= i(x_k, u_k, x_{k+1}, u_{k-1}) <= i_hi  k = 0..N-1  (interval: on `x_next`, `u_previous`)
                e_lo <= e(x(0), x(T), p, T, ∫L dt) <= e_hi          (boundary: `at_start`, `at_end`)
                |u| <= input limit                                  (by default)

over the state and input trajectories, the plant parameters named in
`choose` (with ranges) and, with `FreeTime`, the final time T. Expressions
are CasADi SX built from the problem's symbols, by name::

    ocp = OptimalControlProblem(models.get("pendulum"), final_time=3.0)
    x, u = ocp.x, ocp.u                           # x.z, x.theta, x.dz, x.dtheta; u.F
    ocp.minimize(ocp.integral(u.F**2))
    ocp.subject_to(ocp.at_start(ocp.state) == [0, pi, 0, 0])
    ocp.subject_to(ocp.at_end(ocp.state) == 0)
    ocp.subject_to(ocp.bounded(-1, x.z, 1))
    solution = ocp.solve(Collocation(intervals=60))

This module only records the problem; `mpc.transcription` turns it into a
nonlinear program and `mpc.ocp_solver` solves it with IPOPT.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from models import Plant
from models.checks import real

from .mesh_refinement import solve_refined
from .ocp_solver import OCPSolver


class UnknownNameError(ValueError, AttributeError):
    """A state, input, output, parameter or control name the problem does not have."""


def _seconds(name: str, value) -> float:
    """`value` as a float number of seconds; TypeError naming FreeTime's argument `name` for a bool or a
    value that is not a real number."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise TypeError(f"final_time: FreeTime {name} must be a real number of seconds, got {value!r}")
    return float(value)


@dataclass(frozen=True)
class FreeTime:
    """A free final time T in [lower, upper] s, a decision of the problem.

    guess : the starting value for the solver (default: the middle of the range).
    """

    lower: float
    upper: float
    guess: float | None = None

    def __post_init__(self):
        lower, upper = _seconds("lower", self.lower), _seconds("upper", self.upper)
        if not np.isfinite(lower) or lower <= 0:
            raise ValueError(f"final_time: FreeTime lower bound must be finite and > 0 s, got {self.lower}")
        if not np.isfinite(upper) or upper <= lower:
            raise ValueError(
                f"final_time: FreeTime upper bound must be finite and > lower = {lower} s, got {self.upper}"
            )
        guess = (lower + upper) / 2 if self.guess is None else _seconds("guess", self.guess)
        if not lower <= guess <= upper:
            raise ValueError(f"final_time: FreeTime guess must lie in [{lower}, {upper}] s, got {self.guess}")
        object.__setattr__(self, "lower", lower)
        object.__setattr__(self, "upper", upper)
        object.__setattr__(self, "guess", guess)


class Names:
    """Symbols (or expressions) by name: ``ocp.x.theta`` or ``ocp.x["theta"]``.

    Iterating gives the names in the plant's order.
    """

    def __init__(self, kind: str, owner: str, names, expressions):
        self._kind, self._owner = kind, owner
        self._items = dict(zip(names, expressions))

    def __getattr__(self, name: str):
        if name.startswith("_"):
            raise AttributeError(name)
        return self[name]

    def __getitem__(self, name: str):
        if name not in self._items:
            known = ", ".join(self._items) or "none"
            raise UnknownNameError(f"{self._owner} has no {self._kind} {name!r}; its {self._kind}s are {known}")
        return self._items[name]

    def __iter__(self):
        return iter(self._items)

    def __len__(self) -> int:
        return len(self._items)

    def __dir__(self):
        return list(self._items)

    def __repr__(self) -> str:
        return f"<{self._kind}s of {self._owner}: {', '.join(self._items)}>"

    def _add(self, name, expression) -> None:
        self._items[name] = expression


@dataclass(frozen=True)
class Bounded:
    """lower <= expression <= upper, from `OptimalControlProblem.bounded`."""

    lower: object
    expression: object
    upper: object


@dataclass(frozen=True)
class Constraint:
    """One scalar constraint lower <= expression <= upper as recorded.

    path : True for a constraint along the trajectory (on x, u, y, t), False for one
        on boundary values, integrals, parameters and the final time.
    include_start, include_end : whether a path constraint also holds at t = 0 and t = T.
    interval : True for a constraint on each interval, linking its input to the state at its
        end (`x_next`) or to the previous interval's input (`u_previous`).
    """

    expression: ca.SX
    lower: ca.SX
    upper: ca.SX
    label: str
    path: bool
    include_start: bool = True
    include_end: bool = True
    interval: bool = False


@dataclass(frozen=True)
class Accumulated:
    """An integral ∫₀ᵀ integrand dt or a sum Σₖ integrand(t_k) standing as `symbol` in point expressions."""

    symbol: ca.SX
    integrand: ca.SX
    kind: str  # "integral" or "sum"
    include_end: bool = False


@dataclass(frozen=True)
class ChosenParam:
    """A plant parameter decided by the optimization, in [lower, upper] (SI)."""

    name: str
    lower: float
    upper: float
    guess: float


class OptimalControlProblem:
    """An optimal control problem on `plant`; see the module docstring.

    Parameters
    ----------
    plant : models.Plant
        Its parameter values are the fixed ones (those not in `choose`); a
        solve may override them (`OCPSolver.solve(plant_params=...)`).
    final_time : float (s) or FreeTime
        The horizon T: fixed, or a decision in a range.
    actuator_limit : bool
        Apply the plant's ``|u_i|`` <= input_limit[i] as bounds on the input (default).

    Attributes
    ----------
    x, u, y, p : Names
        States (q then q̇), inputs, outputs y = h(x, p) and plant parameters by name.
    state, input : casadi.SX, (nx,), (nu,)
        The same symbols as vectors in the plant's order.
    t : casadi.SX
        Time along the trajectory, s.
    final_time : casadi.SX
        T (a symbol even when fixed; its value is substituted in the transcription).
    x_next, u_previous : Names
        On interval k, the state at its end x_{k+1} and the input of interval k-1 (on the first
        interval the value given to `input_before`), for constraints linking neighbours.
    state_next, input_previous : casadi.SX, (nx,), (nu,)
        The same symbols as vectors.
    """

    def __init__(self, plant: Plant, final_time, *, actuator_limit: bool = True):
        if not isinstance(plant, Plant):
            raise ValueError(f"plant must be a models.Plant, got {type(plant).__name__}")
        self.plant = plant
        if isinstance(final_time, FreeTime):
            self.free_time: FreeTime | None = final_time
            self.fixed_final_time = None
        else:
            if isinstance(final_time, (bool, np.bool_)) or not isinstance(
                final_time, (int, float, np.integer, np.floating)
            ):
                raise TypeError(f"final_time must be a real number of seconds or a FreeTime, got {final_time!r}")
            value = float(final_time)
            if not np.isfinite(value) or value <= 0:
                raise ValueError(f"final_time must be finite and > 0 s (or a FreeTime), got {final_time}")
            self.free_time, self.fixed_final_time = None, value
        self.actuator_limit = bool(actuator_limit)
        owner = plant.name
        sym = lambda names, suffix="": [ca.SX.sym(n + suffix) for n in names]
        xs, us = sym(plant.state_names), sym(plant.input_names)
        ps = sym([p.name for p in plant.param_info])
        self.state, self.input = ca.vertcat(*xs), ca.vertcat(*us)
        self.param_vector = ca.vertcat(*ps)
        self.t = ca.SX.sym("t")
        self.final_time = ca.SX.sym("T")
        self.x = Names("state", owner, plant.state_names, xs)
        self.u = Names("input", owner, plant.input_names, us)
        self.p = Names("parameter", owner, [p.name for p in plant.param_info], ps)
        y = plant.casadi_h(self.state, self.param_vector)
        self.y = Names("output", owner, plant.output_names, [y[i] for i in range(y.numel())])
        self.c = Names("control", owner, [], [])
        self.controls: dict[str, tuple[float, float]] = {}
        self.control_vector = ca.SX(0, 1)
        self.state_start, self.state_end = (
            ca.vertcat(*sym(plant.state_names, "(0)")),
            ca.vertcat(*sym(plant.state_names, "(T)")),
        )
        self.input_start, self.input_end = (
            ca.vertcat(*sym(plant.input_names, "(0)")),
            ca.vertcat(*sym(plant.input_names, "(T)")),
        )
        next_states, previous_inputs = sym(plant.state_names, "(k+1)"), sym(plant.input_names, "(k-1)")
        self.state_next, self.input_previous = ca.vertcat(*next_states), ca.vertcat(*previous_inputs)
        self.x_next = Names("state at the interval's end", owner, plant.state_names, next_states)
        self.u_previous = Names("input of the previous interval", owner, plant.input_names, previous_inputs)
        self.input_before_start: ca.SX | None = None
        self.control_start, self.control_end = ca.SX(0, 1), ca.SX(0, 1)
        self.parameters: dict[str, tuple[ca.SX, np.ndarray | None]] = {}
        self.fed_input = self.input
        self.chosen: dict[str, ChosenParam] = {}
        self.scales: dict[str, float] = {}
        self.accumulated: list[Accumulated] = []
        self.constraints: list[Constraint] = []
        self.objective: ca.SX | None = None

    # ------------------------------------------------------------------ symbols
    def __repr__(self) -> str:
        horizon = (
            f"T free in [{self.free_time.lower:g}, {self.free_time.upper:g}] s"
            if self.free_time
            else f"T = {self.fixed_final_time:g} s"
        )
        return (
            f"OptimalControlProblem({self.plant.name}, {horizon}, {len(self.constraints)} constraints, "
            f"chosen {list(self.chosen) or 'none'})"
        )

    def _taken(self, name: str) -> bool:
        return (
            name in self.parameters
            or name in self.controls
            or name in ("T", "t")
            or name in self.x
            or name in self.u
            or name in self.p
            or name in self.y
        )

    def parameter(self, name: str, size: int = 1, value=None) -> ca.SX:
        """A value called `name` given at solve time (a reference, an initial state), `size` entries.

        `value` is the default; without one every solve must give it in `params`.
        Returns the SX symbol (a scalar when size is 1).
        """
        if not isinstance(name, str) or not name.isidentifier() or self._taken(name):
            raise ValueError(f"parameter name must be a new identifier, got {name!r}")
        if int(size) != size or size < 1:
            raise ValueError(f"parameter {name!r}: size must be an integer >= 1, got {size}")
        symbol = ca.SX.sym(name, int(size))
        default = None if value is None else _values(value, int(size), f"parameter {name!r} value")
        self.parameters[name] = (symbol, default)
        return symbol

    def control(self, name: str, lower: float = -np.inf, upper: float = np.inf) -> ca.SX:
        """An extra decision called `name`, bounded by lower and upper, held constant on each interval like
        an input, but not fed to the plant.

        For slack variables of soft constraints, for example. Returns its SX symbol.
        """
        if not isinstance(name, str) or not name.isidentifier() or self._taken(name):
            raise ValueError(f"control name must be a new identifier, got {name!r}")
        if not float(lower) < float(upper):
            raise ValueError(f"control {name!r}: lower must be < upper, got [{lower}, {upper}]")
        symbol, start, end = ca.SX.sym(name), ca.SX.sym(name + "(0)"), ca.SX.sym(name + "(T)")
        self.controls[name] = (float(lower), float(upper))
        self.c._add(name, symbol)
        self.control_vector = ca.vertcat(self.control_vector, symbol)
        self.control_start = ca.vertcat(self.control_start, start)
        self.control_end = ca.vertcat(self.control_end, end)
        return symbol

    def plant_input(self, expression) -> None:
        """What the plant receives instead of u: an expression of u, the controls, p and parameters, (nu,).

        For an input-disturbance estimate d̂ given each solve, ``ocp.plant_input(ocp.input + d_hat)``
        with ``d_hat = ocp.parameter("d_hat", nu)``. Bounds (the actuator limit included) stay on u;
        `OCPSolution.plant_inputs` holds what the plant received and `verify` simulates that.
        """
        expression = _sx(expression, "plant_input(...)")
        if expression.numel() != self.plant.nu:
            raise ValueError(
                f"plant_input(...) needs {self.plant.nu} entries (one per input), got {expression.numel()}"
            )
        if ca.depends_on(
            expression, ca.vertcat(self.state, self.t, self.final_time, self._point_symbols, self._interval_symbols)
        ):
            raise ValueError(
                "plant_input(...) may depend on u, the controls, p and parameters only (it is held on each interval)"
            )
        self.fed_input = ca.vec(expression)

    def choose(self, name: str, lower: float, upper: float, guess: float | None = None) -> ca.SX:
        """Make the plant parameter `name` a decision in [lower, upper] (co-design).

        guess : starting value (default: the plant's value), clipped into the range; a finite number.
        Returns its SX symbol (the same as ``ocp.p.<name>``). A bound or guess that is not a real number
        is a TypeError, a NaN guess or bound a ValueError, each naming it.
        """
        symbol = self.p[name]
        info = {p.name: p for p in self.plant.param_info}[name]
        lower = real(lower, f"choose({name!r}) lower", finite=False)
        upper = real(upper, f"choose({name!r}) upper", finite=False)
        if guess is not None:
            guess = real(guess, f"choose({name!r}) guess ({info.unit})")  # NaN or inf refused, naming it
        floor = "> 0" if info.positive else ">= 0"
        if not np.isfinite(lower) or lower < 0 or (info.positive and lower == 0):
            raise ValueError(f"choose({name!r}): lower must be finite and {floor} ({info.unit}), got {lower}")
        if not np.isfinite(upper) or upper <= lower:
            raise ValueError(f"choose({name!r}): upper must be finite and > lower = {lower}, got {upper}")
        start = float(np.clip(self.plant.params[name] if guess is None else guess, lower, upper))
        self.chosen[name] = ChosenParam(name, lower, upper, start)
        return symbol

    def scale(self, **values: float) -> None:
        """Typical magnitudes of states, inputs, controls or chosen parameters, by name (SI).

        Decisions are divided by their scale so the solver sees numbers near one.
        Inputs default to the actuator limit, everything else to 1.
        """
        known = set(self.x) | set(self.u) | set(self.controls) | set(self.p)
        for name, value in values.items():
            if name not in known:
                raise UnknownNameError(
                    f"{self.plant.name} has no state, input, control or parameter {name!r} "
                    f"to scale; choose among {', '.join(sorted(known))}"
                )
            value = float(value)
            if not np.isfinite(value) or value <= 0:
                raise ValueError(f"scale {name}: must be finite and > 0, got {value}")
            self.scales[name] = value

    # -------------------------------------------------------------- expressions
    @property
    def _path_symbols(self) -> ca.SX:
        return ca.vertcat(self.state, self.input, self.control_vector, self.t)

    @property
    def _point_symbols(self) -> ca.SX:
        acc = [a.symbol for a in self.accumulated]
        return ca.vertcat(
            self.state_start,
            self.state_end,
            self.input_start,
            self.input_end,
            self.control_start,
            self.control_end,
            *acc,
        )

    @property
    def _interval_symbols(self) -> ca.SX:
        return ca.vertcat(self.state_next, self.input_previous)

    def _check_path(self, expression, what: str) -> ca.SX:
        expression = _sx(expression, what)
        if ca.depends_on(expression, self._point_symbols):
            raise ValueError(
                f"{what} must be an expression along the path (of x, u, y, t), "
                "not of at_start/at_end values or integrals"
            )
        if ca.depends_on(expression, self._interval_symbols):
            raise ValueError(
                f"{what} cannot use x_next or u_previous: they belong in subject_to(...) (constraints on each interval)"
            )
        return expression

    def input_before(self, value) -> None:
        """The input applied before the first interval, (nu,): `u_previous` on interval 0 takes `value`.

        A number or an expression of `parameter` values, e.g. the input a controller applied
        last: ``ocp.input_before(ocp.parameter("u_prev", nu))``. Needed by constraints on
        `u_previous` (an input rate limit).
        """
        value = _sx(value, "input_before(...)")
        if value.numel() == 1 and self.plant.nu > 1:
            value = ca.repmat(value, self.plant.nu, 1)
        if value.numel() != self.plant.nu:
            raise ValueError(f"input_before(...) needs {self.plant.nu} entries (one per input), got {value.numel()}")
        decisions = ca.vertcat(
            self._path_symbols, self._point_symbols, self._interval_symbols, self.param_vector, self.final_time
        )
        if ca.depends_on(value, decisions):
            raise ValueError("input_before(...) must be a number or an expression of parameter values")
        self.input_before_start = ca.vec(value)

    def at_start(self, expression) -> ca.SX:
        """`expression` of (x, u, t) evaluated at t = 0 (u: the first interval's input)."""
        expression = self._check_path(expression, "at_start(...)")
        return ca.substitute(
            expression, self._path_symbols, ca.vertcat(self.state_start, self.input_start, self.control_start, 0)
        )

    def at_end(self, expression) -> ca.SX:
        """`expression` of (x, u, t) evaluated at t = T (u: the last interval's input)."""
        expression = self._check_path(expression, "at_end(...)")
        return ca.substitute(
            expression,
            self._path_symbols,
            ca.vertcat(self.state_end, self.input_end, self.control_end, self.final_time),
        )

    def integral(self, integrand) -> ca.SX:
        """∫₀ᵀ integrand(x, u, p, t) dt, as a symbol for `minimize` and `subject_to`.

        Collocation integrates with the scheme's quadrature on its polynomial,
        multiple shooting with the same RK4 steps as the state.
        """
        return self._accumulate(integrand, "integral", False)

    def sum(self, summand, include_end: bool = False) -> ca.SX:
        """Σ_{k=0}^{N-1} summand(x_k, u_k, p, t_k) over the mesh points (plus k = N with `include_end`).

        A discrete-time stage cost, as MPC writes it; not scaled by the interval length.
        """
        return self._accumulate(summand, "sum", bool(include_end))

    def _accumulate(self, integrand, kind: str, include_end: bool) -> ca.SX:
        integrand = self._check_path(integrand, f"{kind}(...)")
        if integrand.numel() != 1:
            raise ValueError(f"{kind}(...) needs a scalar expression, got shape {integrand.shape}")
        symbol = ca.SX.sym(f"{kind}_{len(self.accumulated) + 1}")
        self.accumulated.append(Accumulated(symbol, integrand, kind, include_end))
        return symbol

    def bounded(self, lower, expression, upper) -> Bounded:
        """lower <= expression <= upper, for `subject_to` (Python cannot chain SX comparisons)."""
        return Bounded(lower, expression, upper)

    # ------------------------------------------------------------ the problem
    def minimize(self, objective) -> None:
        """Set the objective: a scalar of at_start/at_end values, integrals, sums, p and T."""
        objective = _sx(objective, "the objective")
        if objective.numel() != 1:
            raise ValueError(f"the objective must be a scalar, got shape {objective.shape}")
        if ca.depends_on(objective, ca.vertcat(self._path_symbols, self._interval_symbols)):
            raise ValueError(
                "the objective depends on the path (x, u, y or t): wrap that part in "
                "ocp.integral(...), ocp.sum(...), ocp.at_start(...) or ocp.at_end(...)"
            )
        self.objective = objective

    def maximize(self, objective) -> None:
        """Set the objective to maximize (minimizes its negative; the reported objective is that negative)."""
        self.minimize(-_sx(objective, "the objective"))

    def subject_to(
        self, constraint, *, label: str | None = None, include_start: bool = True, include_end: bool = True
    ) -> None:
        """Add constraints: an SX relation (``==``, ``<=``, ``>=``, elementwise on vectors),
        an `ocp.bounded(lo, e, hi)`, or a list of them.

        A constraint on (x, u, y, t) holds along the whole path (at every
        collocation point, or every shooting node); `include_start` and
        `include_end` drop it at t = 0 or t = T. A constraint that also uses
        `x_next` or `u_previous` holds once on each interval k = 0..N-1 (with
        the state at its end and the previous interval's input): a soft
        bound's slack paired with the next state, an input rate limit.
        Constraints on at_start/at_end values, integrals, p and T hold once.
        Each side may use `parameter` values; a side free of decisions
        becomes a bound. A bound that is NaN is refused (ValueError naming the constraint).
        `label` names the constraint in the solution's largest violation.
        """
        if isinstance(constraint, (list, tuple)):
            for item in constraint:
                self.subject_to(item, label=label, include_start=include_start, include_end=include_end)
            return
        relations = list(self._relations(constraint))
        for _, lower, upper, text in relations:  # all checked before any is added
            for side, bound in (("lower", lower), ("upper", upper)):
                if bound.is_constant() and np.isnan(float(bound)):
                    raise ValueError(
                        f"subject_to({label or text}): its {side} bound is NaN; a bound is a number, ±inf or "
                        "an expression of parameter values"
                    )
        for expression, lower, upper, text in relations:
            path = bool(ca.depends_on(expression, self._path_symbols)) or bool(
                ca.depends_on(ca.vertcat(lower, upper), self._path_symbols)
            )
            point = bool(ca.depends_on(ca.vertcat(expression, lower, upper), self._point_symbols))
            interval = bool(ca.depends_on(ca.vertcat(expression, lower, upper), self._interval_symbols))
            if (path or interval) and point:
                raise ValueError(
                    f"constraint {text} mixes the path (x, u, y, t) with at_start/at_end "
                    "values or integrals; write them as separate constraints"
                )
            self.constraints.append(
                Constraint(
                    expression,
                    lower,
                    upper,
                    label or text,
                    path or interval,
                    bool(include_start),
                    bool(include_end),
                    interval,
                )
            )

    def _relations(self, constraint):
        """(expression, lower, upper, text) per scalar relation; decision-free sides become bounds."""
        # Sides free of these are bounds (numbers and `parameter` values).
        decisions = ca.vertcat(
            self._path_symbols, self._point_symbols, self._interval_symbols, self.param_vector, self.final_time
        )
        inf = ca.SX(np.inf)
        if isinstance(constraint, Bounded):
            expression = _sx(constraint.expression, "bounded(...) expression")
            n = expression.numel()
            lower = _broadcast(_sx(constraint.lower, "bounded(...) lower"), n, "bounded(...) lower")
            upper = _broadcast(_sx(constraint.upper, "bounded(...) upper"), n, "bounded(...) upper")
            for i in range(n):
                text = _short(f"{lower[i]} <= {expression[i]} <= {upper[i]}")
                if ca.depends_on(ca.vertcat(lower[i], upper[i]), decisions):
                    yield expression[i] - lower[i], ca.SX(0), inf, text
                    yield expression[i] - upper[i], -inf, ca.SX(0), text
                else:
                    yield expression[i], lower[i], upper[i], text
            return
        if isinstance(constraint, (bool, np.bool_)) or not isinstance(constraint, (ca.SX, ca.DM)):
            raise ValueError(
                "subject_to needs an SX relation (==, <=, >=) of the problem's symbols or "
                f"ocp.bounded(lower, expression, upper), got {type(constraint).__name__} {constraint!r}"
            )
        constraint = ca.SX(constraint)
        for i in range(constraint.numel()):
            element = constraint[i]
            op = element.op() if element.n_dep() == 2 else None
            if op not in (ca.OP_EQ, ca.OP_LE, ca.OP_LT):
                raise ValueError(f"subject_to needs a relation (==, <=, >=), got {_short(str(element))}")
            left, right = element.dep(0), element.dep(1)
            text = _short(str(element))
            on_left, on_right = ca.depends_on(left, decisions), ca.depends_on(right, decisions)
            if on_left and not on_right:
                yield left, (right if op == ca.OP_EQ else -inf), right, text
            elif on_right and not on_left:
                yield right, left, (left if op == ca.OP_EQ else inf), text
            else:
                yield left - right, (ca.SX(0) if op == ca.OP_EQ else -inf), ca.SX(0), text

    # ----------------------------------------------------------------- solving
    def solver(self, transcription=None, **options):
        """Build the NLP once: an `OCPSolver` to solve with new parameter values and warm starts.

        transcription : `Collocation` (default: Radau, degree 3, 50 intervals) or `MultipleShooting`
        options : see `OCPSolver` (hessian, tolerance, max_iterations, ipopt_options, ...)
        """
        return OCPSolver(self, transcription, **options)

    def solve(
        self,
        transcription=None,
        *,
        refine_tolerance: float | None = None,
        max_refinements: int = 6,
        solver_options: dict | None = None,
        **solve_options,
    ):
        """Transcribe with `transcription` (default: see `solver`), solve once and return an `OCPSolution`.

        refine_tolerance : with collocation, halve the intervals whose collocation defect
            (see `mpc.mesh_refinement`) exceeds this many state units, re-solving
            from the interpolated answer, at most `max_refinements` times.
        solver_options : passed to `OCPSolver`; solve_options to `OCPSolver.solve`
            (x0, params, plant_params, guess, guess_input).
        """
        if refine_tolerance is not None:
            return solve_refined(
                self, transcription, refine_tolerance, max_refinements, solver_options or {}, solve_options
            )
        return self.solver(transcription, **(solver_options or {})).solve(**solve_options)

    def start_from(self, x0=None) -> ca.SX:
        """Fix the whole initial state to a parameter named "x0" (`OCPSolver.solve(x0=...)`).

        `x0` is its default value (nx,); returns the parameter symbol. The form MPC uses:
        the same NLP solved from a new state every sample.
        """
        symbol = self.parameter("x0", self.plant.nx, x0)
        self.subject_to(self.at_start(self.state) == symbol, label="initial state x(0) = x0")
        return symbol

    def check_complete(self) -> None:
        """Raise unless the problem has an objective."""
        if self.objective is None:
            raise ValueError(
                "the problem has no objective: call ocp.minimize(...) (or ocp.minimize(0) for a feasibility problem)"
            )


def _sx(value, what: str) -> ca.SX:
    if isinstance(value, ca.MX):
        raise ValueError(f"{what} must be built from the problem's SX symbols (ocp.x, ocp.u, ...), got an MX")
    try:
        return ca.SX(np.asarray(value, dtype=float)) if isinstance(value, (list, tuple, np.ndarray)) else ca.SX(value)
    except (NotImplementedError, TypeError, RuntimeError, ValueError) as err:
        raise ValueError(f"{what} must be a CasADi SX expression or a number, got {value!r}") from err


def _broadcast(value: ca.SX, n: int, what: str) -> ca.SX:
    if value.numel() == 1:
        return ca.repmat(value, n, 1)
    if value.numel() != n:
        raise ValueError(f"{what} has {value.numel()} entries, the expression {n}")
    return ca.vec(value)


def _values(value, size: int, what: str) -> np.ndarray:
    arr = (
        np.broadcast_to(np.asarray(value, dtype=float), (size,))
        if np.ndim(value) == 0
        else np.asarray(value, dtype=float).reshape(-1)
    )
    if arr.size != size or not np.all(np.isfinite(arr)):
        raise ValueError(f"{what} must be {size} finite numbers, got {value!r}")
    return arr.copy()


def _short(text: str) -> str:
    text = " ".join(text.split())
    return text if len(text) <= 80 else text[:77] + "..."
