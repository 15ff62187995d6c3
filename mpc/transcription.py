"""One optimal control problem, transcribed into one sparse nonlinear program.

Both transcriptions split [0, T] into N intervals at mesh fractions
0 = s_0 < s_1 < ... < s_N = 1 (uniform unless given), t_k = s_k T,
h_k = t_{k+1} - t_k, and hold the input (and any extra control) constant on
each interval: the sample-and-hold a controller applies, and what
`OCPSolution.verify` re-simulates.

- `Collocation`: on interval k the state is the polynomial of degree d
  through x_k and d collocation states x_{k,1..d} at t_k + τ_j h_k, the
  Legendre-Gauss (``"legendre"``) or Legendre-Gauss-Radau (``"radau"``)
  points τ_j of (0, 1]. Its derivative equals f(x, u, p) at the collocation
  points, and x_{k+1} is the polynomial's value at τ = 1. Integrals use the
  points' quadrature weights. Accuracy at the mesh points: order 2d
  (Legendre) and 2d - 1 (Radau) in h.
- `MultipleShooting`: x_{k+1} = the plant's RK4 map over h_k (`substeps`
  steps, the same arithmetic as `Plant.step_function`, with h_k symbolic
  so T may be free), integrals integrated by the same RK4 steps.

The decision vector is ordered stage by stage, w = (x_0, [x_{0,1..d}], u_0,
c_0, x_1, ..., x_N, chosen parameters, T), each entry divided by its scale
(`OptimalControlProblem.scale`; inputs by the actuator limit). `Transcription`
exposes the NLP's pieces (`nlp`, `bounds`, `layout`, the row labels) so a
solver other than IPOPT, or a real-time iteration, can use them.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from models.integrators import rk4
from models.simulate import lagrange_basis, radau_matrices

POINTS = ("legendre", "radau")
MAX_DEGREE = 5


def _intervals(value) -> int:
    if isinstance(value, bool) or int(value) != value or value < 1:
        raise ValueError(f"intervals must be an integer >= 1, got {value}")
    return int(value)


def _mesh(mesh, intervals: int) -> tuple | None:
    if mesh is None:
        return None
    arr = np.asarray(mesh, dtype=float).reshape(-1)
    if (
        arr.size != intervals + 1
        or not np.all(np.isfinite(arr))
        or arr[0] != 0
        or arr[-1] != 1
        or np.any(np.diff(arr) <= 0)
    ):
        raise ValueError(f"mesh must be {intervals + 1} increasing fractions of T from 0 to 1, got {mesh}")
    return tuple(arr)


class _Meshed:
    """The mesh of a transcription's frozen dataclass: `intervals`, or `mesh` (N + 1 fractions of T)."""

    intervals: int
    mesh: tuple | None

    def _check_mesh(self) -> None:
        if self.mesh is not None:
            object.__setattr__(self, "intervals", len(np.asarray(self.mesh).reshape(-1)) - 1)
        object.__setattr__(self, "intervals", _intervals(self.intervals))
        object.__setattr__(self, "mesh", _mesh(self.mesh, self.intervals))

    @property
    def fractions(self) -> np.ndarray:
        """Mesh points as fractions of T, (N+1,)."""
        return np.linspace(0, 1, self.intervals + 1) if self.mesh is None else np.array(self.mesh)


@dataclass(frozen=True)
class Collocation(_Meshed):
    """Direct collocation on N intervals with `degree` points per interval (1-5).

    Attributes
    ----------
    points : "radau" (stiffly accurate, includes the interval's end) or "legendre" (Gauss)
    mesh : optional N + 1 increasing fractions of T from 0 to 1 (default uniform);
        when given, `intervals` is taken from it.
    """

    intervals: int = 50
    degree: int = 3
    points: str = "radau"
    mesh: tuple | None = None

    def __post_init__(self):
        self._check_mesh()
        if isinstance(self.degree, bool) or int(self.degree) != self.degree or not 1 <= self.degree <= MAX_DEGREE:
            raise ValueError(f"degree must be an integer from 1 to {MAX_DEGREE}, got {self.degree}")
        object.__setattr__(self, "degree", int(self.degree))
        if self.points not in POINTS:
            raise ValueError(f"points must be one of {', '.join(POINTS)}, got {self.points!r}")

    def with_mesh(self, fractions) -> Collocation:
        """The same collocation on the mesh `fractions` (N + 1 fractions of T from 0 to 1)."""
        return Collocation(degree=self.degree, points=self.points, mesh=tuple(fractions))


