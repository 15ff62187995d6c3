"""Polynomials and SISO transfer functions, exact: the algebra every loop answer is built from.

Polynomials are descending coefficient arrays (float, leading zeros removed).
Products and sums are formed coefficient by coefficient, never by
subtracting rational functions, so a factor s that the algebra produces is an
exact zero and `zeros_at_origin`, `limit_at_zero` and `dc_gain` are exact
(an infinite limit stays ``inf``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from models import deferred

if TYPE_CHECKING:
    import control
else:
    control = deferred.module("control")

__all__ = [
    "ZERO_TOL",
    "polynomial",
    "poly_add",
    "poly_sub",
    "poly_mul",
    "zeros_at_origin",
    "as_polynomials",
    "tf",
    "pid_polynomials",
    "pid_tf",
    "limit_at_zero",
    "dc_gain",
]

#: Coefficients below this fraction of their polynomial's largest count as exact zeros.
ZERO_TOL = 1e-12


def polynomial(coeffs) -> np.ndarray:
    """Descending coefficients as a float array with leading zeros removed (at least [0])."""
    arr = np.atleast_1d(np.asarray(coeffs, dtype=float)).ravel()
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"polynomial coefficients must be finite, got {arr}")
    nonzero = np.flatnonzero(arr)
    return arr[nonzero[0] :] if nonzero.size else np.zeros(1)


def poly_add(a, b) -> np.ndarray:
    """a(s) + b(s), descending coefficients."""
    a, b = polynomial(a), polynomial(b)
    n = max(a.size, b.size)
    return polynomial(np.pad(a, (n - a.size, 0)) + np.pad(b, (n - b.size, 0)))


def poly_sub(a, b) -> np.ndarray:
    """a(s) − b(s), descending coefficients."""
    return poly_add(a, -polynomial(b))


def poly_mul(*polys) -> np.ndarray:
    """The product of the polynomials, descending coefficients."""
    out = np.ones(1)
    for p in polys:
        out = np.polymul(out, polynomial(p))
    return polynomial(out)


def zeros_at_origin(p, tol: float = ZERO_TOL) -> int:
    """Number of roots at s = 0: trailing coefficients that are zero (relative to the largest)."""
    p = polynomial(p)
    scale = np.max(np.abs(p))
    if scale == 0:
        return p.size
    count = 0
    for c in p[::-1]:
        if abs(c) > tol * scale:
            break
        count += 1
    return count


def as_polynomials(G) -> tuple[np.ndarray, np.ndarray]:
    """(num, den) descending coefficients of a SISO continuous-time transfer function or a number."""
    if np.isscalar(G) or (isinstance(G, np.ndarray) and G.size == 1):
        return polynomial([float(np.asarray(G).ravel()[0])]), np.ones(1)
    if not isinstance(G, control.TransferFunction):
        raise TypeError(f"expected a control.TransferFunction or a number, got {type(G).__name__}")
    if G.ninputs != 1 or G.noutputs != 1:
        raise ValueError(f"expected a SISO transfer function, got {G.noutputs}x{G.ninputs}")
    if G.dt not in (0, None):
        raise ValueError(f"expected a continuous-time transfer function, got dt = {G.dt}")
    den = polynomial(G.den[0][0])
    if not np.any(den):
        raise ValueError("transfer function has a zero denominator")
    return polynomial(G.num[0][0]), den


def tf(num, den) -> control.TransferFunction:
    """Continuous-time SISO transfer function from descending coefficients (validated)."""
    num, den = polynomial(num), polynomial(den)
    if not np.any(den):
        raise ValueError("denominator polynomial is zero")
    return control.tf(num, den)


def pid_polynomials(kp, ki, kd, sigma, integrator: bool, rolloff: bool) -> tuple[np.ndarray, np.ndarray]:
    """(num, den) of k_p + k_i/s + k_d s/(σ s + 1) over the denominator s^[integrator] (σ s + 1)^[rolloff].

    The denominator depends only on the two flags, so two PIDs built with the same
    flags and σ share it exactly (the loop's reference and feedback paths).

    Parameters
    ----------
    kp, ki, kd : gains (units of u per unit of e, per unit·s, per unit/s)
    sigma : dirty-derivative time constant σ, s (read only with `rolloff`)
    integrator : include the factor s of k_i/s in the denominator
    rolloff : include the factor (σ s + 1) of the dirty derivative
    """
    den = np.ones(1)
    if integrator:
        den = poly_mul(den, [1.0, 0.0])
    if rolloff:
        den = poly_mul(den, [sigma, 1.0])
    num = poly_mul([kp], den)
    if integrator:
        num = poly_add(num, poly_mul([ki], [sigma, 1.0] if rolloff else [1.0]))
    derivative = poly_mul([kd, 0.0], [1.0, 0.0] if integrator else [1.0])
    num = poly_add(num, derivative)
    return num, den


def pid_tf(kp: float, ki: float = 0.0, kd: float = 0.0, sigma: float | None = None) -> control.TransferFunction:
    """k_p + k_i/s + k_d s/(σ s + 1) (ideal derivative when `sigma` is None), continuous time."""
    if sigma is not None and not sigma > 0:
        raise ValueError(f"sigma must be > 0 s, got {sigma}")
    return tf(*pid_polynomials(kp, ki, kd, sigma, ki != 0, sigma is not None and kd != 0))


def limit_at_zero(num, den, power: int = 0) -> float:
    """lim_{s→0} N(s) / (D(s) s^power), exact: 0, a finite ratio, or ±inf.

    The sign of an infinite limit is the sign approached from s → 0⁺.
    """
    num, den = polynomial(num), polynomial(den)
    if not np.any(den):
        raise ValueError("denominator is zero")
    if not np.any(num):
        return 0.0
    zn, zd = zeros_at_origin(num), zeros_at_origin(den) + power
    ratio = num[num.size - 1 - zn] / den[den.size - 1 - zeros_at_origin(den)]
    if zn > zd:
        return 0.0
    if zn == zd:
        return float(ratio)
    return float(np.sign(ratio) * np.inf)


def dc_gain(G) -> float:
    """G(0), exact; ±inf for a pole at the origin."""
    return limit_at_zero(*as_polynomials(G))
