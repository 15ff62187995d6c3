"""Metrics against closed forms of first- and second-order step responses, and
against python-control's step_info as a second method."""

import math

import control
import numpy as np
import pytest
from scipy.integrate import quad
from scipy.optimize import brentq

import models
from models import metrics

DT = 1e-3


def first_order(tau, duration=10.0):
    t = np.arange(0.0, duration + DT / 2, DT)
    return t, 1.0 - np.exp(-t / tau)


def second_order_error(zeta, wn):
    """e(t) = y(t) − 1 of ωn² / (s² + 2ζωn s + ωn²) after a unit step (0 < ζ < 1)."""
    wd = wn * math.sqrt(1 - zeta**2)
    return lambda t: -np.exp(-zeta * wn * t) * (np.cos(wd * t) + zeta / math.sqrt(1 - zeta**2) * np.sin(wd * t))


def test_first_order_step_closed_forms():
    tau = 0.5
    t, y = first_order(tau)
    m = metrics.step_metrics(t, y, initial=0.0, target=1.0)
    assert m["rise_time_s"] == pytest.approx(tau * math.log(9), abs=1e-6)  # 10 %→90 %: τ ln 9
    assert m["settling_time_s"] == pytest.approx(tau * math.log(50), abs=1e-6)  # 2 % band: τ ln 50
    assert m["overshoot_pct"] == 0.0
    assert m["ss_error"] < 1e-8
    integrals = metrics.tracking_integrals(t, y, np.ones_like(t))
    assert integrals["iae"] == pytest.approx(tau, rel=1e-6)  # ∫ e^{-t/τ} dt
    assert integrals["itae"] == pytest.approx(tau**2, rel=1e-6)  # ∫ t e^{-t/τ} dt


def test_step_down_from_an_offset_is_the_mirror_image():
    tau = 0.2
    t, y = first_order(tau, 3.0)
    m = metrics.step_metrics(t, 5.0 - 2.0 * y, initial=5.0, target=3.0)
    assert m["rise_time_s"] == pytest.approx(tau * math.log(9), abs=1e-6)
    assert m["settling_time_s"] == pytest.approx(tau * math.log(50), abs=1e-6)


@pytest.mark.parametrize("zeta,wn", [(0.3, 2.0), (0.707, 5.0), (0.1, 1.0)])
def test_second_order_step_closed_forms(zeta, wn):
    error = second_order_error(zeta, wn)
    wd = wn * math.sqrt(1 - zeta**2)
    t = np.arange(0.0, 12.0 / (zeta * wn) + DT / 2, DT)
    y = 1.0 + error(t)
    m = metrics.step_metrics(t, y, initial=0.0, target=1.0)
    assert m["overshoot_pct"] == pytest.approx(100 * math.exp(-math.pi * zeta / math.sqrt(1 - zeta**2)), rel=1e-5)
    assert m["peak_time_s"] == pytest.approx(math.pi / wd, abs=DT)
    # Rise time: the closed form solved for y = 0.1 and 0.9 before the first peak.
    t10 = brentq(lambda s: 1 + error(s) - 0.1, 0, math.pi / wd)
    t90 = brentq(lambda s: 1 + error(s) - 0.9, 0, math.pi / wd)
    assert m["rise_time_s"] == pytest.approx(t90 - t10, abs=1e-5)
    # Settling: the extrema of e are at nπ/ωd with |e| = exp(−nπζ/√(1−ζ²)); the last
    # one outside the 2 % band is followed by the exit through the band edge.
    n = max(k for k in range(1, 200) if math.exp(-k * math.pi * zeta / math.sqrt(1 - zeta**2)) > 0.02)
    sign = math.copysign(1.0, error(n * math.pi / wd))
    exit_time = brentq(lambda s: sign * error(s) - 0.02, n * math.pi / wd, (n + 1) * math.pi / wd)
    assert m["settling_time_s"] == pytest.approx(exit_time, abs=1e-5)
    zeros = [(math.atan2(-1, zeta / math.sqrt(1 - zeta**2)) % math.pi + k * math.pi) / wd for k in range(60)]
    iae = quad(lambda s: abs(error(s)), 0, t[-1], points=[z for z in zeros if z < t[-1]], limit=500)[0]
    assert metrics.tracking_integrals(t, y, np.ones_like(t))["iae"] == pytest.approx(iae, rel=1e-5)


