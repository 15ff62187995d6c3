"""Loopshaping (.14) and frequency-response design of lead, lag and notch compensators.

- `improve_loop`: the .14 recipe. Given a loop L0 = P C_PD, add
  C(s) = K · lead · lag · low-pass so that tracking and disturbance
  rejection improve by a factor below ω_low, noise attenuation improves by a
  factor above ω_high, the crossover stays put and the phase margin is
  restored. Every requirement is checked on the exact closed loops and
  reported met or not met (`analysis.SpecCheck`).
- `flattening_prefilter`: a low-pass prefilter F(s), the fastest
  first-order F keeping max |F T| within 1 % of one.
- `lead_for_crossover`: gain and one or two leads putting the crossover at
  ω_c with a given phase margin.
- Second-order prototype relations (exact for L = ω_n²/(s (s + 2ζω_n))):
  crossover and bandwidth from ω_n, ζ and the phase margin from ζ, used to
  turn "bandwidth 20 rad/s, damping ratio 0.7" into a crossover and
  a phase margin.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from models import deferred

from .analysis.frequency import band_max
from .analysis.loop import Loop
from .analysis.polynomials import as_polynomials, tf, zeros_at_origin
from .analysis.spec_checks import (
    SpecCheck,
    check_band_ratio,
    check_bandwidth,
    check_crossover,
    check_phase_margin,
    check_stable,
)
from .analysis.stability_margins import margins
from .filters import lag, lead, lead_ratio, low_pass

if TYPE_CHECKING:
    import control
else:
    control = deferred.module("control")
scipy = deferred.module("scipy")

__all__ = [
    "prototype_crossover",
    "prototype_bandwidth",
    "prototype_phase_margin",
    "damping_for_phase_margin",
    "crossover_for_bandwidth",
    "lead_for_crossover",
    "LeadDesign",
    "improve_loop",
    "lowpass_corner_for_noise",
    "lag_ratio_for_tracking",
    "LoopshapingResult",
    "flattening_prefilter",
    "phase_at",
    "low_frequency_sign",
    "frequency_design_checks",
]


# ----------------------------------------------------------------- prototype relations
def _check_zeta(zeta):
    """ValueError unless ζ > 0."""
    if not zeta > 0:
        raise ValueError(f"zeta must be > 0, got {zeta}")


def prototype_crossover(wn: float, zeta: float) -> float:
    """Gain crossover of L = ω_n²/(s (s + 2ζω_n)): ω_n √(√(1 + 4ζ⁴) − 2ζ²), rad/s."""
    _check_zeta(zeta)
    return float(wn * np.sqrt(np.sqrt(1 + 4 * zeta**4) - 2 * zeta**2))


def prototype_bandwidth(wn: float, zeta: float) -> float:
    """−3 dB bandwidth of ω_n²/(s² + 2ζω_n s + ω_n²): ω_n √(1 − 2ζ² + √(2 − 4ζ² + 4ζ⁴)), rad/s."""
    _check_zeta(zeta)
    return float(wn * np.sqrt(1 - 2 * zeta**2 + np.sqrt(2 - 4 * zeta**2 + 4 * zeta**4)))


def prototype_phase_margin(zeta: float) -> float:
    """Phase margin of L = ω_n²/(s (s + 2ζω_n)) in degrees: atan(2ζ / √(√(1 + 4ζ⁴) − 2ζ²))."""
    _check_zeta(zeta)
    return float(np.degrees(np.arctan(2 * zeta / np.sqrt(np.sqrt(1 + 4 * zeta**4) - 2 * zeta**2))))


def damping_for_phase_margin(pm_deg: float) -> float:
    """The ζ whose prototype loop has phase margin `pm_deg` (inverse of `prototype_phase_margin`)."""
    if not 0 < pm_deg < 90:
        raise ValueError(f"phase margin must be in (0, 90) deg, got {pm_deg}")
    return float(scipy.optimize.brentq(lambda z: prototype_phase_margin(z) - pm_deg, 1e-6, 50.0, xtol=1e-14))


def crossover_for_bandwidth(bandwidth: float, zeta: float) -> float:
    """Crossover of the prototype loop whose closed loop has the given bandwidth and damping."""
    wn = bandwidth / prototype_bandwidth(1.0, zeta)
    return prototype_crossover(wn, zeta)


def low_frequency_sign(L) -> float:
    """Sign of L's low-frequency gain: of N_low/D_low, the lowest nonzero coefficients."""
    num, den = as_polynomials(L)
    n_low = num[num.size - 1 - zeros_at_origin(num)]
    d_low = den[den.size - 1 - zeros_at_origin(den)]
    return float(np.sign(n_low / d_low))


