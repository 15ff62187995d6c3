"""What a plant's physics function reads and returns, checked: its namespaces and its `Physics` record.

A declaration's physics function (`models.declare`) reads the plant's symbols by name from
namespaces, ``p.m``, ``q.theta``, ``dq.theta``, ``u.tau``, ``s.i`` (`Symbols`): a name the plant
does not declare is an AttributeError naming the plant, the name and the declared ones. What it
returns is checked here before the equations of motion are derived (`checked_physics`): the types
and sizes of every part, and (`check_finite`) that no part holds a non-finite number, such as an
infinite mass typed into the energies (``math.inf * dq.x**2 / 2``, or ``dq.x**2 / (2 / math.inf)``,
which CasADi folds to the constant inf); `check_mass_matrix` refuses a mass matrix that is
indefinite or singular wherever it is sampled.
"""

from __future__ import annotations

import numbers
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import casadi as ca
import numpy as np

if TYPE_CHECKING:
    from .plant import Declaration


@dataclass(frozen=True)
class Physics:
    """What a declaration returns, all CasADi SX (or numbers).

    Attributes
    ----------
    kinetic : T(q, q̇, p) in J
    potential : V(q, s, p) in J
    forces : generalized forces Q(q, q̇, s, u, p), one per coordinate
    outputs : mapping output name -> expression of (q, q̇, s, p); not of the inputs
    rates : mapping first-order state name -> its derivative ṡ = g(q, q̇, s, u, p),
        one per declared first-order state (or a sequence in declaration order)

    A purely first-order plant gives only `rates` and `outputs`.
    """

    kinetic: ca.SX | float = 0
    potential: ca.SX | float = 0
    forces: Sequence = ()
    outputs: Mapping[str, ca.SX] = field(default_factory=dict)
    rates: Mapping[str, ca.SX] | Sequence = field(default_factory=dict)


class Symbols:
    """A namespace of a plant's symbols (or values) by name, as a physics function reads them: ``p.m``.

    An attribute the plant does not declare is an AttributeError naming the plant, the reader
    (`reader`: "the physics function", "the operating point"), the name read and the declared names.

    Parameters
    ----------
    plant : the plant's name
    prefix : the namespace's name in messages ("p", "q", "dq", "u", "s")
    kind : what its names are, plural ("parameters", "coordinates", "inputs", "first-order states")
    values : name -> CasADi symbol or number
    reader : who reads it, for messages
    """

    __slots__ = ("_plant", "_prefix", "_kind", "_values", "_reader")

    def __init__(self, plant: str, prefix: str, kind: str, values: Mapping[str, Any], reader: str):
        for slot, value in zip(self.__slots__, (plant, prefix, kind, dict(values), reader)):
            object.__setattr__(self, slot, value)

    def __getattr__(self, name: str):
        """The symbol `name`; AttributeError naming the plant and its declared names when there is none."""
        values = object.__getattribute__(self, "_values")
        if name in values:
            return values[name]
        if name.startswith("__"):  # protocol look-ups (copy, pickle) get Python's own answer
            raise AttributeError(name)
        plant, prefix, kind, reader = (
            object.__getattribute__(self, k) for k in ("_plant", "_prefix", "_kind", "_reader")
        )
        declared = ", ".join(values) or "none"
        raise AttributeError(
            f"{plant}: {reader} uses {prefix}.{name}, which is not declared; the {kind} of {plant} are: {declared}"
        )

    def __setattr__(self, name: str, value) -> None:
        raise AttributeError(f"{object.__getattribute__(self, '_plant')}: the plant's symbols cannot be assigned")

    def __dir__(self) -> list[str]:
        return list(object.__getattribute__(self, "_values"))

    def __repr__(self) -> str:
        values = object.__getattribute__(self, "_values")
        return f"{object.__getattribute__(self, '_prefix')}({', '.join(values)})"