@pytest.mark.parametrize(
    "system",
    [
        control.tf([2.0], [0.5, 1.0]),  # first order, DC gain 2
        control.tf([1.5 * 9.0], [1.0, 3.0, 9.0]),  # ζ = 0.5, ωn = 3, DC gain 1.5
        control.tf([4.0, 8.0], [1.0, 3.0, 6.0, 4.0 * 1.0]),  # third order with a zero
        control.tf([-1.0, 2.0], [1.0, 2.0, 2.0]),  # non-minimum phase, undershoot
    ],
)
def test_agrees_with_python_control_step_info(system):
    t = np.linspace(0.0, 30.0, 30001)
    dt = t[1] - t[0]
    response = control.step_response(system, t)
    y = np.squeeze(response.outputs)
    reference = control.step_info(system, t)
    final = float(np.real(control.dcgain(system)))
    ours = metrics.step_metrics(t, y, initial=0.0, target=final)
    # Tolerances as in python-control's own tests: one sample for times.
    assert ours["rise_time_s"] == pytest.approx(reference["RiseTime"], abs=dt)
    assert ours["settling_time_s"] == pytest.approx(reference["SettlingTime"], abs=dt)
    assert ours["overshoot_pct"] == pytest.approx(reference["Overshoot"], rel=1e-9, abs=1e-12)


def test_a_response_that_never_arrives_is_infinite_not_a_number():
    t, y = first_order(1.0, 2.0)  # covers 86 % in 2 s
    m = metrics.step_metrics(t, y, initial=0.0, target=1.0)
    assert m["rise_time_s"] == math.inf and m["settling_time_s"] == math.inf
    with pytest.raises(ValueError, match="step of size zero"):
        metrics.step_metrics(t, y, initial=1.0, target=1.0)


def test_input_metrics_by_hand():
    t = np.arange(5) * 0.1
    u = np.array([[0.5], [2.0], [-3.0], [0.9995]])
    m = metrics.input_metrics(t, u, [1.0])
    assert m["peak_u"] == 3.0 and m["u_limit"] == 1.0
    assert m["saturated_frac"] == 0.75  # 2, -3 and 0.9995 (within 0.1 %) are at the limit
    assert m["energy"] == pytest.approx((0.25 + 1 + 1 + 0.9995**2) * 0.1)  # delivered input, clipped
    assert m["input_violation"] == pytest.approx(2.0)  # |−3| is 200 % beyond the limit


def make_result(t, x, r, u, limit=1.0, diverged_at=None, step_time=None):
    n = len(t) - 1
    return models.ClosedLoopResult(
        t=t,
        x=x,
        y=x[:, :1],
        r=r[:, None],
        u=u,
        d=np.zeros_like(u),
        measured=x[:-1, :1],
        xc=None,
        step_time=np.full(n, 1e-4) if step_time is None else step_time,
        status=None,
        input_limit=np.array([limit]),
        state_names=("z", "dz"),
        output_names=("z",),
        input_names=("F",),
        diverged_at=diverged_at,
    )


def test_run_metrics_takes_the_worst_of_a_series_of_steps():
    # Two first-order steps: 0 → 1 with τ = 0.1, then 1 → 0.5 with τ = 0.3.
    t = np.arange(0.0, 6.0 + DT / 2, DT)
    first = t < 3.0
    z = np.where(first, 1 - np.exp(-t / 0.1), 0.5 + 0.5 * np.exp(-(t - 3.0) / 0.3))
    r = np.where(first, 1.0, 0.5)
    x = np.column_stack([z, np.gradient(z, t)])
    u = np.full((len(t) - 1, 1), 0.5)
    m = metrics.run_metrics(make_result(t, x, r, u), "z", bounds={"z": (0.0, 0.8)})
    assert m["rise_time_s"] == pytest.approx(0.3 * math.log(9), abs=1e-5)
    assert m["settling_time_s"] == pytest.approx(0.3 * math.log(50), abs=1e-5)
    assert m["iae"] == pytest.approx(0.1 + 0.5 * 0.3, rel=1e-4)
    assert m["itae"] == pytest.approx(0.1**2 + 0.5 * 0.3**2, rel=1e-3)
    assert m["violation"] == pytest.approx((1.0 - 0.8) / 0.8, rel=1e-4)  # z reaches 1 > 0.8
    assert m["step_ms"] == pytest.approx(0.1)


def test_a_diverged_run_has_no_numbers():
    t = np.arange(0.0, 1.0 + DT / 2, DT)
    x = np.column_stack([t, np.ones_like(t)])
    m = metrics.run_metrics(make_result(t, x, np.ones_like(t), np.zeros((len(t) - 1, 1)), diverged_at=0.5), "z")
    assert all(math.isnan(m[k]) for k in metrics.METRIC_COLUMNS if k != "u_limit")


def test_aggregate_is_worst_case_and_sample_standard_deviation():
    rows = [dict.fromkeys(metrics.METRIC_COLUMNS, v) for v in (1.0, 2.0, 4.0, math.nan)]
    rows[0]["settling_time_s"] = math.inf  # one sample never settles
    out = metrics.aggregate(rows)
    assert out["iae"] == 4.0 and out["settling_time_s"] == math.inf
    assert out["iae_std"] == pytest.approx(np.std([1.0, 2.0, 4.0], ddof=1))
    assert out["settling_time_s_std"] == pytest.approx(np.std([2.0, 4.0], ddof=1))