@dataclass(frozen=True)
class MultipleShooting(_Meshed):
    """Multiple shooting with the plant's RK4 map: `substeps` RK4 steps per interval, N intervals.

    `mesh`: N + 1 increasing fractions of T from 0 to 1 (then N follows from it), or None for a
    uniform mesh of `intervals`."""

    intervals: int = 50
    substeps: int = 1
    mesh: tuple | None = None

    def __post_init__(self):
        self._check_mesh()
        if isinstance(self.substeps, bool) or int(self.substeps) != self.substeps or self.substeps < 1:
            raise ValueError(f"substeps must be an integer >= 1, got {self.substeps}")
        object.__setattr__(self, "substeps", int(self.substeps))

    def with_mesh(self, fractions) -> MultipleShooting:
        """The same shooting on the mesh `fractions` (N + 1 fractions of T from 0 to 1)."""
        return MultipleShooting(substeps=self.substeps, mesh=tuple(fractions))


@dataclass(frozen=True)
class CollocationCoefficients:
    """The Lagrange polynomials through τ_0 = 0 and the collocation points τ_1..τ_d of (0, 1].

    tau : (d+1,);  derivative : (d+1, d), derivative[r, j] = ℓ_r'(τ_{j+1});
    continuity : (d+1,), ℓ_r(1);  quadrature : (d,), the points' weights on [0, 1].
    """

    tau: np.ndarray
    derivative: np.ndarray
    continuity: np.ndarray
    quadrature: np.ndarray


def collocation_coefficients(degree: int, points: str) -> CollocationCoefficients:
    """Coefficients of the collocation equations for `degree` Legendre or Radau points."""
    Collocation(degree=degree, points=points)  # validates
    if points == "radau":
        tau, derivative = radau_matrices(degree)  # the Radau simulator's own coefficients
    else:
        tau = np.array([0.0] + ca.collocation_points(degree, points))
        derivative = lagrange_basis(tau, tau[1:])[1].T.copy()
    values_at_one, _ = lagrange_basis(tau, [1.0])
    # The interpolatory quadrature on the points, sum_j w_j tau_j^k = 1/(k+1) for k < d (then exact to degree
    # 2d - 1 on Gauss points, 2d - 2 on Radau points).
    weights = np.linalg.solve(np.vander(tau[1:], increasing=True).T, 1.0 / np.arange(1, degree + 1))
    return CollocationCoefficients(tau, derivative, values_at_one[0], weights)


@dataclass(frozen=True)
class Layout:
    """Where each quantity sits in the decision vector w (indices into w).

    states : (N+1, nx) at the mesh points;  collocation : (N, d, nx) or (N, 0, nx)
    inputs : (N, nu);  controls : (N, nc);  chosen : name -> index;  final_time : index or None
    """

    states: np.ndarray
    collocation: np.ndarray
    inputs: np.ndarray
    controls: np.ndarray
    chosen: dict
    final_time: int | None
    size: int


@dataclass
class _Rows:
    """Constraint rows g with bounds (SX in the NLP parameters) and labels."""

    g: list = field(default_factory=list)
    lower: list = field(default_factory=list)
    upper: list = field(default_factory=list)
    labels: list = field(default_factory=list)

    def add(self, expressions, lower, upper, labels) -> None:
        """Append the rows `expressions` with bounds (scalars broadcast) and labels (one, or one per row)."""
        g = ca.vec(ca.SX(expressions))
        n = g.numel()
        fit = lambda b: ca.repmat(ca.SX(b), n, 1) if ca.SX(b).numel() == 1 else ca.vec(ca.SX(b))
        self.g.append(g)
        self.lower.append(fit(lower))
        self.upper.append(fit(upper))
        self.labels.extend(labels if isinstance(labels, list) else [labels] * n)


@dataclass
class _Symbols:
    """The NLP's symbols and the expressions every step of `Transcription` reads.

    w : scaled decisions (nw,);  P : NLP parameters;  p : the plant's parameter vector (chosen ones
    from w, fixed ones from P);  T : final time;  X : N + 1 mesh states;  XC : N lists of d
    collocation states;  U, C : N inputs and controls (physical);  t_mesh : N + 1 times;  h : N
    interval lengths;  user_symbols, user_values : the problem's parameters and their slices of P;
    path_in, path_names : inputs of a path Function (x, u, c, t, p, T, user parameters)
    """

    w: ca.SX
    P: ca.SX
    p: ca.SX
    T: ca.SX
    X: list
    XC: list
    U: list
    C: list
    t_mesh: list
    h: list
    user_symbols: list
    user_values: list
    path_in: list
    path_names: list

    def bound_of(self, expression):
        """`expression` (a bound, in the problem's parameter symbols) in the NLP parameters P."""
        if not self.user_symbols:
            return expression
        return ca.substitute(expression, ca.vertcat(*self.user_symbols), ca.vertcat(*self.user_values))


