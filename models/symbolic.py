"""Printed expressions of a declared plant: CasADi SX converted to sympy, simplified, typeset.

`to_sympy` walks a scalar SX expression graph (`op()`, `dep(i)`,
`is_symbolic()`, `name()`, `is_constant()`) and rebuilds it in sympy.
`kinetic_energy` and `equations_of_motion` evaluate a plant declaration with
named symbols (the coordinate, input and parameter names), derive the
Euler-Lagrange equations with `models.lagrangian` exactly as the simulator
does, and return them as simplified sympy expressions; `latex` typesets them
with dots for time derivatives (θ̇ as ``\\dot{\\theta}``).

Nothing here knows about a particular plant.
"""

from __future__ import annotations

import re
from typing import TYPE_CHECKING

import casadi as ca

from . import deferred
from .lagrangian import euler_lagrange
from .physics import namespaces
from .plant import Declaration, Plant

if TYPE_CHECKING:
    import sympy
else:
    sympy = deferred.module("sympy")

# SymPy's functions are looked up at the call, so importing this module does not import SymPy.
_UNARY = {
    ca.OP_NEG: lambda a: -a,
    ca.OP_SIN: lambda a: sympy.sin(a),
    ca.OP_COS: lambda a: sympy.cos(a),
    ca.OP_TAN: lambda a: sympy.tan(a),
    ca.OP_EXP: lambda a: sympy.exp(a),
    ca.OP_LOG: lambda a: sympy.log(a),
    ca.OP_SQRT: lambda a: sympy.sqrt(a),
    ca.OP_SQ: lambda a: a**2,
    ca.OP_TWICE: lambda a: 2 * a,
    ca.OP_INV: lambda a: 1 / a,
    ca.OP_FABS: lambda a: sympy.Abs(a),
    ca.OP_ASIN: lambda a: sympy.asin(a),
    ca.OP_ACOS: lambda a: sympy.acos(a),
    ca.OP_ATAN: lambda a: sympy.atan(a),
    ca.OP_SINH: lambda a: sympy.sinh(a),
    ca.OP_COSH: lambda a: sympy.cosh(a),
    ca.OP_TANH: lambda a: sympy.tanh(a),
    ca.OP_SIGN: lambda a: sympy.sign(a),
}
_BINARY = {
    ca.OP_ADD: lambda a, b: a + b,
    ca.OP_SUB: lambda a, b: a - b,
    ca.OP_MUL: lambda a, b: a * b,
    ca.OP_DIV: lambda a, b: a / b,
    ca.OP_POW: lambda a, b: a**b,
    ca.OP_CONSTPOW: lambda a, b: a**b,
    ca.OP_ATAN2: lambda a, b: sympy.atan2(a, b),
    ca.OP_FMIN: lambda a, b: sympy.Min(a, b),
    ca.OP_FMAX: lambda a, b: sympy.Max(a, b),
}


def _constant(value: float) -> sympy.Expr:
    """A number as sympy: an Integer when integral, else the simplest rational or surd within 1e-12."""
    if float(value).is_integer():
        return sympy.Integer(int(value))
    return sympy.nsimplify(value, tolerance=1e-12 * max(1.0, abs(value)))


def to_sympy(expr: ca.SX, symbols: dict[str, sympy.Symbol] | None = None) -> sympy.Expr:
    """The sympy expression of a scalar CasADi SX expression.

    Parameters
    ----------
    expr : SX, 1 x 1
    symbols : SX symbol name -> sympy Symbol; names not listed become ``sympy.Symbol(name)``

    Raises
    ------
    ValueError
        For a non-scalar expression, or an operation with no sympy counterpart (naming its code).
    """
    expr = ca.SX(expr)
    if expr.numel() != 1:
        raise ValueError(f"to_sympy converts scalar expressions, got shape {expr.shape}")
    symbols = dict(symbols or {})
    memo: dict[int, sympy.Expr] = {}

    def convert(node: ca.SX) -> sympy.Expr:
        # Depth first; memo makes a shared subexpression one sympy node.
        key = node.element_hash()
        if key in memo:
            return memo[key]
        if node.is_symbolic():
            name = node.name()
            out = symbols.setdefault(name, sympy.Symbol(name))
        elif node.is_constant():
            out = _constant(float(node))
        else:
            op = node.op()
            if op in _UNARY:
                out = _UNARY[op](convert(node.dep(0)))
            elif op in _BINARY:
                out = _BINARY[op](convert(node.dep(0)), convert(node.dep(1)))
            else:
                raise ValueError(f"to_sympy: CasADi operation {op} has no sympy counterpart here")
        memo[key] = out
        return out

    return convert(expr)