def namespaces(decl: Declaration, q, dq, u, p, s, reader: str = "the physics function") -> list[Symbols]:
    """The namespaces (q, dq, u, p, and s when the plant has first-order states) of `decl` over the
    vectors (CasADi symbols or numbers) `q`, `dq`, `u`, `p`, `s`, in declaration order."""
    name = decl.name
    spaces = [
        Symbols(name, "q", "coordinates", {c: q[i] for i, c in enumerate(decl.coordinates)}, reader),
        Symbols(name, "dq", "coordinates", {c: dq[i] for i, c in enumerate(decl.coordinates)}, reader),
        Symbols(name, "u", "inputs", {c: u[i] for i, c in enumerate(decl.inputs)}, reader),
        Symbols(name, "p", "parameters", {pp.name: p[i] for i, pp in enumerate(decl.params)}, reader),
    ]
    if decl.first_order:
        spaces.append(
            Symbols(name, "s", "first-order states", {c: s[i] for i, c in enumerate(decl.first_order)}, reader)
        )
    return spaces


def parameter_values(decl: Declaration, values, reader: str) -> Symbols:
    """The namespace ``p`` of `decl`'s parameter `values` (numbers, declaration order), read by `reader`."""
    return Symbols(decl.name, "p", "parameters", {pp.name: v for pp, v in zip(decl.params, values)}, reader)


def check_finite(decl: Declaration, parts: Mapping[str, ca.SX]) -> None:
    """Refuse a part of the physics (name -> SX expression) that holds a non-finite number (inf, NaN).

    An infinite mass, length or spring typed into a physics function makes an energy that is not a
    mechanism's: CasADi keeps ``inf * dq**2`` (q̈ is then silently 0) or folds ``dq**2 / 0`` to the
    constant inf (no velocity left in it). The numbers in the expression graph are what is checked,
    so an expression that is finite only at some states (1/cos q) is not refused.

    Raises
    ------
    ValueError
        Naming the plant, the part and the number.
    """
    for what, expr in parts.items():
        fun = ca.Function("part", ca.symvar(expr), [expr])
        for k in range(fun.n_instructions()):
            if fun.instruction_id(k) == ca.OP_CONST and not np.isfinite(fun.instruction_constant(k)):
                raise ValueError(
                    f"{decl.name}: {what} holds the non-finite number {fun.instruction_constant(k)} (an infinite "
                    "or NaN mass, length or other constant in the physics function); every parameter and "
                    "constant must be finite"
                )


def scalar_expression(value, what: str) -> ca.SX:
    """One CasADi SX scalar from an SX expression or a real number (TypeError/ValueError naming `what`)."""
    if isinstance(value, (ca.SX, ca.DM)):
        expr = ca.SX(value)
    elif isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_)):
        expr = ca.SX(float(value))
    else:
        raise TypeError(f"{what} must be a CasADi SX expression or a number, got {type(value).__name__} {value!r}")
    if expr.shape != (1, 1):
        raise ValueError(f"{what} must be one scalar expression, got shape {expr.shape}")
    return expr


