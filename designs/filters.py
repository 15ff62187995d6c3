"""Compensators C(s) from frequency specs, and the block that runs any C(s) discretized by Tustin.

Builders (continuous time, return ``control.TransferFunction``):

- `lead(omega, phase_deg)`: maximum phase `phase_deg` at `omega`, unit gain there
- `lag(omega_zero, low_frequency_gain)`: (s + z)/(s + z/M), gain M at DC, 1 at high frequency
- `proportional_integral(omega_zero)`: (s + z)/s
- `notch(omega, zeta_zero, zeta_pole)`: (s² + 2ζ_z ω s + ω²)/(s² + 2ζ_p ω s + ω²)
- `low_pass(omega, order)`: (ω/(s + ω))^order
- `prefilter(omega, order)`: a unit-DC-gain low-pass for the reference path

`TransferFunctionBlock` runs u = u_ff + sat(C(s) (F(s) r − y_c)) at sample
period T_s with C and F discretized by Tustin's rule. Tustin's rule is a
linear map of the coefficient vectors, so the block's gains are the
continuous-time coefficients themselves and a closed loop stays
differentiable in them.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import casadi as ca
import numpy as np

import models
from models import deferred
from models.checks import positive

from .analysis.polynomials import as_polynomials, tf
from .discrete import saturate
from .pid import coordinate_reader, equilibrium_feedforward, numbers_repr, reference_feedforward

if TYPE_CHECKING:
    import control
else:
    control = deferred.module("control")

__all__ = [
    "lead",
    "lag",
    "proportional_integral",
    "notch",
    "low_pass",
    "prefilter",
    "lead_ratio",
    "tustin_matrix",
    "padded_coefficients",
    "TustinSection",
    "TransferFunctionBlock",
]


# ----------------------------------------------------------------- builders
def lead_ratio(phase_deg: float) -> float:
    """α = p/z of a lead with maximum phase `phase_deg`: α = (1 + sin φ)/(1 − sin φ)."""
    phase = np.radians(phase_deg)
    if not 0 < phase < np.pi / 2:
        raise ValueError(f"a single lead adds between 0 and 90 deg, got {phase_deg} deg; use two in series")
    return float((1 + np.sin(phase)) / (1 - np.sin(phase)))


def lead(omega: float, phase_deg: float) -> control.TransferFunction:
    """Lead √α (s + ω/√α)/(s + ω√α): maximum phase `phase_deg` at `omega` rad/s, |C(jω)| = 1 there."""
    omega = positive(omega, "lead frequency omega (rad/s)")
    alpha = lead_ratio(phase_deg)
    zero, pole = omega / np.sqrt(alpha), omega * np.sqrt(alpha)
    return tf([1 / zero, 1.0], [1 / pole, 1.0]) * (1 / np.sqrt(alpha))


def lag(omega_zero: float, low_frequency_gain: float) -> control.TransferFunction:
    """Lag (s + z)/(s + z/M): gain M at DC, 1 at high frequency, zero at `omega_zero` rad/s."""
    omega_zero = positive(omega_zero, "lag zero (rad/s)")
    gain = positive(low_frequency_gain, "lag low-frequency gain")
    if gain <= 1:
        raise ValueError(f"a lag raises the low-frequency gain: need a gain > 1, got {gain}")
    return tf([1.0, omega_zero], [1.0, omega_zero / gain])


def proportional_integral(omega_zero: float) -> control.TransferFunction:
    """PI (s + z)/s: integrator with its zero at `omega_zero` rad/s, unit high-frequency gain."""
    omega_zero = positive(omega_zero, "PI zero (rad/s)")
    return tf([1.0, omega_zero], [1.0, 0.0])


def notch(omega: float, zeta_zero: float, zeta_pole: float = 0.7) -> control.TransferFunction:
    """Notch (s² + 2ζ_z ω s + ω²)/(s² + 2ζ_p ω s + ω²), unit gain at DC and high frequency."""
    omega = positive(omega, "notch frequency (rad/s)")
    zeta_zero = float(zeta_zero)
    if not 0 <= zeta_zero < zeta_pole:
        raise ValueError(f"a notch needs 0 <= zeta_zero < zeta_pole, got {zeta_zero} and {zeta_pole}")
    return tf([1.0, 2 * zeta_zero * omega, omega**2], [1.0, 2 * zeta_pole * omega, omega**2])


def low_pass(omega: float, order: int = 1) -> control.TransferFunction:
    """(ω/(s + ω))^order: unit DC gain, −20·order dB/decade above `omega` rad/s."""
    omega = positive(omega, "low-pass corner (rad/s)")
    if int(order) != order or order < 1:
        raise ValueError(f"order must be a positive integer, got {order}")
    return tf([1.0], [1 / omega, 1.0]) ** int(order)


def prefilter(omega: float, order: int = 1) -> control.TransferFunction:
    """Reference prefilter F(s): a unit-DC-gain low-pass at `omega` rad/s."""
    return low_pass(omega, order)


# ----------------------------------------------------------------- Tustin
def tustin_matrix(order: int, sample_period: float) -> np.ndarray:
    """T with (T c)_j = coefficient of z^(n−j) in Σ_i c_i (2/T_s)^i (z − 1)^i (z + 1)^(n−i).

    `c` holds the continuous coefficients in descending powers of s (c_0 of
    s^n); the discrete polynomial is in descending powers of z.
    """
    ts = positive(sample_period, "sample_period (s)")
    n = int(order)
    matrix = np.zeros((n + 1, n + 1))
    for col in range(n + 1):
        power = n - col  # power of s this coefficient multiplies
        poly = np.array([(2 / ts) ** power])
        for _ in range(power):
            poly = np.polymul(poly, [1.0, -1.0])
        for _ in range(n - power):
            poly = np.polymul(poly, [1.0, 1.0])
        matrix[:, col] = poly
    return matrix


def padded_coefficients(G, what: str) -> tuple[np.ndarray, np.ndarray]:
    """(num, den) of a proper G(s), num padded with leading zeros to den's length; `what` names G in errors."""
    num, den = as_polynomials(G)
    if num.size > den.size:
        raise ValueError(f"{what} is not causal: numerator degree {num.size - 1} > denominator degree {den.size - 1}")
    return np.pad(num, (den.size - num.size, 0)), den


