"""Smoothed copies of CasADi SX Functions: every switch blended over a band of a given width.

Saturation, conditional integration and back-calculation anti-windup are
written with `casadi.if_else` and comparisons (`models.saturate`,
`designs.discrete`). Through them a closed-loop cost is continuous but only
piecewise smooth in the gains: its gradient jumps wherever one sample enters
or leaves a limit, and a quasi-Newton method stalls on the kinks.
`smoothed(fun)` rewrites `fun`'s algorithm, instruction by instruction, with
each comparison ``a < b`` (and ``a <= b``, ``fmin``, ``fmax``) replaced by a
smooth truth value

    c = S((b − a) / (width · m) + 1/2),    m = sqrt((a² + b²) / 2),

where S is the quintic smoothstep (S(t) = t³ (10 − 15 t + 6 t²) on [0, 1],
0 below, 1 above; twice continuously differentiable) and `width` is a new
last input, relative to the size m of the compared values (so a saturation
at L is blended over |u − L| <= width · L / 2, whatever u's unit). Boolean
operations become products (not c = 1 − c, c₁ and c₂ = c₁ c₂, c₁ or c₂ =
c₁ + c₂ − c₁ c₂) and ``if_else(c, x, y)`` becomes c x + (1 − c) y (a branch
whose weight is exactly zero contributes exactly zero, as in CasADi, even
where it is not finite).

Outside the bands every c is exactly 0 or 1, so the smoothed Function
returns the original's values there, bit for bit up to the sums with exact
zeros: a point whose every switch is farther than width · m / 2 from its
threshold has the same closed-loop cost smoothed and exact. Equality tests
(``==``, ``!=``, guards such as "k_i = 0") stay exact, as do ``fabs`` and
``sign`` (kinks at zero only, not at a limit).
"""

from __future__ import annotations

import casadi as ca

#: Comparisons a < b and a <= b are blended (the boundary itself has measure zero).
_COMPARISONS = {ca.OP_LT, ca.OP_LE}


def smooth_step(z):
    """Quintic smoothstep of z + 1/2: 0 for z <= −1/2, 1 for z >= 1/2, C² in between."""
    t = ca.fmin(ca.fmax(z + 0.5, 0.0), 1.0)
    return t**3 * (10 - 15 * t + 6 * t**2)


def smooth_less(a, b, width):
    """Smooth truth value of a < b, blended over |a − b| <= width · sqrt((a² + b²) / 2) / 2."""
    scale = width * ca.sqrt((a**2 + b**2) / 2) + 1e-300
    return smooth_step((b - a) / scale)


def smoothed(fun: ca.Function, name: str | None = None) -> ca.Function:
    """`fun` with its switches blended; one more input, "width" (scalar, relative, > 0).

    Parameters
    ----------
    fun : an SX Function (CasADi's scalar graph; `Block.casadi_step`, the closed-loop step)
    name : the new Function's name (default ``fun.name() + "_smoothed"``)

    Returns
    -------
    casadi.Function with `fun`'s inputs and "width", and `fun`'s outputs.

    Raises
    ------
    TypeError
        When `fun` is not an SX Function (an MX graph has no scalar instructions to rewrite).
    """
    if not isinstance(fun, ca.Function) or not fun.is_a("SXFunction"):
        raise TypeError(f"smoothed needs an SX casadi.Function, got {type(fun).__name__} {fun!r}")
    inputs = fun.sx_in()
    width = ca.SX.sym("width")
    outputs = [[ca.SX(0)] * fun.nnz_out(i) for i in range(fun.n_out())]
    work: dict[int, ca.SX] = {}
    for k in range(fun.n_instructions()):
        op = fun.instruction_id(k)
        args = fun.instruction_input(k)
        out = fun.instruction_output(k)
        if op == ca.OP_INPUT:
            work[out[0]] = inputs[args[0]].nz[args[1]]
        elif op == ca.OP_OUTPUT:
            outputs[out[0]][out[1]] = work[args[0]]
        elif op == ca.OP_CONST:
            work[out[0]] = ca.SX(fun.instruction_constant(k))
        elif op in _COMPARISONS:
            work[out[0]] = smooth_less(work[args[0]], work[args[1]], width)
        elif op == ca.OP_NOT:
            work[out[0]] = 1 - work[args[0]]
        elif op == ca.OP_AND:
            work[out[0]] = work[args[0]] * work[args[1]]
        elif op == ca.OP_OR:
            a, b = work[args[0]], work[args[1]]
            work[out[0]] = a + b - a * b
        elif op == ca.OP_IF_ELSE_ZERO:
            # c x, but exactly 0 where c is 0 even if x is not finite (a guarded 1 / k at k = 0).
            c = work[args[0]]
            work[out[0]] = ca.SX.binary(ca.OP_IF_ELSE_ZERO, c, c * work[args[1]])
        elif op in (ca.OP_FMIN, ca.OP_FMAX):
            a, b = work[args[0]], work[args[1]]
            first = smooth_less(a, b, width) if op == ca.OP_FMIN else smooth_less(b, a, width)
            work[out[0]] = first * a + (1 - first) * b
        elif len(args) == 1:
            work[out[0]] = ca.SX.unary(op, work[args[0]])
        elif len(args) == 2:
            work[out[0]] = ca.SX.binary(op, work[args[0]], work[args[1]])
        else:
            raise TypeError(
                f"smoothed: {fun.name()} has an instruction with operation {op} "
                f"and {len(args)} arguments, which it cannot rewrite"
            )
    results = []
    for i in range(fun.n_out()):
        sp = fun.sparsity_out(i)
        results.append(ca.SX(sp, ca.vertcat(*outputs[i])) if outputs[i] else ca.SX(sp))
    return ca.Function(
        name or fun.name() + "_smoothed", [*inputs, width], results, [*fun.name_in(), "width"], fun.name_out()
    )