def phase_at(L, omega: float) -> float:
    """Phase of L(jω) in degrees, continuous from the low-frequency asymptote −90°·type.

    For a positive low-frequency gain the asymptote is −90° per integrator
    (−180° for 1/s²), so the phase margin is 180° + phase at crossover.
    """
    num, den = as_polynomials(L)
    n_type = zeros_at_origin(den) - zeros_at_origin(num)
    grid = np.logspace(np.log10(omega) - 8, np.log10(omega), 4000)
    resp = np.polyval(num, 1j * grid) / np.polyval(den, 1j * grid) * (1j * grid) ** n_type
    phase = np.unwrap(np.angle(resp))
    phase -= 2 * np.pi * np.round(phase[0] / (2 * np.pi))  # start within (−180°, 180°]
    return float(np.degrees(phase[-1]) - 90.0 * n_type)


# ----------------------------------------------------------------- lead design
@dataclass(frozen=True)
class LeadDesign:
    """C(s) = gain · lead^count putting L's crossover at `crossover` with `phase_margin_deg`.

    Attributes
    ----------
    controller : C(s)
    gain : K
    lead_phase_deg : total phase added at the crossover (split over `count` leads)
    count : 0, 1 or 2 leads
    zero, pole : the corner frequencies of each lead, rad/s
    """

    controller: control.TransferFunction
    gain: float
    lead_phase_deg: float
    count: int
    zero: float
    pole: float
    crossover: float
    phase_margin_deg: float


def lead_for_crossover(
    L0, crossover: float, phase_margin_deg: float, max_phase_per_lead: float = 65.0, extra_deg: float = 0.0
) -> LeadDesign:
    """Gain and lead(s) so that K·lead·L0 crosses over at `crossover` with the given phase margin.

    The lead is centred at the crossover (maximum phase there); phase above
    `max_phase_per_lead` is split over two identical leads.

    Raises
    ------
    ValueError
        When more than two leads would be needed.
    """
    if not crossover > 0:
        raise ValueError(f"crossover must be > 0 rad/s, got {crossover}")
    poles = np.roots(as_polynomials(L0)[1])
    if np.any(poles.real > 1e-9):
        raise ValueError(
            f"lead_for_crossover needs a loop without right-half-plane poles (got {poles}); "
            "stabilize the plant first (e.g. an inner PD loop)"
        )
    # The controller takes the sign of the plant's low-frequency gain (negative for −g/s²).
    sign = low_frequency_sign(L0)
    L0 = sign * L0
    phase = phase_at(L0, crossover)
    # Phase margin = 180 + phase (phase continuous from DC, within (-540, 180)).
    needed = phase_margin_deg - (180.0 + phase) + extra_deg
    needed = (needed + 180.0) % 360.0 - 180.0
    if needed <= 0:
        count, per, comp = 0, 0.0, tf([1.0], [1.0])
    else:
        count = 1 if needed <= max_phase_per_lead else 2
        per = needed / count
        if per >= 89.0:
            raise ValueError(
                f"the loop needs {needed:.1f} deg of lead at {crossover:g} rad/s; more than two leads would be needed"
            )
        comp = lead(crossover, per) ** count
    num, den = as_polynomials(comp * L0)
    gain = 1.0 / abs(np.polyval(num, 1j * crossover) / np.polyval(den, 1j * crossover))
    alpha = lead_ratio(per) if count else 1.0
    return LeadDesign(
        controller=comp * (sign * gain),
        gain=float(sign * gain),
        lead_phase_deg=float(max(needed, 0.0)),
        count=count,
        zero=float(crossover / np.sqrt(alpha)),
        pole=float(crossover * np.sqrt(alpha)),
        crossover=float(crossover),
        phase_margin_deg=float(phase_margin_deg),
    )


