"""The sets of a constraint-tightening (tube) linear MPC, computed once with numpy and LPs.

Tube MPC (Mayne, Seron & Raković 2005, "Robust model predictive control of constrained
linear systems with bounded disturbances", Automatica 41(2) 219–224) plans with the nominal
model z⁺ = A z + B v and applies u = v + K (x − z). The error e = x − z of the true system
x⁺ = A x + B u + w, w ∈ W, then follows e⁺ = (A + B K) e + w and stays in any robust
positively invariant (RPI) set Z it starts in, so the nominal plan only has to satisfy

    x ∈ z_0 ⊕ Z,   z_k ∈ X ⊖ Z,   v_k ∈ U ⊖ K Z,   z_N ∈ X_f,

with X_f positively invariant for z⁺ = (A + B K) z inside the tightened sets. This module
builds W, K, Z, the tightened sets and X_f; `build_tube` returns them as `TubeSets`, whose
docstring states what they guarantee. It knows no plant; all coordinates are the MPC's
deviations from its operating point.

The sets (`mpc.sets`) are kept exact: polytopes in H-representation with LP support
functions, zonotopes with closed-form ones; a Pontryagin difference is exact through the
support function, P ⊖ S = {x : H_i x ≤ h_i − h_S(H_i)}.

The minimal RPI set is approximated after Raković, Kerrigan, Kouramas & Mayne (2005),
"Invariant approximations of the minimal robust positively invariant set", IEEE TAC 50(3)
406–410, through support functions only (no vertex enumeration); see
`minimal_rpi_approximation`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from models import deferred
from models.checks import as_matrix, as_vector, integer, positive, real
from models.lqr import dlqr, format_values, state_input_pair

from .sets import HIGHS_OPTIONS, ConvexSet, EmptySetError, Polytope, Zonotope, as_directions, maximal_invariant_set

scipy = deferred.module("scipy")

__all__ = [
    "vertex_models",
    "input_disturbance_set",
    "parametric_error_set",
    "disturbance_set",
    "ancillary_feedback",
    "InvariantApproximation",
    "minimal_rpi_approximation",
    "invariant_polytope",
    "check_minimal_margins",
    "tighten",
    "TubeOptions",
    "TubeSets",
    "build_tube",
]


# ------------------------------------------------------------------ the disturbance set W
def input_disturbance_set(B, bound) -> Zonotope:
    """W_d = B·[−d_max, d_max]: an input disturbance |d_j| ≤ bound_j held over the sample (x⁺ = … + B d).

    Parameters
    ----------
    B : (nx, nu) the discrete input matrix;  bound : (nu,) or a scalar, d_max ≥ 0 in the input's units
    """
    B = np.asarray(B, dtype=float)
    B = as_matrix(B[:, None] if B.ndim == 1 else B, B.shape[1] if B.ndim == 2 else 1, "B")
    bound = as_vector(np.broadcast_to(np.asarray(bound, dtype=float), (B.shape[1],)), B.shape[1], "input_bound")
    if np.any(bound < 0):
        raise ValueError(f"the input disturbance bound must be >= 0, got {bound}")
    return Zonotope(np.zeros(B.shape[0]), B * bound)


def vertex_models(plant, parameters, state, input, sample_period: float) -> tuple[list, list]:
    """The discrete affine models x⁺ = x_e + A_i (x − x_e) + B_i (u − u_e) + a_i of `plant` with each row of
    `parameters` (S, n_params), linearized at one point (state, input) and held over `sample_period` (ZOH).

    a_i = ∫₀^Ts e^{A_i s} ds f_i(x_e, u_e) is what model i drifts in a sample from (x_e, u_e), not its
    equilibrium (the arm's gravity, the ball's weight): the `offsets` of `parametric_error_set`.

    Returns
    -------
    (models, offsets) : [(A_i (nx, nx), B_i (nx, nu))], [a_i (nx,)], one each per row of `parameters`
    """
    Ts = positive(sample_period, "sample_period (s)")
    n, m = plant.nx, plant.nu
    models, offsets = [], []
    for row in np.atleast_2d(parameters):
        continuous = plant.linearize(state, input, params=row, check=False)
        block = np.zeros((n + m + 1, n + m + 1))
        block[:n, :n], block[:n, n : n + m] = continuous.A, continuous.B
        block[:n, -1] = np.asarray(plant.f(state, input, plant.param_vector(row)), dtype=float).ravel()
        held = scipy.linalg.expm(block * Ts)
        models.append((held[:n, :n], held[:n, n : n + m]))
        offsets.append(held[:n, -1])
    return models, offsets


def parametric_error_set(A, B, vertex_models, state_lower, state_upper, input_lower, input_upper, offsets=None):
    """A box containing the one-step model error of every model in the hull of `vertex_models`.

    The error of a model (A_i, B_i, a_i) against the nominal (A, B) at (x, u) is
    E_i(x, u) = (A_i − A) x + (B_i − B) u + a_i. Over the region X × U (a box), each E_i is
    linear in (x, u), so its exact range in row r is the centre value ± the absolute row times
    the half-widths; the box returned is the interval hull of the union of these ranges over i.

    What it covers, and why that is sound: any model in the convex hull, (A_θ, B_θ, a_θ) =
    Σ θ_i (A_i, B_i, a_i) with θ ≥ 0, Σ θ = 1 (and so any that changes from one sample to the
    next inside the hull), has at each (x, u) the error Σ θ_i E_i(x, u), a convex combination of
    points of the box, hence in the box. It covers nothing outside: a parameter whose model is
    not in the hull of the supplied corners (A(p), B(p) are not affine in p, so the corners of
    a ±5 % box need not span its interior's models: add interior models to the list), a state or
    input outside the region, and the linearization's remainder for a nonlinear plant.

    Parameters
    ----------
    A, B : (nx, nx), (nx, nu) the nominal (prediction) model
    vertex_models : sequence of (A_i, B_i) pairs, the models at the corners of the parameter box
    state_lower, state_upper : (nx,) the region X the states stay in (deviation coordinates)
    input_lower, input_upper : (nu,) the region U of the input applied to the plant (u + d)
    offsets : optional sequence of (nx,) affine terms a_i (x⁺ = A_i x + B_i u + a_i), e.g. when
        the nominal operating point is not an equilibrium of model i

    Returns
    -------
    Zonotope, the box (an axis-aligned zonotope; sides of zero width have no generator)
    """
    A, B = state_input_pair(A, B)
    n, m = B.shape
    region = Polytope.box(
        np.concatenate([as_vector(state_lower, n, "state_lower"), as_vector(input_lower, m, "input_lower")]),
        np.concatenate([as_vector(state_upper, n, "state_upper"), as_vector(input_upper, m, "input_upper")]),
    )
    upper_region, lower_region = region.h[: n + m], -region.h[n + m :]
    middle, half = (upper_region + lower_region) / 2, (upper_region - lower_region) / 2
    models = list(vertex_models)
    if not models:
        raise ValueError("vertex_models is empty; give the (A_i, B_i) of the parameter box's corners")
    shifts = [np.zeros(n)] * len(models) if offsets is None else list(offsets)
    if len(shifts) != len(models):
        raise ValueError(f"need one offset per vertex model: {len(models)} models, {len(shifts)} offsets")
    low, high = np.full(n, np.inf), np.full(n, -np.inf)
    for i, ((A_i, B_i), a_i) in enumerate(zip(models, shifts)):
        A_i, B_i = state_input_pair(A_i, B_i)
        if A_i.shape != A.shape or B_i.shape != B.shape:
            raise ValueError(f"vertex model {i} has shapes {A_i.shape}, {B_i.shape}; need {A.shape}, {B.shape}")
        error = np.hstack([A_i - A, B_i - B])
        centre = error @ middle + as_vector(a_i, n, f"offset {i}")
        radius = np.abs(error) @ half
        low, high = np.minimum(low, centre - radius), np.maximum(high, centre + radius)
    return Zonotope.box(low, high)


def disturbance_set(
    A,
    B,
    *,
    input_bound=0.0,
    vertex_models=(),
    state_lower=None,
    state_upper=None,
    input_lower=None,
    input_upper=None,
    offsets=None,
) -> Zonotope:
    """W for x⁺ = A x + B u + w: the input disturbance and the parametric error together.

    With the true model x⁺ = A_θ x + B_θ (u + d), |d| ≤ d_max,

        x⁺ − (A x + B u) = B d + (A_θ − A) x + (B_θ − B)(u + d),

    so W = B·[−d_max, d_max] ⊕ E(X × (U ⊕ [−d_max, d_max])): the parametric error's input region
    is widened by the disturbance (`parametric_error_set`). Without vertex models, W = B·[−d_max, d_max].

    Parameters
    ----------
    input_bound : (nu,) or scalar d_max ≥ 0
    vertex_models, state_lower, state_upper, input_lower, input_upper, offsets : as `parametric_error_set`,
        with the input region that of u (the tightened input bounds lie inside the physical ones)
    """
    A, B = state_input_pair(A, B)
    W = input_disturbance_set(B, input_bound)
    if not list(vertex_models):
        return W
    if any(v is None for v in (state_lower, state_upper, input_lower, input_upper)):
        raise ValueError("a parametric error needs its region: state_lower, state_upper, input_lower, input_upper")
    d = np.broadcast_to(np.asarray(input_bound, dtype=float), (B.shape[1],))
    widened = (
        as_vector(input_lower, B.shape[1], "input_lower") - d,
        as_vector(input_upper, B.shape[1], "input_upper") + d,
    )
    error = parametric_error_set(A, B, vertex_models, state_lower, state_upper, *widened, offsets=offsets)
    return W.plus(error)


# ------------------------------------------------------- ancillary feedback and the error's set Z
def ancillary_feedback(A, B, state_weight, input_weight) -> np.ndarray:
    """K of u = v + K (x − z): the discrete LQR of (A, B, Q, R), signed so that A + B K is the closed loop.

    `models.lqr.dlqr` returns the gain of u = −K_lqr x; this is −K_lqr, (nu, nx).
    """
    gain, _ = dlqr(A, B, state_weight, input_weight, "tube ancillary feedback")
    return -gain


def _schur(closed_loop) -> np.ndarray:
    """A_K as a finite square matrix; ValueError (an empty tube) unless every |eigenvalue| < 1."""
    A_K = as_matrix(closed_loop, np.shape(closed_loop)[-1], "A + B K", rows=np.shape(closed_loop)[-1])
    poles = np.linalg.eigvals(A_K)
    if np.any(np.abs(poles) >= 1):
        bad = poles[np.abs(poles) >= 1]
        raise ValueError(
            f"the tube is empty: A + B K is not Schur (eigenvalue(s) {format_values(bad)} with |z| >= 1), so no "
            "bounded set holds the error e⁺ = (A + B K) e + w; choose a stabilizing ancillary feedback K"
        )
    return A_K


@dataclass(frozen=True)
class InvariantApproximation:
    """F(α, s) = (1 − α)⁻¹ ⊕_{i<s} A_K^i W: an RPI outer approximation of the minimal RPI set F_∞.

    Raković et al. (2005): when A_K^s W ⊆ α W with 0 ∈ int W and 0 ≤ α < 1,
    F(α, s) is convex, compact and RPI for e⁺ = A_K e + w, w ∈ W, and with F_s = ⊕_{i<s} A_K^i W,

        F_∞ ⊆ F(α, s) = F_s ⊕ α (1 − α)⁻¹ F_s ⊆ F_∞ ⊕ {e : |e_j| ≤ ε_j},
        ε_j = α (1 − α)⁻¹ max(h_{F_s}(e_j), h_{F_s}(−e_j))        (the paper's ε-ball, per state);

    per direction, h_{F_∞}(d) ≤ h_{F(α,s)}(d) ≤ h_{F_∞}(d) / (1 − α).

    Attributes
    ----------
    closed_loop : (nx, nx) A_K = A + B K;  disturbance : W (a `Zonotope` or a `Polytope`)
    alpha : α;  terms : s;  epsilon : (nx,) ε_j in each state's unit
    """

    closed_loop: np.ndarray
    disturbance: Zonotope | Polytope
    alpha: float
    terms: int
    epsilon: np.ndarray

    @property
    def dimension(self) -> int:
        """nx, the error's dimension."""
        return self.closed_loop.shape[0]

    def support(self, directions) -> np.ndarray:
        """h_{F(α,s)}(d) = (1 − α)⁻¹ Σ_{i<s} h_W((A_K^i)ᵀ d), (k,): exact (W's own support function)."""
        D = as_directions(directions, self.dimension)
        total = np.zeros(D.shape[0])
        for _ in range(self.terms):
            total += self.disturbance.support(D)
            D = D @ self.closed_loop
        return total / (1 - self.alpha)

    def zonotope(self) -> Zonotope:
        """F(α, s) as a zonotope, for a zonotope W: centre and generators (1 − α)⁻¹ A_K^i (c, G), i < s."""
        W = self.disturbance
        if not isinstance(W, Zonotope):
            raise TypeError(f"F(α, s) is a zonotope only when W is one; W is a {type(W).__name__}")
        centre, blocks, power = np.zeros(self.dimension), [], np.eye(self.dimension)
        for _ in range(self.terms):
            centre += power @ W.center
            blocks.append(power @ W.generators)
            power = self.closed_loop @ power
        return Zonotope(centre / (1 - self.alpha), np.hstack(blocks) / (1 - self.alpha))


def _disturbance_facets(W: Zonotope | Polytope, facet_limit: int) -> Polytope:
    """W = {f_jᵀ w ≤ g_j} with every g_j > 0 (0 ∈ int W), or ValueError saying why α < 1 cannot be met."""
    hint = "; add a small box to W for the error the model leaves out, so that 0 is inside W"
    if isinstance(W, Zonotope):
        try:
            facets = W.facets(facet_limit)
        except ValueError as error:
            raise ValueError(f"the tube is empty: A_K^s W ⊆ α W cannot hold for α < 1, as {error}{hint}") from None
    elif isinstance(W, Polytope):
        facets = W
        if not np.all(np.isfinite(W.support(np.vstack([np.eye(W.dimension), -np.eye(W.dimension)])))):
            raise ValueError("the disturbance set W is unbounded; the tube would be too")
    else:
        raise TypeError(f"the disturbance set W must be a Zonotope or a Polytope, got {type(W).__name__}")
    if np.any(facets.h <= 0):
        j = int(np.argmin(facets.h))
        raise ValueError(
            f"the tube is empty: the origin is not in the interior of W (facet {j}, normal {facets.H[j]}, "
            f"has bound {facets.h[j]:.3g} <= 0), so A_K^s W ⊆ α W cannot hold for α < 1{hint}"
        )
    return facets


def minimal_rpi_approximation(
    closed_loop, disturbance, relative_epsilon: float = 0.01, max_terms: int = 5000, facet_limit: int = 5000
) -> InvariantApproximation:
    """F(α, s) of Raković et al. (2005) for e⁺ = A_K e + w, w ∈ W: the smallest s that meets the accuracy.

    With W = {f_jᵀ w ≤ g_j} (a zonotope's exact facets), α°(s) = max_j h_W((A_K^s)ᵀ f_j) / g_j is
    the smallest α with A_K^s W ⊆ α W (the paper's eq. (11)); s is the first with
    α°(s) / (1 − α°(s)) ≤ relative_epsilon, so F(α, s) ⊆ (1 + relative_epsilon) F_∞ in every
    direction, and α = α°(s). Only support functions are evaluated.

    Parameters
    ----------
    closed_loop : (nx, nx) A_K = A + B K, Schur
    disturbance : W, a full-dimensional `Zonotope` (boxes included) or a bounded `Polytope`, 0 ∈ int W
    relative_epsilon : > 0, the relative accuracy above
    max_terms : cap on s;  facet_limit : cap on W's candidate facets

    Raises
    ------
    ValueError
        The tube is empty (A_K not Schur, 0 not in the interior of W: W flat, e.g. an input
        disturbance alone), or not computed: no s ≤ max_terms meets the accuracy (the message gives α°(max_terms)
        and about how many more terms it would take at the rate ρ(A_K) per term).
    """
    A_K = _schur(closed_loop)
    n = A_K.shape[0]
    rel = positive(relative_epsilon, "relative_epsilon")
    max_terms = integer(max_terms, "max_terms", minimum=1)
    facets = _disturbance_facets(disturbance, integer(facet_limit, "facet_limit", minimum=2))
    if disturbance.dimension != n:
        raise ValueError(f"W is {disturbance.dimension}-dimensional, the error e has {n} states")
    target = rel / (1 + rel)
    rows, axes, reach = facets.H, np.vstack([np.eye(n), -np.eye(n)]), np.zeros(2 * n)
    alpha, terms = np.inf, 0
    while terms < max_terms:
        terms += 1
        reach += disturbance.support(axes)  # h_{F_s}(±e_j) with s = terms
        axes, rows = axes @ A_K, rows @ A_K
        alpha = float(np.max(disturbance.support(rows) / facets.h))
        if alpha <= target:
            break
    if alpha > target:
        rho = float(np.max(np.abs(np.linalg.eigvals(A_K))))
        more = int(np.ceil(np.log(alpha / target) / -np.log(rho))) if 0 < rho < 1 else 0
        raise ValueError(
            f"the tube is not computed to the accuracy asked: A_K^s W ⊆ α W needs α <= {target:.4g} "
            f"(relative_epsilon {rel:g}), but at s = max_terms = {max_terms} the smallest α is {alpha:.4g}; "
            f"A_K is Schur (spectral radius {rho:.6g}), so α falls about {rho:.6g}× per term and about "
            f"{more} more terms would reach it (a W thin in some direction, as a small interior box makes it, "
            "needs many): raise max_terms or relative_epsilon, or make K faster"
        )
    epsilon = alpha / (1 - alpha) * np.maximum(reach[:n], reach[n:])
    return InvariantApproximation(A_K, disturbance, max(alpha, 0.0), terms, epsilon)


def _least_rpi_bounds(A_K: np.ndarray, W: ConvexSet, core: np.ndarray, chains: np.ndarray, length: int):
    """Template rows D and bounds c making {D e ≤ c} RPI, by one LP.

    The template D is `core` (unit rows) and, for each row d of `chains`, the chain d A_K^t / ‖d A_K^t‖,
    t = 0..length. The LP (after Trodden 2016, IEEE TAC 61(12), "A one-step approach to computing a
    polytopic robust positively invariant set") is

        maximize Σ c   subject to   c_i ≤ d_iᵀ A_K ξ_i + h_W(d_i),  core_rows ξ_i ≤ c_core
                                    (each core row and each chain's last row i, one ξ_i each),
                                    c_t ≤ γ_t c_{t+1} + h_W(d_t)   (a chain's row t and the next,
                                    γ_t = ‖d_t A_K‖, as d_t A_K = γ_t d_{t+1} exactly).

    Each right-hand side T'_i(c) bounds d_iᵀ(A_K e + w) over e in the template polytope (which the
    core rows alone contain, a relaxation), so c ≥ T'(c) is RPI. T' rises with c, so at the LP's
    maximum of {c ≤ T'(c)} every constraint holds with equality: c = T'(c), RPI. Along a chain,
    c_0 = Σ_t (Π γ) h_W(d_t) + the tail: the mRPI set's support value in d_0 truncated at `length`
    terms, plus what the core bounds beyond.
    """
    sparse = scipy.sparse
    heads = chains / np.linalg.norm(chains, axis=1)[:, None]
    links, gains = [heads], []
    for _ in range(length):
        following = links[-1] @ A_K
        if not np.all(np.linalg.norm(following, axis=1) > 0):
            break  # a nilpotent A_K ends the chain: dᵀA_K^t = 0
        gains.append(np.linalg.norm(following, axis=1))
        links.append(following / gains[-1][:, None])
    length = len(gains)
    chain_rows = np.stack(links, axis=1).reshape(-1, A_K.shape[0])  # chain j's links at j·(length+1) + t
    D = np.vstack([core, chain_rows])
    rc, n, m, r = len(core), A_K.shape[0], len(chains), len(D)
    owners = np.concatenate([np.arange(rc), rc + np.arange(m) * (length + 1) + length])  # rows with a ξ
    pick = sparse.csr_matrix((np.ones(len(owners)), (np.arange(len(owners)), owners)), shape=(len(owners), r))
    take_core = sparse.csr_matrix((np.ones(rc), (np.arange(rc), np.arange(rc))), shape=(rc, r))
    inside = sparse.hstack(
        [-sparse.kron(np.ones((len(owners), 1)), take_core), sparse.kron(sparse.eye(len(owners)), core)]
    )
    image = sparse.hstack([pick, -sparse.block_diag([row[None, :] for row in D[owners] @ A_K])])
    linked = rc + (np.arange(m)[:, None] * (length + 1) + np.arange(length)).reshape(-1)  # rows t < length
    gamma = np.array(gains).T.reshape(-1) if length else np.zeros(0)  # in the order of `linked`
    count = np.arange(len(linked))
    values = np.concatenate([np.ones(len(linked)), -gamma])
    step = sparse.csr_matrix((values, (np.r_[count, count], np.r_[linked, linked + 1])), shape=(len(linked), r))
    step = sparse.hstack([step, sparse.csr_matrix((len(linked), len(owners) * n))])
    h_W = W.support(D)
    result = scipy.optimize.linprog(
        np.concatenate([-np.ones(r), np.zeros(len(owners) * n)]),
        A_ub=sparse.vstack([inside, image, step], format="csr"),
        b_ub=np.concatenate([np.zeros(len(owners) * rc), h_W[owners], h_W[linked]]),
        bounds=(None, None),
        method="highs-ds",
        options=HIGHS_OPTIONS,
    )
    if result.status != 0:
        raise ValueError(f"the template of {r} directions admits no bounded RPI polytope (LP: {result.message})")
    return D, result.x[:r]


def _certified(A_K: np.ndarray, W: ConvexSet, D: np.ndarray, c: np.ndarray) -> np.ndarray:
    """c dilated to (1 + δ + η) c so that {D e ≤ c} is RPI, verified by LP; ValueError when it cannot be.

    With r = T(c) − c < h_W(D), T((1 + δ) c) = (1 + δ) T(c) − δ h_W(D) ≤ (1 + δ) c for δ ≥ max r_i / (h_W(d_i) − r_i)
    (the polytope scales with c). The further η = max(1e-9, 1e-8 max c / min h_W(D)) leaves every row a
    margin η h_W(d_i) ≥ 1e-8 max c, a hundred times the LPs' feasibility tolerance, for the verification.
    """
    disturbance_support = W.support(D)
    residual = Polytope(D, c).support(D @ A_K) + disturbance_support - c
    room = disturbance_support - residual
    if np.all(room > 0):
        margin = max(1e-9, 1e-8 * float(np.max(np.abs(c))) / float(np.min(disturbance_support)))
        c = c * (1 + max(0.0, float(np.max(residual / room))) + margin)
        if np.all(Polytope(D, c).support(D @ A_K) + disturbance_support <= c):
            return c
    raise ValueError(f"the polytope could not be certified RPI (largest residual {float(np.max(residual)):.3g})")


def invariant_polytope(
    approximation: InvariantApproximation,
    *,
    facet_limit: int = 5000,
    template=None,
    contraction: float | None = None,
    iterations: int = 200,
    chain_length: int | None = None,
) -> tuple[Polytope, bool]:
    """An RPI polytope Z ⊇ F_∞ in H-representation, certified by LP; and whether Z is F(α, s) itself.

    Exact: when W is a zonotope and F(α, s) has at most `facet_limit` candidate facets, Z is
    F(α, s) by its facets (`Zonotope.facets`), dilated by 1 + η against round-off (`_certified`:
    η ≥ 1e-9, typically below 1e-6), with the ε of `approximation`.

    Otherwise Z is an RPI polytope {D e ≤ c} of a template D, its bounds from one LP
    (`_least_rpi_bounds`). D is a core of the facets of the maximal λ-contractive set of A_K in
    F(α, s)'s interval hull (λ = `contraction`, default (1 + ρ(A_K)) / 2; Gilbert–Tan capped at
    `iterations`), in which an RPI set exists, and ±e_j; and for each row d of `template` (the
    constraint rows to tighten, (r, nx)) the chain d A_K^t, t ≤ `chain_length` (default s), along
    which h_Z(d) comes out as the mRPI set's support value truncated at that many terms plus the
    core's tail. Z ⊇ F_∞ (every closed RPI set does), so h_Z(d) ≥ (1 − α) h_{F(α,s)}(d).

    Returns
    -------
    (Z, exact) : the Polytope (redundant rows removed) and whether it is F(α, s)

    Raises
    ------
    ValueError
        When the template admits no RPI polytope, or the certificate fails.
    """
    A_K, W, n = approximation.closed_loop, approximation.disturbance, approximation.dimension
    if isinstance(W, Zonotope):
        zonotope = approximation.zonotope()
        if zonotope.facet_count() <= facet_limit:
            facets = zonotope.facets(facet_limit).without_redundancy()
            return Polytope(facets.H, _certified(A_K, W, facets.H, facets.h)), True
    axes = np.vstack([np.eye(n), -np.eye(n)])
    half = np.max(approximation.support(axes).reshape(2, n), axis=0)
    rho = float(np.max(np.abs(np.linalg.eigvals(A_K))))
    lam = (1 + rho) / 2 if contraction is None else real(contraction, "contraction")
    if not rho < lam < 1:
        raise ValueError(f"contraction λ must be in (ρ(A_K), 1) = ({rho:.4g}, 1), got {lam}")
    contractive = maximal_invariant_set(A_K / lam, Polytope.box(-half, half), iterations).H
    core = np.unique(np.round(np.vstack([contractive, axes]), 12), axis=0)
    heads = np.zeros((0, n)) if template is None else as_matrix(template, n, "template")
    length = approximation.terms if chain_length is None else integer(chain_length, "chain_length", minimum=0)
    D, c = _least_rpi_bounds(A_K, W, core, heads, length if len(heads) else 0)
    reduced = Polytope(D, c).without_redundancy()  # then certified: the rows returned are the rows verified
    return Polytope(reduced.H, _certified(A_K, W, reduced.H, reduced.h)), False


# ------------------------------------------------------------------ tightening and the tube's record
def check_minimal_margins(approximation: InvariantApproximation, rows, bounds, labels: Sequence[str]) -> None:
    """Refuse, before any polytope is built, a row {rows_i e ≤ bounds_i} that no RPI set of A_K and W fits.

    Every RPI set of e⁺ = A_K e + w, w ∈ W, containing 0 contains F_∞, so its margin h_Z(d) is at
    least h_{F_∞}(d) ≥ (1 − α) h_{F(α,s)}(d) (`InvariantApproximation`): a row whose bound is not above
    that lower bound cannot be tightened by any tube of this K and W, whatever Z is computed.

    Parameters
    ----------
    approximation : F(α, s) of A_K and W;  rows : (r, nx) the rows d_i;  bounds : (r,)
    labels : (r,) what each row is, for the message ("state constraint 'theta1 upper'")

    Raises
    ------
    ValueError
        Naming every such row, the largest lack relative to its bound first: its name, at least how much
        it lacks, its bound and the least margin it needs.
    """
    needed = (1 - approximation.alpha) * approximation.support(rows)
    bounds = np.asarray(bounds, dtype=float)
    bad = lacking_rows(needed, bounds)
    if bad:
        parts = [
            f"{labels[i]} lacks at least {needed[i] - bounds[i]:.3g} (bound {bounds[i]:.6g}, needs a margin of at "
            f"least {needed[i]:.6g})"
            for i in bad
        ]
        raise ValueError(
            "the error set is larger than the constraints can hold, for every RPI set of this K and W: "
            + "; ".join(parts)
            + " (a margin at least the minimal RPI set's support in the row's direction). Loosen the "
            "constraint, shrink W (the parametric region or the disturbance) or change K"
        )


def lacking_rows(margins: np.ndarray, bounds: np.ndarray) -> list[int]:
    """The rows whose margin is not below their bound, the largest lack relative to its bound first."""
    bad = np.flatnonzero(margins >= bounds)
    relative = (margins[bad] - bounds[bad]) / np.maximum(np.abs(bounds[bad]), 1e-300)
    return [int(i) for i in bad[np.argsort(-relative, kind="stable")]]


def tighten(rows, bounds, error_set: ConvexSet, names: Sequence[str], what: str = "constraint"):
    """{y : rows y ≤ bounds} ⊖ S as bounds − h_S(rows_i) (exact for any convex S), refusing a row it empties.

    For the state constraints, rows = G and S = Z; for the inputs, rows = (K; −K) (the state rows
    of K e) and S = Z, which is U ⊖ K Z.

    Returns
    -------
    (tightened, margins) : (r,) each, tightened = bounds − margins, margins = h_S(rows_i)

    Raises
    ------
    ValueError
        Naming every row whose tightened bound is ≤ 0 (the operating point is then not strictly
        inside it), the largest lack relative to its bound first: its name, how much it lacks, its
        bound and the margin h_S it needs.
    """
    margins = error_set.support(rows)
    bounds = np.asarray(bounds, dtype=float)
    tightened = bounds - margins
    bad = lacking_rows(margins, bounds)
    if bad:
        parts = [
            f"{what} {names[i]!r} lacks {margins[i] - bounds[i]:.3g} (bound {bounds[i]:.6g}, needs a margin of "
            f"{margins[i]:.6g} for the error set)"
            for i in bad
        ]
        raise ValueError(
            "the error set is larger than the constraints can hold: "
            + "; ".join(parts)
            + ". Loosen the constraint, shrink W (the parametric region or the disturbance) or change K"
        )
    return tightened, margins


@dataclass(frozen=True)
class TubeOptions:
    """How `build_tube` computes its sets (the caps are counted in iterations, never in time).

    Attributes
    ----------
    relative_epsilon : F(α, s) ⊆ (1 + relative_epsilon) F_∞ direction by direction (α/(1 − α) ≤ it)
    max_terms : cap on s, the terms of F(α, s)
    facet_limit : the most candidate facets of F(α, s) enumerated for an exact Z (0: Z from the template)
    template : rows (r, nx) added to Z's template when F(α, s) has more facets than `facet_limit`
        (the constraint rows G and ±K are always added; `invariant_polytope`)
    contraction : λ of the template's contractive set, in (ρ(A_K), 1); None: (1 + ρ(A_K)) / 2
    iterations : the Gilbert–Tan cap, of the terminal set and of the template's contractive set
    zonotope : Z is F(α, s) itself as a zonotope (W must be one), RPI by Raković et al.'s theorem with
        support values in closed form: no facets and no LP, for a state whose template LP is too large
        (its size grows with the contractive core's rows squared); membership costs an LP per point
    """

    relative_epsilon: float = 0.01
    max_terms: int = 5000
    facet_limit: int = 5000
    template: np.ndarray | None = None
    contraction: float | None = None
    iterations: int = 200
    zonotope: bool = False


@dataclass(frozen=True)
class TubeSets:
    """The sets a tube MPC needs, in the MPC's deviation coordinates, and what they guarantee.

    What is guaranteed (the argument of Mayne, Seron & Raković 2005, Automatica 41(2), with the
    sets here): let the plant be the LTI prediction model with an additive
    disturbance, x⁺ = A x + B u + w, with w_k ∈ W at every step, and the state x measured. Let
    the controller solve, at each sample, the nominal problem over (z_0, v_0..v_{N−1}) with
    z_{k+1} = A z_k + B v_k and the constraints

        x − z_0 ∈ Z (error_set),  z_k ∈ X̄ = X ⊖ Z (state_constraints), k < N,
        v_k ∈ [input_lower, input_upper] = U ⊖ K Z,  z_N ∈ X_f (terminal_set),

    and apply u = v_0 + K (x − z_0). If that problem is feasible at the first sample, then it is
    feasible at every later sample (recursive feasibility: the shifted plan with the terminal
    move K z_N is feasible, since A_K X_f ⊆ X_f ⊆ X̄, K X_f ⊆ Ū and Z is RPI), and the true
    state and input satisfy G x_k ≤ g and the input bounds at every sample, for every
    disturbance sequence in W. With z_0 fixed to the nominal successor (z as the controller's
    state, x_0 − z_0 ∈ Z at the start) the same holds. The paper's robust exponential stability
    of Z also needs the MPC's terminal cost to be a Lyapunov function of A_K (the Riccati
    P when K is the LQR gain of the same Q, R); these sets do not fix the cost.

    Numbers: a zonotope Z (`TubeOptions.zonotope`) is F(α, s), RPI by Raković et al.'s theorem for
    the α found with A_K^s W ⊆ α W (support values, exact up to round-off); a polytope Z is verified
    RPI by LP after a dilation that leaves each row a margin of at least 1e-8·max h_Z against the
    LPs' round-off (`invariant_polytope`); the margins are DAQP LP optima (exact to about 1e-12
    relative in the tests); X_f is invariant to 1e-10·max(1, |d|)
    (`maximal_invariant_set`).

    For a nonlinear plant, only what W covers is guaranteed: the guarantee holds while the
    plant's one-step deviation x⁺ − (A x + B u) is in W, which `disturbance_set` ensures for a
    model in the hull of the supplied vertex models (possibly varying from step to step), an
    input disturbance within its bound held over the sample, and (x, u) in the region the
    parametric error was bounded on. That region must contain X and U for the argument to
    close (give the region's state box as constraints too). Not covered: the linearization's
    remainder of the nonlinear dynamics, parameters whose models leave the vertices' hull,
    measurement noise or estimation error, and delays.

    Attributes
    ----------
    feedback : (nu, nx) K of u = v + K (x − z) (note: −(models.lqr.dlqr's K))
    closed_loop : (nx, nx) A + B K
    disturbance : W;  approximation : F(α, s) with alpha, terms (s) and epsilon (ε per state)
    error_set : Z, an RPI Polytope ⊇ F_∞, or F(α, s) as a Zonotope (`TubeOptions.zonotope`);
        error_set_exact : whether Z is F(α, s) (its facets, or the zonotope) or a template's
    state_constraints : X̄ = {G x ≤ g − h_Z(G_i)};  state_margins : (ns,) h_Z(G_i)
    state_constraint_names : (ns,) names of X's rows, for messages
    input_lower, input_upper : (nu,) the tightened input bounds (v's);  input_margins : (2 nu,)
        h_Z(K_j) then h_Z(−K_j)
    terminal_set : X_f, the maximal positively invariant set of A + B K in X̄ ∩ {K z ∈ Ū}
    """

    feedback: np.ndarray
    closed_loop: np.ndarray
    disturbance: Zonotope | Polytope
    approximation: InvariantApproximation
    error_set: Polytope | Zonotope
    error_set_exact: bool
    state_constraints: Polytope
    state_margins: np.ndarray
    state_constraint_names: tuple[str, ...]
    input_lower: np.ndarray
    input_upper: np.ndarray
    input_margins: np.ndarray
    terminal_set: Polytope

    @property
    def alpha(self) -> float:
        """α of F(α, s): A_K^s W ⊆ α W."""
        return self.approximation.alpha

    @property
    def terms(self) -> int:
        """s of F(α, s), its number of terms."""
        return self.approximation.terms

    @property
    def epsilon(self) -> np.ndarray:
        """(nx,) ε_j: F(α, s) ⊆ F_∞ ⊕ {|e_j| ≤ ε_j}."""
        return self.approximation.epsilon


def build_tube(
    A,
    B,
    disturbance: Zonotope | Polytope,
    state_constraints: Polytope,
    input_lower,
    input_upper,
    *,
    state_weight=None,
    input_weight=None,
    feedback=None,
    state_constraint_names: Sequence[str] | None = None,
    options: TubeOptions | None = None,
) -> TubeSets:
    """The tube MPC's sets for x⁺ = A x + B u + w, w ∈ W (see `TubeSets` for the guarantee).

    Parameters
    ----------
    A, B : (nx, nx), (nx, nu) the discrete prediction model, in deviations from the operating point
    disturbance : W, e.g. `disturbance_set(...)`
    state_constraints : X = {G x ≤ g}, the physical limits in deviation coordinates
    input_lower, input_upper : (nu,) the input bounds in deviations (−u_max − ue, u_max − ue)
    state_weight, input_weight : Q, R of the ancillary LQR (both, when `feedback` is not given)
    feedback : (nu, nx) K of u = v + K (x − z), instead of the LQR
    state_constraint_names : (ns,) names of X's rows; default "row i"
    options : TubeOptions

    Raises
    ------
    ValueError
        Naming the culprit: non-finite or misshapen data; an empty tube (A + B K not Schur,
        0 ∉ int W, α not reached); a constraint the error set does not fit in (row, bound,
        margin lacking), refused from the minimal RPI set's lower bound before Z is built when no RPI
        set of this K and W fits (`check_minimal_margins`), else from Z; an empty terminal set or one
        that does not contain the origin.
    """
    options = TubeOptions() if options is None else options
    A, B = state_input_pair(A, B)
    n, m = B.shape
    if feedback is None:
        if state_weight is None or input_weight is None:
            raise ValueError("give the ancillary feedback K, or both weights Q and R of its LQR")
        K = ancillary_feedback(A, B, state_weight, input_weight)
    else:
        K = as_matrix(feedback, n, "feedback K", rows=m)
    if not isinstance(state_constraints, Polytope):
        raise TypeError(f"state_constraints must be a Polytope {{G x <= g}}, got {type(state_constraints).__name__}")
    if state_constraints.dimension != n:
        raise ValueError(f"the state constraints are {state_constraints.dimension}-dimensional; the model has {n}")
    lower, upper = as_vector(input_lower, m, "input_lower"), as_vector(input_upper, m, "input_upper")
    names = tuple(state_constraint_names or (f"row {i}" for i in range(len(state_constraints.h))))
    if len(names) != len(state_constraints.h):
        raise ValueError(f"need {len(state_constraints.h)} state_constraint_names, got {len(names)}")
    approximation = minimal_rpi_approximation(A + B @ K, disturbance, options.relative_epsilon, options.max_terms)
    input_rows, input_bounds = np.vstack([K, -K]), np.concatenate([upper, -lower])
    input_names = [f"input {j} upper" for j in range(m)] + [f"input {j} lower" for j in range(m)]
    check_minimal_margins(
        approximation,
        np.vstack([state_constraints.H, input_rows]),
        np.concatenate([state_constraints.h, input_bounds]),
        [*(f"state constraint {name!r}" for name in names), *(f"input bound {name!r}" for name in input_names)],
    )
    Z: Polytope | Zonotope
    if options.zonotope:
        if not isinstance(disturbance, Zonotope):
            raise TypeError(f"TubeOptions.zonotope needs W as a Zonotope, got {type(disturbance).__name__}")
        Z, exact = approximation.zonotope(), True
    else:
        Z, exact = invariant_polytope(
            approximation,
            facet_limit=options.facet_limit,
            template=np.vstack([*([] if options.template is None else [options.template]), state_constraints.H, K, -K]),
            contraction=options.contraction,
            iterations=options.iterations,
        )
    g_bar, state_margins = tighten(state_constraints.H, state_constraints.h, Z, names, "state constraint")
    u_bar, input_margins = tighten(input_rows, input_bounds, Z, input_names, "input bound")
    X_bar = Polytope(state_constraints.H, g_bar)
    eye = np.eye(m)
    admissible = X_bar.intersect(Polytope(np.vstack([eye, -eye]), u_bar).preimage(K))
    try:
        terminal = maximal_invariant_set(A + B @ K, admissible, options.iterations)
    except ValueError as error:  # EmptySetError or the iteration cap, said of the terminal set
        raise type(error)(f"the terminal set is refused: {error}") from None
    if not terminal.contains(np.zeros(n), tolerance=0.0)[0]:
        raise EmptySetError("the terminal set is refused: it does not contain the origin (the operating point)")
    return TubeSets(
        feedback=K,
        closed_loop=A + B @ K,
        disturbance=disturbance,
        approximation=approximation,
        error_set=Z,
        error_set_exact=exact,
        state_constraints=X_bar,
        state_margins=state_margins,
        state_constraint_names=names,
        input_lower=-u_bar[m:],
        input_upper=u_bar[:m],
        input_margins=input_margins,
        terminal_set=terminal,
    )