class DecisionBounds:
    """Simple bounds of the scaled decisions: numeric ones in arrays, those that are `parameter`
    values as SX per entry; several bounds on one entry give the tightest."""

    def __init__(self, scale: np.ndarray):
        self.scale = scale
        self.lower, self.upper = np.full(len(scale), -np.inf), np.full(len(scale), np.inf)
        self.lower_of_params: dict[int, ca.SX] = {}
        self.upper_of_params: dict[int, ca.SX] = {}

    def bound(self, indices, lower, upper) -> None:
        """lower <= decision <= upper (physical units) for the decisions `indices`."""
        indices, scale = np.atleast_1d(indices), self.scale
        for value, numeric, symbolic, pick in (
            (lower, self.lower, self.lower_of_params, ca.fmax),
            (upper, self.upper, self.upper_of_params, ca.fmin),
        ):
            value = ca.SX(value)
            if value.is_constant():
                combine = np.maximum if pick is ca.fmax else np.minimum
                numeric[indices] = combine(numeric[indices], float(value) / scale[indices])
            else:
                for i in indices:
                    symbolic[i] = pick(symbolic[i], value / scale[i]) if i in symbolic else value / scale[i]

    def expressions(self) -> tuple[ca.SX, ca.SX]:
        """(lbx, ubx) as SX in the NLP parameters."""
        lbx_all, ubx_all = ca.SX(ca.DM(self.lower)), ca.SX(ca.DM(self.upper))
        for i, value in self.lower_of_params.items():
            lbx_all[i] = ca.fmax(value, self.lower[i])
        for i, value in self.upper_of_params.items():
            ubx_all[i] = ca.fmin(value, self.upper[i])
        return lbx_all, ubx_all


