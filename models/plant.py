"""Plants declared once by their energies; everything else derived.

A declaration is a function of symbolic namespaces (q, dq, u, p) returning a
`Physics` record, or (q, dq, u, p, s) when the plant also has first-order
states s with their own equations (a motor current, an actuator lag, a
thermal state); `declare` registers it. `Plant` turns the symbols into
CasADi Functions (dynamics, outputs, energy, Jacobians) and numeric helpers.

State order: the coordinates q, then their rates q̇, then the first-order
states s, so x = (q, q̇, s) and nx = 2 nq + ns. Either part may be empty: a
purely first-order plant has no coordinates.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from .checks import as_vector, boolean, integer, positive, real, real_array
from .integrators import rk4
from .lagrangian import EquationsOfMotion, euler_lagrange
from .linear import LinearModel
from .physics import Physics as Physics
from .physics import check_finite, check_mass_matrix, checked_physics, namespaces, parameter_values


@dataclass(frozen=True)
class Param:
    """A physical parameter: name, nominal value, SI unit.

    `positive=True` means the value must be > 0; otherwise it must be >= 0
    (damping, or masses a variant sets to zero). `description` says what it is, in words.
    """

    name: str
    value: float
    unit: str
    description: str = ""
    positive: bool = True


@dataclass(frozen=True)
class Declaration:
    """A plant as `declare` records it: names, parameters, limits and the physics function.

    Attributes
    ----------
    name, title : the registry name and a one-line description
    coordinates, inputs, first_order : names of q, u and s
    params : tuple of Param
    input_limit : (nu,) symmetric actuator limits
    physics : (q, dq, u, p[, s]) -> Physics
    operating_point : p -> dict of the standard equilibrium's fixed values
    uncertain : names of the parameters the controller knows only to ±5 %
    """

    name: str
    title: str
    coordinates: tuple
    inputs: tuple
    params: tuple
    input_limit: tuple
    physics: Callable
    operating_point: Callable = field(default=lambda p: {})
    uncertain: tuple = ()
    first_order: tuple = ()


_REGISTRY: dict[str, Declaration] = {}


def declare(
    *,
    name: str,
    title: str,
    coordinates,
    inputs,
    params,
    input_limit,
    operating_point: Callable | None = None,
    uncertain=(),
    first_order=(),
    register: bool = True,
    replace: bool = False,
):
    """Decorator turning `physics(q, dq, u, p) -> Physics` into a plant declaration.

    Parameters
    ----------
    name : str
        Registry name used by `models.get`, and the name of the plant's folders and files: a safe
        identifier (a letter, then ASCII letters, digits or underscores, at most 64 characters).
    title : str
        Free text describing the plant (shown in tables and pages, escaped there).
    coordinates, inputs : sequence of str
        Generalized coordinates q and input names; q may be empty for a purely
        first-order plant.
    params : sequence of Param
    input_limit : float or sequence of float
        Symmetric actuator limit ``|u_i|`` <= input_limit[i] on the total input.
    operating_point : callable p -> dict, optional
        The standard equilibrium's fixed coordinates (or first-order states,
        or inputs) as a function of the parameter namespace (for example the
        ball at the beam's middle).
    uncertain : sequence of str
        Parameters the case study says the controller knows only to ±5 %.
    first_order : sequence of str
        First-order states s; the physics function then takes a fifth
        namespace, ``physics(q, dq, u, p, s)``, and gives ṡ in `Physics.rates`.
        The state is x = (q, q̇, s).
    register : bool
        False builds a declaration for a user's own plant without adding it
        to the registry; pass it to `Plant`.
    replace : bool
        Allow `register` to replace a plant already registered under `name`
        (refused otherwise, so a user plant cannot silently shadow a case study).
    """
    plant_name(name)
    _check_name(title, f"{name}: title")
    register, replace = boolean(register, "register"), boolean(replace, "replace")
    coordinates = _names(coordinates, f"{name}: coordinates")
    inputs = _names(inputs, f"{name}: inputs")
    first_order = _names(first_order, f"{name}: first_order")
    params = tuple(params) if isinstance(params, (list, tuple)) else params
    if not isinstance(params, tuple) or not all(isinstance(p, Param) for p in params):
        raise TypeError(f"{name}: params must be a sequence of models.Param, got {params!r}")
    uncertain = _names(uncertain, f"{name}: uncertain")
    limit = tuple(_limit_vector(input_limit, len(inputs), f"{name}: input_limit", inputs))
    if operating_point is not None and not callable(operating_point):
        raise TypeError(f"{name}: operating_point must be a callable p -> dict, got {operating_point!r}")

    def wrap(physics: Callable) -> Declaration:
        # The declaration of `physics`, checked, and registered unless register=False.
        if not callable(physics):
            raise TypeError(f"{name}: declare(...) decorates a physics function, got {physics!r}")
        decl = Declaration(
            name,
            title,
            coordinates,
            inputs,
            params,
            limit,
            physics,
            operating_point or (lambda p: {}),
            uncertain,
            first_order,
        )
        _check_declaration(decl)
        if register:
            if name in _REGISTRY and not replace:
                raise ValueError(
                    f"a plant named {name!r} is already registered ({_REGISTRY[name].title}); "
                    "pass replace=True to replace it, or register=False for a plant of your own"
                )
            _REGISTRY[name] = decl
        return decl

    return wrap


#: A plant's name: it becomes a folder name, a part of C identifiers and of page anchors.
PLANT_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_]{0,63}")


def plant_name(value) -> str:
    """`value` if it is a safe plant name: a letter, then letters, digits or underscores (ASCII), at most
    64 characters. TypeError for a non-string, ValueError naming the rule otherwise."""
    _check_name(value, "name")
    if not PLANT_NAME.fullmatch(value):
        raise ValueError(
            "name must be a safe identifier (a letter, then letters, digits or underscores, ASCII, at most 64 "
            f"characters; free text goes in title), got {value!r}"
        )
    return value


def _check_name(value, what: str) -> str:
    """`value` if it is a non-empty string, else TypeError naming `what`."""
    if not isinstance(value, str) or not value:
        raise TypeError(f"{what} must be a non-empty string, got {value!r}")
    return value


def _names(values, what: str) -> tuple:
    """A tuple of non-empty strings; a bare string is refused (it would be split into letters)."""
    if isinstance(values, str) or not isinstance(values, (list, tuple)):
        raise TypeError(f"{what} must be a list or tuple of names, got {values!r}")
    for value in values:
        _check_name(value, f"{what} entry")
    return tuple(values)


def _limit_vector(value, size: int, what: str, inputs) -> np.ndarray:
    """Input limits as (size,) floats, each finite and > 0: one number for all, or one per input."""
    arr = real_array(value, what)
    if arr.ndim == 0:
        arr = np.full(size, float(arr))
    elif arr.shape != (size,):
        raise ValueError(f"{what} must be one number for every input or one per input {tuple(inputs)}, got {value!r}")
    for entry in arr:
        if not np.isfinite(entry) or entry <= 0:
            raise ValueError(f"{what} must be finite and > 0, got {entry:g}")
    return arr


def _check_declaration(decl: Declaration) -> None:
    """Refuse repeated names, a plant without states, an undeclared uncertain parameter and a parameter
    value out of its range (ValueError naming the plant and what is wrong)."""
    names = [p.name for p in decl.params]
    states = decl.coordinates + tuple("d" + c for c in decl.coordinates) + decl.first_order
    for group, what in (
        (decl.coordinates, "coordinate"),
        (decl.inputs, "input"),
        (names, "parameter"),
        (states, "state"),
    ):
        if len(set(group)) != len(group):
            raise ValueError(f"{decl.name}: repeated {what} name in {group}")
    if not states:
        raise ValueError(f"{decl.name}: declare at least one coordinate or first-order state")
    for name in decl.uncertain:
        if name not in names:
            raise ValueError(f"{decl.name}: uncertain parameter {name!r} is not declared")
    for p in decl.params:
        _check_name(p.name, f"{decl.name}: Param name")
        value = real(p.value, f"{decl.name}: Param {p.name} value", finite=False)
        if not np.isfinite(value) or value < 0 or (p.positive and value == 0):
            raise ValueError(
                f"{decl.name}: Param {p.name} ({p.unit}) must be finite and "
                f"{'> 0' if p.positive else '>= 0'}, got {value}"
            )


def names() -> list[str]:
    """Names of the registered plants."""
    return list(_REGISTRY)


def declaration(name: str) -> Declaration:
    """The registered declaration called `name` (ValueError listing the registered plants otherwise)."""
    _check_name(name, "plant name")
    if name not in _REGISTRY:
        raise ValueError(f"unknown plant {name!r}; valid plants: {', '.join(_REGISTRY)}")
    return _REGISTRY[name]


_SYMBOLIC_CACHE: dict[str, tuple[Declaration, _Symbolic]] = {}


class _Symbolic:
    """The CasADi Functions of one declaration; shared by every Plant built from it."""

    def __init__(self, decl: Declaration):
        nq, nu, ns = len(decl.coordinates), len(decl.inputs), len(decl.first_order)
        q = ca.SX.sym("q", nq)
        dq = ca.SX.sym("dq", nq)
        u = ca.SX.sym("u", nu)
        p = ca.SX.sym("p", len(decl.params))
        s = ca.SX.sym("s", ns)
        phys = decl.physics(*namespaces(decl, q, dq, u, p, s))
        kinetic, potential, forces, outputs, rates = checked_physics(decl, phys)
        check_finite(
            decl,
            {"the kinetic energy": kinetic, "the potential energy": potential}
            | {f"the generalized force of {c!r}": f for c, f in zip(decl.coordinates, forces)}
            | {f"the output {k!r}": e for k, e in outputs.items()}
            | {f"the first-order equation of {k!r}": rates[i] for i, k in enumerate(decl.first_order)},
        )
        self.output_names = tuple(outputs)
        y = ca.vertcat(*outputs.values()) if outputs else ca.SX(0, 1)
        if ca.depends_on(y, u):
            raise ValueError(
                f"{decl.name}: outputs must not depend on the inputs "
                f"({', '.join(n for n, e in outputs.items() if ca.depends_on(e, u))} do)"
            )
        if ns and ca.depends_on(kinetic, s):
            raise ValueError(
                f"{decl.name}: the kinetic energy must not depend on the first-order states "
                f"{decl.first_order} (the Euler-Lagrange derivation would miss their rates)"
            )
        try:
            self.eom: EquationsOfMotion = euler_lagrange(q, dq, kinetic, potential, forces, decl.coordinates)
        except ValueError as err:
            raise ValueError(f"{decl.name}: {err}") from None
        if nq:
            check_mass_matrix(decl, self.eom.mass_matrix, q, p)
        x = ca.vertcat(q, dq, s)
        xdot = ca.vertcat(dq, self.eom.accel, rates)
        self.f = ca.Function("f", [x, u, p], [xdot], ["x", "u", "p"], ["xdot"])
        self.h = ca.Function("h", [x, p], [y], ["x", "p"], ["y"])
        self.energy = ca.Function("energy", [x, p], [kinetic + potential], ["x", "p"], ["E"])
        self.jacobians = ca.Function(
            "jacobians",
            [x, u, p],
            [ca.jacobian(xdot, x), ca.jacobian(xdot, u), ca.jacobian(y, x)],
            ["x", "u", "p"],
            ["A", "B", "C"],
        )
        # Configuration from the outputs that depend on q alone, when those are
        # linear in q and determine it.
        rows = [i for i in range(y.numel()) if not ca.depends_on(y[i], ca.vertcat(dq, s))]
        y_q = y if len(rows) == y.numel() else y[rows]
        out_per_q = ca.jacobian(y_q, q)
        self.configuration = None
        if nq and not ca.depends_on(out_per_q, ca.vertcat(q, p)) and y_q.numel() >= nq:
            cq = np.array(ca.DM(out_per_q))
            if np.linalg.matrix_rank(cq) == nq:
                offset = ca.substitute(y_q, q, ca.DM.zeros(nq))
                ys = ca.SX.sym("y", y.numel())
                ys_q = ys if len(rows) == y.numel() else ys[rows]
                q_of_y = ca.DM(np.linalg.pinv(cq)) @ (ys_q - offset)
                self.configuration = ca.Function("configuration", [ys, p], [q_of_y], ["y", "p"], ["q"])
        # Static balance at rest (q̇ = 0): accelerations and first-order rates as
        # a function of the unknowns (q, s, u), for equilibria.
        at_rest = ca.substitute(ca.vertcat(self.eom.accel, rates), dq, ca.DM.zeros(nq))
        unknowns = ca.vertcat(q, s, u)
        self.static = ca.Function("static", [unknowns, p], [at_rest, ca.jacobian(at_rest, unknowns)])
        # Input that balances the static forces at configuration q (exact when
        # the balance is solvable, least squares otherwise); used as feedforward.
        # With first-order states the balance also asks ṡ = 0, solved for (s, u).
        static_force = ca.substitute(self.eom.forces - self.eom.gravity, dq, ca.DM.zeros(nq))
        if ns:
            static_force = ca.vertcat(static_force, ca.substitute(rates, dq, ca.DM.zeros(nq)))
        balance_unknowns = ca.vertcat(s, u)
        force_per_input = ca.jacobian(static_force, balance_unknowns)
        if ca.depends_on(force_per_input, balance_unknowns):
            self.static_input = None
        else:
            residual = ca.substitute(static_force, balance_unknowns, ca.DM.zeros(ns + nu))
            balance = -ca.solve(force_per_input.T @ force_per_input, force_per_input.T @ residual)
            self.static_input = ca.Function("static_input", [q, p], [balance[ns:]], ["q", "p"], ["u"])


class Plant:
    """A declared plant with parameter values.

    Built from `decl`, a `Declaration` (the energies, coordinates and inputs; see `models.catalog`),
    with `params` overriding its nominal values and `input_limit` its actuator limit.

    Attributes
    ----------
    name, title : str
    coordinate_names, first_order_names, state_names, input_names, output_names : tuple of str
        States are (q, q̇, s): coordinates, their rates (names with a ``d``
        prefix, ``dtheta``), then the first-order states.
    params : dict
        Parameter values (SI), nominal unless overridden.
    param_info : tuple of Param
    input_limit : ndarray, (nu,)
        Symmetric actuator limit on the total input.
    casadi_f : casadi.Function (x, u, p) -> xdot
    casadi_h : casadi.Function (x, p) -> y
    """

    def __init__(self, decl: Declaration, params: Mapping[str, float] | None = None, input_limit=None):
        if not isinstance(decl, Declaration):
            raise TypeError(f"Plant needs a declaration made by models.declare, got {type(decl).__name__} {decl!r}")
        if params is not None and not isinstance(params, Mapping):
            raise TypeError(f"{decl.name}: params must be a mapping name -> value, got {params!r}")
        self.declaration = decl
        if decl.name not in _SYMBOLIC_CACHE or _SYMBOLIC_CACHE[decl.name][0] is not decl:
            _SYMBOLIC_CACHE[decl.name] = (decl, _Symbolic(decl))
        self._sym: _Symbolic = _SYMBOLIC_CACHE[decl.name][1]
        self.name = decl.name
        self.title = decl.title
        self.param_info = decl.params
        self.coordinate_names = decl.coordinates
        self.first_order_names = decl.first_order
        self.state_names = decl.coordinates + tuple("d" + c for c in decl.coordinates) + decl.first_order
        self.input_names = decl.inputs
        self.output_names = self._sym.output_names
        self.params = self._validated({p.name: p.value for p in decl.params} | dict(params or {}))
        limit = decl.input_limit if input_limit is None else input_limit
        self.input_limit = _limit_vector(limit, self.nu, f"{self.name}: input_limit", self.input_names)
        self.casadi_f = self._sym.f
        self.casadi_h = self._sym.h
        self.casadi_energy = self._sym.energy
        # Compiled functions of this plant (RK4 steps, simulators), shared by the simulators; public so
        # that models.simulate, closed_loop and monte_carlo_batch fill it without reaching into a private
        # attribute.
        self.function_cache: dict = {}

    def __reduce__(self):
        """Pickled by name (for worker processes, e.g. Dask): the receiver rebuilds it from its own registry."""
        if _REGISTRY.get(self.name) is not self.declaration:
            raise TypeError(
                f"the plant {self.name!r} is not the registered declaration of that name, so another "
                "process cannot rebuild it; declare it with register=True in an importable module"
            )
        return (registered_plant, (self.name, dict(self.params), self.input_limit.tolist()))

    # ----------------------------------------------------------------- sizes
    @property
    def nq(self) -> int:
        """Number of generalized coordinates q."""
        return len(self.coordinate_names)

    @property
    def n_first_order(self) -> int:
        """Number of first-order states s (after q and q̇ in the state)."""
        return len(self.first_order_names)

    @property
    def nx(self) -> int:
        """Number of states, 2 nq + ns."""
        return 2 * self.nq + self.n_first_order

    @property
    def nu(self) -> int:
        """Number of inputs."""
        return len(self.input_names)

    @property
    def ny(self) -> int:
        """Number of outputs."""
        return len(self.output_names)

    @property
    def n_params(self) -> int:
        """Number of parameters, the length of p."""
        return len(self.param_info)

    @property
    def uncertain_params(self) -> tuple:
        """Parameters the case study perturbs by ±5 % for the controller."""
        return self.declaration.uncertain

    def __repr__(self) -> str:
        vals = ", ".join(f"{k}={v:g}" for k, v in self.params.items())
        return f"Plant({self.name!r}, {vals}, input_limit={self.input_limit.tolist()})"

    # ------------------------------------------------------------ parameters
    def with_params(self, **overrides) -> Plant:
        """A copy with some parameter values changed (validated)."""
        return Plant(self.declaration, self.params | overrides, self.input_limit)

    def with_input_limit(self, input_limit) -> Plant:
        """A copy with another actuator limit `input_limit` (a number, or one per input, in the inputs' SI units;
        for example the UUV's 250 N m variant)."""
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
        """`values` (name -> number) checked: known names, finite, > 0 (or >= 0 where allowed)."""
        info = {p.name: p for p in self.param_info}
        out = {}
        for key, value in values.items():
            if key not in info:
                raise ValueError(f"{self.name} has no parameter {key!r}; its parameters are {', '.join(info)}")
            pinfo = info[key]
            value = real(value, f"{self.name}: parameter {key} ({pinfo.unit})", finite=False)
            if not np.isfinite(value) or value < 0 or (pinfo.positive and value == 0):
                need = "> 0" if pinfo.positive else ">= 0"
                raise ValueError(f"{self.name}: parameter {key} ({pinfo.unit}) must be finite and {need}, got {value}")
            out[key] = value
        return out

    # -------------------------------------------------------------- numerics
    def f(self, x, u, params=None) -> np.ndarray:
        """State derivative xdot = f(x, u, p), (nx,), for one state (nx,) and input (nu,); p is `params`
        (default: the plant's own)."""
        x = as_vector(x, self.nx, f"{self.name} state {self.state_names}")
        u = as_vector(u, self.nu, f"{self.name} input {self.input_names}")
        return np.asarray(self.casadi_f(x, u, self.param_vector(params))).ravel()

    def output(self, x, params=None) -> np.ndarray:
        """Outputs y = h(x, p), (ny,); p is `params` (default: the plant's own)."""
        x = as_vector(x, self.nx, f"{self.name} state {self.state_names}")
        return np.asarray(self.casadi_h(x, self.param_vector(params))).ravel()

    def energy(self, x, params=None) -> float:
        """Total mechanical energy T + V in J at state x (the first-order states store none of it), with
        `params` (default: the plant's own)."""
        x = as_vector(x, self.nx, f"{self.name} state {self.state_names}")
        return float(self.casadi_energy(x, self.param_vector(params)))

    def equilibrium_input(self, q, params=None) -> np.ndarray:
        """Input holding the plant at rest at configuration q (feedforward), (nu,).

        Least squares when no input balances the static forces exactly; see
        `equilibrium` for a checked solve. `params`: the parameter values (default: the plant's own).
        """
        if self._sym.static_input is None:
            raise ValueError(f"{self.name}: the input enters the forces nonlinearly; use equilibrium() instead")
        q = as_vector(q, self.nq, f"{self.name} configuration {self.coordinate_names}")
        ue = np.asarray(self._sym.static_input(q, self.param_vector(params))).ravel()
        if not np.all(np.isfinite(ue)):
            raise ValueError(
                f"{self.name}: no unique input holds the plant at rest at q = {q} (the static "
                "balance is singular there); use equilibrium() instead"
            )
        return ue

    @property
    def casadi_configuration(self) -> ca.Function:
        """CasADi Function (y, p) -> q recovering the configuration from the outputs.

        Exists when the outputs are linear in q and determine it (all the case
        studies: the satellite measures phi - theta, so phi = y[0] + y[1]).
        """
        if self._sym.configuration is None:
            raise ValueError(
                f"{self.name}: the outputs {self.output_names} do not determine the configuration linearly"
            )
        return self._sym.configuration

    def equilibrium_input_jacobian(self, q=None, params=None) -> np.ndarray:
        """∂u_e/∂q of `equilibrium_input`, (nu, nq), at q (default the standard operating point).

        The ball on beam's m1 g / ell on z; zero where gravity does not load the input.
        `params`: the parameter values (default: the plant's own).
        """
        q = (
            self.equilibrium(params=params)[0][: self.nq]
            if q is None
            else as_vector(q, self.nq, f"{self.name} configuration {self.coordinate_names}")
        )
        qs = ca.SX.sym("q", self.nq)
        p = self.param_vector(params)
        jac = ca.Function("equilibrium_input_jacobian", [qs], [ca.jacobian(self.casadi_equilibrium_input(qs, p), qs)])
        value = np.asarray(jac(q), dtype=float).reshape(self.nu, self.nq)
        if not np.all(np.isfinite(value)):
            raise ValueError(
                f"{self.name}: the equilibrium input has no finite derivative at q = {q} (the static "
                "balance is singular there)"
            )
        return value

    @property
    def casadi_equilibrium_input(self) -> ca.Function:
        """CasADi Function (q, p) -> u of `equilibrium_input`, for controller blocks."""
        if self._sym.static_input is None:
            raise ValueError(f"{self.name}: the input enters the forces nonlinearly")
        return self._sym.static_input

    def equilibrium(self, params=None, tol: float = 1e-10, **fixed) -> tuple[np.ndarray, np.ndarray]:
        """Solve f(x, u) = 0 at rest with the named coordinates (or first-order states, or inputs) fixed.

        `params` are the parameter values (default: the plant's own) and `tol` the largest residual
        of f accepted. With nothing fixed, the declaration's standard operating point is used
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
            For an unknown name, when every unknown is fixed (nothing left to
            solve for), or when no equilibrium has the fixed values.
        """
        tol = positive(tol, f"{self.name}: equilibrium tol")
        p = self.param_vector(params)
        if not fixed:
            point = self.declaration.operating_point(parameter_values(self.declaration, p, "the operating point"))
            if not isinstance(point, Mapping):
                raise TypeError(f"{self.name}: operating_point must return a dict of fixed values, got {point!r}")
            fixed = dict(point)
        unknown_names = self.coordinate_names + self.first_order_names + self.input_names
        for key, value in fixed.items():
            if key not in unknown_names:
                first_order = f", first-order states {self.first_order_names}" if self.first_order_names else ""
                raise ValueError(
                    f"{self.name}: cannot fix {key!r}; choose among coordinates "
                    f"{self.coordinate_names}{first_order} and inputs {self.input_names}"
                )
            if not np.isfinite(real(value, f"{self.name}: fixed value {key}", finite=False)):
                raise ValueError(f"{self.name}: fixed value {key}={value} is not finite")
        free = np.array([n not in fixed for n in unknown_names])
        if not free.any():
            given = ", ".join(f"{k}={v:g}" for k, v in fixed.items())
            raise ValueError(
                f"{self.name}: equilibrium({given}) fixes every coordinate and input, leaving "
                "nothing to solve for; leave at least one free (to test a point, evaluate f(x, u))"
            )
        z = np.array([float(fixed.get(n, 0.0)) for n in unknown_names])
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
        if not np.all(np.isfinite(z)) or not np.all(np.isfinite(res)) or np.max(np.abs(res)) > tol:
            worst = int(np.argmax(np.abs(np.nan_to_num(res, nan=np.inf))))
            what = (
                f"the acceleration of {self.coordinate_names[worst]}"
                if worst < self.nq
                else f"the rate of {self.first_order_names[worst - self.nq]}"
            )
            given = ", ".join(f"{k}={v:g}" for k, v in fixed.items())
            raise ValueError(
                f"{self.name}: no equilibrium with {given}: {what} "
                f"cannot vanish (residual {np.max(np.abs(res)):.3g} after Gauss-Newton)"
            )
        nqs = self.nq + self.n_first_order
        return np.concatenate([z[: self.nq], np.zeros(self.nq), z[self.nq : nqs]]), z[nqs:]

    def linearize(self, xe=None, ue=None, params=None, check: bool = True) -> LinearModel:
        """Exact Jacobian linearization about (xe, ue).

        Without arguments, about the standard operating point `equilibrium()`.
        With `check`, raises unless f(xe, ue) = 0 (to 1e-8), because away
        from an equilibrium the linear model would miss a constant term.
        `params`: the parameter values (default: the plant's own).
        """
        check = boolean(check, "check")
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
                raise ValueError(
                    f"{self.name}: (xe, ue) is not an equilibrium (|f| = {res:.3g}); "
                    "pass check=False to linearize anyway"
                )
        A, B, C = (np.asarray(m, dtype=float) for m in self._sym.jacobians(xe, ue, p))
        return LinearModel(
            A=A,
            B=B,
            C=C,
            D=np.zeros((self.ny, self.nu)),
            xe=xe,
            ue=ue,
            ye=self.output(xe, p),
            state_names=self.state_names,
            input_names=self.input_names,
            output_names=self.output_names,
            name=self.name,
        )

    # ------------------------------------------------------------ simulation
    def step_function(self, sample_period: float, substeps: int = 10) -> ca.Function:
        """CasADi Function (x, u, p) -> x after `sample_period` s of RK4.

        `substeps` fixed RK4 steps with the input held; the expression is
        expanded to SX so a mapaccum over it runs in CasADi's fast VM.
        """
        sample_period = positive(sample_period, "sample_period (s)")
        substeps = integer(substeps, "substeps", minimum=1)
        key = (sample_period, substeps)
        if key not in self.function_cache:
            x = ca.SX.sym("x", self.nx)
            u = ca.SX.sym("u", self.nu)
            p = ca.SX.sym("p", self.n_params)
            xs = rk4(lambda xs, t: self.casadi_f(xs, u, p), x, sample_period, int(substeps))
            # Common subexpressions repeat across the unrolled stages.
            self.function_cache[key] = ca.Function("rk4", [x, u, p], [ca.cse(xs)], ["x", "u", "p"], ["x_next"])
        return self.function_cache[key]


def get(name: str, input_limit=None, **overrides) -> Plant:
    """The registered plant `name` with parameter overrides, e.g. ``get("arm", m=0.6)``, and the actuator limit
    `input_limit` (default the declaration's)."""
    return Plant(declaration(name), overrides, input_limit)


def registered_plant(name: str, params: Mapping[str, float], input_limit) -> Plant:
    """The registered plant `name` with these parameter values and actuator limit (how a Plant unpickles)."""
    return Plant(declaration(name), params, input_limit)
