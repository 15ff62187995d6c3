"""Loop algebra and the frequency- and steady-state answers of the .10 and .13 homework.

Every closed loop here is the two-degree-of-freedom loop

    u = C_r(s) r − C_y(s) (y + n) + d_i,    y = P(s) u + d_o,

which covers PD/PID with the derivative on the error (C_r = C_y) or on the
measurement (C_r = k_p + k_i/s, C_y = k_p + k_i/s + k_d s), prefilters
(C_r = F C) and any C(s). Transfer functions are built from polynomial
products, never by subtracting rational functions, so a zero at s = 0 that
the algebra produces (an integrator, a derivative on the measurement) is an
exact zero and the system type and the steady-state limits come out exact:
an infinite error stays ``inf``.

Angles are in rad, frequencies in rad/s; "percent" values are 100·|G(jω)|
of the named transfer function (for a disturbance in N or N m reaching an
angle, that is rad per 100 N m, as the text's questions count it).

The modules, each importable on its own:

- `polynomials`: exact polynomial algebra, transfer functions, limits at s = 0
- `loop`: the `Loop` and its closed loops, poles and steady-state errors
- `frequency`: band maxima, the .13 percentages, Bode data
- `stability_margins`: gain and phase margins of continuous and sampled loops
- `time_response`: exact step responses and step_info
- `spec_checks`: `SpecCheck` and the checks of frequency, pole and step specs
"""

from .frequency import (
    band_max,
    bode_data,
    percent_input_disturbance_below,
    percent_noise_above,
    percent_output_disturbance_below,
    percent_tracking_error_below,
)
from .loop import Loop, UnstableLoopError, steady_state_errors
from .polynomials import (
    ZERO_TOL,
    as_polynomials,
    dc_gain,
    limit_at_zero,
    pid_tf,
    poly_add,
    poly_mul,
    poly_sub,
    polynomial,
    tf,
    zeros_at_origin,
)
from .spec_checks import (
    SpecCheck,
    check_band_ratio,
    check_bandwidth,
    check_crossover,
    check_damping,
    check_phase_margin,
    check_stable,
    check_step,
    check_step_nonlinear,
    step_checks,
)
from .stability_margins import SLOWEST, crossover_margins, discrete_grid, margins, sampled_response
from .time_response import step_info, step_response

__all__ = [
    "Loop",
    "UnstableLoopError",
    "SpecCheck",
    "ZERO_TOL",
    "SLOWEST",
    "polynomial",
    "poly_add",
    "poly_sub",
    "poly_mul",
    "zeros_at_origin",
    "as_polynomials",
    "tf",
    "pid_tf",
    "limit_at_zero",
    "dc_gain",
    "steady_state_errors",
    "band_max",
    "percent_tracking_error_below",
    "percent_input_disturbance_below",
    "percent_output_disturbance_below",
    "percent_noise_above",
    "margins",
    "crossover_margins",
    "discrete_grid",
    "sampled_response",
    "bode_data",
    "step_info",
    "step_response",
    "check_band_ratio",
    "check_phase_margin",
    "check_crossover",
    "check_step",
    "step_checks",
    "check_step_nonlinear",
    "check_stable",
    "check_damping",
    "check_bandwidth",
]
