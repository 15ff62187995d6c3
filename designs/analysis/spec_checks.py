"""Requirements judged on a design: `SpecCheck` records for frequency, pole and step-response specs.

Each `check_*` returns one `SpecCheck` (or a list for the step specs): what
was required, what the design achieves and whether it is met. The step specs
are judged on a linear closed loop (`check_step`) or on one nonlinear
closed-loop simulation (`check_step_nonlinear`) by the same `step_checks`.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING

import numpy as np

import models
from models import deferred

from .frequency import band_max
from .loop import Loop
from .polynomials import as_polynomials, dc_gain, poly_mul, tf
from .stability_margins import margins
from .time_response import step_info

if TYPE_CHECKING:
    import control
else:
    control = deferred.module("control")

__all__ = [
    "SpecCheck",
    "check_band_ratio",
    "check_phase_margin",
    "check_crossover",
    "check_damping",
    "check_bandwidth",
    "check_stable",
    "check_step",
    "step_checks",
    "check_step_nonlinear",
]


@dataclass(frozen=True)
class SpecCheck:
    """One requirement and whether the design meets it.

    Attributes
    ----------
    spec : what is required, in words
    met : bool
    value : what the design achieves (SI; degrees only where the name says deg)
    required : the bound it is compared with
    frequency : rad/s where the value was found (None for time-domain specs)
    """

    spec: str
    met: bool
    value: float
    required: float
    frequency: float | None = None
    detail: str = field(default="")

    def as_dict(self) -> dict:
        """The check as a plain dict (for the answers' records)."""
        return asdict(self)


def check_band_ratio(new, old, low: float, high: float, factor: float, what: str) -> SpecCheck:
    """|new(jω)| ≤ |old(jω)| / factor for all ω in [low, high] (grid as in `band_max`)."""
    num_n, den_n = as_polynomials(new)
    num_o, den_o = as_polynomials(old)
    ratio = tf(poly_mul(num_n, den_o), poly_mul(den_n, num_o))
    worst, where = band_max(ratio, low, high)
    band = f"below {high:g} rad/s" if low == 0 else f"above {low:g} rad/s"
    return SpecCheck(
        f"{what} {band} improved {factor:g}x",
        bool(worst <= 1.0 / factor + 1e-12),
        float(1.0 / worst) if worst > 0 else float(np.inf),
        float(factor),
        where,
        "value: smallest improvement factor old/new in the band",
    )


def check_phase_margin(
    L, minimum_deg: float | None = None, target_deg: float | None = None, tolerance_deg: float = 5.0
) -> SpecCheck:
    """PM ≥ `minimum_deg`, or |PM − target| ≤ tolerance when `target_deg` is given."""
    m = margins(L)
    if target_deg is not None:
        return SpecCheck(
            f"phase margin about {target_deg:g} deg (±{tolerance_deg:g})",
            bool(abs(m["pm_deg"] - target_deg) <= tolerance_deg),
            m["pm_deg"],
            target_deg,
            m["gain_crossover"],
        )
    if minimum_deg is None:
        raise ValueError("check_phase_margin needs minimum_deg or target_deg; got neither")
    return SpecCheck(
        f"phase margin >= {minimum_deg:g} deg",
        bool(m["pm_deg"] >= minimum_deg),
        m["pm_deg"],
        minimum_deg,
        m["gain_crossover"],
    )


def check_crossover(L, omega: float, rel_tol: float = 0.05) -> SpecCheck:
    """Gain crossover within `rel_tol` of `omega` rad/s."""
    w = margins(L)["gain_crossover"]
    return SpecCheck(
        f"crossover at {omega:g} rad/s (±{100 * rel_tol:g} %)",
        bool(np.isfinite(w) and abs(w - omega) <= rel_tol * omega),
        w,
        omega,
        w,
    )


def check_damping(loop: Loop, zeta_min: float) -> SpecCheck:
    """Every closed-loop pole damped at least `zeta_min` (value: the least damped pole's ζ)."""
    poles = loop.poles()
    zeta = float(np.min(-poles.real / np.abs(poles)))
    return SpecCheck(f"every closed-loop pole damped (zeta >= {zeta_min:g})", zeta >= zeta_min, zeta, zeta_min)


def check_bandwidth(T, bandwidth: float, rel_tol: float = 0.2) -> SpecCheck:
    """Closed-loop −3 dB bandwidth of T (1/√2 of its DC gain) within `rel_tol` of `bandwidth` rad/s."""
    value = float(control.bandwidth(T, 20 * np.log10(1 / np.sqrt(2))))
    return SpecCheck(
        f"closed-loop bandwidth about {bandwidth:g} rad/s (±{100 * rel_tol:g} %)",
        bool(abs(value - bandwidth) <= rel_tol * bandwidth),
        value,
        bandwidth,
    )


def check_stable(loop: Loop) -> SpecCheck:
    """All closed-loop poles in the open left half plane (value: largest real part)."""
    worst = float(np.max(loop.poles().real))
    return SpecCheck("closed loop stable", worst < 0, worst, 0.0)


def check_step(
    T,
    *,
    amplitude: float = 1.0,
    rise_time: float | None = None,
    settling_time: float | None = None,
    overshoot_percent: float | None = None,
    steady_state_error_percent: float | None = None,
    reference_dc: float = 1.0,
    settling_threshold: float = 0.02,
) -> list[SpecCheck]:
    """Step-response specs of a closed loop T (reference → output), python-control's step_info.

    Rise time 10–90 %, settling to `settling_threshold` of the final value,
    overshoot relative to the final value, steady-state error relative to
    the commanded value (`reference_dc` = 1 for a unit-gain goal).
    """
    return step_checks(
        step_info(T, settling_threshold),
        dc_gain(T),
        reference_dc=reference_dc,
        rise_time=rise_time,
        settling_time=settling_time,
        overshoot_percent=overshoot_percent,
        steady_state_error_percent=steady_state_error_percent,
        settling_threshold=settling_threshold,
    )


def step_checks(
    info: dict,
    final: float,
    *,
    reference_dc: float = 1.0,
    rise_time: float | None = None,
    settling_time: float | None = None,
    overshoot_percent: float | None = None,
    steady_state_error_percent: float | None = None,
    settling_threshold: float = 0.02,
    label_suffix: str = "",
) -> list[SpecCheck]:
    """The step specs asked for, judged on a `control.step_info` result and the final value.

    The one place that turns step-response numbers into `SpecCheck`s, for a
    linear closed loop (`check_step`) and for a nonlinear simulation
    (`check_step_nonlinear`); `label_suffix` tells them apart in the labels.
    """
    out = []
    if rise_time is not None:
        out.append(
            SpecCheck(
                f"rise time < {rise_time:g} s{label_suffix}", info["RiseTime"] < rise_time, info["RiseTime"], rise_time
            )
        )
    if settling_time is not None:
        out.append(
            SpecCheck(
                f"settling time ({100 * settling_threshold:g} %) < {settling_time:g} s{label_suffix}",
                info["SettlingTime"] < settling_time,
                info["SettlingTime"],
                settling_time,
            )
        )
    if overshoot_percent is not None:
        out.append(
            SpecCheck(
                f"overshoot < {overshoot_percent:g} %{label_suffix}",
                info["Overshoot"] < overshoot_percent,
                info["Overshoot"],
                overshoot_percent,
            )
        )
    if steady_state_error_percent is not None:
        err = 100 * abs(reference_dc - final) / abs(reference_dc)
        out.append(
            SpecCheck(
                f"steady-state error < {steady_state_error_percent:g} %{label_suffix}",
                err < steady_state_error_percent,
                err,
                steady_state_error_percent,
            )
        )
    return out


def check_step_nonlinear(
    plant, block, step: float, tracked: str, *, duration: float = 10.0, threshold: float = 0.02, **specs
) -> list[SpecCheck]:
    """Step specs of the nonlinear closed loop (one `models.simulate_closed_loop` run), and the actuator.

    The loop starts at the plant's standard equilibrium and the reference steps
    by `step` on `tracked` at t = 0; `specs` are the keywords of `step_checks`
    (rise_time, settling_time, overshoot_percent, steady_state_error_percent).
    The last check says whether the command stayed within the actuator limit.
    """
    x0, _ = plant.equilibrium()
    y0 = x0[plant.coordinate_names.index(tracked)]
    res = models.simulate_closed_loop(plant, block, y0 + step, duration, x0=x0)
    y = (res.state(tracked) - y0) / step
    info = control.step_info(y, T=res.t, yfinal=y[-1], SettlingTimeThreshold=threshold)
    checks = step_checks(info, y[-1], settling_threshold=threshold, label_suffix=" (nonlinear)", **specs)
    peak = float(np.max(np.abs(res.u)))
    checks.append(
        SpecCheck(
            f"command within the {plant.input_limit[0]:g} actuator limit",
            peak <= plant.input_limit[0] * (1 + 1e-12),
            peak,
            float(plant.input_limit[0]),
        )
    )
    return checks
