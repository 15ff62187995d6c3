"""The two-degree-of-freedom loop of P(s), C_y(s), C_r(s): its closed loops, poles and steady-state errors.

    u = C_r(s) r − C_y(s) (y + n) + d_i,    y = P(s) u + d_o

covers PD/PID with the derivative on the error (C_r = C_y) or on the
measurement (C_r = k_p + k_i/s, C_y = k_p + k_i/s + k_d s), prefilters
(C_r = F C) and any C(s). Every closed loop is a ratio of polynomial
products over the characteristic polynomial D_P D_C + N_P N_Cy, so zeros at
s = 0 stay exact (see `designs.analysis.polynomials`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from models import deferred

from .polynomials import (
    as_polynomials,
    limit_at_zero,
    pid_polynomials,
    poly_add,
    poly_mul,
    poly_sub,
    polynomial,
    tf,
    zeros_at_origin,
)

if TYPE_CHECKING:
    import control
else:
    control = deferred.module("control")

__all__ = ["Loop", "UnstableLoopError", "steady_state_errors"]


class UnstableLoopError(ValueError):
    """A steady-state or frequency answer was asked of a closed loop that is not stable."""


def _cancel_origin(num, den) -> control.TransferFunction:
    """num/den with common factors of s removed exactly."""
    num, den = polynomial(num), polynomial(den)
    common = min(zeros_at_origin(num), zeros_at_origin(den))
    if common:
        num, den = polynomial(num[:-common]), polynomial(den[:-common])
    return tf(num, den)


@dataclass(frozen=True)
class Loop:
    """The two-degree-of-freedom loop u = C_r r − C_y (y + n) + d_i, y = P u + d_o.

    Attributes
    ----------
    plant : P(s), from the plant input to the measured (controlled) output
    feedback : C_y(s), acting on the measurement
    reference : C_r(s), acting on the reference
    name : str
    """

    plant: control.TransferFunction
    feedback: control.TransferFunction
    reference: control.TransferFunction
    name: str = ""

    @classmethod
    def unity(cls, plant, controller, name: str = "") -> Loop:
        """Error feedback u = C (r − y): C_r = C_y = C."""
        return cls(_as_tf(plant), _as_tf(controller), _as_tf(controller), name)

    @classmethod
    def pid(
        cls,
        plant,
        kp: float,
        ki: float = 0.0,
        kd: float = 0.0,
        *,
        sigma: float | None = None,
        derivative_on: str = "measurement",
        prefilter=None,
        name: str = "",
    ) -> Loop:
        """PID with the derivative on the measurement (the text's choice) or on the error.

        With `prefilter` F(s), the reference path is F·C_r.
        """
        if derivative_on not in ("measurement", "error"):
            raise ValueError(f"derivative_on must be 'measurement' or 'error', got {derivative_on!r}")
        if sigma is not None and not sigma > 0:
            raise ValueError(f"sigma must be > 0 s, got {sigma}")
        flags = (ki != 0, sigma is not None and kd != 0)
        feedback = tf(*pid_polynomials(kp, ki, kd, sigma, *flags))
        kd_reference = kd if derivative_on == "error" else 0.0
        # Same denominator on both paths, so N_Cy - N_Cr cancels exactly.
        reference = tf(*pid_polynomials(kp, ki, kd_reference, sigma, *flags))
        if prefilter is not None:
            reference = _as_tf(prefilter) * reference
        return cls(_as_tf(plant), feedback, reference, name)

    # polynomial parts over one controller denominator
    def _parts(self):
        """(N_P, D_P, N_Cy, N_Cr, D_C): the plant's polynomials and both controller paths over one denominator."""
        n_p, d_p = as_polynomials(self.plant)
        n_y, d_y = as_polynomials(self.feedback)
        n_r, d_r = as_polynomials(self.reference)
        if d_y.size == d_r.size and np.array_equal(d_y / d_y[0], d_r / d_r[0]):
            d_c = d_y
            n_r = n_r * (d_y[0] / d_r[0])
        else:
            d_c = poly_mul(d_y, d_r)
            n_y, n_r = poly_mul(n_y, d_r), poly_mul(n_r, d_y)
        return n_p, d_p, n_y, n_r, d_c

    def characteristic(self) -> np.ndarray:
        """Closed-loop characteristic polynomial D_P D_C + N_P N_Cy (descending)."""
        n_p, d_p, n_y, _, d_c = self._parts()
        return poly_add(poly_mul(d_p, d_c), poly_mul(n_p, n_y))

    def poles(self) -> np.ndarray:
        """Closed-loop poles (complex), sorted by real part."""
        roots = np.roots(self.characteristic())
        return roots[np.argsort(roots.real)]

    def is_stable(self) -> bool:
        """All closed-loop poles strictly in the left half plane."""
        return bool(np.all(self.poles().real < 0))

    def loop_gain(self) -> control.TransferFunction:
        """L(s) = P(s) C_y(s), the loop broken at the plant input."""
        n_p, d_p = as_polynomials(self.plant)
        n_y, d_y = as_polynomials(self.feedback)
        return _cancel_origin(poly_mul(n_p, n_y), poly_mul(d_p, d_y))

    def _closed(self, num) -> control.TransferFunction:
        """num over the characteristic polynomial: a closed loop of this loop."""
        return tf(num, self.characteristic())

    def reference_to_output(self) -> control.TransferFunction:
        """T_r = P C_r / (1 + P C_y)."""
        n_p, _, _, n_r, _ = self._parts()
        return self._closed(poly_mul(n_p, n_r))

    def reference_to_error(self) -> control.TransferFunction:
        """E/R = 1 − T_r = (D_P D_C + N_P (N_Cy − N_Cr)) / Δ, e = r − y."""
        n_p, d_p, n_y, n_r, d_c = self._parts()
        return self._closed(poly_add(poly_mul(d_p, d_c), poly_mul(n_p, poly_sub(n_y, n_r))))

    def input_disturbance_to_output(self) -> control.TransferFunction:
        """Y/D_i = P / (1 + P C_y)."""
        n_p, _, _, _, d_c = self._parts()
        return self._closed(poly_mul(n_p, d_c))

    def output_disturbance_to_output(self) -> control.TransferFunction:
        """Y/D_o = 1 / (1 + P C_y), the sensitivity S."""
        _, d_p, _, _, d_c = self._parts()
        return self._closed(poly_mul(d_p, d_c))

    def noise_to_output(self) -> control.TransferFunction:
        """Y/N = −P C_y / (1 + P C_y) = −T."""
        n_p, _, n_y, _, _ = self._parts()
        return self._closed(-poly_mul(n_p, n_y))

    def reference_to_input(self) -> control.TransferFunction:
        """U/R = C_r D_P / ... : the command a reference asks of the actuator."""
        _, d_p, _, n_r, _ = self._parts()
        return self._closed(poly_mul(d_p, n_r))

    def require_stable(self, what: str = "this answer") -> None:
        """Raise UnstableLoopError naming the right-half-plane poles unless the loop is stable."""
        poles = self.poles()
        bad = poles[poles.real >= 0]
        if bad.size:
            raise UnstableLoopError(
                f"{self.name or 'closed loop'} is not stable (poles "
                f"{np.array2string(bad, precision=4)} in the closed right half plane): "
                f"{what} does not exist"
            )


def _as_tf(G) -> control.TransferFunction:
    """G (a SISO transfer function or a number) as a validated continuous-time transfer function."""
    num, den = as_polynomials(G)
    return tf(num, den)


def steady_state_errors(loop: Loop) -> dict:
    """System type and steady-state error e = r − y to unit step, ramp and parabola.

    The type is the number of zeros at s = 0 of E/R; the errors are
    lim s→0 of E/R · s / s^(k+1). Exact (``inf`` for an unbounded error).

    Raises
    ------
    UnstableLoopError
        If the closed loop is not stable (no steady state exists).
    """
    loop.require_stable("a steady-state error")
    num, den = as_polynomials(loop.reference_to_error())
    return {
        "type": zeros_at_origin(num),
        "ess_step": limit_at_zero(num, den, 0),
        "ess_ramp": limit_at_zero(num, den, 1),
        "ess_parabola": limit_at_zero(num, den, 2),
    }