class TustinSection:
    """Transposed direct form II of one Tustin-discretized C(s), written for symbolic coefficients.

    With a[0] = 1, state s and input e:  u = b0 e + s0,
    s_i⁺ = s_(i+1) + b_(i+1) e − a_(i+1) u.  In this (observer) form the
    state matrix is F = [−a_(1:) | shift] with output row H = (1, 0, …), so
    F − K H has characteristic polynomial z^n + (a_(1:) + K)·(z^(n−1), …, 1).
    """

    def __init__(self, order: int, sample_period: float):
        self.order = order
        self.matrix = ca.DM(tustin_matrix(order, sample_period))

    def coefficients(self, num, den):
        """(b, a): the z-domain coefficients of num/den (continuous, descending) by Tustin, a[0] = 1."""
        b, a = self.matrix @ num, self.matrix @ den
        return b / a[0], a / a[0]

    def expr(self, state, signal, num, den):
        """One sample of the section in transposed direct form II: (state next (order,), output)."""
        b, a = self.coefficients(num, den)
        out = b[0] * signal + (state[0] if self.order else 0)
        nxt = [
            (state[i + 1] if i + 1 < self.order else 0) + b[i + 1] * signal - a[i + 1] * out for i in range(self.order)
        ]
        return (ca.vertcat(*nxt) if self.order else ca.SX(0, 1)), out

    def tracking_gain(self, den, pole: float):
        """K with eig(F − K H) all at `pole` (symbolic in the denominator coefficients)."""
        _, a = self.coefficients(ca.DM.zeros(self.order + 1), den)
        desired = np.poly(np.full(self.order, pole))
        return ca.vertcat(*[desired[i + 1] - a[i + 1] for i in range(self.order)])

    def steady_state(self, signal: float, num, den) -> np.ndarray:
        """State of the section at rest under a constant input (requires a finite DC gain)."""
        b, a = (np.asarray(v).ravel() for v in self.coefficients(ca.DM(num), ca.DM(den)))
        if abs(a.sum()) < 1e-14:
            return np.zeros(self.order)
        out = b.sum() / a.sum() * signal
        state = np.zeros(self.order)
        for i in reversed(range(self.order)):
            state[i] = (state[i + 1] if i + 1 < self.order else 0) + b[i + 1] * signal - a[i + 1] * out
        return state