def checked_physics(decl: Declaration, phys) -> tuple:
    """(kinetic, potential, forces (nq,), outputs {name: SX}, rates (ns,)) checked against `decl`."""
    where = f"{decl.name}: the physics function {getattr(decl.physics, '__name__', decl.physics)!r}"
    if not isinstance(phys, Physics):
        raise TypeError(f"{where} must return models.Physics, got {type(phys).__name__} {phys!r}")
    kinetic = scalar_expression(phys.kinetic, f"{decl.name}: Physics.kinetic")
    potential = scalar_expression(phys.potential, f"{decl.name}: Physics.potential")
    nq, ns = len(decl.coordinates), len(decl.first_order)
    raw_forces = phys.forces
    if isinstance(raw_forces, ca.SX):
        raw_forces = [raw_forces[i] for i in range(raw_forces.numel())]
    if isinstance(raw_forces, (str, Mapping)) or not isinstance(raw_forces, (list, tuple)):
        raise TypeError(
            f"{decl.name}: Physics.forces must be a list with one generalized force per "
            f"coordinate {decl.coordinates}, got {phys.forces!r}"
        )
    if len(raw_forces) != nq:
        raise ValueError(
            f"{decl.name}: Physics.forces needs one generalized force per coordinate "
            f"{decl.coordinates} ({nq}), got {len(raw_forces)}"
        )
    forces = [
        scalar_expression(f, f"{decl.name}: generalized force of {c!r}") for f, c in zip(raw_forces, decl.coordinates)
    ]
    if not isinstance(phys.outputs, Mapping):
        raise TypeError(f"{decl.name}: Physics.outputs must be a mapping name -> expression, got {phys.outputs!r}")
    outputs = {}
    for key, value in phys.outputs.items():
        if not isinstance(key, str) or not key:
            raise TypeError(f"{decl.name}: output name must be a non-empty string, got {key!r}")
        outputs[key] = scalar_expression(value, f"{decl.name}: output {key!r}")
    raw_rates = phys.rates
    if isinstance(raw_rates, Mapping):
        if set(raw_rates) != set(decl.first_order):
            raise ValueError(
                f"{decl.name}: Physics.rates must give one equation per first-order state "
                f"{decl.first_order}, got {tuple(raw_rates)}"
            )
        raw_rates = [raw_rates[k] for k in decl.first_order]
    elif isinstance(raw_rates, ca.SX):
        raw_rates = [raw_rates[i] for i in range(raw_rates.numel())]
    elif isinstance(raw_rates, str) or not isinstance(raw_rates, (list, tuple)):
        raise TypeError(
            f"{decl.name}: Physics.rates must map each first-order state to its derivative, got {phys.rates!r}"
        )
    if len(raw_rates) != ns:
        raise ValueError(
            f"{decl.name}: Physics.rates needs one equation per first-order state "
            f"{decl.first_order} ({ns}), got {len(raw_rates)}"
        )
    rates = [
        scalar_expression(r, f"{decl.name}: first-order equation of {k!r}") for r, k in zip(raw_rates, decl.first_order)
    ]
    return kinetic, potential, forces, outputs, ca.vertcat(*rates) if rates else ca.SX(0, 1)


def check_mass_matrix(decl: Declaration, mass_matrix: ca.SX, q: ca.SX, p: ca.SX) -> None:
    """Refuse a mass matrix that is singular or indefinite at every sampled configuration.

    Evaluated at the nominal parameters, at q = 0 and at two seeded random
    configurations in [-1, 1]: a matrix singular at all three is singular
    structurally (a combination of velocities has no kinetic energy), not at
    an isolated configuration.
    """
    fun = ca.Function("mass_matrix", [q, p], [mass_matrix])
    nominal = np.array([pp.value for pp in decl.params], dtype=float)
    rng = np.random.default_rng(0)
    points = [np.zeros(q.numel())] + [rng.uniform(-1.0, 1.0, q.numel()) for _ in range(2)]
    singular: list[np.ndarray] = []  # per configuration, the velocity direction without kinetic energy
    for point in points:
        matrix = np.asarray(fun(point, nominal), dtype=float)
        if not np.all(np.isfinite(matrix)):
            return
        eig, vectors = np.linalg.eigh((matrix + matrix.T) / 2)
        scale = max(np.max(np.abs(eig)), np.finfo(float).tiny)
        if eig[0] < -1e-12 * scale:
            raise ValueError(
                f"{decl.name}: the mass matrix is not positive definite at q = {point.round(3)} "
                f"(eigenvalue {eig[0]:.3g}): the kinetic energy is negative for some velocities"
            )
        if eig[0] <= 1e-12 * scale:
            singular.append(vectors[:, 0])
    if len(singular) == len(points):
        combo = " + ".join(f"{c:.3g} d{n}" for c, n in zip(singular[0], decl.coordinates) if abs(c) > 1e-9)
        raise ValueError(
            f"{decl.name}: the mass matrix is singular: the velocity combination {combo} has "
            "no kinetic energy, so the accelerations are undetermined"
        )