# ----------------------------------------------------------------- .14 loopshaping
@dataclass(frozen=True)
class LoopshapingResult:
    """C(s) added to a loop, and which requirement holds.

    Attributes
    ----------
    controller : the added compensator C(s) (L = L0 C)
    baseline : L0;  loop : L0 C
    lag_zero, lag_gain, lowpass_corner, lowpass_order, lead_phase_deg, gain
    specs : list of SpecCheck
    """

    controller: control.TransferFunction
    baseline: control.TransferFunction
    loop: control.TransferFunction
    lag_zero: float
    lag_gain: float
    lowpass_corner: float
    lowpass_order: int
    lead_phase_deg: float
    gain: float
    specs: list = field(default_factory=list)

    @property
    def all_met(self) -> bool:
        """Every requirement in `specs` is met."""
        return all(s.met for s in self.specs)


def _lowpass_response(omega, corner: float, order: int) -> np.ndarray:
    """(ω_lp/(jω + ω_lp))^order at omega (F,) rad/s."""
    return (corner / (1j * omega + corner)) ** order


def _lag_response(omega, zero: float, gain: float) -> np.ndarray:
    """(jω + z)/(jω + z/M) at omega (F,) rad/s: the lag of zero z and ratio M."""
    return (1j * omega + zero) / (1j * omega + zero / gain)


def lowpass_corner_for_noise(baseline, compensator, omega, order: int, target: float, lo: float, hi: float) -> float:
    """The low-pass corner ω_lp (rad/s) at which the largest noise ratio |T_new/T_old| on `omega` is `target`.

    With the added compensator C = `compensator` · (ω_lp/(s + ω_lp))^order,
    T_new/T_old = C (1 + L0)/(1 + L0 C); the corner is found by `brentq` in [lo, hi].

    Parameters
    ----------
    baseline : L0(jω) on `omega`, complex (F,)
    compensator : the rest of the compensator (lead · lag) on `omega`, complex (F,)
    omega : (F,) rad/s, the band the noise requirement covers (above ω_high)
    order : poles of the low-pass
    target : the largest ratio allowed, 1 / (factor × margin)
    lo, hi : rad/s, the search interval

    Returns
    -------
    The corner; `lo` when even `lo` leaves the ratio above `target`, `hi` when `hi` already meets it.
    """

    def noise_ratio(corner):
        c = compensator * _lowpass_response(omega, corner, order)
        return np.max(np.abs(c * (1 + baseline) / (1 + baseline * c)))

    if noise_ratio(lo) > target:
        return lo
    if noise_ratio(hi) <= target:
        return hi
    return scipy.optimize.brentq(lambda w: noise_ratio(w) - target, lo, hi, xtol=1e-12 * hi)


def lag_ratio_for_tracking(baseline, compensator, omega, zero: float, need: float) -> tuple[float, bool]:
    """The lag ratio M at which the smallest sensitivity improvement |S_old/S_new| on `omega` is `need`.

    With the added compensator C = `compensator` · (s + z)/(s + z/M),
    S_old/S_new = |1 + L0 C|/|1 + L0|. M starts just above 1; the bracket grows
    by factors of 4 up to 1e12, then `brentq` finds M.

    Parameters
    ----------
    baseline : L0(jω) on `omega`, complex (F,)
    compensator : the rest of the compensator (lead · low-pass) on `omega`, complex (F,)
    omega : (F,) rad/s, the band the tracking requirement covers (below ω_low)
    zero : the lag zero z, rad/s
    need : the improvement asked for, factor × margin

    Returns
    -------
    (M, reached) : reached is False when no M up to the bracket's end reaches `need` with this zero
    (then M is that end); M = 1 + 1e-9 when no lag is needed.
    """

    def tracking_gain(gain):
        c = compensator * _lag_response(omega, zero, gain)
        return np.min(np.abs((1 + baseline * c) / (1 + baseline)))

    if tracking_gain(1.0 + 1e-9) >= need:
        return 1.0 + 1e-9, True
    m_hi = 4.0
    while tracking_gain(m_hi) < need and m_hi < 1e12:
        m_hi *= 4.0
    if tracking_gain(m_hi) < need:
        return m_hi, False
    return scipy.optimize.brentq(lambda m: tracking_gain(m) - need, 1.0 + 1e-9, m_hi, xtol=1e-12), True


