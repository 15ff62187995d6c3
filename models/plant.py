"""Plants declared once by their energies; everything else derived.

A declaration is a function of symbolic namespaces (q, dq, u, p) returning a
`Physics` record; `declare` registers it. `Plant` turns the symbols into CasADi
Functions (dynamics, outputs, energy, Jacobians) and numeric helpers.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from types import SimpleNamespace
from typing import Callable, Mapping

import casadi as ca
import numpy as np

from .checks import as_vector
from .lagrangian import EquationsOfMotion, euler_lagrange
from .linear import LinearModel


@dataclass(frozen=True)
class Param:
    """A physical parameter: name, nominal value, SI unit.

    `positive=True` means the value must be > 0; otherwise it must be >= 0
    (damping, or masses a variant sets to zero).
    """

    name: str
    value: float
    unit: str
    description: str = ""
    positive: bool = True


@dataclass(frozen=True)
class Physics:
    """What a declaration returns, all CasADi SX.

    kinetic : T(q, q̇, p) in J;  potential : V(q, p) in J
    forces : generalized forces Q(q, q̇, u, p), one per coordinate
    outputs : mapping output name -> expression of (q, p)
    """

    kinetic: ca.SX
    potential: ca.SX
    forces: list
    outputs: Mapping[str, ca.SX]


@dataclass(frozen=True)
class Declaration:
    name: str
    title: str
    coordinates: tuple
    inputs: tuple
    params: tuple
    input_limit: tuple
    physics: Callable
    operating_point: Callable = field(default=lambda p: {})
    uncertain: tuple = ()


_REGISTRY: dict[str, Declaration] = {}


def declare(*, name: str, title: str, coordinates, inputs, params, input_limit,
            operating_point: Callable | None = None, uncertain=(), register: bool = True):
    """Decorator turning `physics(q, dq, u, p) -> Physics` into a plant declaration.

    Parameters
    ----------
    name : str
        Registry name used by `models.get`.
    coordinates, inputs : sequence of str
        Generalized coordinates q (state is (q, q̇)) and input names.
    params : sequence of Param
    input_limit : float or sequence of float
        Symmetric actuator limit |u_i| <= input_limit[i] on the total input.
    operating_point : callable p -> dict, optional
        The standard equilibrium's fixed coordinates as a function of the
        parameter namespace (for example the ball at the beam's middle).
    uncertain : sequence of str
        Parameters the case study says the controller knows only to ±5 %.
    register : bool
        False builds a declaration for a user's own plant without adding it
        to the registry; pass it to `Plant`.
    """

    def wrap(physics: Callable) -> Declaration:
        limit = tuple(float(v) for v in np.atleast_1d(input_limit))
        decl = Declaration(name, title, tuple(coordinates), tuple(inputs), tuple(params), limit,
                           physics, operating_point or (lambda p: {}), tuple(uncertain))
        _check_declaration(decl)
        if register:
            _REGISTRY[name] = decl
        return decl

    return wrap


def _check_declaration(decl: Declaration) -> None:
    names = [p.name for p in decl.params]
    for group, what in ((decl.coordinates, "coordinate"), (decl.inputs, "input"), (names, "parameter")):
        if len(set(group)) != len(group):
            raise ValueError(f"{decl.name}: repeated {what} name in {group}")
    if len(decl.input_limit) != len(decl.inputs):
        raise ValueError(f"{decl.name}: need one input limit per input {decl.inputs}")
    for name in decl.uncertain:
        if name not in names:
            raise ValueError(f"{decl.name}: uncertain parameter {name!r} is not declared")


def names() -> list[str]:
    """Names of the registered plants."""
    return list(_REGISTRY)


def declaration(name: str) -> Declaration:
    if name not in _REGISTRY:
        raise ValueError(f"unknown plant {name!r}; valid plants: {', '.join(_REGISTRY)}")
    return _REGISTRY[name]


_SYMBOLIC_CACHE: dict[str, "_Symbolic"] = {}


class _Symbolic:
    """The CasADi Functions of one declaration; shared by every Plant built from it."""

    def __init__(self, decl: Declaration):
        nq, nu = len(decl.coordinates), len(decl.inputs)
        q = ca.SX.sym("q", nq)
        dq = ca.SX.sym("dq", nq)
        u = ca.SX.sym("u", nu)
        p = ca.SX.sym("p", len(decl.params))
        ns = lambda vec, keys: SimpleNamespace(**{k: vec[i] for i, k in enumerate(keys)})
        phys = decl.physics(ns(q, decl.coordinates), ns(dq, decl.coordinates), ns(u, decl.inputs),
                            ns(p, [pp.name for pp in decl.params]))
        self.output_names = tuple(phys.outputs)
        y = ca.vertcat(*phys.outputs.values())
        if ca.depends_on(y, ca.vertcat(dq, u)):
            raise ValueError(f"{decl.name}: outputs must depend on the configuration q only")
        self.eom: EquationsOfMotion = euler_lagrange(q, dq, phys.kinetic, phys.potential, phys.forces)
        x = ca.vertcat(q, dq)
        xdot = ca.vertcat(dq, self.eom.accel)
        self.f = ca.Function("f", [x, u, p], [xdot], ["x", "u", "p"], ["xdot"])
        self.h = ca.Function("h", [x, p], [y], ["x", "p"], ["y"])
        self.energy = ca.Function("energy", [x, p], [phys.kinetic + phys.potential], ["x", "p"], ["E"])
        self.jacobians = ca.Function("jacobians", [x, u, p],
                                     [ca.jacobian(xdot, x), ca.jacobian(xdot, u), ca.jacobian(y, x)],
                                     ["x", "u", "p"], ["A", "B", "C"])
        # Configuration from outputs, when the outputs are linear in q and determine it.
        out_per_q = ca.jacobian(y, q)
        self.configuration = None
        if not ca.depends_on(out_per_q, ca.vertcat(q, p)) and y.numel() >= nq:
            cq = np.array(ca.DM(out_per_q))
            if np.linalg.matrix_rank(cq) == nq:
                offset = ca.substitute(y, q, ca.DM.zeros(nq))
                ys = ca.SX.sym("y", y.numel())
                q_of_y = ca.DM(np.linalg.pinv(cq)) @ (ys - offset)
                self.configuration = ca.Function("configuration", [ys, p], [q_of_y], ["y", "p"], ["q"])
        # Static balance at rest: accelerations as a function of (q, u), for equilibria.
        at_rest = ca.substitute(self.eom.accel, dq, ca.DM.zeros(nq))
        qu = ca.vertcat(q, u)
        self.static = ca.Function("static", [qu, p], [at_rest, ca.jacobian(at_rest, qu)])
        # Input that balances the static forces at configuration q (exact when
        # the balance is solvable, least squares otherwise); used as feedforward.
        static_force = ca.substitute(self.eom.forces - self.eom.gravity, dq, ca.DM.zeros(nq))
        force_per_input = ca.jacobian(static_force, u)
        if ca.depends_on(force_per_input, u):
            self.static_input = None
        else:
            residual = ca.substitute(static_force, u, ca.DM.zeros(nu))
            ue = -ca.solve(force_per_input.T @ force_per_input, force_per_input.T @ residual)
            self.static_input = ca.Function("static_input", [q, p], [ue], ["q", "p"], ["u"])


class Plant:
    """A declared plant with parameter values.

    Attributes
    ----------
    name, title : str
    coordinate_names, state_names, input_names, output_names : tuple of str
        States are (q, q̇); velocity names carry a ``d`` prefix (``dtheta``).
    params : dict
        Parameter values (SI), nominal unless overridden.
    param_info : tuple of Param
    input_limit : ndarray, (nu,)
        Symmetric actuator limit on the total input.
    casadi_f : casadi.Function (x, u, p) -> xdot
    casadi_h : casadi.Function (x, p) -> y
    """

    def __init__(self, decl: Declaration, params: Mapping[str, float] | None = None,
                 input_limit=None):
        self.declaration = decl
        if decl.name not in _SYMBOLIC_CACHE or _SYMBOLIC_CACHE[decl.name][0] is not decl:
            _SYMBOLIC_CACHE[decl.name] = (decl, _Symbolic(decl))
        self._sym: _Symbolic = _SYMBOLIC_CACHE[decl.name][1]
        self.name = decl.name
        self.title = decl.title
        self.param_info = decl.params
        self.coordinate_names = decl.coordinates
        self.state_names = decl.coordinates + tuple("d" + c for c in decl.coordinates)
        self.input_names = decl.inputs
        self.output_names = self._sym.output_names
        self.params = self._validated({p.name: p.value for p in decl.params} | dict(params or {}))
        limit = decl.input_limit if input_limit is None else np.broadcast_to(input_limit, (self.nu,))
        self.input_limit = np.array([self._check_limit(v) for v in limit])
        self.casadi_f = self._sym.f
        self.casadi_h = self._sym.h
        self.casadi_energy = self._sym.energy
        # Compiled functions of this plant (RK4 steps, simulators), shared by the simulators; public so
        # that models.simulate and models.closed_loop fill it without reaching into a private attribute.
        self.function_cache: dict = {}

    # ----------------------------------------------------------------- sizes
    @property
    def nq(self) -> int:
        return len(self.coordinate_names)

    @property
    def nx(self) -> int:
        return 2 * self.nq

    @property
    def nu(self) -> int:
        return len(self.input_names)

    @property
    def ny(self) -> int:
        return len(self.output_names)

    @property
    def n_params(self) -> int:
        return len(self.param_info)

    @property
    def uncertain_params(self) -> tuple:
        """Parameters the case study perturbs by ±5 % for the controller."""
        return self.declaration.uncertain

    def __repr__(self) -> str:
        vals = ", ".join(f"{k}={v:g}" for k, v in self.params.items())
        return f"Plant({self.name!r}, {vals}, input_limit={self.input_limit.tolist()})"

    # ------------------------------------------------------------ parameters
    def with_params(self, **overrides) -> "Plant":
        """A copy with some parameter values changed (validated)."""
        return Plant(self.declaration, self.params | overrides, self.input_limit)

    def with_input_limit(self, input_limit) -> "Plant":
        """A copy with another actuator limit (for example the UUV's 250 N m variant)."""
        return Plant(self.declaration, self.params, input_limit)

    def param_vector(self, params=None) -> np.ndarray:
        """Parameter values as the vector p the CasADi Functions take, (np,).

        `params` may be None (this plant's values), a dict of overrides, or a
        full vector.
        """
        if params is None:
            return np.array([self.params[p.name] for p in self.param_info])
        if isinstance(params, Mapping):
            merged = self._validated(self.params | dict(params))
            return np.array([merged[p.name] for p in self.param_info])
        vec = as_vector(params, self.n_params, f"{self.name} parameter vector")
        self._validated(dict(zip(self.params, vec)))
        return vec

    def _validated(self, values: dict) -> dict:
        info = {p.name: p for p in self.param_info}
        out = {}
        for key, value in values.items():
            if key not in info:
                raise ValueError(f"{self.name} has no parameter {key!r}; its parameters are "
                                 f"{', '.join(info)}")
            value = float(value)
            pinfo = info[key]
            if not np.isfinite(value) or value < 0 or (pinfo.positive and value == 0):
                need = "> 0" if pinfo.positive else ">= 0"
                raise ValueError(f"{self.name}: parameter {key} ({pinfo.unit}) must be finite and "
                                 f"{need}, got {value}")
            out[key] = value
        return out

    def _check_limit(self, value) -> float:
        value = float(value)
        if not np.isfinite(value) or value <= 0:
            raise ValueError(f"{self.name}: input_limit must be finite and > 0, got {value}")
        return value

    # -------------------------------------------------------------- numerics
    def f(self, x, u, params=None) -> np.ndarray:
        """State derivative xdot = f(x, u, p), (nx,), for one state (nx,) and input (nu,)."""
        x = as_vector(x, self.nx, f"{self.name} state {self.state_names}")
        u = as_vector(u, self.nu, f"{self.name} input {self.input_names}")
        return np.asarray(self.casadi_f(x, u, self.param_vector(params))).ravel()

    def output(self, x, params=None) -> np.ndarray:
        """Outputs y = h(x, p), (ny,)."""
        x = as_vector(x, self.nx, f"{self.name} state {self.state_names}")
        return np.asarray(self.casadi_h(x, self.param_vector(params))).ravel()

    def energy(self, x, params=None) -> float:
        """Total mechanical energy T + V in J at state x."""
        x = as_vector(x, self.nx, f"{self.name} state {self.state_names}")
        return float(self.casadi_energy(x, self.param_vector(params)))

    def equilibrium_input(self, q, params=None) -> np.ndarray:
        """Input holding the plant at rest at configuration q (feedforward), (nu,).

        Least squares when no input balances the static forces exactly; see
        `equilibrium` for a checked solve.
        """
        if self._sym.static_input is None:
            raise ValueError(f"{self.name}: the input enters the forces nonlinearly; "
                             "use equilibrium() instead")
        q = as_vector(q, self.nq, f"{self.name} configuration {self.coordinate_names}")
        return np.asarray(self._sym.static_input(q, self.param_vector(params))).ravel()

    @property
    def casadi_configuration(self) -> ca.Function:
        """CasADi Function (y, p) -> q recovering the configuration from the outputs.

        Exists when the outputs are linear in q and determine it (all the case
        studies: the satellite measures phi - theta, so phi = y[0] + y[1]).
        """
        if self._sym.configuration is None:
            raise ValueError(f"{self.name}: the outputs {self.output_names} do not determine the "
                             "configuration linearly")
        return self._sym.configuration

    def equilibrium_input_jacobian(self, q=None, params=None) -> np.ndarray:
        """∂u_e/∂q of `equilibrium_input`, (nu, nq), at q (default the standard operating point).

        The ball on beam's m1 g / ell on z; zero where gravity does not load the input.
        """
        q = self.equilibrium(params=params)[0][:self.nq] if q is None else \
            as_vector(q, self.nq, f"{self.name} configuration {self.coordinate_names}")
        qs = ca.SX.sym("q", self.nq)
        p = self.param_vector(params)
        jac = ca.Function("equilibrium_input_jacobian", [qs], [ca.jacobian(self.casadi_equilibrium_input(qs, p), qs)])
        return np.asarray(jac(q), dtype=float).reshape(self.nu, self.nq)

    @property
    def casadi_equilibrium_input(self) -> ca.Function:
        """CasADi Function (q, p) -> u of `equilibrium_input`, for controller blocks."""
        if self._sym.static_input is None:
            raise ValueError(f"{self.name}: the input enters the forces nonlinearly")
        return self._sym.static_input

    def equilibrium(self, params=None, tol: float = 1e-10, **fixed) -> tuple[np.ndarray, np.ndarray]:
        """Solve f(x, u) = 0 at rest with the named coordinates (or inputs) fixed.

        With nothing fixed, the declaration's standard operating point is used
        (for example the ball at the middle of the beam). Remaining unknowns
        start at zero; Gauss-Newton with minimum-norm steps picks the
        equilibrium nearest that start when several exist.

        Returns
        -------
        xe : ndarray, (nx,)   velocities are zero
        ue : ndarray, (nu,)

        Raises
        ------
        ValueError
            For an unknown name, or when no equilibrium has the fixed values.
        """
        p = self.param_vector(params)
        if not fixed:
            pns = SimpleNamespace(**dict(zip(self.params, p)))
            fixed = dict(self.declaration.operating_point(pns))
        unknown_names = self.coordinate_names + self.input_names
        for key, value in fixed.items():
            if key not in unknown_names:
                raise ValueError(f"{self.name}: cannot fix {key!r}; choose among coordinates "
                                 f"{self.coordinate_names} and inputs {self.input_names}")
            if not np.isfinite(float(value)):
                raise ValueError(f"{self.name}: fixed value {key}={value} is not finite")
        z = np.array([float(fixed.get(n, 0.0)) for n in unknown_names])
        free = np.array([n not in fixed for n in unknown_names])
        for _ in range(60):
            res, jac = (np.asarray(v) for v in self._sym.static(z, p))
            res = res.ravel()
            if np.max(np.abs(res)) < tol * 1e-3:
                break
            step = np.linalg.lstsq(jac[:, free], res, rcond=None)[0]
            z[free] -= step
            if np.max(np.abs(step)) < 1e-15:
                break
        res = np.asarray(self._sym.static(z, p)[0]).ravel()
        if not np.all(np.isfinite(z)) or np.max(np.abs(res)) > tol:
            worst = self.coordinate_names[int(np.argmax(np.abs(res)))]
            given = ", ".join(f"{k}={v:g}" for k, v in fixed.items())
            raise ValueError(f"{self.name}: no equilibrium with {given}: the acceleration of {worst} "
                             f"cannot vanish (residual {np.max(np.abs(res)):.3g} after Gauss-Newton)")
        return np.concatenate([z[:self.nq], np.zeros(self.nq)]), z[self.nq:]

    def linearize(self, xe=None, ue=None, params=None, check: bool = True) -> LinearModel:
        """Exact Jacobian linearization about (xe, ue).

        Without arguments, about the standard operating point `equilibrium()`.
        With `check`, raises unless f(xe, ue) = 0 (to 1e-8), because away
        from an equilibrium the linear model would miss a constant term.
        """
        if xe is None and ue is None:
            xe, ue = self.equilibrium(params=params)
        elif xe is None or ue is None:
            raise ValueError("give both xe and ue, or neither for the standard operating point")
        xe = as_vector(xe, self.nx, f"{self.name} state {self.state_names}")
        ue = as_vector(ue, self.nu, f"{self.name} input {self.input_names}")
        p = self.param_vector(params)
        if check:
            res = np.max(np.abs(self.f(xe, ue, p)))
            if res > 1e-8:
                raise ValueError(f"{self.name}: (xe, ue) is not an equilibrium (|f| = {res:.3g}); "
                                 "pass check=False to linearize anyway")
        A, B, C = (np.asarray(m, dtype=float) for m in self._sym.jacobians(xe, ue, p))
        return LinearModel(A=A, B=B, C=C, D=np.zeros((self.ny, self.nu)), xe=xe, ue=ue,
                           ye=self.output(xe, p), state_names=self.state_names,
                           input_names=self.input_names, output_names=self.output_names,
                           name=self.name)

    # ------------------------------------------------------------ simulation
    def step_function(self, sample_period: float, substeps: int = 10) -> ca.Function:
        """CasADi Function (x, u, p) -> x after `sample_period` s of RK4.

        `substeps` fixed RK4 steps with the input held; the expression is
        expanded to SX so a mapaccum over it runs in CasADi's fast VM.
        """
        key = (float(sample_period), int(substeps))
        if key not in self.function_cache:
            if not np.isfinite(sample_period) or sample_period <= 0:
                raise ValueError(f"sample_period must be > 0 s, got {sample_period}")
            if int(substeps) < 1:
                raise ValueError(f"substeps must be >= 1, got {substeps}")
            x = ca.SX.sym("x", self.nx)
            u = ca.SX.sym("u", self.nu)
            p = ca.SX.sym("p", self.n_params)
            h = sample_period / int(substeps)
            xs = x
            for _ in range(int(substeps)):
                k1 = self.casadi_f(xs, u, p)
                k2 = self.casadi_f(xs + h / 2 * k1, u, p)
                k3 = self.casadi_f(xs + h / 2 * k2, u, p)
                k4 = self.casadi_f(xs + h * k3, u, p)
                xs = xs + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
            # Common subexpressions repeat across the unrolled stages.
            self.function_cache[key] = ca.Function("rk4", [x, u, p], [ca.cse(xs)], ["x", "u", "p"], ["x_next"])
        return self.function_cache[key]


def get(name: str, input_limit=None, **overrides) -> Plant:
    """The registered plant `name` with parameter overrides, e.g. ``get("arm", m=0.6)``."""
    return Plant(declaration(name), overrides, input_limit)