class Transcription:
    """The NLP of an `OptimalControlProblem` on one mesh.

    Construction runs the steps in order: the decisions' layout and scales, the symbols, the
    dynamics (collocation or shooting rows), the accumulated sums and integrals, the simple bounds,
    the constraints (those that are bounds, then path, interval and point rows), the objective.

    Parameters
    ----------
    ocp : OptimalControlProblem
    method : Collocation or MultipleShooting
    chosen_as_parameters : treat the chosen plant parameters as given values (the inner
        problem of nested co-design) instead of decisions.

    Attributes
    ----------
    nlp : dict of SX  {"x": w (scaled decisions), "p": P (NLP parameters), "f": objective, "g": constraints}
    bounds : casadi.Function  P -> (lbx, ubx, lbg, ubg), bounds of the scaled w and of g
    layout : Layout;  scale : ndarray (nw,), physical value = scale * w
    constraint_labels : list of str, one per row of g;  decision_labels : one per entry of w
    dynamics_rows : (N, nx) rows of g holding the shooting gaps (x_{k+1} - F(x_k, u_k)) / scale,
        multiple shooting only (None for collocation)
    parameter_slices : name -> slice of P ("plant" for the fixed plant parameters)
    fixed_param_names, chosen_names : tuple of str
    mesh : ndarray (N+1,), mesh points as fractions of T
    """

    def __init__(self, ocp, method=None, *, chosen_as_parameters: bool = False):
        ocp.check_complete()
        method = Collocation() if method is None else method
        if not isinstance(method, (Collocation, MultipleShooting)):
            raise ValueError(f"transcription must be a Collocation or a MultipleShooting, got {method!r}")
        plant = ocp.plant
        self.ocp, self.method, self.plant = ocp, method, plant
        self.mesh = method.fractions
        self.intervals = method.intervals
        self.degree = method.degree if isinstance(method, Collocation) else 0
        chosen = {} if chosen_as_parameters else dict(ocp.chosen)
        self.chosen_names = tuple(chosen)
        self.fixed_param_names = tuple(p.name for p in plant.param_info if p.name not in chosen)
        self._points = method.points if isinstance(method, Collocation) else ""
        self.coefficients = collocation_coefficients(self.degree, self._points) if self.degree else None

        self._lay_out(chosen)
        self._scales(chosen)
        sym = self._symbols(chosen)
        rows = _Rows()
        integrals = [a for a in ocp.accumulated if a.kind == "integral"]
        integrand_fn = ca.Function(
            "integrands", sym.path_in, [ca.vertcat(*[a.integrand for a in integrals])], sym.path_names, ["L"]
        )
        fed_fn = ca.Function("plant_input", sym.path_in, [ocp.fed_input], sym.path_names, ["u_plant"])
        fed = [
            fed_fn(sym.X[k], sym.U[k], sym.C[k], sym.t_mesh[k], sym.p, sym.T, *sym.user_values)
            for k in range(self.intervals)
        ]
        self.dynamics_rows: np.ndarray | None = None  # set by _shooting_rows
        if self.degree:
            ends, integral_values = self._collocation_rows(sym, fed, integrand_fn, len(integrals), rows)
        else:
            ends, integral_values = self._shooting_rows(sym, fed, integrand_fn, len(integrals), rows)
        self._accumulate(sym, integral_values)

        bounds = DecisionBounds(self.scale)
        self._simple_bounds(bounds, chosen)
        general_path, general_point = self._constraints_as_bounds(sym, bounds, chosen)
        self._path_rows(sym, [c for c in general_path if not c.interval], rows)
        self._interval_rows(sym, [c for c in general_path if c.interval], ends, rows)
        objective = self._point_rows(sym, general_point, rows)

        g = ca.vertcat(*rows.g) if rows.g else ca.SX(0, 1)
        self.nlp = {"x": sym.w, "p": sym.P, "f": objective, "g": g}
        self.constraint_labels = rows.labels
        lbg = ca.vertcat(*rows.lower) if rows.lower else ca.SX(0, 1)
        ubg = ca.vertcat(*rows.upper) if rows.upper else ca.SX(0, 1)
        lbx_all, ubx_all = bounds.expressions()
        self.bounds = ca.Function("bounds", [sym.P], [lbx_all, ubx_all, lbg, ubg], ["P"], ["lbx", "ubx", "lbg", "ubg"])
        self.values = ca.Function(
            "values",
            [sym.w, sym.P],
            [objective, self.accumulated_values, sym.T, sym.p, g, ca.horzcat(*fed)],
            ["w", "P"],
            ["f", "accumulated", "T", "p", "g", "plant_inputs"],
        )

    # -------------------------------------------------------------------- construction steps
    def _lay_out(self, chosen: dict) -> None:
        """The decisions' order, stage by stage (`layout`), and a label for each (`decision_labels`)."""
        ocp, plant = self.ocp, self.plant
        N, d, nx, nu, nc = self.intervals, self.degree, plant.nx, plant.nu, len(ocp.controls)
        states, colloc = np.empty((N + 1, nx), int), np.empty((N, d, nx), int)
        inputs, controls = np.empty((N, nu), int), np.empty((N, nc), int)
        labels: list[str] = []
        counter = itertools.count()
        take = lambda n: np.array([next(counter) for _ in range(n)], dtype=int)
        for k in range(N):
            states[k] = take(nx)
            labels += [f"{n} at mesh point {k}" for n in plant.state_names]
            for j in range(d):
                colloc[k, j] = take(nx)
                labels += [f"{n} at interval {k} collocation point {j + 1}" for n in plant.state_names]
            inputs[k] = take(nu)
            labels += [f"{n} on interval {k}" for n in plant.input_names]
            controls[k] = take(nc)
            labels += [f"{n} on interval {k}" for n in ocp.controls]
        states[N] = take(nx)
        labels += [f"{n} at mesh point {N}" for n in plant.state_names]
        chosen_index = {name: int(take(1)[0]) for name in chosen}
        labels += [f"parameter {name}" for name in chosen]
        final_index = int(take(1)[0]) if ocp.free_time else None
        if final_index is not None:
            labels.append("final time T")
        self.layout = Layout(states, colloc, inputs, controls, chosen_index, final_index, next(counter))
        self.decision_labels = labels

    def _scales(self, chosen: dict) -> None:
        """Each decision's scale (`scale`; physical = scale * w): `OptimalControlProblem.scale`'s, else
        the actuator limit for inputs, the guess (or upper bound) for a chosen parameter, the guess
        for a free final time, and 1."""
        ocp, plant, layout = self.ocp, self.plant, self.layout
        state_scale = np.array([ocp.scales.get(n, 1.0) for n in plant.state_names])
        input_scale = np.array([ocp.scales.get(n, plant.input_limit[i]) for i, n in enumerate(plant.input_names)])
        control_scale = np.array([ocp.scales.get(n, 1.0) for n in ocp.controls])
        scale = np.ones(layout.size)
        scale[layout.states] = state_scale
        scale[layout.collocation] = state_scale
        scale[layout.inputs] = input_scale
        scale[layout.controls] = control_scale
        for name, index in layout.chosen.items():
            guess = chosen[name].guess
            scale[index] = ocp.scales.get(name, guess if guess > 0 else chosen[name].upper)
        if layout.final_time is not None:
            scale[layout.final_time] = ocp.free_time.guess
        self.scale = scale
        self.state_scale = state_scale

    def _symbols(self, chosen: dict) -> _Symbols:
        """w and P, and the physical quantities on the mesh in them (`_Symbols`); sets
        `parameter_slices`, `param_expression` and `final_time_expression`."""
        ocp, plant, layout, N, d = self.ocp, self.plant, self.layout, self.intervals, self.degree
        w = ca.SX.sym("w", layout.size)
        phys = w * ca.DM(self.scale)
        sizes = [len(self.fixed_param_names)] + [sym.numel() for sym, _ in ocp.parameters.values()]
        offsets = np.concatenate([[0], np.cumsum(sizes)]).astype(int)
        P = ca.SX.sym("P", int(offsets[-1]))
        self.parameter_slices = {"plant": slice(0, offsets[1])}
        for i, name in enumerate(ocp.parameters):
            self.parameter_slices[name] = slice(offsets[i + 1], offsets[i + 2])
        user_values = [P[self.parameter_slices[name]] for name in ocp.parameters]
        user_symbols = [sym for sym, _ in ocp.parameters.values()]
        fixed_pos = {name: i for i, name in enumerate(self.fixed_param_names)}
        p = ca.vertcat(
            *[phys[layout.chosen[q.name]] if q.name in chosen else P[fixed_pos[q.name]] for q in plant.param_info]
        )
        final = layout.final_time
        T = phys[final] if final is not None else ca.SX(ocp.fixed_final_time)
        self.final_time_expression = T
        self.param_expression = p
        t_mesh = [T * s for s in self.mesh]
        return _Symbols(
            w=w,
            P=P,
            p=p,
            T=T,
            X=[phys[layout.states[k]] for k in range(N + 1)],
            XC=[[phys[layout.collocation[k, j]] for j in range(d)] for k in range(N)],
            U=[phys[layout.inputs[k]] for k in range(N)],
            C=[phys[layout.controls[k]] for k in range(N)],
            t_mesh=t_mesh,
            h=[t_mesh[k + 1] - t_mesh[k] for k in range(N)],
            user_symbols=user_symbols,
            user_values=user_values,
            path_in=[ocp.state, ocp.input, ocp.control_vector, ocp.t, ocp.param_vector, ocp.final_time, *user_symbols],
            path_names=["x", "u", "c", "t", "p", "T", *ocp.parameters],
        )

    def _collocation_rows(self, sym: _Symbols, fed: list, integrand_fn, n_integrals: int, rows: _Rows):
        """The collocation and continuity rows of every interval; (each interval's end state by its
        polynomial, the integrals by the points' quadrature)."""
        plant, cc, d = self.plant, self.coefficients, self.degree
        assert cc is not None
        nx, f, state_scale = plant.nx, plant.casadi_f, self.state_scale
        xk, xc = ca.SX.sym("xk", nx), ca.SX.sym("xc", nx, d)
        uk, pk, hk = ca.SX.sym("u", plant.nu), ca.SX.sym("p", plant.n_params), ca.SX.sym("h")
        nodes = ca.horzcat(xk, xc)
        residual = ca.horzcat(
            *[(hk * f(xc[:, j], uk, pk) - nodes @ ca.DM(cc.derivative[:, j])) / state_scale for j in range(d)]
        )
        interval = ca.Function(
            "collocation_interval",
            [xk, xc, uk, pk, hk],
            [ca.vec(residual), nodes @ ca.DM(cc.continuity)],
            ["x", "xc", "u", "p", "h"],
            ["residual", "x_end"],
        )
        integral_values = ca.SX.zeros(n_integrals)
        ends = []  # the state at each interval's end as its own integration gives it (x_{k+1} when feasible)
        X, XC, U, C, h = sym.X, sym.XC, sym.U, sym.C, sym.h
        for k in range(self.intervals):
            res, x_end = interval(X[k], ca.horzcat(*XC[k]), fed[k], sym.p, h[k])
            ends.append(x_end)
            names = plant.state_names
            rows.add(res, 0, 0, [f"collocation of {n} on interval {k}, point {j + 1}" for j in range(d) for n in names])
            rows.add(
                (X[k + 1] - x_end) / state_scale, 0, 0, [f"continuity of {n} at mesh point {k + 1}" for n in names]
            )
            for j in range(d):
                tj = sym.t_mesh[k] + cc.tau[j + 1] * h[k]
                integral_values += (
                    h[k] * cc.quadrature[j] * integrand_fn(XC[k][j], U[k], C[k], tj, sym.p, sym.T, *sym.user_values)
                )
        return ends, integral_values

    def _shooting_rows(self, sym: _Symbols, fed: list, integrand_fn, n_integrals: int, rows: _Rows):
        """The shooting gap rows of every interval (`dynamics_rows`); (each interval's end state by
        its RK4 map, the integrals by the same steps)."""
        plant, N, nx = self.plant, self.intervals, self.plant.nx
        assert isinstance(self.method, MultipleShooting)
        step = rk4_interval(plant, integrand_fn, self.method.substeps)
        integral_values = ca.SX.zeros(n_integrals)
        ends = []
        dynamics_rows = np.empty((N, nx), int)
        X = sym.X
        for k in range(N):
            x_next, q = step(X[k], sym.U[k], fed[k], sym.C[k], sym.t_mesh[k], sym.h[k], sym.p, sym.T, *sym.user_values)
            ends.append(x_next)
            dynamics_rows[k] = len(rows.labels) + np.arange(nx)
            labels = [f"shooting gap of {n} at mesh point {k + 1}" for n in plant.state_names]
            rows.add((X[k + 1] - x_next) / self.state_scale, 0, 0, labels)
            integral_values += q
        self.dynamics_rows = dynamics_rows
        return ends, integral_values

    def _accumulate(self, sym: _Symbols, integral_values) -> None:
        """`accumulated_values`: each `ocp.accumulated` (sums over the mesh, the end included where
        asked, and the integrals) in its order."""
        ocp, N = self.ocp, self.intervals
        sums = [a for a in ocp.accumulated if a.kind == "sum"]
        summand_fn = ca.Function(
            "summands", sym.path_in, [ca.vertcat(*[a.integrand for a in sums])], sym.path_names, ["l"]
        )
        X, U, C = sym.X, sym.U, sym.C
        sum_values = ca.SX.zeros(len(sums))
        for k in range(N):
            sum_values += summand_fn(X[k], U[k], C[k], sym.t_mesh[k], sym.p, sym.T, *sym.user_values)
        if sums:
            end_terms = summand_fn(X[N], U[N - 1], C[N - 1], sym.T, sym.p, sym.T, *sym.user_values)
            sum_values += ca.vertcat(*[end_terms[i] if a.include_end else 0 for i, a in enumerate(sums)])
        accumulated_values = []
        counts = {"integral": 0, "sum": 0}
        for a in ocp.accumulated:
            source = integral_values if a.kind == "integral" else sum_values
            accumulated_values.append(source[counts[a.kind]])
            counts[a.kind] += 1
        self.accumulated_values = ca.vertcat(*accumulated_values)

    def _simple_bounds(self, bounds: DecisionBounds, chosen: dict) -> None:
        """The actuator limit, the controls' ranges, the chosen parameters' and the free time's."""
        ocp, plant, layout = self.ocp, self.plant, self.layout
        if ocp.actuator_limit:
            for i in range(plant.nu):
                bounds.bound(layout.inputs[:, i], -plant.input_limit[i], plant.input_limit[i])
        for i, (lo, hi) in enumerate(ocp.controls.values()):
            bounds.bound(layout.controls[:, i], lo, hi)
        for name, index in layout.chosen.items():
            bounds.bound(index, chosen[name].lower, chosen[name].upper)
        if layout.final_time is not None:
            bounds.bound(layout.final_time, ocp.free_time.lower, ocp.free_time.upper)

    def _constraints_as_bounds(self, sym: _Symbols, bounds: DecisionBounds, chosen: dict) -> tuple[list, list]:
        """Every constraint on one decision symbol alone becomes bounds (a path constraint on a state
        bounds it at every mesh and collocation point it covers); returns the rest, (path, point).

        Raises
        ------
        ValueError
            For a constraint on no decision of this problem.
        """
        ocp, layout, N = self.ocp, self.layout, self.intervals
        states, colloc, inputs, controls = layout.states, layout.collocation, layout.inputs, layout.controls
        path_targets = {}
        for kind, vector in (("state", ocp.state), ("input", ocp.input), ("control", ocp.control_vector)):
            for i, sym_i in enumerate(_elements(vector)):
                path_targets[sym_i.name()] = (sym_i, kind, i)
        point_targets = {}
        for vec, where in (
            (ocp.state_start, states[0]),
            (ocp.state_end, states[N]),
            (ocp.input_start, inputs[0]),
            (ocp.input_end, inputs[N - 1]),
            (ocp.control_start, controls[0]),
            (ocp.control_end, controls[N - 1]),
        ):
            for i, sym_i in enumerate(_elements(vec)):
                point_targets[sym_i.name()] = (sym_i, int(where[i]))
        for name, index in layout.chosen.items():
            point_targets[name] = (ocp.p[name], index)
        if layout.final_time is not None:
            point_targets["T"] = (ocp.final_time, layout.final_time)
        decisions = ca.vertcat(
            ocp._path_symbols,
            ocp._point_symbols,
            ocp._interval_symbols,
            *[ocp.p[n] for n in chosen],
            ocp.final_time if layout.final_time is not None else ca.SX(0, 1),
        )
        general_path, general_point = [], []
        for con in ocp.constraints:
            if not ca.depends_on(con.expression, decisions):
                raise ValueError(
                    f"constraint {con.label!r} involves no decision of this problem "
                    "(its value is fixed by the parameters)"
                )
            lower, upper = sym.bound_of(con.lower), sym.bound_of(con.upper)
            target = con.expression.name() if con.expression.is_symbolic() else None
            if con.path and target in path_targets and ca.is_equal(con.expression, path_targets[target][0]):
                _, kind, i = path_targets[target]
                if kind == "state":
                    first, last = (0 if con.include_start else 1), (N if con.include_end else N - 1)
                    bounds.bound(states[first : last + 1, i], lower, upper)
                    inner = colloc[:, :, i].ravel()
                    if self._points == "radau" and not con.include_end:
                        inner = inner[:-1]  # Radau's last point of the last interval is x_N
                    bounds.bound(inner, lower, upper)
                else:
                    bounds.bound((inputs if kind == "input" else controls)[:, i], lower, upper)
            elif not con.path and target in point_targets and ca.is_equal(con.expression, point_targets[target][0]):
                bounds.bound(point_targets[target][1], lower, upper)
            elif con.path:
                general_path.append(con)
            else:
                general_point.append(con)
        return general_path, general_point

    def _path_rows(self, sym: _Symbols, constraints: list, rows: _Rows) -> None:
        """The rows of general path constraints at every mesh point they cover and at the collocation
        points inside the intervals."""
        if not constraints:
            return
        ocp, N, d = self.ocp, self.intervals, self.degree
        tau_nodes = self.coefficients.tau if self.coefficients is not None else np.zeros(1)
        path_fn = ca.Function(
            "path_constraints", sym.path_in, [ca.vertcat(*[c.expression for c in constraints])], sym.path_names, ["g"]
        )
        lows = ca.vertcat(*[sym.bound_of(c.lower) for c in constraints])
        highs = ca.vertcat(*[sym.bound_of(c.upper) for c in constraints])
        free_time = self.layout.final_time is not None
        where = "of T" if free_time else "s"
        X, XC, U, C, args = sym.X, sym.XC, sym.U, sym.C, (sym.p, sym.T, *sym.user_values)
        for k in range(N + 1):
            uk, ck = (U[k], C[k]) if k < N else (U[N - 1], C[N - 1])
            keep = [
                i
                for i, c in enumerate(constraints)
                if not ((k == 0 and not c.include_start) or (k == N and not c.include_end))
            ]
            if keep:
                values = path_fn(X[k], uk, ck, sym.t_mesh[k], *args)
                at = self.mesh[k] * (1 if free_time else ocp.fixed_final_time)
                rows.add(
                    ca.vertcat(*[values[i] for i in keep]),
                    ca.vertcat(*[lows[i] for i in keep]),
                    ca.vertcat(*[highs[i] for i in keep]),
                    [f"{constraints[i].label} at mesh point {k} (t = {at:.4g} {where})" for i in keep],
                )
            if k < N:
                interior = range(d - 1) if self._points == "radau" else range(d)
                for j in interior:
                    tj = sym.t_mesh[k] + tau_nodes[j + 1] * sym.h[k]
                    values = path_fn(XC[k][j], U[k], C[k], tj, *args)
                    labels = [f"{c.label} on interval {k}, collocation point {j + 1}" for c in constraints]
                    rows.add(values, lows, highs, labels)

    def _interval_rows(self, sym: _Symbols, constraints: list, ends: list, rows: _Rows) -> None:
        """The rows of interval constraints (on x_next and u_previous), once per interval.

        On interval k, x_next is the state its integration ends in (equal to x_{k+1} at a feasible
        point) so that each row involves the decisions of interval k alone, the stage structure a
        Riccati or condensing QP solver wants; u_previous is u_{k-1}.
        """
        if not constraints:
            return
        ocp, plant, U = self.ocp, self.plant, sym.U
        expressions = ca.vertcat(*[c.expression for c in constraints])
        uses_previous = ca.depends_on(expressions, ocp.input_previous)
        if uses_previous and ocp.input_before_start is None:
            raise ValueError(
                "a constraint uses u_previous: give the input before the first interval with ocp.input_before(...)"
            )
        before = sym.bound_of(ocp.input_before_start) if uses_previous else ca.SX.zeros(plant.nu)
        interval_fn = ca.Function(
            "interval_constraints",
            [*sym.path_in, ocp.state_next, ocp.input_previous],
            [expressions],
            [*sym.path_names, "x_next", "u_previous"],
            ["g"],
        )
        lows = ca.vertcat(*[sym.bound_of(c.lower) for c in constraints])
        highs = ca.vertcat(*[sym.bound_of(c.upper) for c in constraints])
        for k in range(self.intervals):
            values = interval_fn(
                sym.X[k],
                U[k],
                sym.C[k],
                sym.t_mesh[k],
                sym.p,
                sym.T,
                *sym.user_values,
                ends[k],
                U[k - 1] if k else before,
            )
            rows.add(values, lows, highs, [f"{c.label} on interval {k}" for c in constraints])

    def _point_rows(self, sym: _Symbols, constraints: list, rows: _Rows) -> ca.SX:
        """The rows of point constraints (on the start, the end, accumulated values, parameters and
        T); returns the objective, a Function of the same point values."""
        ocp, N = self.ocp, self.intervals
        point_in = [
            ocp.state_start,
            ocp.state_end,
            ocp.input_start,
            ocp.input_end,
            ocp.control_start,
            ocp.control_end,
            ca.vertcat(*[a.symbol for a in ocp.accumulated]),
            ocp.param_vector,
            ocp.final_time,
            *sym.user_symbols,
        ]
        X, U, C = sym.X, sym.U, sym.C
        point_args = [
            X[0],
            X[N],
            U[0],
            U[N - 1],
            C[0],
            C[N - 1],
            self.accumulated_values,
            sym.p,
            sym.T,
            *sym.user_values,
        ]
        if constraints:
            point_fn = ca.Function("point_constraints", point_in, [ca.vertcat(*[c.expression for c in constraints])])
            rows.add(
                point_fn(*point_args),
                ca.vertcat(*[sym.bound_of(c.lower) for c in constraints]),
                ca.vertcat(*[sym.bound_of(c.upper) for c in constraints]),
                [c.label for c in constraints],
            )
        return ca.Function("objective", point_in, [ocp.objective])(*point_args)

    # -------------------------------------------------------------------- helpers
    def parameter_values(self, x0=None, params=None, plant_params=None) -> np.ndarray:
        """The NLP parameter vector P from defaults and overrides.

        Parameters
        ----------
        x0 : the initial state, for a problem with `start_from`
        params : name -> value of the parameters declared by `OptimalControlProblem.parameter`
        plant_params : name -> value of fixed plant parameters (default: the plant's)
        """
        ocp = self.ocp
        values = dict(params or {})
        for name in values:
            if name not in ocp.parameters:
                raise ValueError(
                    f"params: the problem has no parameter {name!r}; its parameters are "
                    f"{', '.join(ocp.parameters) or 'none'}"
                )
        if x0 is not None:
            if "x0" not in ocp.parameters:
                raise ValueError(
                    "x0 given, but the problem has no start_from(): call ocp.start_from() to make the "
                    "initial state a parameter"
                )
            values["x0"] = x0
        if plant_params:
            for name in plant_params:
                if name not in self.fixed_param_names:
                    raise ValueError(
                        f"plant_params: {name!r} is not a fixed parameter of {self.plant.name}; "
                        f"fixed parameters are {', '.join(self.fixed_param_names)}"
                    )
        full = self.plant.param_vector(dict(plant_params or {}))
        index = {q.name: i for i, q in enumerate(self.plant.param_info)}
        out = np.empty(self.nlp["p"].numel())
        out[self.parameter_slices["plant"]] = [full[index[n]] for n in self.fixed_param_names]
        for name, (sym, default) in ocp.parameters.items():
            value = values.get(name, default)
            if value is None:
                raise ValueError(f"params: parameter {name!r} has no default; give its value")
            arr = np.asarray(value, dtype=float).reshape(-1)
            if arr.size == 1 and sym.numel() > 1:
                arr = np.full(sym.numel(), arr[0])
            if arr.size != sym.numel() or not np.all(np.isfinite(arr)):
                raise ValueError(f"params: {name!r} needs {sym.numel()} finite values, got {value!r}")
            out[self.parameter_slices[name]] = arr
        return out