def _crossover_and_starting_lag(
    L0, crossover, low_frequency: float, low_factor: float, high_frequency: float, lag_zero_ratio: float, margin: float
) -> tuple[float, float, float]:
    """(crossover ω_c, starting lag zero, starting lag ratio) of `improve_loop`, rad/s and ratio.

    ω_c is `crossover` or L0's own; the lag zero ω_c / `lag_zero_ratio`, raised to the lowest
    zero that can give `low_factor` at ω_low; the ratio 1.2 × factor × margin.

    Raises
    ------
    ValueError
        If L0 has no crossover and none is given, or unless ω_low < ω_c < ω_high.
    """
    base = margins(L0)
    wc = base["gain_crossover"] if crossover is None else float(crossover)
    if not np.isfinite(wc):
        raise ValueError("the baseline loop has no gain crossover; give `crossover`")
    if not low_frequency < wc < high_frequency:
        raise ValueError(
            f"need low_frequency < crossover < high_frequency, got {low_frequency:g}, {wc:g}, {high_frequency:g} rad/s"
        )
    lag_zero = wc / lag_zero_ratio
    floor = low_frequency * np.sqrt(low_factor**2 - 1) * 1.5
    lag_zero = max(lag_zero, floor)  # a lag zero below this cannot give the factor at ω_low
    lag_gain = low_factor * margin * 1.2
    return wc, lag_zero, lag_gain


def improve_loop(
    L0,
    *,
    low_frequency: float,
    low_factor: float,
    high_frequency: float,
    high_factor: float,
    phase_margin_deg: float = 60.0,
    phase_tolerance_deg: float = 5.0,
    crossover: float | None = None,
    lowpass_order: int = 2,
    lag_zero_ratio: float = 10.0,
    margin: float = 1.05,
    iterations: int = 60,
) -> LoopshapingResult:
    """The .14 design: lag for low frequencies, low-pass for noise, lead for the phase margin.

    Parameters
    ----------
    L0 : the baseline loop gain P C_PD
    low_frequency, low_factor : improve tracking and disturbance rejection by
        `low_factor` for all frequencies below `low_frequency` rad/s
    high_frequency, high_factor : improve noise attenuation by `high_factor` above `high_frequency`
    phase_margin_deg : target phase margin (the text: "around 60 deg")
    crossover : rad/s; default L0's own crossover (kept)
    lowpass_order : poles of the low-pass ("add one to two poles")
    lag_zero_ratio : lag zero at crossover / this (keeps the lag's phase lag small); raised
        towards crossover / 2 when no lag ratio can reach the low-frequency factor (type-0 loops)
    margin : design each factor with this much to spare (1.05: 5 %)
    iterations : at most this many rounds of lead, low-pass corner and lag ratio

    Each round places the lead for the crossover and phase margin on L0 · lag · low-pass,
    then the low-pass corner for the noise factor (`lowpass_corner_for_noise`) and the lag
    ratio for the tracking factor (`lag_ratio_for_tracking`), on fixed frequency grids,
    until corner and ratio change by less than 1e-9 relative.

    The requirements are checked on the exact closed loops: |S_new| ≤ |S_old|/factor
    below ω_low (tracking error and output disturbance), |P S_new| likewise
    for input disturbances, |T_new| ≤ |T_old|/factor above ω_high, the phase
    margin, the crossover and closed-loop stability.

    Raises
    ------
    ValueError
        If the frequencies are not ordered ω_low < crossover < ω_high.
    """
    wc, lag_zero, lag_gain = _crossover_and_starting_lag(
        L0, crossover, low_frequency, low_factor, high_frequency, lag_zero_ratio, margin
    )
    corner = high_frequency
    # Frequency responses on fixed grids; the iteration only multiplies arrays.
    w_low = np.logspace(np.log10(low_frequency) - 6, np.log10(low_frequency), 1201)
    w_high = np.logspace(np.log10(high_frequency), np.log10(high_frequency) + 6, 1201)
    L0_low, L0_high = _response(L0, w_low), _response(L0, w_high)
    order = int(lowpass_order)
    for _ in range(iterations):
        design = lead_for_crossover(L0 * lag(lag_zero, lag_gain) * low_pass(corner, order), wc, phase_margin_deg)
        lead_high = _response(design.controller, w_high) * _lag_response(w_high, lag_zero, lag_gain)
        lead_low = _response(design.controller, w_low) * _lowpass_response(w_low, corner, order)
        target = 1.0 / (high_factor * margin)
        new_corner = lowpass_corner_for_noise(
            L0_high, lead_high, w_high, order, target, wc * 1e-3, high_frequency * 1e3
        )
        new_gain, reached = lag_ratio_for_tracking(L0_low, lead_low, w_low, lag_zero, low_factor * margin)
        if not reached and lag_zero * 1.25 <= wc / 2:
            # No lag ratio reaches the factor with this zero (a type-0 loop): move the zero up.
            lag_zero *= 1.25
            continue
        # An unreachable factor keeps the bracket's end: the spec check below reports it.
        converged = abs(new_corner - corner) <= 1e-9 * corner and abs(new_gain - lag_gain) <= 1e-9 * lag_gain
        corner, lag_gain = float(new_corner), float(new_gain)
        if converged:
            break
    lp = low_pass(corner, lowpass_order)
    lag_tf = lag(lag_zero, lag_gain)
    design = lead_for_crossover(L0 * lag_tf * lp, wc, phase_margin_deg)
    comp = design.controller * lag_tf * lp
    L = L0 * comp
    specs = loop_improvement_specs(L0, L, low_frequency, low_factor, high_frequency, high_factor)
    specs.append(check_phase_margin(L, target_deg=phase_margin_deg, tolerance_deg=phase_tolerance_deg))
    specs.append(check_crossover(L, wc))
    return LoopshapingResult(
        controller=comp,
        baseline=L0,
        loop=L,
        lag_zero=float(lag_zero),
        lag_gain=lag_gain,
        lowpass_corner=corner,
        lowpass_order=int(lowpass_order),
        lead_phase_deg=design.lead_phase_deg,
        gain=design.gain,
        specs=specs,
    )