def latex_name(name: str, dots: int = 0) -> str:
    """LaTeX of a symbol name: greek letters and ℓ as such, trailing digits as a subscript, `dots` dots."""
    match = re.fullmatch(r"([A-Za-z]+?)(\d*)", name)
    base, index = (match.group(1), match.group(2)) if match else (name, "")
    text = sympy.latex(sympy.Symbol(base)) if base != "ell" else r"\ell"
    if index:
        text += f"_{{{index}}}"
    if dots:
        text = "\\" + "d" * dots + "ot{" + text + "}"
    return text


class DeclarationSymbols:
    """A declaration evaluated on named symbols: q (coordinate names), q̇ ("d" + name), q̈ ("dd" + name), u, p.

    Attributes
    ----------
    q, dq, ddq, u, p : SX column vectors
    physics : the declaration's `Physics` on them
    symbols : SX name -> sympy Symbol (real)
    latex_names : sympy Symbol -> LaTeX (dots for rates)
    """

    def __init__(self, decl: Declaration):
        self.declaration = decl
        names = [p.name for p in decl.params]
        self.q = ca.vertcat(*[ca.SX.sym(c) for c in decl.coordinates])
        self.dq = ca.vertcat(*[ca.SX.sym("d" + c) for c in decl.coordinates])
        self.ddq = ca.vertcat(*[ca.SX.sym("dd" + c) for c in decl.coordinates])
        self.u = ca.vertcat(*[ca.SX.sym(n) for n in decl.inputs])
        self.p = ca.vertcat(*[ca.SX.sym(n) for n in names])
        self.physics = decl.physics(*namespaces(decl, self.q, self.dq, self.u, self.p, ca.SX(0, 1))[:4])
        self.symbols: dict[str, sympy.Symbol] = {}
        self.latex_names: dict[sympy.Symbol, str] = {}
        for prefix, dots in (("", 0), ("d", 1), ("dd", 2)):
            for c in decl.coordinates:
                self._name(prefix + c, latex_name(c, dots))
        for n in (*decl.inputs, *names):
            self._name(n, latex_name(n))

    def _name(self, name: str, text: str) -> None:
        """Record the real sympy symbol `name` and its LaTeX `text`."""
        symbol = sympy.Symbol(name, real=True)
        self.symbols[name] = symbol
        self.latex_names[symbol] = text

    def sympy(self, expr) -> sympy.Expr:
        """A scalar SX expression of these symbols in sympy."""
        return to_sympy(expr, self.symbols)


def _declaration(plant: Plant | Declaration) -> Declaration:
    """The declaration of a plant, or the declaration itself."""
    return plant.declaration if isinstance(plant, Plant) else plant


def kinetic_energy(plant: Plant | Declaration) -> sympy.Expr:
    """T(q, q̇, p) of the declaration, simplified (J)."""
    named = DeclarationSymbols(_declaration(plant))
    return sympy.simplify(named.sympy(named.physics.kinetic))


def equations_of_motion(plant: Plant | Declaration) -> list[sympy.Eq]:
    """M(q) q̈ = Q − C(q, q̇) q̇ − ∂V/∂q, one simplified equation per coordinate.

    The left side is the mass matrix row times the accelerations (named "dd" +
    coordinate), the right side the generalized forces less the Coriolis and
    gravity terms, all derived by `models.lagrangian.euler_lagrange`.
    """
    named = DeclarationSymbols(_declaration(plant))
    phys = named.physics
    eom = euler_lagrange(named.q, named.dq, phys.kinetic, phys.potential, phys.forces)
    equations = []
    for i in range(named.q.numel()):
        lhs = sum(
            (named.sympy(eom.mass_matrix[i, j]) * named.sympy(named.ddq[j]) for j in range(named.q.numel())),
            sympy.Integer(0),
        )
        rhs = named.sympy(eom.forces[i] - eom.coriolis[i] - eom.gravity[i])
        equations.append(sympy.Eq(sympy.simplify(lhs), sympy.simplify(rhs)))
    return equations


def latex(expr, plant: Plant | Declaration) -> str:
    """LaTeX of a sympy expression or equation of the plant's named symbols (dots for rates)."""
    named = DeclarationSymbols(_declaration(plant))
    return sympy.latex(expr, symbol_names=named.latex_names)
