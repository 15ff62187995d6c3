"""Euler-Lagrange equations by symbolic differentiation.

For generalized coordinates q with kinetic energy T(q, q̇), potential V(q) and
generalized forces Q(q, q̇, u) the Euler-Lagrange equations

    d/dt ∂T/∂q̇ − ∂T/∂q + ∂V/∂q = Q

expand, with M(q) = ∂²T/∂q̇² and d/dt ∂T/∂q̇ = M q̈ + (∂/∂q ∂T/∂q̇) q̇, into

    M(q) q̈ = Q − C(q, q̇) q̇ − ∂V/∂q,   C(q, q̇) q̇ = (∂/∂q ∂T/∂q̇) q̇ − ∂T/∂q.

Nothing here knows about any particular plant.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca


@dataclass(frozen=True)
class EquationsOfMotion:
    """Symbolic equations of motion M(q) q̈ = rhs, all CasADi SX.

    Attributes
    ----------
    mass_matrix : SX, (nq, nq)
    coriolis : SX, (nq,)  the vector C(q, q̇) q̇
    gravity : SX, (nq,)  the vector ∂V/∂q
    forces : SX, (nq,)  the generalized forces Q
    accel : SX, (nq,)  q̈ = M⁻¹ (Q − C q̇ − ∂V/∂q)
    """

    mass_matrix: ca.SX
    coriolis: ca.SX
    gravity: ca.SX
    forces: ca.SX
    accel: ca.SX


def euler_lagrange(
    q: ca.SX, dq: ca.SX, kinetic: ca.SX, potential: ca.SX, forces, coordinate_names=None
) -> EquationsOfMotion:
    """Derive the equations of motion from the energies and generalized forces.

    Parameters
    ----------
    q, dq : SX column vectors, (nq,)
        Generalized coordinates and their rates; nq may be 0 (no mechanics).
    kinetic, potential : SX scalars
        T(q, q̇) and V(q); any parameters appear as free symbols.
    forces : SX column vector or list of SX, (nq,)
        Generalized forces Q(q, q̇, u), including dissipation.
    coordinate_names : sequence of str, optional
        Names of q used in error messages.

    Raises
    ------
    ValueError
        When the forces do not match the coordinates, the potential depends on
        the velocities, or a coordinate has no kinetic energy (its diagonal
        mass-matrix entry is structurally zero, so q̈ is undetermined).
    """
    nq = q.numel()
    names = list(coordinate_names) if coordinate_names is not None else [f"q[{i}]" for i in range(nq)]
    forces = ca.vertcat(*forces) if isinstance(forces, (list, tuple)) else ca.SX(forces)
    if forces.numel() != nq:
        raise ValueError(f"need one generalized force per coordinate ({nq}), got {forces.numel()}")
    if ca.depends_on(potential, dq):
        raise ValueError("the potential energy must not depend on the velocities")
    if nq == 0:
        empty = ca.SX(0, 1)
        return EquationsOfMotion(ca.SX(0, 0), empty, empty, empty, empty)
    mass_matrix, momentum = ca.hessian(kinetic, dq)
    for k in range(nq):
        if ca.SX(mass_matrix[k, k]).is_zero():
            raise ValueError(
                f"the kinetic energy has no term in the velocity of coordinate {names[k]!r} "
                "(zero mass-matrix diagonal), so its acceleration is undetermined; give it "
                "kinetic energy or declare it as a first-order state"
            )
    coriolis = ca.jtimes(momentum, q, dq) - ca.gradient(kinetic, q)
    gravity = ca.gradient(potential, q)
    accel = solve_spd(mass_matrix, forces - coriolis - gravity)
    return EquationsOfMotion(mass_matrix, coriolis, gravity, forces, accel)


def solve_spd(matrix: ca.SX, rhs: ca.SX) -> ca.SX:
    """Solve matrix · v = rhs symbolically by Gaussian elimination without pivoting.

    Valid for symmetric positive definite matrices, as every mass matrix is.
    Rows are eliminated in minimum-degree order (fewest structural nonzeros
    first), so an arrowhead mass matrix such as the crane's gets no fill-in.
    Cheaper than CasADi's symbolic QR, which matters because the result is
    evaluated at every RK4 stage.
    """
    n = matrix.shape[0]
    a = {(i, j): matrix[i, j] for i in range(n) for j in range(n) if not ca.SX(matrix[i, j]).is_zero()}
    b = [rhs[i] for i in range(n)]
    remaining = list(range(n))
    order = []
    while remaining:
        k = min(remaining, key=lambda i: sum((i, j) in a for j in remaining))
        remaining.remove(k)
        order.append(k)
        if (k, k) not in a:
            raise ValueError(f"the matrix has a structurally zero pivot in row {k}; it is not positive definite")
        for i in remaining:
            if (i, k) not in a:
                continue
            factor = a[(i, k)] / a[(k, k)]
            for j in remaining:
                if (k, j) in a:
                    a[(i, j)] = a.get((i, j), 0) - factor * a[(k, j)]
            b[i] = b[i] - factor * b[k]
    v: list[ca.SX] = [ca.SX(0)] * n  # filled in reverse elimination order
    for pos in reversed(range(n)):
        k = order[pos]
        later = [j for j in order[pos + 1 :] if (k, j) in a]
        v[k] = (b[k] - sum((a[(k, j)] * v[j] for j in later), ca.SX(0))) / a[(k, k)]
    return ca.vertcat(*v)
