"""The one metrics module: every column of every study table is computed here.

Step metrics follow the usual definitions, measured against the commanded
value (the reference), not against wherever the response ends up:

- rise time: from the first time the output covers 10 % of the step to the
  first time it covers 90 % (linear interpolation between samples);
- settling time: time after the step from which the output stays within
  2 % of the step size around the commanded value;
- overshoot: the largest excursion past the commanded value, in % of the step;
- steady-state error: |command − mean of the output over the last 5 % of the segment|.

A response that never reaches 90 % or never settles gets ``inf`` (it takes
longer than the run), not a number that looks like a result. python-control's
`control.step_info` uses the same definitions with the final value as target
and sample (not interpolated) times; `tests/models/test_metrics.py` checks the
two agree to one sample on linear responses.

Sustained oscillation (a limit cycle): in the second half of the last
constant-reference segment, the output minus a fitted quadratic trend swings
by more than the settling band, at least two full periods, without decaying
(see `oscillation`). A response that settles, or only drifts, has none.

Integral metrics: IAE = ∫|e| dt and ITAE = ∫(t − t_step)|e| dt with e = r − y,
t_step the time of the most recent change of the reference (the plain ITAE for
a single step at t = 0). Input metrics are computed from the commanded input
(what the controller asked for) except the control energy, which uses the
input the actuator delivered (the command clipped to the limit).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

#: Columns of a study table that are metrics, in order.
METRIC_COLUMNS = (
    "rise_time_s",
    "settling_time_s",
    "overshoot_pct",
    "ss_error",
    "iae",
    "itae",
    "peak_u",
    "u_limit",
    "saturated_frac",
    "energy",
    "violation",
    "step_ms",
    "step_ms_max",
    "oscillation_amplitude",
    "oscillation_period_s",
)

#: Metrics whose Monte Carlo spread (standard deviation) is reported as ``<name>_std``.
SPREAD_COLUMNS = ("rise_time_s", "settling_time_s", "overshoot_pct", "ss_error", "iae", "itae", "peak_u", "energy")

#: Relative tolerance for counting a command as at the actuator limit.
SATURATION_TOLERANCE = 1e-3

#: Settling band, as a fraction of the step: the settling time and the smallest oscillation that counts.
SETTLING_BAND = 0.02

#: Fraction of a segment (or run) whose mean gives the steady-state error and the final values.
FINAL_WINDOW = 0.05

#: An oscillation is sustained when its amplitude in the second half of the window is at least this
#: fraction of that in the first half (a decaying one, e^{-ζ ω_n T/4} over a window T, falls below it
#: for ζ ω_n T > 0.9).
SUSTAINED_RATIO = 0.8


def first_crossing(t: np.ndarray, y: np.ndarray, level: float, direction: float) -> float:
    """Earliest time at which ``direction * (y - level) >= 0``, interpolated linearly.

    Parameters
    ----------
    t, y : (N,) sample times (s) and values
    level : threshold
    direction : +1 for an upward crossing, -1 for a downward one

    Returns
    -------
    float : time in s; ``inf`` when the threshold is never reached
    """
    above = direction * (y - level) >= 0
    hits = np.flatnonzero(above)
    if hits.size == 0:
        return math.inf
    k = int(hits[0])
    if k == 0:
        return float(t[0])
    y0, y1 = y[k - 1], y[k]
    return float(t[k - 1] + (t[k] - t[k - 1]) * (level - y0) / (y1 - y0))


def step_metrics(
    t,
    y,
    *,
    initial: float,
    target: float,
    band: float = SETTLING_BAND,
    rise_limits: tuple = (0.1, 0.9),
    final_window: float = FINAL_WINDOW,
) -> dict:
    """Rise time, settling time, overshoot and steady-state error of one step.

    Parameters
    ----------
    t : (N,) s, sample times from the step on (t[0] is the time of the step)
    y : (N,) the tracked output at those times
    initial : output value before the step
    target : commanded value after the step (pass the final value instead to
        measure against where the response settles, as `control.step_info` does)
    band : settling band as a fraction of the step size |target − initial|
    rise_limits : fractions of the step between which the rise time is measured
    final_window : fraction of the segment averaged for the steady-state error

    Returns
    -------
    dict with rise_time_s, settling_time_s (s after t[0], ``inf`` if never),
    overshoot_pct (%), ss_error (units of y), peak_time_s
    """
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    if t.shape != y.shape or t.ndim != 1 or t.size < 2:
        raise ValueError(f"t and y must be 1-D of the same length >= 2, got {t.shape} and {y.shape}")
    size = target - initial
    if size == 0:
        raise ValueError("a step of size zero has no rise time, settling time or overshoot")
    direction = math.copysign(1.0, size)
    start = t[0]
    low = first_crossing(t, y, initial + rise_limits[0] * size, direction)
    high = first_crossing(t, y, initial + rise_limits[1] * size, direction)
    rise = high - low if math.isfinite(high) else math.inf

    error = y - target
    tolerance = band * abs(size)
    outside = np.flatnonzero(np.abs(error) > tolerance)
    if outside.size == 0:
        settling = 0.0
    elif outside[-1] == len(t) - 1:
        settling = math.inf
    else:
        k = int(outside[-1])
        edge = math.copysign(tolerance, error[k])
        settling = t[k] + (t[k + 1] - t[k]) * (error[k] - edge) / (error[k] - error[k + 1]) - start

    excursion = direction * error
    peak = int(np.argmax(excursion))
    overshoot = max(0.0, 100.0 * excursion[peak] / abs(size))
    n_final = max(1, int(math.ceil(final_window * len(y))))
    ss_error = abs(target - float(np.mean(y[-n_final:])))
    return {
        "rise_time_s": float(rise),
        "settling_time_s": float(settling),
        "overshoot_pct": float(overshoot),
        "ss_error": ss_error,
        "peak_time_s": float(t[peak] - start),
    }


def reference_changes(r: np.ndarray) -> np.ndarray:
    """Sample indices k >= 1 at which the reference differs from sample k − 1, (M,)."""
    r = np.asarray(r, dtype=float)
    return np.flatnonzero(np.abs(np.diff(r)) > 1e-12 * max(1.0, float(np.max(np.abs(r))))) + 1


def segments(t, y, r) -> list[tuple[int, int, float, float]]:
    """Split a run into constant-reference segments that start with a step.

    The first segment starts at sample 0 with the output's initial value as
    the level before the step (the plant starts at rest before the command).

    Returns
    -------
    list of (start index, end index (exclusive), level before, commanded level)
    """
    r = np.asarray(r, dtype=float)
    starts = [0, *reference_changes(r).tolist()]
    ends = starts[1:] + [len(r)]
    out = []
    for i, (a, b) in enumerate(zip(starts, ends)):
        before = float(y[0]) if i == 0 else float(r[a - 1])
        out.append((a, b, before, float(r[a])))
    return out


def tracking_integrals(t, y, r) -> dict:
    """IAE = ∫|r − y| dt and ITAE = ∫(t − t_step)|r − y| dt, trapezoid rule over the samples.

    The reference is held between samples (r[k] on [t[k], t[k+1]), as the
    controller sees it); t_step is the time of the most recent reference
    change (t[0] before the first).

    Returns
    -------
    dict with iae (units of y times s) and itae (units of y times s²)
    """
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    r = np.asarray(r, dtype=float)
    held = r[:-1]
    left, right = np.abs(held - y[:-1]), np.abs(held - y[1:])
    since = np.full(len(t) - 1, t[0])
    for k in reference_changes(r):
        since[k:] = t[k]
    dt = np.diff(t)
    iae = float(np.sum((left + right) / 2 * dt))
    itae = float(np.sum(((t[:-1] - since) * left + (t[1:] - since) * right) / 2 * dt))
    return {"iae": iae, "itae": itae}


def input_metrics(t, u, limit) -> dict:
    """Peak command, fraction of samples at the limit, control energy and input violation.

    Parameters
    ----------
    t : (N+1,) s, sample times; the command u[k] is held on [t[k], t[k+1])
    u : (N, nu) commanded input
    limit : (nu,) symmetric actuator limit

    Returns
    -------
    dict with peak_u (largest |u| over inputs and time), u_limit, saturated_frac
    (fraction of samples with some |u_i| within 0.1 % of or beyond its limit),
    energy (∫ clip(u)² dt summed over inputs, units of u² s), input_violation
    (largest (|u_i| − limit_i) / limit_i, 0 when the command stays inside)
    """
    t = np.asarray(t, dtype=float)
    u = np.atleast_2d(np.asarray(u, dtype=float))
    if u.shape[0] != len(t) - 1:
        u = u.T
    limit = np.broadcast_to(np.asarray(limit, dtype=float), (u.shape[1],))
    dt = np.diff(t)[:, None]
    magnitude = np.abs(u)
    at_limit = np.any(magnitude >= limit * (1 - SATURATION_TOLERANCE), axis=1)
    delivered = np.clip(u, -limit, limit)
    return {
        "peak_u": float(np.max(magnitude)),
        "u_limit": float(np.max(limit)),
        "saturated_frac": float(np.mean(at_limit)),
        "energy": float(np.sum(delivered**2 * dt)),
        "input_violation": float(max(0.0, np.max((magnitude - limit) / limit))),
    }


def bound_excursions(x: np.ndarray, state_names: Sequence[str], bounds: Mapping[str, tuple]) -> dict:
    """How far each bounded state went beyond its (low, high) bounds, in its own units (0 if never).

    Parameters
    ----------
    x : (N+1, nx) states;  state_names : (nx,) names
    bounds : state name -> (low, high), SI units

    Returns
    -------
    dict state name -> largest max(low − x, x − high, 0) over the run
    """
    out = {}
    for name, (low, high) in bounds.items():
        if name not in state_names:
            raise ValueError(f"bounds name state {name!r}, which is not one of {tuple(state_names)}")
        if not high > low:
            raise ValueError(f"bounds of {name!r} must have low < high, got ({low}, {high})")
        values = x[:, list(state_names).index(name)]
        out[name] = max(0.0, float(np.max(np.maximum(low - values, values - high))))
    return out


def bound_violation(x: np.ndarray, state_names: Sequence[str], bounds: Mapping[str, tuple]) -> float:
    """Largest excursion of a state beyond its (low, high) bounds, as a fraction of high − low (0 if none)."""
    excess = bound_excursions(x, state_names, bounds)
    return max([excess[name] / (high - low) for name, (low, high) in bounds.items()], default=0.0)


def final_values(
    t: np.ndarray, x: np.ndarray, state_names: Sequence[str], names: Sequence[str], final_window: float = FINAL_WINDOW
) -> dict:
    """Mean of each named state over the last `final_window` fraction of the run (as ss_error's window)."""
    n_final = max(1, int(math.ceil(final_window * len(t))))
    return {name: float(np.mean(x[-n_final:, list(state_names).index(name)])) for name in names}


def _crossings(values: np.ndarray, hysteresis: float) -> int:
    """Sign changes of `values` that swing from beyond +hysteresis to beyond −hysteresis or back."""
    sides = np.sign(values) * (np.abs(values) > hysteresis)
    sides = sides[sides != 0]
    return int(np.count_nonzero(np.diff(sides)))


def oscillation(t, y, r, band: float = SETTLING_BAND, step: float | None = None) -> dict:
    """Amplitude and period of a sustained oscillation at the end of a run (NaN when there is none).

    The window is the second half of the last constant-reference segment. The
    output minus a least-squares quadratic (which absorbs an approach to rest
    or a drift) must cross zero, with a hysteresis of a quarter of the
    threshold, at least 4 times (two periods) in the window and twice in each
    half; its amplitude (half the peak-to-peak) must exceed ``band * step``
    in the second half and be at least `SUSTAINED_RATIO` of the first half's.

    Parameters
    ----------
    t, y, r : (N+1,) s, tracked output, reference
    band : threshold as a fraction of the step (the settling band)
    step : step size the threshold refers to (default: the last segment's step, or
        the largest reference change when the last segment has none)

    Returns
    -------
    dict with oscillation_amplitude (units of y) and oscillation_period_s (s), NaN if not sustained
    """
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    r = np.asarray(r, dtype=float)
    none = {"oscillation_amplitude": math.nan, "oscillation_period_s": math.nan}
    parts = segments(t, y, r)
    a, b, before, after = parts[-1]
    if step is None:
        step = abs(after - before) or max((abs(p[3] - p[2]) for p in parts), default=0.0)
    start = a + (b - a) // 2
    if b - start < 8 or step == 0 or not np.all(np.isfinite(y[start:b])):
        return none
    tw, yw = t[start:b], y[start:b]
    scale = tw - tw[0]
    residual = yw - np.polyval(np.polyfit(scale, yw, 2), scale)
    threshold = band * abs(step)
    half = len(residual) // 2
    first, second = residual[:half], residual[half:]
    amplitude = [(float(np.max(p)) - float(np.min(p))) / 2 for p in (first, second)]
    crossings = [_crossings(p, threshold / 4) for p in (first, second)]
    total = _crossings(residual, threshold / 4)
    if total < 4 or min(crossings) < 2 or amplitude[1] <= threshold or amplitude[1] < SUSTAINED_RATIO * amplitude[0]:
        return none
    return {"oscillation_amplitude": amplitude[1], "oscillation_period_s": 2 * float(tw[-1] - tw[0]) / total}


def drift(t, y, r, band: float = SETTLING_BAND) -> float:
    """The rate (units of y per s) at which the output's mean still moves steadily at the end of a run
    (NaN when it does not).

    The window is the second half of the last constant-reference segment, as for `oscillation`; a
    straight line is fitted to each half of it. The output drifts when both slopes have the same sign,
    the second is at least `SUSTAINED_RATIO` of the first (not an approach to rest that slows down),
    and over the window it moves by more than ``band`` times the step. Returns the slope of a line fitted
    to the whole window (an oscillation on the drift biases it by up to its amplitude over the window).
    """
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    parts = segments(t, y, np.asarray(r, dtype=float))
    a, b, before, after = parts[-1]
    step = abs(after - before) or max((abs(p[3] - p[2]) for p in parts), default=0.0)
    start = a + (b - a) // 2
    if b - start < 8 or step == 0 or not np.all(np.isfinite(y[start:b])):
        return math.nan
    tw, yw = t[start:b], y[start:b]
    half = len(tw) // 2
    slopes = [float(np.polyfit(tw[i:j] - tw[i], yw[i:j], 1)[0]) for i, j in ((0, half), (half, len(tw)))]
    steady = slopes[0] * slopes[1] > 0 and abs(slopes[1]) >= SUSTAINED_RATIO * abs(slopes[0])
    rate = float(np.polyfit(tw - tw[0], yw, 1)[0])
    if not steady or abs(rate) * (tw[-1] - tw[0]) <= band * step:
        return math.nan
    return rate


def run_metrics(result, tracked: str, bounds: Mapping[str, tuple] | None = None, band: float = SETTLING_BAND) -> dict:
    """Every table column for one closed-loop run (a `models.ClosedLoopResult`).

    Step metrics are computed per reference segment and the worst (largest)
    is kept, so a series of steps reports its slowest, most overshooting step.

    Parameters
    ----------
    result : ClosedLoopResult of the nonlinear plant
    tracked : name of the state that follows the reference
    bounds : state name -> (low, high) in SI units, counted in `violation`
    band : settling band, fraction of the step (the specs' `settling_band`)

    Returns
    -------
    dict with the `METRIC_COLUMNS`; all NaN except u_limit when the run diverged
    """
    metrics = dict.fromkeys(METRIC_COLUMNS, math.nan)
    metrics["u_limit"] = float(np.max(result.input_limit))
    if result.diverged_at is not None:
        return metrics
    t = result.t
    y = result.x[:, result.state_names.index(tracked)]
    r = result.r[:, 0]
    worst = {"rise_time_s": 0.0, "settling_time_s": 0.0, "overshoot_pct": 0.0, "ss_error": 0.0}
    for a, b, before, after in segments(t, y, r):
        if after == before or b - a < 2:
            continue
        seg = step_metrics(t[a:b], y[a:b], initial=before, target=after, band=band)
        for key in worst:
            worst[key] = max(worst[key], seg[key])
    metrics |= worst
    metrics |= oscillation(t, y, r)
    metrics |= tracking_integrals(t, y, r)
    inputs = input_metrics(t, result.u, result.input_limit)
    violation = inputs.pop("input_violation")
    metrics |= inputs
    metrics["violation"] = max(violation, bound_violation(result.x, result.state_names, bounds or {}))
    steps = np.asarray(result.step_time, dtype=float)
    if steps.size and np.any(np.isfinite(steps)):
        metrics["step_ms"] = 1e3 * float(np.nanmean(steps))
        metrics["step_ms_max"] = 1e3 * float(np.nanmax(steps))
    return metrics


def aggregate(rows: Sequence[dict]) -> dict:
    """Worst case and spread of per-sample metrics over a Monte Carlo.

    Every metric is "larger is worse", so the worst case is the maximum over
    the samples that did not diverge; ``<metric>_std`` is the standard
    deviation over the samples where the metric is finite (NaN if fewer than 2).

    Parameters
    ----------
    rows : per-sample dicts from `run_metrics`; diverged samples have NaN metrics

    Returns
    -------
    dict with the `METRIC_COLUMNS` (worst case) and the ``*_std`` spreads
    """
    out = {}
    for key in METRIC_COLUMNS:
        values = np.array([row[key] for row in rows], dtype=float)
        kept = values[~np.isnan(values)]
        out[key] = float(np.max(kept)) if kept.size else math.nan
    for key in SPREAD_COLUMNS:
        values = np.array([row[key] for row in rows], dtype=float)
        finite = values[np.isfinite(values)]
        out[f"{key}_std"] = float(np.std(finite, ddof=1)) if finite.size >= 2 else math.nan
    return out