def rk4_interval(plant, integrands: ca.Function, substeps: int) -> ca.Function:
    """RK4 over one interval of symbolic length h, with the integrands integrated alongside.

    integrands : Function (x, u, c, t, p, T, user parameters...) -> L (nL,)
    Returns the Function (x, u, u_plant, c, t0, h, p, T, user parameters...) -> (x after h,
    ∫ L dt over h): `substeps` steps of `models.integrators.rk4` (as `Plant.step_function`) with the
    plant fed u_plant, h an input so the final time may be free and the mesh non-uniform.
    """
    x, u, fed = ca.SX.sym("x", plant.nx), ca.SX.sym("u", plant.nu), ca.SX.sym("u_plant", plant.nu)
    c = ca.SX.sym("c", integrands.size1_in(2))
    t0, h, p, T = ca.SX.sym("t0"), ca.SX.sym("h"), ca.SX.sym("p", plant.n_params), ca.SX.sym("T")
    user_names = [integrands.name_in(i) for i in range(6, integrands.n_in())]
    user = [ca.SX.sym(name, integrands.size1_in(6 + i)) for i, name in enumerate(user_names)]
    nx = plant.nx

    def rate(z, t):  # the state and the running integrals together; the integrands read the state only
        xs = z[:nx]
        return ca.vertcat(plant.casadi_f(xs, fed, p), integrands(xs, u, c, t, p, T, *user))

    z = rk4(rate, ca.vertcat(x, ca.SX.zeros(integrands.size1_out(0))), h, substeps, t0)
    xs, q = z[:nx], z[nx:]
    return ca.Function(
        "rk4_interval",
        [x, u, fed, c, t0, h, p, T, *user],
        [ca.cse(xs), ca.cse(q)],
        ["x", "u", "u_plant", "c", "t0", "h", "p", "T", *user_names],
        ["x_next", "integrals"],
    )


def _elements(vector: ca.SX) -> list:
    return [vector[i] for i in range(vector.numel())]
