"""Root locus: Evans forms, the integrator gain of .10, and lead-lag design by the angle condition.

A characteristic equation D(s) + k N(s) = 0 is in Evans form 1 + k L(s) = 0
with L = N/D. The locus itself comes from python-control
(`control.root_locus_map`); the gain at which the locus leaves a region of
the plane is found exactly, from the real roots of a polynomial.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from models import deferred

from .analysis.loop import Loop
from .analysis.polynomials import as_polynomials, dc_gain, poly_add, poly_mul, polynomial, tf
from .analysis.time_response import step_info

if TYPE_CHECKING:
    import control
else:
    control = deferred.module("control")

__all__ = [
    "evans_form",
    "integrator_evans_form",
    "locus",
    "damping_ratios",
    "gain_leaving_damping",
    "integrator_gain",
    "LeadLagDesign",
    "lead_by_angle",
    "lag_for_static_gain",
    "dominant_pair",
    "lead_lag_for_static_gain",
]


def evans_form(char_base, char_gain) -> control.TransferFunction:
    """L(s) = N/D for the characteristic equation D(s) + k N(s) = 0 (descending coefficients)."""
    den, num = polynomial(char_base), polynomial(char_gain)
    if not np.any(num):
        raise ValueError("the gain does not enter the characteristic equation")
    return tf(num, den)


def integrator_evans_form(plant, kp: float, kd: float = 0.0) -> control.TransferFunction:
    """Evans form for k_i of PID on `plant`: s (D + N (k_d s + k_p)) + k_i N = 0.

    The same for the derivative on the error or on the measurement (the
    characteristic polynomial does not depend on where k_d acts).
    """
    num, den = as_polynomials(plant)
    base = poly_mul([1.0, 0.0], poly_add(den, poly_mul(num, [kd, kp])))
    return evans_form(base, num)


def locus(L, gains) -> np.ndarray:
    """Closed-loop poles of 1 + k L(s) = 0 for each gain, (len(gains), n), from python-control."""
    gains = np.atleast_1d(np.asarray(gains, dtype=float))
    return control.root_locus_map(L, gains).loci


def damping_ratios(poles) -> np.ndarray:
    """ζ = −Re(p)/|p| of each pole (1 for a pole at the origin's left on the real axis)."""
    poles = np.asarray(poles, dtype=complex)
    mag = np.abs(poles)
    return np.where(mag > 0, -poles.real / np.where(mag > 0, mag, 1.0), 0.0)


def gain_leaving_damping(L, zeta_min: float, sign: float = 1.0) -> float:
    """Smallest |k| (with the given sign) at which a pole of 1 + k L = 0 reaches damping `zeta_min`.

    A branch leaves the sector {ζ ≥ ζ_min} either across the ray
    s = ω e^{j(π − arccos ζ_min)} (where k = −D(s)/N(s) must be real, a
    polynomial condition in ω) or through s = 0. Both are solved exactly.

    Returns
    -------
    float : the boundary gain k (signed); inf if no branch ever leaves.
    """
    if not 0 < zeta_min < 1:
        raise ValueError(f"zeta_min must be in (0, 1), got {zeta_min}")
    num, den = as_polynomials(L)
    angle = np.pi - np.arccos(zeta_min)
    direction = np.exp(1j * angle)

    # D(ω d) and N(ω d) as polynomials in ω: coefficient of ω^k gets d^k.
    def on_ray(p):
        n = p.size - 1
        return p * direction ** np.arange(n, -1, -1)

    d_ray, n_ray = on_ray(den), on_ray(num)
    # k real  <=>  Im(D conj(N)) = 0.
    cross = np.polymul(d_ray, np.conj(n_ray)).imag
    candidates = []
    roots = np.roots(polynomial(cross)) if np.any(np.abs(cross) > 0) else np.array([])
    for w in roots:
        if abs(w.imag) < 1e-9 * max(1.0, abs(w)) and w.real > 0:
            s = w.real * direction
            n_val = np.polyval(num, s)
            if abs(n_val) > 0:
                candidates.append((-np.polyval(den, s) / n_val).real)
    n0 = np.polyval(num, 0.0)
    if n0 != 0:
        candidates.append(-np.polyval(den, 0.0) / n0)
    signed = [k for k in candidates if np.sign(k) == np.sign(sign) and k != 0]
    return float(min(signed, key=abs)) if signed else float(np.sign(sign) * np.inf)


def integrator_gain(
    plant,
    kp: float,
    kd: float,
    zeta_min: float,
    overshoot_allowance: float | None = 10.0,
    derivative_on: str = "measurement",
) -> dict:
    """The .10 choice of k_i along its root locus.

    "Choose k_i sufficiently large to drive the error to zero as quickly as
    possible without significantly degrading the transient response".
    We take the largest k_i for which (1) every closed-loop pole
    keeps damping ≥ `zeta_min` (we use 0.9 of the PD loop's ζ; found
    exactly with `gain_leaving_damping`) and (2) the step overshoot of the
    PID loop stays within `overshoot_allowance` percentage points of the PD
    loop's (the PI zero at −k_i/k_p adds overshoot the poles do not show;
    bisection, None to skip). The sign of k_i is that of k_p (both negative
    for a plant of negative gain, such as −g/s²).

    Returns
    -------
    dict with ki, evans (Evans-form L(s)), poles at ki, zeta_min, ki_damping (the bound from (1))
    and the overshoots (percent) of the PD and PID loops.

    Raises
    ------
    ValueError
        If the PD poles are already below `zeta_min`.
    """
    L = integrator_evans_form(plant, kp, kd)
    start = np.roots(as_polynomials(L)[1])
    start = start[np.abs(start) > 1e-12]
    if np.any(damping_ratios(start) < zeta_min):
        raise ValueError(f"the PD poles {start} already have damping below zeta_min = {zeta_min}")
    ki_damping = gain_leaving_damping(L, zeta_min, np.sign(kp))
    if not np.isfinite(ki_damping):
        raise ValueError("the k_i locus never leaves the damping sector; choose k_i by another rule")

    def overshoot(ki):
        loop = Loop.pid(plant, kp, ki, kd, derivative_on=derivative_on)
        return step_info(loop.reference_to_output())["Overshoot"]

    os_pd = overshoot(0.0)
    unit_dc = abs(dc_gain(Loop.pid(plant, kp, 0.0, kd, derivative_on=derivative_on).reference_to_output()) - 1) < 1e-9
    ki = ki_damping
    # Only a loop already at unit DC gain can compare overshoots: where the PD loop settles elsewhere
    # (type 0), the integrator's job is to move the final value, which step_info counts as overshoot.
    if overshoot_allowance is not None and unit_dc and overshoot(ki) > os_pd + overshoot_allowance:
        lo, hi = 0.0, 1.0  # fractions of ki_damping
        for _ in range(40):
            mid = 0.5 * (lo + hi)
            if overshoot(mid * ki_damping) > os_pd + overshoot_allowance:
                hi = mid
            else:
                lo = mid
        ki = lo * ki_damping
    poles = locus(L, [ki])[0]
    return {
        "ki": float(ki),
        "evans": L,
        "poles": poles[np.argsort(poles.real)],
        "zeta_min": zeta_min,
        "ki_damping": float(ki_damping),
        "overshoot_pd": float(os_pd),
        "overshoot_pid": float(overshoot(ki)),
    }


def dominant_pair(wn: float, zeta: float) -> complex:
    """Upper pole −ζω_n + jω_n√(1 − ζ²) of a second-order pair."""
    if not (wn > 0 and 0 < zeta < 1):
        raise ValueError(f"need wn > 0 and 0 < zeta < 1, got {wn}, {zeta}")
    return complex(-zeta * wn, wn * np.sqrt(1 - zeta**2))


@dataclass(frozen=True)
class LeadLagDesign:
    """C(s) = K (s + z)/(s + p) · (s + z_lag)/(s + p_lag) from the root locus.

    Attributes
    ----------
    gain, lead_zero, lead_pole, lag_zero, lag_pole : K and the corner magnitudes in rad/s
        (C has zeros at −z and poles at −p); lag_zero = lag_pole = 0 means no lag
    target : the dominant closed-loop pole the lead places
    """

    gain: float
    lead_zero: float
    lead_pole: float
    target: complex
    lag_zero: float = 0.0
    lag_pole: float = 0.0

    def lead_tf(self) -> control.TransferFunction:
        """The lead K (s + z)/(s + p), the gain included."""
        return tf([self.gain, self.gain * self.lead_zero], [1.0, self.lead_pole])

    def lag_tf(self) -> control.TransferFunction:
        """The lag (s + z_lag)/(s + p_lag), or 1 when there is none."""
        if self.lag_zero == 0:
            return tf([1.0], [1.0])
        return tf([1.0, self.lag_zero], [1.0, self.lag_pole])

    def transfer_function(self) -> control.TransferFunction:
        """C(s): the lead times the lag."""
        return self.lead_tf() * self.lag_tf()


def lead_by_angle(plant, target: complex, zero: float) -> LeadLagDesign:
    """Lead K (s + z)/(s + p) putting a closed-loop pole at `target` (angle and magnitude conditions).

    The zero −z is chosen; the pole −p supplies the missing angle so that
    ∠G(s*) + ∠(s* + z) − ∠(s* + p) = −180°, and K = 1/|G(s*) (s* + z)/(s* + p)|.

    Raises
    ------
    ValueError
        When the zero leaves more than 180° of angle to add, so that no real
        pole works (move the zero or use two leads), or the pole comes out
        in the right half plane.
    """
    num, den = as_polynomials(plant)
    s = complex(target)
    if s.imag <= 0:
        raise ValueError(f"target must be the upper pole of a pair (imag > 0), got {target}")
    if not zero > 0:
        raise ValueError(f"the lead zero must be in the left half plane (z > 0), got {zero}")
    g = np.polyval(num, s) / np.polyval(den, s)
    # Angle the pole must subtract: ∠(s* + p) = ∠G + ∠(s* + z) + 180°.
    needed = np.angle(g) + np.angle(s + zero) + np.pi
    needed = (needed + np.pi) % (2 * np.pi) - np.pi
    if not 0 < needed < np.pi:
        raise ValueError(
            f"with the zero at -{zero:g} the pole would need an angle of {np.degrees(needed):.1f} deg; "
            "move the zero or add a second lead"
        )
    pole = s.imag / np.tan(needed) - s.real
    if pole <= 0:
        raise ValueError(f"the lead pole comes out at {-pole:.4g} (right half plane); move the zero")
    gain = 1.0 / abs(g * (s + zero) / (s + pole))
    return LeadLagDesign(gain=float(gain), lead_zero=float(zero), lead_pole=float(pole), target=s)


def lag_for_static_gain(design: LeadLagDesign, plant, static_gain: float, zero: float) -> LeadLagDesign:
    """Add a lag (s + z)/(s + p) raising the loop's static gain K_p = L(0) to `static_gain`.

    p = z · L_lead(0)/`static_gain`; z is chosen well below the dominant
    poles so that the lag barely moves them.
    """
    if not zero > 0:
        raise ValueError(f"lag zero must be > 0 rad/s, got {zero}")
    current = dc_gain(design.lead_tf() * plant)
    if not np.isfinite(current) or current == 0:
        raise ValueError(f"the lead loop's static gain is {current}; a lag cannot set it")
    ratio = static_gain / current
    if ratio <= 1:
        return design
    return LeadLagDesign(
        gain=design.gain,
        lead_zero=design.lead_zero,
        lead_pole=design.lead_pole,
        target=design.target,
        lag_zero=float(zero),
        lag_pole=float(zero / ratio),
    )


def lead_lag_for_static_gain(
    plant, wn: float, zeta: float, lead_zero: float, lag_zero: float, static_gain: float
) -> tuple[LeadLagDesign, LeadLagDesign]:
    """A lead placing the dominant pair (ω_n, ζ) by the angle condition, and a lag raising K_p.

    The lag is fixed first and the lead is placed on G·lag, so the lag's phase
    at s* is compensated and the dominant poles stay exactly at s*; the lag
    ratio is iterated until the static gain K_p = L(0) equals `static_gain`.

    Returns
    -------
    (lead alone placed on G, the final lead-lag)
    """
    s_star = dominant_pair(wn, zeta)
    lead_alone = lead_by_angle(plant, s_star, lead_zero)
    g0 = dc_gain(plant)
    ratio = static_gain / (lead_alone.gain * lead_zero / lead_alone.lead_pole * g0)
    for _ in range(100):
        lag_tf = tf([1.0, lag_zero], [1.0, lag_zero / ratio])
        lead = lead_by_angle(plant * lag_tf, s_star, lead_zero)
        achieved = lead.gain * lead_zero / lead.lead_pole * ratio * g0
        new_ratio = ratio * static_gain / achieved
        if abs(new_ratio - ratio) <= 1e-12 * ratio:
            break
        ratio = new_ratio
    return lead_alone, lag_for_static_gain(lead, plant, static_gain, lag_zero)