class TransferFunctionBlock(models.Block):
    """u = u_ff + sat(C(s) (F(s) r − y_c)), C and F discretized by Tustin at T_s.

    Parameters
    ----------
    known : the plant the controller knows (reading the coordinate; feedforward)
    coordinate : the controlled coordinate, e.g. "phi"
    controller : C(s), proper (a non-causal C raises)
    prefilter : F(s) on the reference, proper; None for F = 1
    sample_period : s, no default: the value is the design's (the case study's), never the library's
    output_limit : symmetric saturation of u (actuator limit, or the outer
        loop's bound on the inner reference); None for none
    feedforward : add the known plant's equilibrium input at the measured configuration
        (True or "measurement"), or at the reference ("reference": the
        controlled coordinate at r, the others at the operating point)
    anti_windup : "observer" feeds the saturation's excess back into C's state,
        x⁺ = F x + G e + K (u − u_unsat), with K placing every eigenvalue of
        F − K H at `tracking_pole` (the controller then tracks the applied
        output, Åström & Hägglund's observer form of back-calculation); "none"
    tracking_pole : z-plane pole of the anti-windup observer (0.9: a time
        constant of about ten samples)
    limit_about : coordinate name; saturate the output to that measured
        coordinate ± `output_limit` instead of 0 ± `output_limit`. For an
        outer loop whose output is an absolute inner reference (the
        satellite's θ_d): bounding θ_d − θ keeps the inner loop out of
        saturation, and the anti-windup then knows when the inner loop cannot follow.

    Gains ``num``, ``den`` (and ``prefilter_num``, ``prefilter_den``) are
    the continuous-time coefficients in descending powers of s.
    The state is (prefilter state, controller state); the prefilter starts
    at rest at the first reference, the controller at zero.
    """

    def __init__(
        self,
        known: models.Plant,
        coordinate: str,
        controller,
        *,
        prefilter=None,
        sample_period: float,
        output_limit: float | None = None,
        feedforward: bool | str = False,
        anti_windup: str = "observer",
        tracking_pole: float = 0.9,
        limit_about: str | None = None,
        name: str = "C(s)",
    ):
        if anti_windup not in ("observer", "none"):
            raise ValueError(f"anti_windup must be 'observer' or 'none', got {anti_windup!r}")
        if not 0 <= tracking_pole < 1:
            raise ValueError(f"tracking_pole must be in [0, 1), got {tracking_pole}")
        self.tracking_pole = float(tracking_pole)
        num, den = padded_coefficients(controller, "controller C(s)")
        gains = {"num": num, "den": den}
        self._controller = TustinSection(den.size - 1, sample_period)
        self._prefilter = None
        if prefilter is not None:
            f_num, f_den = padded_coefficients(prefilter, "prefilter F(s)")
            gains |= {"prefilter_num": f_num, "prefilter_den": f_den}
            self._prefilter = TustinSection(f_den.size - 1, sample_period)
        self.output_limit = None if output_limit is None else positive(output_limit, "output_limit")
        self.anti_windup = anti_windup
        self.coordinate = coordinate
        self._read = coordinate_reader(known, coordinate)
        if limit_about is not None and self.output_limit is None:
            raise ValueError("limit_about needs an output_limit")
        self.limit_about = limit_about
        self._read_center = coordinate_reader(known, limit_about) if limit_about is not None else None
        if feedforward not in (False, True, "measurement", "reference"):
            raise ValueError(f"feedforward must be False, True/'measurement' or 'reference', got {feedforward!r}")
        self._feedforward = None
        self._feedforward_on_reference = feedforward == "reference"
        if feedforward in (True, "measurement"):
            self._feedforward = equilibrium_feedforward(known)
        elif feedforward == "reference":
            self._feedforward = reference_feedforward(known, coordinate)
        n_prefilter = self._prefilter.order if self._prefilter else 0
        self._n_prefilter = n_prefilter
        super().__init__(
            sample_period=sample_period,
            n_state=n_prefilter + self._controller.order,
            n_measured=known.ny,
            n_reference=1,
            n_input=1,
            gains=gains,
            measures="outputs",
            name=name,
        )

    def transfer_function(self) -> control.TransferFunction:
        """C(s) with the current gains."""
        return tf(self.gains["num"], self.gains["den"])

    def __repr__(self) -> str:
        fields = dict(self.gains) | {"Ts": self.sample_period, "limit": self.output_limit}
        return numbers_repr("TransferFunctionBlock", {"coordinate": self.coordinate} | fields)

    def expr(self, xc, y, r, gains):
        """One sample: the prefiltered reference, C(z) on the error, the feedforward, saturation, anti-windup."""
        npf = self._n_prefilter
        if self._prefilter is not None:
            xf_next, r_filtered = self._prefilter.expr(xc[:npf], r[0], gains["prefilter_num"], gains["prefilter_den"])
        else:
            xf_next, r_filtered = ca.SX(0, 1), r[0]
        error = r_filtered - self._read(y)
        xk = xc[npf:]
        xk_next, u_feedback = self._controller.expr(xk, error, gains["num"], gains["den"])
        if self._feedforward is None:
            u_unsat = u_feedback
        else:
            u_unsat = u_feedback + self._feedforward(r[0] if self._feedforward_on_reference else y)
        if self.output_limit is None:
            return ca.vertcat(xf_next, xk_next), u_unsat
        center = self._read_center(y) if self._read_center is not None else 0
        u = center + saturate(u_unsat - center, self.output_limit)
        if self.anti_windup == "observer" and self._controller.order:
            # The state tracks the applied output: x⁺ = F x + G e + K (u − u_unsat).
            xk_next = xk_next + self._controller.tracking_gain(gains["den"], self.tracking_pole) * (u - u_unsat)
        return ca.vertcat(xf_next, xk_next), u

    def initial_state(self, y0, r0) -> np.ndarray:
        """The prefilter at rest at the first reference r0, the controller's state at zero."""
        parts = []
        if self._prefilter is not None:
            parts.append(
                self._prefilter.steady_state(
                    float(np.ravel(r0)[0]), self.gains["prefilter_num"], self.gains["prefilter_den"]
                )
            )
        parts.append(np.zeros(self._controller.order))
        return np.concatenate(parts)
