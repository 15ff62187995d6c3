"""Successive loop closure: cascade transfer functions from the linearization, inner and outer loops.

The cascade u → q_inner → q_outer (for example a cart's force → pendulum
angle → cart position) comes from the plant's exact linearization
q̈ = A_q q + A_v q̇ + B u, not from hand algebra:

- inner plant: the inner coordinate's own row, q̈_i = A_q[i,i] q_i + A_v[i,i] q̇_i + B_i u,
  with the outer coordinate's terms dropped (the "disturbances that have
  been ignored"); `CascadePlants.dropped` lists them.
- outer plant: the exact ratio (q_outer/u)/(q_inner/u) of the full
  linearization's transfer functions, which eliminates u (for a pendulum on
  a cart, (g − ℓ s²)/s²).

The outer loop is designed on K_DC·G_outer, the inner loop replaced by its
DC gain K_DC. Textbooks often assume K_DC = 1; we use the computed value
(it is not 1 when the inner plant has a static term a0 ≠ 0).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Generic, Literal, TypeVar

import casadi as ca
import numpy as np

import models
from models import deferred
from models.linear import LinearModel, chop

from .analysis.polynomials import as_polynomials, poly_add, poly_mul, polynomial, tf, zeros_at_origin
from .filters import TustinSection, padded_coefficients
from .pid import PID, PDDesign, numbers_repr, pd_design, pd_saturation, second_order_coefficients

if TYPE_CHECKING:
    import control
else:
    control = deferred.module("control")
scipy = deferred.module("scipy")

__all__ = [
    "CascadePlants",
    "cascade_plants",
    "coordinate_model",
    "low_frequency_model",
    "zero_cancelling_filter",
    "place_pair",
    "cascade_poles",
    "SuccessiveLoopClosure",
    "separation_for",
    "successive_loop_closure",
    "cascade_blocks",
    "FilteredBlock",
    "zero_cancelling_design",
    "outer_plant_seen",
    "coupling_tf",
    "PlacedPD",
]


def coordinate_model(lin: LinearModel) -> LinearModel:
    """The same linearization with the generalized coordinates q as outputs (C = [I 0])."""
    nq = lin.nx // 2
    C = np.hstack([np.eye(nq), np.zeros((nq, nq))])
    return replace(lin, C=C, D=np.zeros((nq, lin.nu)), ye=lin.xe[:nq], output_names=lin.state_names[:nq])


@dataclass(frozen=True)
class CascadePlants:
    """The transfer-function cascade u → inner coordinate → outer coordinate.

    Attributes
    ----------
    inner : inner coordinate / input, the outer coordinate's terms dropped
    outer : outer coordinate / inner coordinate, exact (u eliminated)
    inner_full : inner coordinate / input with every coupling kept
    dropped : state name -> coefficient of that state in the inner row's acceleration
    inner_coordinate, outer_coordinate, input : names
    """

    inner: control.TransferFunction
    outer: control.TransferFunction
    inner_full: control.TransferFunction
    dropped: dict
    inner_coordinate: str
    outer_coordinate: str
    input: str
    linearization: LinearModel = field(repr=False)


def cascade_plants(known: models.Plant, inner: str, outer: str, lin: LinearModel | None = None) -> CascadePlants:
    """Cascade transfer functions of `known` about its standard operating point (or `lin`).

    Parameters
    ----------
    known : the plant the controller knows
    inner, outer : coordinate names, e.g. "theta", "z"
    lin : a linearization of `known` to use instead of the standard one
    """
    lin = known.linearize() if lin is None else lin
    names = known.coordinate_names
    for c in (inner, outer):
        if c not in names:
            raise ValueError(f"{known.name} has no coordinate {c!r}; coordinates are {names}")
    if inner == outer:
        raise ValueError("the inner and outer coordinates must differ")
    if lin.nu != 1:
        raise ValueError("successive loop closure needs a single input")
    nq = known.nq
    i = names.index(inner)
    row = nq + i
    stiffness, damping, gain = lin.A[row, i], lin.A[row, nq + i], lin.B[row, 0]
    if gain == 0:
        raise ValueError(
            f"{known.name}: the input does not act on {inner}'s acceleration; choose another inner coordinate"
        )
    inner_tf = tf([gain], [1.0, -damping, -stiffness])
    dropped = {
        lin.state_names[j]: float(lin.A[row, j]) for j in range(lin.nx) if j not in (i, nq + i) and lin.A[row, j] != 0
    }
    coords = coordinate_model(lin)
    inner_full = coords.tf(inner, lin.input_names[0])
    outer_full = coords.tf(outer, lin.input_names[0])
    n_in, d_in = as_polynomials(inner_full)
    n_out, d_out = as_polynomials(outer_full)
    # (N_out/D)/(N_in/D): the common denominator cancels; so do common powers of s.
    num, den = poly_mul(n_out, d_in), poly_mul(d_out, n_in)
    common = min(zeros_at_origin(num), zeros_at_origin(den))
    if common:
        num, den = num[:-common], den[:-common]
    num, den = _reduce(num, den)
    return CascadePlants(
        inner=inner_tf,
        outer=tf(num / den[0], den / den[0]),
        inner_full=inner_full,
        dropped=dropped,
        inner_coordinate=inner,
        outer_coordinate=outer,
        input=lin.input_names[0],
        linearization=lin,
    )


def _reduce(num, den, tol: float = 1e-8):
    """Cancel common roots of num and den (roots equal to `tol` relative)."""
    num, den = polynomial(num), polynomial(den)
    num_roots, den_roots = list(np.roots(num)), list(np.roots(den))
    kept_num = []
    for z in num_roots:
        match = [k for k, p in enumerate(den_roots) if abs(p - z) <= tol * max(1.0, abs(z))]
        if match:
            den_roots.pop(match[0])
        else:
            kept_num.append(z)
    if len(kept_num) == len(num_roots):
        return num, den
    return (chop(num[0] * np.real(np.poly(kept_num)), 1e-12), chop(den[0] * np.real(np.poly(den_roots)), 1e-12))


def low_frequency_model(G) -> control.TransferFunction:
    """Keep only the lowest-order term of G's numerator: G ≈ n_low s^k / D(s).

    A pendulum's outer plant (g − ℓ s²)/s² becomes g/s², valid for
    ω ≪ √(g/ℓ); used for an outer PD whose closed loop is to equal a
    second-order one.
    """
    num, den = as_polynomials(G)
    k = zeros_at_origin(num)
    low = np.zeros(k + 1)
    low[0] = num[num.size - 1 - k]
    return tf(low, den)


def zero_cancelling_filter(G_outer, inner_dc_gain: float) -> control.TransferFunction:
    """F(s) cancelling the outer plant's stable real zeros and the inner loop's DC gain.

    F(s) = (1/K_DC) ∏ z_i/(s + z_i) over the zeros −z_i of G_outer with
    z_i > 0 real. With it, K_DC F(s) G_outer(s) keeps only the zeros a filter
    may not cancel (right-half-plane or imaginary ones), so a PD on the
    reduced plant matches a second-order closed loop exactly (the
    controlbook's pendulum solution; our text does not use it).
    """
    if not np.isfinite(inner_dc_gain) or inner_dc_gain == 0:
        raise ValueError(f"inner_dc_gain must be finite and nonzero, got {inner_dc_gain}")
    num, _ = as_polynomials(G_outer)
    zeros = np.roots(num)
    stable = [z for z in zeros if abs(z.imag) < 1e-9 and z.real < 0]
    if not stable:
        raise ValueError(f"the outer plant has no stable real zero to cancel (zeros {zeros})")
    filt = tf([1.0 / inner_dc_gain], [1.0])
    for z in stable:
        filt = filt * tf([-z.real], [1.0, -z.real])
    return filt


def place_pair(L0, wn: float, zeta: float) -> dict:
    """Root-locus design of a PD: put a closed-loop pole pair exactly at ω_n, ζ.

    With C(s) = k_p + k_d s and 1 + L0(s) C(s) = 0 at s* = −ζω_n + jω_n√(1−ζ²),
    k_p + k_d s* = −1/L0(s*) fixes both gains (the angle and magnitude
    conditions). The remaining poles are wherever the loop puts them.

    Returns
    -------
    dict with kp, kd and poles (all closed-loop poles of 1 + L0 (k_p + k_d s)).
    """
    if not (wn > 0 and 0 < zeta < 1):
        raise ValueError(f"need wn > 0 and 0 < zeta < 1, got wn = {wn}, zeta = {zeta}")
    s_star = complex(-zeta * wn, wn * np.sqrt(1 - zeta**2))
    num, den = as_polynomials(L0)
    target = -np.polyval(den, s_star) / np.polyval(num, s_star)
    kd = target.imag / s_star.imag
    kp = target.real - kd * s_star.real
    char = poly_add(den, poly_mul(num, [kd, kp]))
    poles = np.roots(char)
    return {"kp": float(kp), "kd": float(kd), "poles": poles[np.argsort(poles.real)]}


def cascade_poles(
    lin: LinearModel,
    inner: str,
    outer: str,
    inner_gains: tuple,
    outer_gains: tuple,
    outer_filter=None,
    feedforward_gradient=None,
) -> np.ndarray:
    """Closed-loop poles of the full linearization under ideal PD cascade control.

    u = u_e(q) + k_pi (θ_d − θ) − k_di θ̇ and θ_d = F(s)[k_po (r − z) − k_do ż]
    (the derivative placement does not change the poles). With
    `outer_filter` F(s) its realization joins the state;
    `feedforward_gradient` is ∂u_e/∂q at the operating point (nq,), the
    linearized equilibrium-input feedforward (ball on beam: m1 g/ℓ on z).
    """
    nq = lin.nx // 2
    names = lin.state_names[:nq]
    i, o = names.index(inner), names.index(outer)
    kpi, kdi = inner_gains
    kpo, kdo = outer_gains
    inner_row = np.zeros(lin.nx)
    inner_row[i], inner_row[nq + i] = -kpi, -kdi
    outer_row = np.zeros(lin.nx)
    outer_row[o], outer_row[nq + o] = -kpo, -kdo
    if feedforward_gradient is not None:
        inner_row[:nq] += np.asarray(feedforward_gradient, dtype=float)
    if outer_filter is None:
        K = -(inner_row + kpi * outer_row)
        closed = lin.A - lin.B @ K[None, :]
    else:
        fs = control.tf2ss(outer_filter)
        Af, Bf, Cf, Df = (np.atleast_2d(np.asarray(m, dtype=float)) for m in (fs.A, fs.B, fs.C, fs.D))
        # θ_d = Cf xf + Df v, v = outer_row · x; xf' = Af xf + Bf v
        u_x = inner_row + kpi * Df[0, 0] * outer_row
        u_f = kpi * Cf[0]
        top = np.hstack([lin.A + lin.B @ u_x[None, :], lin.B @ u_f[None, :]])
        bottom = np.hstack([Bf @ outer_row[None, :], Af])
        closed = np.vstack([top, bottom])
    poles = np.linalg.eigvals(closed)
    return poles[np.argsort(poles.real)]


def separation_for(design, target: float, low: float, high: float, what: str = "inner step") -> float:
    """Solve design(a) = target for a in [low, high] by bisection on a monotone ratio.

    Used to choose the free inner-loop step A_θ so that the inner and outer
    natural frequencies are `target` apart. Raises naming the range when no
    solution exists.
    """
    f_low, f_high = design(low) - target, design(high) - target
    if np.sign(f_low) == np.sign(f_high):
        raise ValueError(
            f"no {what} in [{low:g}, {high:g}] gives a bandwidth separation of {target:g} "
            f"(ratio runs from {f_low + target:.3g} to {f_high + target:.3g})"
        )
    return float(scipy.optimize.brentq(lambda a: design(a) - target, low, high, xtol=1e-12))


@dataclass(frozen=True)
class PlacedPD:
    """Gains of a PD placed by the root locus (`place_pair`), usable as the outer design of a
    `SuccessiveLoopClosure` in `cascade_blocks`."""

    kp: float
    kd: float


#: The outer loop's design: a saturation-rule PDDesign, or gains placed by the root locus.
OuterDesign = TypeVar("OuterDesign", bound=PDDesign | PlacedPD)


@dataclass(frozen=True)
class SuccessiveLoopClosure(Generic[OuterDesign]):
    """A two-loop design: inner PD on the inner coordinate, outer loop on K_DC·G_outer.

    Attributes
    ----------
    plants : the cascade transfer functions
    inner : PDDesign of the inner loop
    inner_dc_gain : K_DC of the inner closed loop
    outer_model : the plant the outer loop was designed on
    outer : PDDesign of the outer loop (for a root-locus placement, its PlacedPD gains)
    outer_dc_gain : DC gain of the outer closed loop on its design model
    separation : ω_n,inner / ω_n,outer
    inner_limit : bound on the inner reference (the outer block's saturation), rad
    full_poles : closed-loop poles of the full linearization under both loops
    outer_filter : zero-cancelling filter, or None
    """

    plants: CascadePlants
    inner: PDDesign
    inner_dc_gain: float
    outer_model: control.TransferFunction
    outer: OuterDesign
    outer_dc_gain: float
    separation: float
    inner_limit: float
    full_poles: np.ndarray
    outer_filter: control.TransferFunction | None = None


def _outer_design(model, *, outer_step, inner_step, zeta_outer, derivative):
    """Outer loop by the saturation rule: the inner reference just reaches `inner_step` on `outer_step`."""
    _, n0, _, _ = second_order_coefficients(model)
    kp = np.sign(n0) * inner_step / outer_step
    design = pd_design(model, zeta=zeta_outer, kp=kp, derivative=derivative)
    return PDDesign(**{**design.__dict__, "step": outer_step, "input_bound": inner_step})


def successive_loop_closure(
    known: models.Plant,
    inner: str,
    outer: str,
    *,
    inner_bound: float,
    outer_step: float,
    separation: float = 10.0,
    zeta_inner: float = 0.707,
    zeta_outer: float = 0.707,
    outer_derivative: bool = True,
    outer_model: str = "exact",
    inner_step: float | None = None,
    inner_step_range: tuple = (1e-4, np.pi / 2),
    lin: LinearModel | None = None,
    feedforward_gradient=None,
) -> SuccessiveLoopClosure[PDDesign]:
    """The text's .8 two-loop design by saturation rules, with bandwidth separation.

    Inner loop: k_p,θ = ±`inner_bound`/A_θ, ω_n,θ and k_d,θ from ζ_θ. Outer
    loop on K_DC·G_outer: k_p,outer = ±A_θ/A_outer, ω_n and k_d from ζ_outer
    (or a P loop with ``outer_derivative=False``). The text leaves A_θ to the
    student; unless `inner_step` is given we choose it so that
    ω_n,θ/ω_n,outer = `separation` (M = 10 by default), which makes the
    outer loop's "inner loop ≈ K_DC" assumption hold.

    Parameters
    ----------
    known : plant the controller knows
    inner, outer : coordinate names
    inner_bound : bound on the linearized input ũ (after the equilibrium input), units of u
    outer_step : the text's step on the outer reference (A_z, A_φ), SI
    outer_model : "exact" (the exact ratio, which must be second order) or
        "low_frequency" (keep the numerator's lowest term: the pendulum's
        (g − ℓ s²)/s² ≈ g/s², valid well below √(g/ℓ))
    inner_step_range : where to look for A_θ, rad
    feedforward_gradient : ∂u_e/∂q of the equilibrium-input feedforward (for `full_poles`)

    Raises
    ------
    ValueError
        When no A_θ in the range gives the separation, or a loop is unstable.
    """
    if outer_model not in ("exact", "low_frequency"):
        raise ValueError(f"outer_model must be 'exact' or 'low_frequency', got {outer_model!r}")
    plants = cascade_plants(known, inner, outer, lin)
    model_of = (lambda G: G) if outer_model == "exact" else low_frequency_model

    def build(a_inner):
        inner_design = pd_saturation(plants.inner, input_bound=inner_bound, step=a_inner, zeta=zeta_inner)
        model = inner_design.dc_gain * model_of(plants.outer)
        outer_design = _outer_design(
            model, outer_step=outer_step, inner_step=a_inner, zeta_outer=zeta_outer, derivative=outer_derivative
        )
        return inner_design, model, outer_design

    if inner_step is None:

        def ratio(a):
            try:
                i, _, o = build(a)
            except ValueError:
                return np.inf  # inner loop not stabilized: A_θ too large for the bound
            return i.wn / o.wn

        lo, hi = inner_step_range
        # A_θ beyond which the saturation-rule k_p no longer stabilizes: search below it.
        if not np.isfinite(ratio(hi)):
            hi = _stable_edge(ratio, lo, hi)
        inner_step = separation_for(ratio, separation, lo, hi, "inner step A_theta (rad)")
    inner_design, model, outer_design = build(inner_step)
    poles = cascade_poles(
        plants.linearization,
        inner,
        outer,
        (inner_design.kp, inner_design.kd),
        (outer_design.kp, outer_design.kd),
        feedforward_gradient=feedforward_gradient,
    )
    return SuccessiveLoopClosure(
        plants=plants,
        inner=inner_design,
        inner_dc_gain=inner_design.dc_gain,
        outer_model=model,
        outer=outer_design,
        outer_dc_gain=outer_design.dc_gain,
        separation=inner_design.wn / outer_design.wn,
        inner_limit=float(inner_step),
        full_poles=poles,
    )


def _stable_edge(ratio, lo, hi, iterations: int = 200) -> float:
    """Largest a in [lo, hi] with a finite ratio(a), by bisection (ratio finite at lo)."""
    if not np.isfinite(ratio(lo)):
        raise ValueError(f"no inner step in [{lo:g}, {hi:g}] rad gives a stable inner loop")
    for _ in range(iterations):
        mid = 0.5 * (lo + hi)
        if np.isfinite(ratio(mid)):
            lo = mid
        else:
            hi = mid
    return lo


def cascade_blocks(
    known: models.Plant,
    slc: SuccessiveLoopClosure,
    *,
    inner_coordinate: str | None = None,
    outer_coordinate: str | None = None,
    ki: float | None = None,
    inner_ki: float | None = None,
    anti_windup: str = "back_calculation",
    rate_limit: float | None = None,
    outer_derivative_on: str = "measurement",
    outer_limit: float | Literal["inner_step"] | None = "inner_step",
    outer_limit_about: str | None = None,
    feedforward: bool = False,
    sample_period: float,
    sigma: float,
    name: str = "PD",
) -> models.Cascade:
    """The two PID blocks of a successive-loop-closure design, composed by `models.Cascade`.

    Parameters
    ----------
    known : the plant whose outputs the blocks read (for the two-load crane, the crane itself)
    slc : the design
    inner_coordinate, outer_coordinate : names in `known` (default the design's)
    ki : outer integrator gain, or None for PD
    inner_ki : inner integrator gain (back-calculation at the actuator limit, or none with
        ``anti_windup="none"``), or None
    outer_limit : bound on the inner reference; "inner_step" uses the design's A_θ, None for no bound
    outer_limit_about : bound the inner reference about this measured coordinate instead of 0
    feedforward : add `known`'s equilibrium input in the inner block
    sample_period : s, of both blocks;  sigma : their dirty derivative's time constant σ, s
    name : the cascade's name; the blocks' names add "outer (x)" and "inner (θ)"

    A design with an `outer_filter` (`zero_cancelling_design`) filters the
    outer block's output (after its saturation) before the inner loop.
    """
    inner_coordinate = inner_coordinate or slc.plants.inner_coordinate
    outer_coordinate = outer_coordinate or slc.plants.outer_coordinate
    limit = slc.inner_limit if outer_limit == "inner_step" else outer_limit
    outer_block: models.Block = PID(
        known,
        outer_coordinate,
        kp=slc.outer.kp,
        kd=slc.outer.kd,
        ki=ki,
        derivative_on=outer_derivative_on,
        anti_windup=anti_windup if ki is not None else "none",
        rate_limit=rate_limit,
        output_limit=limit,
        limit_about=outer_limit_about,
        sample_period=sample_period,
        sigma=sigma,
        name=f"{name} outer ({outer_coordinate})",
    )
    if slc.outer_filter is not None:
        outer_block = FilteredBlock(
            outer_block, slc.outer_filter, name=f"{name} outer ({outer_coordinate}), zero-cancelling filter"
        )
    inner_block = PID(
        known,
        inner_coordinate,
        kp=slc.inner.kp,
        kd=slc.inner.kd,
        ki=inner_ki,
        anti_windup="none" if anti_windup == "none" else "back_calculation",
        output_limit=float(known.input_limit[0]),
        feedforward=feedforward,
        sample_period=sample_period,
        sigma=sigma,
        name=f"{name} inner ({inner_coordinate})",
    )
    return models.Cascade(outer_block, inner_block, name=name)


class FilteredBlock(models.Block):
    """A block whose output passes through a Tustin-discretized filter F(s) (the zero-cancelling filter).

    Gains are the block's own plus ``filter_num`` and ``filter_den`` (continuous
    coefficients of F). The block saturates before the filter, as in the
    controlbook's pendulum solution.
    """

    def __init__(self, block: models.Block, filter_tf, name: str | None = None):
        num, den = padded_coefficients(filter_tf, "filter F(s)")
        self.block = block
        self._section = TustinSection(den.size - 1, block.sample_period)
        gains = dict(block.gains) | {"filter_num": num, "filter_den": den}
        super().__init__(
            sample_period=block.sample_period,
            n_state=block.n_state + self._section.order,
            n_measured=block.n_measured,
            n_reference=block.n_reference,
            n_input=block.n_input,
            gains=gains,
            measures=block.measures,
            name=name or f"F(s)·{block.name}",
        )

    def __repr__(self) -> str:
        filter_gains = {k: v for k, v in self.gains.items() if k.startswith("filter_")}
        return f"FilteredBlock({self.block!r}, " + numbers_repr("F", filter_gains) + ")"

    def expr(self, xc, y, r, gains):
        """One sample: the block's step, then the filter section on its output."""
        nb = self.block.n_state
        own = {k: v for k, v in gains.items() if not k.startswith("filter_")}
        xb_next, v = self.block.expr(xc[:nb], y, r, own)
        xf_next, out = self._section.expr(xc[nb:], v, gains["filter_num"], gains["filter_den"])
        return ca.vertcat(xb_next, xf_next), out

    def initial_state(self, y0, r0) -> np.ndarray:
        """The block's initial state, the filter at rest at the block's first output."""
        xb = self.block.initial_state(y0, r0)
        _, v = self.block.step(xb, y0, r0)
        xf = self._section.steady_state(float(v[0]), self.gains["filter_num"], self.gains["filter_den"])
        return np.concatenate([xb, xf])


def zero_cancelling_design(
    slc: SuccessiveLoopClosure, *, separation: float = 10.0, zeta_outer: float = 0.707
) -> SuccessiveLoopClosure[PDDesign]:
    """Redesign the outer loop of `slc` with the zero-cancelling filter (the controlbook's pendulum).

    F(s) cancels the outer plant's stable zeros and K_DC; the PD then acts on
    the reduced plant K_DC F G_outer, whose closed loop is exactly second
    order with ω_n = ω_n,inner/`separation` and ζ = `zeta_outer` (up to the
    non-minimum-phase zero it keeps). `full_poles` include the filter.
    """
    filt = zero_cancelling_filter(slc.plants.outer, slc.inner_dc_gain)
    num, den = _reduce(*(as_polynomials(slc.inner_dc_gain * filt * slc.plants.outer)))
    reduced = tf(num, den)
    outer = pd_design(reduced, wn=slc.inner.wn / separation, zeta=zeta_outer)
    poles = cascade_poles(
        slc.plants.linearization,
        slc.plants.inner_coordinate,
        slc.plants.outer_coordinate,
        (slc.inner.kp, slc.inner.kd),
        (outer.kp, outer.kd),
        outer_filter=filt,
    )
    return SuccessiveLoopClosure(
        plants=slc.plants,
        inner=slc.inner,
        inner_dc_gain=slc.inner_dc_gain,
        outer_model=reduced,
        outer=outer,
        outer_dc_gain=outer.dc_gain,
        separation=slc.inner.wn / outer.wn,
        inner_limit=slc.inner_limit,
        full_poles=poles,
        outer_filter=filt,
    )


def outer_plant_seen(inner_loop, G_outer) -> control.TransferFunction:
    """The plant an outer controller sees: the inner closed loop (reference to output) times the outer plant.

    `inner_loop` is a `designs.analysis.Loop`; its roll-off is kept, unlike the
    K_DC approximation of `successive_loop_closure`.
    """
    n_t, d_t = as_polynomials(inner_loop.reference_to_output())
    n_o, d_o = as_polynomials(G_outer)
    return tf(np.polymul(n_t, n_o), np.polymul(d_t, d_o))


def coupling_tf(plants: CascadePlants) -> control.TransferFunction:
    """Transfer function from the outer coordinate to the inner one through the dropped coupling terms.

    The inner row's dropped stiffness c_q and damping c_v on the outer
    coordinate act as (c_v s + c_q) outer / (inner characteristic polynomial).
    """
    outer = plants.outer_coordinate
    c_q = plants.dropped.get(outer, 0.0)
    c_v = plants.dropped.get("d" + outer, 0.0)
    _, d_in = as_polynomials(plants.inner)
    return tf([c_v, c_q], d_in / d_in[0])
