"""Convex sets for set-based control, exact and small: polytopes, zonotopes, invariant sets.

- `Polytope` {x : H x ≤ h}: support function by LP (DAQP; HiGHS where DAQP does not settle),
  Pontryagin difference against any set given by its support function,
  P ⊖ S = {x : H_i x ≤ h_i − h_S(H_i)} (exact), preimage under a matrix, intersection,
  redundancy removal by LP, Chebyshev ball.
- `Zonotope` c + G [−1, 1]^m (boxes included): support function dᵀc + ‖Gᵀd‖₁ in closed form,
  linear map and Minkowski sum (exact), sign corners, and its exact facets when they are few.
- `maximal_invariant_set`: the maximal positively invariant set of x⁺ = A x in a polytope
  (Gilbert & Tan 1991).

A Minkowski sum is kept as its support function, h_{P ⊕ Q} = h_P + h_Q; anything with a
`support(directions)` method is a `ConvexSet`. `mpc.tube` builds a tube MPC's sets on these.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from typing import Protocol

import daqp
import numpy as np

from models import deferred
from models.checks import as_matrix, as_vector, integer

scipy = deferred.module("scipy")

__all__ = [
    "ConvexSet",
    "EmptySetError",
    "Polytope",
    "Zonotope",
    "as_directions",
    "maximal_invariant_set",
    "HIGHS_OPTIONS",
]

#: Constraint violation the LPs accept (DAQP's default, 1e-6, would let support values grow by it).
PRIMAL_TOLERANCE = 1e-10
#: HiGHS' smallest feasibility tolerances, for the LPs DAQP does not report optimal.
HIGHS_OPTIONS = {"primal_feasibility_tolerance": 1e-10, "dual_feasibility_tolerance": 1e-10}
#: DAQP's infinity (an absent bound).
INFINITY = 1e30


class EmptySetError(ValueError):
    """A polytope with no point: its LP is infeasible."""


class ConvexSet(Protocol):
    """A compact convex set known by its support function h(d) = max_{x ∈ set} dᵀx."""

    @property
    def dimension(self) -> int:
        """n, the dimension of the space the set lies in."""
        ...

    def support(self, directions) -> np.ndarray:
        """h(d) for each row d of `directions` (k, n): (k,)."""
        ...


def as_directions(directions, n: int) -> np.ndarray:
    """Directions as a finite (k, n) array (one direction (n,) becomes one row)."""
    D = np.asarray(directions, dtype=float)
    D = D.reshape(1, -1) if D.ndim == 1 else D
    if D.ndim != 2 or D.shape[1] != n:
        raise ValueError(f"directions must have {n} columns, got shape {np.shape(directions)}")
    if not np.all(np.isfinite(D)):
        raise ValueError("directions must be finite")
    return D


def _maximize(H: np.ndarray, bounds: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """max dᵢᵀx over {H x ≤ bᵢ} for each row dᵢ of `directions` (k, n); `bounds` (r,) or (k, r) per row.

    Returns values (k,), +inf where unbounded, and maximizers (k, n), NaN where unbounded. Each LP
    goes to DAQP (dual active set on proximal-point steps, the fast path's solver: a few tenths of
    a millisecond for a few hundred rows), scaled to unit bounds and a unit direction with a unit
    proximal weight, so that its steps reach the optimal vertex (its automatic weight of 1e-6
    stopped 2e-11 short of a box's face and failed on some 4-D zonotopes). An LP DAQP does not
    report optimal goes to HiGHS' dual simplex, which decides unbounded or empty.
    Raises EmptySetError when {H x ≤ b} is empty.
    """
    k, n = directions.shape
    # DAQP reads its arrays' memory as C-contiguous without checking the strides: pass fresh copies.
    H, bounds = np.ascontiguousarray(H, dtype=float), np.broadcast_to(bounds, (k, H.shape[0]))
    values, points = np.full(k, np.inf), np.full((k, n), np.nan)
    no_cost, no_lower = np.zeros((n, n)), np.full(H.shape[0], -INFINITY)
    for i in range(k):
        scale = float(np.max(np.abs(bounds[i]), initial=0.0)) or 1.0
        length = float(np.linalg.norm(directions[i])) or 1.0
        cost, upper = np.array(-directions[i] / length, order="C"), np.array(bounds[i] / scale, order="C")
        x, _, flag, _ = daqp.solve(no_cost, cost, H, upper, no_lower, primal_tol=PRIMAL_TOLERANCE, eps_prox=1.0)
        x = x * scale
        if flag != 1:
            result = scipy.optimize.linprog(
                -directions[i], A_ub=H, b_ub=bounds[i], bounds=(None, None), method="highs-ds", options=HIGHS_OPTIONS
            )
            if result.status == 2:
                raise EmptySetError("the polytope {x : H x <= h} is empty (its LP is infeasible)")
            if result.status not in (0, 3):
                raise RuntimeError(f"the support LP failed: DAQP exit flag {flag}, HiGHS: {result.message}")
            x = result.x if result.status == 0 else None
        if x is not None:
            points[i], values[i] = x, directions[i] @ x
    return values, points


@dataclass(frozen=True)
class Polytope:
    """The polyhedron {x : H x ≤ h}, with H's rows scaled to unit length (the same set).

    Attributes
    ----------
    H : (r, n) unit rows;  h : (r,)
    """

    H: np.ndarray
    h: np.ndarray

    def __post_init__(self):
        """Check H (r, n) and h (r,) finite, refuse zero rows, scale the rows to unit length."""
        H = as_matrix(np.atleast_2d(self.H), np.atleast_2d(self.H).shape[1], "H")
        h = as_vector(self.h, H.shape[0], "h")
        norms = np.linalg.norm(H, axis=1)
        if np.any(norms == 0):
            raise ValueError(f"row {int(np.argmin(norms))} of H is zero; give only rows that constrain x")
        object.__setattr__(self, "H", H / norms[:, None])
        object.__setattr__(self, "h", h / norms)

    @classmethod
    def box(cls, lower, upper) -> Polytope:
        """{x : lower ≤ x ≤ upper}, finite bounds with lower ≤ upper; rows (I; −I)."""
        lower = as_vector(lower, np.size(lower), "lower")
        upper = as_vector(upper, lower.size, "upper")
        if np.any(lower > upper):
            raise ValueError(f"the box is empty: lower {lower} > upper {upper}")
        eye = np.eye(lower.size)
        return cls(np.vstack([eye, -eye]), np.concatenate([upper, -lower]))

    @property
    def dimension(self) -> int:
        """n, the number of columns of H."""
        return self.H.shape[1]

    def support_points(self, directions) -> tuple[np.ndarray, np.ndarray]:
        """Support values h(d) (k,) (+inf where unbounded) and maximizers (k, n), by LP."""
        return _maximize(self.H, self.h, as_directions(directions, self.dimension))

    def support(self, directions) -> np.ndarray:
        """h(d) = max {dᵀx : H x ≤ h} for each row d of `directions` (k, n) or one (n,): (k,)."""
        return self.support_points(directions)[0]

    def contains(self, points, tolerance: float = 1e-9) -> np.ndarray:
        """Whether each point (k, n) satisfies H x ≤ h + tolerance: bool (k,)."""
        X = as_directions(points, self.dimension)
        return np.all(X @ self.H.T <= self.h + tolerance, axis=1)

    def preimage(self, matrix) -> Polytope:
        """{x : M x ∈ self} = {x : H M x ≤ h} for M (n, n_x)."""
        M = as_matrix(matrix, np.shape(matrix)[-1], "matrix", rows=self.dimension)
        return Polytope(self.H @ M, self.h)

    def intersect(self, other: Polytope) -> Polytope:
        """self ∩ other: the rows of both."""
        return Polytope(np.vstack([self.H, other.H]), np.concatenate([self.h, other.h]))

    def minus(self, other: ConvexSet) -> Polytope:
        """The Pontryagin difference self ⊖ S = {x : x + S ⊆ self}, exact: H_i x ≤ h_i − h_S(H_i)."""
        return Polytope(self.H, self.h - other.support(self.H))

    def chebyshev_ball(self) -> tuple[np.ndarray, float]:
        """Centre (n,) and radius of the largest ball inside (max r, H x + r ≤ h); < 0 when empty, inf if unbounded."""
        n = self.dimension
        cost = np.zeros(n + 1)
        cost[-1] = -1.0
        result = scipy.optimize.linprog(
            cost,
            A_ub=np.hstack([self.H, np.ones((len(self.h), 1))]),
            b_ub=self.h,
            bounds=(None, None),
            method="highs-ds",
            options=HIGHS_OPTIONS,
        )
        if result.status == 3:
            return np.zeros(n), np.inf
        if result.status != 0:
            raise RuntimeError(f"the Chebyshev-ball LP failed: {result.message}")
        return result.x[:n], float(result.x[-1])

    def without_redundancy(self, tolerance: float = 1e-10) -> Polytope:
        """The same set with the rows the others imply removed (LP per candidate row).

        Duplicate rows go first (the tighter kept). Row i is redundant when max H_i x over the
        other rows, with row i relaxed by 1, is ≤ h_i + tolerance·max(1, max |h|). A screen of all
        rows against all others finds the candidates; they are then removed one at a time,
        each tested against the rows still kept, so two rows that imply each other keep one.
        """
        keys = np.round(self.H, 12)
        order = np.lexsort((self.h, *keys.T[::-1]))
        _, first = np.unique(keys[order], axis=0, return_index=True)
        keep = np.sort(order[first])
        H, h = self.H[keep], self.h[keep]
        relaxed = h + np.eye(h.size)
        values, _ = _maximize(H, relaxed, H)
        slack = np.full(h.size, tolerance * max(1.0, float(np.max(np.abs(h), initial=0.0))))
        kept = np.ones(h.size, dtype=bool)
        for i in np.flatnonzero(values <= h + slack):
            others = kept.copy()
            others[i] = False
            rows = np.vstack([H[others], H[i]])
            value, _ = _maximize(rows, np.concatenate([h[others], [h[i] + 1.0]]), H[i][None, :])
            if value[0] <= h[i] + slack[i]:
                kept[i] = False
        return Polytope(H[kept], h[kept])


@dataclass(frozen=True)
class Zonotope:
    """The zonotope {c + G ξ : ξ ∈ [−1, 1]^m}; a box is one with diagonal G.

    Attributes
    ----------
    center : (n,);  generators : (n, m)
    """

    center: np.ndarray
    generators: np.ndarray

    def __post_init__(self):
        """Check the centre (n,) and generators (n, m) finite and of matching sizes."""
        c = as_vector(self.center, np.size(self.center), "center")
        G = np.asarray(self.generators, dtype=float)
        G = G.reshape(c.size, -1) if G.ndim < 2 else G  # a 1-D zonotope's generators may come flat
        object.__setattr__(self, "center", c)
        object.__setattr__(self, "generators", as_matrix(G, G.shape[1], "generators", rows=c.size))

    @classmethod
    def box(cls, lower, upper) -> Zonotope:
        """The box lower ≤ x ≤ upper (finite, lower ≤ upper); its zero-width sides have no generator."""
        box = Polytope.box(lower, upper)  # checks the bounds
        n = box.dimension
        lower, upper = -box.h[n:], box.h[:n]
        half = (upper - lower) / 2
        return cls((upper + lower) / 2, np.diag(half)[:, half > 0])

    @property
    def dimension(self) -> int:
        """n, the size of the centre."""
        return self.center.size

    def support(self, directions) -> np.ndarray:
        """h(d) = dᵀc + ‖Gᵀd‖₁ for each row of `directions` (k, n): (k,), exact."""
        D = as_directions(directions, self.dimension)
        return D @ self.center + np.abs(D @ self.generators).sum(axis=1)

    def support_points(self, directions) -> tuple[np.ndarray, np.ndarray]:
        """Support values (k,) and maximizers c + G sign(Gᵀd) (k, n)."""
        D = as_directions(directions, self.dimension)
        return self.support(D), self.center + np.sign(D @ self.generators) @ self.generators.T

    def contains(self, points, tolerance: float = 1e-9) -> np.ndarray:
        """Whether each point x (k, n) is c + G ξ with every |ξ_j| ≤ 1 + tolerance (a relative tolerance
        on the zonotope's gauge): bool (k,), by one feasibility LP per point (n rows, m bounded columns)."""
        X = as_directions(points, self.dimension)
        m = self.generators.shape[1]
        inside = np.zeros(len(X), dtype=bool)
        for k, x in enumerate(X):
            result = scipy.optimize.linprog(
                np.zeros(m),
                A_eq=self.generators,
                b_eq=x - self.center,
                bounds=(-1 - tolerance, 1 + tolerance),
                method="highs",
                options=HIGHS_OPTIONS,
            )
            inside[k] = result.status == 0
        return inside

    def linear_map(self, matrix) -> Zonotope:
        """{M x : x ∈ self} = (M c, M G), exact for any M (p, n)."""
        M = as_matrix(matrix, self.dimension, "matrix")
        return Zonotope(M @ self.center, M @ self.generators)

    def plus(self, other: Zonotope) -> Zonotope:
        """The Minkowski sum self ⊕ other = (c₁ + c₂, [G₁ G₂]), exact."""
        if other.dimension != self.dimension:
            raise ValueError(f"cannot add a {other.dimension}-D zonotope to a {self.dimension}-D one")
        return Zonotope(self.center + other.center, np.hstack([self.generators, other.generators]))

    def interval_hull(self) -> tuple[np.ndarray, np.ndarray]:
        """The smallest box containing the zonotope: (lower, upper) = c ∓ |G| 1."""
        radius = np.abs(self.generators).sum(axis=1)
        return self.center - radius, self.center + radius

    def corners(self, limit: int = 2**16) -> np.ndarray:
        """c + G s for every s ∈ {−1, 1}^m, (2^m, n): every vertex is among them."""
        m = self.generators.shape[1]
        if 2**m > limit:
            raise ValueError(f"a zonotope of {m} generators has 2^{m} sign corners, more than limit = {limit}")
        signs = np.array(list(itertools.product((-1.0, 1.0), repeat=m))).reshape(-1, m)
        return self.center + signs @ self.generators.T

    def facet_count(self) -> int:
        """Candidate facets of `facets`: 2·C(m, n − 1) over the m nonzero generators."""
        m = int(np.count_nonzero(np.linalg.norm(self.generators, axis=0)))
        return 2 * math.comb(m, self.dimension - 1)

    def facets(self, limit: int = 5000) -> Polytope:
        """The exact H-representation, for a full-dimensional zonotope of at most `limit` candidate facets.

        Every facet of a zonotope is parallel to n − 1 linearly independent generators, so its
        normal is the generalized cross product of those generators (the signed (n−1)-minors);
        each candidate ±normal with the support value as bound is a supporting half-space, and
        together they are exactly the zonotope. No vertex is enumerated.

        Raises
        ------
        ValueError
            When the zonotope is not full-dimensional (rank G < n), or has more than `limit`
            candidate facets (2·C(m, n − 1)).
        """
        n = self.dimension
        G = self.generators[:, np.linalg.norm(self.generators, axis=0) > 0]
        rank = int(np.linalg.matrix_rank(G)) if G.size else 0
        if rank < n:
            raise ValueError(f"the zonotope is not full-dimensional: its generators span {rank} of {n} dimensions")
        if self.facet_count() > limit:
            raise ValueError(
                f"the zonotope has {self.facet_count()} candidate facets ({G.shape[1]} generators in {n}-D), "
                f"more than limit = {limit}"
            )
        if n == 1:
            normals = np.ones((1, 1))
        else:
            unit = G / np.linalg.norm(G, axis=0)  # the normal's direction does not depend on the lengths
            subsets = np.array(list(itertools.combinations(range(G.shape[1]), n - 1)))
            minors = unit.T[subsets]  # (count, n − 1, n): the rows of each subset's generators
            columns = [np.delete(np.arange(n), j) for j in range(n)]
            normals = np.stack([(-1) ** j * np.linalg.det(minors[:, :, columns[j]]) for j in range(n)], axis=1)
            normals = normals[np.linalg.norm(normals, axis=1) > 1e-10]  # dependent subsets have none
            normals /= np.linalg.norm(normals, axis=1)[:, None]
            sign = np.sign(normals[np.arange(len(normals)), np.argmax(np.abs(normals), axis=1)])
            normals = np.unique(np.round(normals * sign[:, None], 12), axis=0)  # parallel generators repeat
        both = np.vstack([normals, -normals])
        return Polytope(both, self.support(both))


def maximal_invariant_set(closed_loop, constraints: Polytope, iterations: int = 200) -> Polytope:
    """The maximal positively invariant set O_∞ of x⁺ = A_K x inside `constraints` (Gilbert & Tan 1991).

    O_k = {x : C A_K^t x ≤ d, t = 0..k}; each step adds the rows of C A_K^(k+1) that O_k does not
    already imply (LP), and stops at the first k where none is new: then O_{k+1} = O_k, which is
    O_∞ (finitely determined; for Schur A_K and bounded constraints with 0 in their interior it is
    reached). A row counts as implied when its LP maximum exceeds d_i by at most 1e-10·max(1, |d_i|),
    and redundant rows are removed from the result with the tolerance of `Polytope.without_redundancy`.

    Parameters
    ----------
    closed_loop : (nx, nx);  constraints : {C x ≤ d}, e.g. the tightened X̄ ∩ {x : K x ∈ Ū}
    iterations : the cap on k

    Raises
    ------
    EmptySetError (a ValueError)
        When O_k becomes empty or has no interior (no state keeps its successors inside).
    ValueError
        When the set is not determined within `iterations` steps.
    """
    A_K = as_matrix(closed_loop, constraints.dimension, "closed_loop", rows=constraints.dimension)
    C, d = constraints.H, constraints.h
    rows, bounds, current = [C], [d], C
    for k in range(1, integer(iterations, "iterations", minimum=1) + 1):
        current = current @ A_K
        O_k = Polytope(np.vstack(rows), np.concatenate(bounds))
        try:
            values = O_k.support(current)
        except EmptySetError:
            raise EmptySetError(
                f"the maximal invariant set is empty: no state keeps its first {k - 1} successors "
                "inside the constraints"
            ) from None
        flat = np.linalg.norm(current, axis=1) == 0
        if np.any(flat & (d < 0)):
            raise EmptySetError("the maximal invariant set is empty: a constraint excludes the origin A_K^k x = 0")
        new = (values > d + 1e-10 * np.maximum(1.0, np.abs(d))) & ~flat
        if not np.any(new):
            O_inf = O_k.without_redundancy()
            if O_inf.chebyshev_ball()[1] <= 0:
                raise EmptySetError(f"the maximal invariant set has no interior (determined after {k - 1} steps)")
            return O_inf
        rows.append(current[new])
        bounds.append(d[new])
    raise ValueError(
        f"the maximal invariant set is not determined within iterations = {iterations} steps "
        "(Gilbert–Tan); raise the cap, or bound every state the set leaves unbounded"
    )
