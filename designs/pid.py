"""PD and PID: the saturation-rule design (.8), and the discrete PID block (.11).

Design functions work on a second-order loop plant

    G(s) = (n1 s + n0) / (s² + a1 s + a0)

(n1 = 0 for every case study's inner loop; the satellite's outer loop has
n1 ≠ 0). With u = k_p (r − y) − k_d ẏ the closed-loop characteristic
polynomial is (1 + n1 k_d) s² + (a1 + n1 k_p + n0 k_d) s + (a0 + n0 k_p),
whichever of the error or the measurement the derivative acts on.

The block `PID` is the textbook's discrete controller (Beard & McLain's
controlbook, ``ctrlPID``): trapezoidal integrator, dirty derivative
s/(σ s + 1) by Tustin, saturation last, and one of two anti-windup schemes.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import casadi as ca
import numpy as np

import models
from models import deferred
from models.checks import positive

from .analysis.polynomials import as_polynomials, dc_gain, tf
from .discrete import back_calculation, dirty_derivative, integrate_while_slow, saturate, trapezoid

if TYPE_CHECKING:
    import control
else:
    control = deferred.module("control")
scipy = deferred.module("scipy")

__all__ = [
    "PDDesign",
    "second_order_coefficients",
    "pd_design",
    "pd_saturation",
    "max_equilibrium_input",
    "linearized_input_bound",
    "coordinate_reader",
    "equilibrium_feedforward",
    "reference_feedforward",
    "PID",
]


# ----------------------------------------------------------------- design
def second_order_coefficients(G) -> tuple[float, float, float, float]:
    """(n1, n0, a1, a0) of G(s) = (n1 s + n0) / (s² + a1 s + a0).

    Raises
    ------
    ValueError
        If G is not of that form (denominator of degree 2, numerator of degree ≤ 1).
    """
    num, den = as_polynomials(G)
    if den.size != 3 or num.size > 2:
        raise ValueError(f"expected (n1 s + n0)/(s^2 + a1 s + a0), got numerator {num} and denominator {den}")
    num, den = num / den[0], den / den[0]
    num = np.pad(num, (2 - num.size, 0))
    return float(num[0]), float(num[1]), float(den[1]), float(den[2])


@dataclass(frozen=True)
class PDDesign:
    """A PD (or P) loop on a second-order plant.

    Attributes
    ----------
    kp, kd : gains, u = k_p (r − y) − k_d ẏ (units of u per unit of y, and per unit/s)
    wn : rad/s, zeta : closed-loop natural frequency and damping ratio
    poles : (2,) complex closed-loop poles
    dc_gain : closed-loop DC gain from r to y (1 only for a type-1 plant)
    plant : the loop plant G(s); closed_loop : r → y with the derivative on the measurement
    step, input_bound : the saturation rule's step and bound, when used (else nan)
    """

    kp: float
    kd: float
    wn: float
    zeta: float
    poles: np.ndarray
    dc_gain: float
    plant: control.TransferFunction
    closed_loop: control.TransferFunction
    step: float = float("nan")
    input_bound: float = float("nan")

    def as_dict(self) -> dict:
        """The gains, ω_n, ζ, poles and DC gain as a dict (the homework's numbers)."""
        return {
            "kp": self.kp,
            "kd": self.kd,
            "wn": self.wn,
            "zeta": self.zeta,
            "poles": self.poles,
            "dc_gain": self.dc_gain,
        }


def pd_design(
    plant, *, zeta: float | None = None, kp: float | None = None, wn: float | None = None, derivative: bool = True
) -> PDDesign:
    """Match the closed loop of a PD (or P) loop to s² + 2ζω_n s + ω_n².

    Give either `kp` (the saturation rule; ω_n follows) or `wn` (k_p
    follows). With ``derivative=False`` (a P loop) only k_p is free and ζ is
    whatever the plant's damping leaves.

    Parameters
    ----------
    plant : G(s) = (n1 s + n0)/(s² + a1 s + a0)
    zeta : desired damping ratio (ignored for a P loop)
    kp : proportional gain, or None
    wn : desired natural frequency in rad/s, or None

    Raises
    ------
    ValueError
        When both or neither of kp and wn are given, or when the requested
        loop is not stable (for example a saturation-rule k_p too small to
        overcome an unstable plant: the message says how large it must be).
    """
    if (kp is None) == (wn is None):
        raise ValueError("give exactly one of kp (saturation rule) and wn (natural frequency)")
    n1, n0, a1, a0 = second_order_coefficients(plant)
    if n0 == 0:
        raise ValueError("plant has no static gain n0; a PD cannot place its poles")
    if derivative:
        if zeta is None or not zeta > 0:
            raise ValueError(f"zeta must be > 0, got {zeta}")
        if wn is not None:
            wn = positive(wn, "wn (rad/s)")
            # (a0 + n0 kp) = wn² (1 + n1 kd) and (a1 + n1 kp + n0 kd) = 2ζwn (1 + n1 kd): linear in (kp, kd).
            matrix = np.array([[n0, -(wn**2) * n1], [n1, n0 - 2 * zeta * wn * n1]])
            kp, kd = np.linalg.solve(matrix, [wn**2 - a0, 2 * zeta * wn - a1])
        else:
            if n1 != 0:
                raise ValueError("with a plant zero (n1 != 0) give wn, not kp")
            assert kp is not None  # exactly one of kp and wn is given (checked above)
            stiffness = a0 + n0 * kp
            if stiffness <= 0:
                raise ValueError(
                    f"kp = {kp:.4g} does not stabilize the plant: need a0 + n0 kp > 0, that is "
                    f"kp {'>' if n0 > 0 else '<'} {-a0 / n0:.4g}; reduce the step or raise the bound"
                )
            wn = float(np.sqrt(stiffness))
            kd = (2 * zeta * wn - a1) / n0
    else:
        kd = 0.0
        if kp is None:
            assert wn is not None  # exactly one of kp and wn is given (checked above)
            kp = (wn**2 - a0) / n0
        stiffness, damping = a0 + n0 * kp, a1 + n1 * kp
        if stiffness <= 0 or damping <= 0:
            raise ValueError(f"P loop with kp = {kp:.4g} is not stable (s^2 + {damping:.4g} s + {stiffness:.4g})")
        wn = float(np.sqrt(stiffness))
        zeta = damping / (2 * wn)
    kp, kd = float(kp), float(kd)
    lead = 1 + n1 * kd
    char = np.array([lead, a1 + n1 * kp + n0 * kd, a0 + n0 * kp])
    roots = np.roots(char)
    if lead <= 0 or np.any(roots.real >= 0):
        raise ValueError(f"the PD loop is not stable: poles {roots}")
    closed = tf([n1 * kp, n0 * kp], char)
    return PDDesign(
        kp=kp,
        kd=kd,
        wn=float(wn),
        zeta=float(zeta),
        poles=roots[np.argsort(roots.imag)],
        dc_gain=dc_gain(closed),
        plant=plant,
        closed_loop=closed,
    )


def pd_saturation(plant, *, input_bound: float, step: float, zeta: float) -> PDDesign:
    """The text's rule (.8): k_p so that a step of `step` on the reference just saturates the input.

    |k_p| = input_bound / step, with the sign of the plant's gain (so that
    the loop is stable); ω_n and k_d follow from the characteristic
    polynomial s² + (a1 + n0 k_d) s + (a0 + n0 k_p) = s² + 2ζω_n s + ω_n².

    Parameters
    ----------
    plant : b0/(s² + a1 s + a0)
    input_bound : bound on the linearized input, e.g. τ̃_max (units of u)
    step : step size on the reference (units of y, rad for angles)
    zeta : damping ratio
    """
    input_bound = positive(input_bound, "input_bound")
    step = positive(step, "step")
    _, n0, _, _ = second_order_coefficients(plant)
    design = pd_design(plant, zeta=zeta, kp=np.sign(n0) * input_bound / step)
    return PDDesign(**{**design.__dict__, "step": step, "input_bound": input_bound})


def max_equilibrium_input(known: models.Plant, ranges: dict) -> tuple[float, dict]:
    """Largest |u_e(q)| of the equilibrium (feedforward) input over a box of configurations.

    Parameters
    ----------
    known : the plant the controller knows
    ranges : coordinate -> (low, high) in SI units; coordinates not named
        stay at the standard operating point (empty: the operating point only)

    Returns
    -------
    (value, q) : the largest magnitude of the (first) input and the configuration where it occurs
    """
    q0 = dict(zip(known.coordinate_names, known.equilibrium()[0][: known.nq]))
    if not ranges:
        return float(abs(known.equilibrium_input(known.equilibrium()[0][: known.nq])[0])), {}
    for name in ranges:
        if name not in q0:
            raise ValueError(f"{known.name} has no coordinate {name!r}; coordinates are {known.coordinate_names}")
    names = list(ranges)
    lows = np.array([ranges[n][0] for n in names], dtype=float)
    highs = np.array([ranges[n][1] for n in names], dtype=float)
    if np.any(highs < lows):
        raise ValueError(f"each range must have low <= high, got {ranges}")

    index = [known.coordinate_names.index(n) for n in names]
    base = np.array([q0[c] for c in known.coordinate_names])
    p = known.param_vector()

    def q_of(values):
        q = base.copy()
        q[index] = values
        return q

    def magnitude(values):
        return abs(known.equilibrium_input(q_of(values))[0])

    # Dense grid (one mapped CasADi call), then a bounded local refinement from the best point.
    points = 201 if len(names) == 1 else 61
    axes = [np.linspace(lo, hi, points) for lo, hi in zip(lows, highs)]
    grid = np.array(np.meshgrid(*axes, indexing="ij")).reshape(len(names), -1).T
    qs = np.tile(base, (grid.shape[0], 1))
    qs[:, index] = grid
    mapped = known.casadi_equilibrium_input.map(grid.shape[0])
    values = np.abs(np.asarray(mapped(qs.T, p))[0])
    best = grid[int(np.argmax(values))]
    refined = scipy.optimize.minimize(lambda v: -magnitude(v), best, bounds=list(zip(lows, highs)), method="L-BFGS-B")
    if -refined.fun > values.max():
        best = refined.x
    return float(magnitude(best)), dict(zip(names, map(float, best)))


def linearized_input_bound(known: models.Plant, ranges: dict) -> dict:
    """The text's .8(b)/(c): bound on ũ = u − u_e when the largest equilibrium input is used.

    ũ_max = u_max − max |u_e(q)| over the configurations in `ranges`.

    Raises
    ------
    ValueError
        When the equilibrium input alone exceeds the actuator limit.
    """
    u_max = float(known.input_limit[0])
    ue_max, where = max_equilibrium_input(known, ranges)
    if ue_max >= u_max:
        raise ValueError(
            f"{known.name}: the equilibrium input {ue_max:.4g} at {where} reaches the actuator "
            f"limit {u_max:g}; nothing is left for feedback"
        )
    return {"input_limit": u_max, "max_equilibrium_input": ue_max, "at": where, "bound": u_max - ue_max}


# ----------------------------------------------------------------- block pieces
def coordinate_reader(known: models.Plant, coordinate: str):
    """y ↦ q_coordinate from the plant's outputs (the satellite's φ = y0 + y1), as a CasADi map."""
    if coordinate not in known.coordinate_names:
        raise ValueError(f"{known.name} has no coordinate {coordinate!r}; coordinates are {known.coordinate_names}")
    index = known.coordinate_names.index(coordinate)
    configuration = known.casadi_configuration
    p = ca.DM(known.param_vector())
    return lambda y: configuration(y, p)[index]


def equilibrium_feedforward(known: models.Plant):
    """y ↦ u_e(q(y)): the input that holds the known plant at rest at the measured configuration.

    For the arm m g ℓ/2 cos θ, for the ball on beam (m1 z/ℓ + m2/2) g cos θ;
    computed from the plant's declaration, never typed.
    """
    configuration = known.casadi_configuration
    static = known.casadi_equilibrium_input
    p = ca.DM(known.param_vector())
    return lambda y: static(configuration(y, p), p)[0]


def reference_feedforward(known: models.Plant, coordinate: str):
    """r ↦ u_e(q_r): the equilibrium input with `coordinate` at the reference, the rest at the operating point.

    A model-based feedforward that predicts the input holding the plant at
    the desired configuration (for a vehicle's roll, the gravity-buoyancy
    torque at the desired roll angle).
    """
    if coordinate not in known.coordinate_names:
        raise ValueError(f"{known.name} has no coordinate {coordinate!r}; coordinates are {known.coordinate_names}")
    index = known.coordinate_names.index(coordinate)
    q0 = ca.DM(known.equilibrium()[0][: known.nq])
    unit = ca.DM.zeros(known.nq)
    unit[index] = 1
    static = known.casadi_equilibrium_input
    p = ca.DM(known.param_vector())
    return lambda r: static(q0 + unit * (r - q0[index]), p)[0]


ANTI_WINDUP = ("back_calculation", "integrate_while_slow", "none")


def format_number(value) -> str:
    """A gain as printed in a repr: 4 significant digits, one-element arrays as numbers, arrays as lists."""
    if value is None:
        return "None"
    array = np.asarray(value, dtype=float)
    if array.size == 1:
        return f"{float(array.ravel()[0]):.4g}"
    return "[" + ", ".join(f"{v:.4g}" for v in array.ravel()) + "]"


def numbers_repr(kind: str, fields: dict) -> str:
    """``kind(name=value, ...)`` with every value formatted by `format_number` (strings quoted)."""
    parts = [f"{k}={v!r}" if isinstance(v, str) else f"{k}={format_number(v)}" for k, v in fields.items()]
    return f"{kind}(" + ", ".join(parts) + ")"


class PID(models.Block):
    """Discrete PID on one coordinate, at sample period Ts (the text's .11 controller).

    u = sat(u_ff + k_p e + k_i I − k_d ẏ), e = r − y_c, with y_c the
    controlled coordinate read from the plant's outputs, I the trapezoidal
    integral of e and ẏ the dirty derivative s/(σ s + 1) of y_c (or +k_d ė
    with ``derivative_on="error"``). Saturation at `output_limit` comes last.

    Parameters
    ----------
    known : the plant the controller knows (for reading the coordinate and the feedforward)
    coordinate : name of the controlled coordinate, e.g. "theta"
    kp, kd : gains (tunable)
    ki : integrator gain (tunable), or None for a PD without integrator state
    sample_period : s, no default: the value is the design's (the case study's), never the library's
    sigma : time constant σ of the dirty derivative s/(σ s + 1), s; no default either
    derivative_on : "measurement" (no derivative kick) or "error"
    anti_windup : "back_calculation" (integral bled by T_s/k_i (u − u_unsat)),
        "integrate_while_slow" (integrate only while |ẏ| < `rate_limit`, for
        any sign of k_i: the textbook's scheme for a negative k_i) or "none"
    rate_limit : units of y per s, for "integrate_while_slow"
    output_limit : symmetric saturation of the output (the actuator limit,
        or the outer loop's bound on the inner reference); None for none
    feedforward : add the equilibrium input u_e(q(y)) of `known` (arm, ball on beam)
    limit_about : coordinate name; saturate to that measured coordinate ± `output_limit`
        (an outer loop commanding an absolute inner angle, the satellite's θ_d ∈ θ ± A_θ)

    State x_c = (e_prev, y_prev, ẏ estimate[, integral]).
    """

    def __init__(
        self,
        known: models.Plant,
        coordinate: str,
        *,
        kp: float,
        kd: float = 0.0,
        ki: float | None = None,
        sample_period: float,
        sigma: float,
        derivative_on: str = "measurement",
        anti_windup: str = "back_calculation",
        rate_limit: float | None = None,
        output_limit: float | None = None,
        feedforward: bool = False,
        limit_about: str | None = None,
        name: str = "PID",
    ):
        if derivative_on not in ("measurement", "error"):
            raise ValueError(f"derivative_on must be 'measurement' or 'error', got {derivative_on!r}")
        if anti_windup not in ANTI_WINDUP:
            raise ValueError(f"anti_windup must be one of {ANTI_WINDUP}, got {anti_windup!r}")
        if ki is not None and anti_windup == "back_calculation" and output_limit is None:
            raise ValueError("back-calculation anti-windup needs an output_limit to saturate at")
        if ki is not None and anti_windup == "integrate_while_slow" and not (rate_limit and rate_limit > 0):
            raise ValueError(f"integrate_while_slow needs a rate_limit > 0, got {rate_limit}")
        if output_limit is not None:
            output_limit = positive(output_limit, "output_limit")
        positive(sigma, "sigma (s)")
        self.coordinate, self.sigma, self.derivative_on = coordinate, float(sigma), derivative_on
        self.anti_windup, self.rate_limit, self.output_limit = anti_windup, rate_limit, output_limit
        self.has_integrator, self.has_feedforward = ki is not None, bool(feedforward)
        self._read = coordinate_reader(known, coordinate)
        self._feedforward = equilibrium_feedforward(known) if feedforward else None
        if limit_about is not None and output_limit is None:
            raise ValueError("limit_about needs an output_limit")
        self.limit_about = limit_about
        self._read_center = coordinate_reader(known, limit_about) if limit_about is not None else None
        gains = {"kp": kp, "kd": kd} | ({"ki": ki} if ki is not None else {})
        super().__init__(
            sample_period=sample_period,
            n_state=3 + self.has_integrator,
            n_measured=known.ny,
            n_reference=1,
            n_input=1,
            gains=gains,
            measures="outputs",
            name=name,
        )

    def __repr__(self) -> str:
        kind = "PID" if self.has_integrator else "PD"
        fields = dict(self.gains) | {"sigma": self.sigma, "Ts": self.sample_period, "limit": self.output_limit}
        return numbers_repr(kind, {"coordinate": self.coordinate} | fields)

    def expr(self, xc, y, r, gains):
        """One sample: the error, the dirty derivative, the integral and feedforward, saturation, anti-windup."""
        ts = self.sample_period
        e_prev, y_prev, rate_prev = xc[0], xc[1], xc[2]
        yc = self._read(y)
        error = r[0] - yc
        if self.derivative_on == "measurement":
            rate = dirty_derivative(rate_prev, y_prev, yc, self.sigma, ts)
            u_derivative = -gains["kd"] * rate
        else:
            rate = dirty_derivative(rate_prev, e_prev, error, self.sigma, ts)
            u_derivative = gains["kd"] * rate
        u_unsat = gains["kp"] * error + u_derivative
        if self._feedforward is not None:
            u_unsat = u_unsat + self._feedforward(y)
        if self.has_integrator:
            integral = trapezoid(xc[3], e_prev, error, ts)
            u_unsat = u_unsat + gains["ki"] * integral
        if self.output_limit is None:
            u = u_unsat
        else:
            center = self._read_center(y) if self._read_center is not None else 0
            u = center + saturate(u_unsat - center, self.output_limit)
        state = [error, yc, rate]
        if self.has_integrator:
            if self.anti_windup == "back_calculation":
                integral = back_calculation(integral, u_unsat, u, gains["ki"], ts)
            elif self.anti_windup == "integrate_while_slow":
                integral = integrate_while_slow(xc[3], integral, rate, self.rate_limit)
            state.append(integral)
        return ca.vertcat(*state), u

    def initial_state(self, y0, r0) -> np.ndarray:
        """Start with the current error and measurement and no derivative (no kick at t = 0)."""
        y_sym = ca.SX.sym("y", self.n_measured)
        yc = float(ca.Function("read", [y_sym], [self._read(y_sym)])(np.asarray(y0, dtype=float)))
        error = float(np.asarray(r0, dtype=float).ravel()[0]) - yc
        return np.array([error, yc, 0.0] + ([0.0] if self.has_integrator else []))