def _response(G, omega) -> np.ndarray:
    """G(jω) at omega (F,) rad/s, complex (F,)."""
    num, den = as_polynomials(G)
    s = 1j * omega
    return np.polyval(num, s) / np.polyval(den, s)


def loop_improvement_specs(L0, L, low_frequency, low_factor, high_frequency, high_factor) -> list[SpecCheck]:
    """The .14 requirements on the exact closed loops of L0 (baseline) and L (new), unity feedback.

    With the plant unchanged, tracking error, output and input disturbances
    all scale with the sensitivity S = 1/(1 + L), so one ratio covers them;
    noise reaches the output through T = L/(1 + L).
    """
    old, new = Loop.unity(L0, 1.0, "baseline"), Loop.unity(L, 1.0, "loopshaped")
    return [
        check_stable(new),
        check_band_ratio(
            new.output_disturbance_to_output(),
            old.output_disturbance_to_output(),
            0.0,
            low_frequency,
            low_factor,
            "tracking and disturbance rejection",
        ),
        check_band_ratio(
            new.noise_to_output(), old.noise_to_output(), high_frequency, np.inf, high_factor, "noise attenuation"
        ),
    ]


def flattening_prefilter(T, tolerance: float = 0.01, order: int = 1) -> dict:
    """The fastest low-pass prefilter F with max |F(jω) T(jω)| ≤ 1 + tolerance (a flat closed loop).

    Returns
    -------
    dict with prefilter F(s), corner (rad/s), peak_before and peak_after (max |T|, max |F T|).
    """
    peak_before = band_max(T, 0.0, np.inf)[0]
    dc = abs(band_max(T, 0.0, 1e-12)[0])
    bound = (1 + tolerance) * dc

    def excess(w):
        return band_max(low_pass(w, order) * T, 0.0, np.inf)[0] - bound

    if peak_before <= bound:
        return {
            "prefilter": tf([1.0], [1.0]),
            "corner": float(np.inf),
            "peak_before": peak_before,
            "peak_after": peak_before,
        }
    lo, hi = 1e-6, 1e6
    if excess(lo) > 0:
        raise ValueError("no first-order prefilter flattens this closed loop")
    corner = scipy.optimize.brentq(excess, lo, hi, xtol=1e-9)
    corner *= 1 - 1e-6  # stay on the flat side of the bound
    F = low_pass(corner, order)
    return {
        "prefilter": F,
        "corner": float(corner),
        "peak_before": float(peak_before),
        "peak_after": float(band_max(F * T, 0.0, np.inf)[0]),
    }


def frequency_design_checks(loop: Loop, crossover: float, pm_deg: float, bandwidth: float) -> list[SpecCheck]:
    """A frequency-response design's requirements: stable, crossover and phase margin as designed
    (±1 deg), closed-loop bandwidth as asked."""
    L = loop.loop_gain()
    return [
        check_stable(loop),
        check_crossover(L, crossover),
        check_phase_margin(L, target_deg=pm_deg, tolerance_deg=1.0),
        check_bandwidth(loop.reference_to_output(), bandwidth),
    ]
