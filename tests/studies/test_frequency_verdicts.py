"""Frequency specs in a table's verdict: a Block row's loop, linearized at the run's rest point, is held
to the case's margins and bandwidth, with the numbers python-control finds on that loop."""

import re
import warnings

import control
import numpy as np
import pytest

import models
from designs.pid import PID
from models import specs
from models.specs import Specs
from studies import judging, loops, runner
from studies.case import CaseStudy, step

NAME = "test_frequency_judged_mass"
LIMIT = 20.0


@models.declare(
    name=NAME,
    title="mass with a damper (frequency specs test)",
    coordinates=("x",),
    inputs=("F",),
    params=(models.Param("m", 1.0, "kg"), models.Param("b", 1.2, "N s/m")),
    input_limit=LIMIT,
    uncertain=("m", "b"),
)
def damped_mass(q, dq, u, p):
    return models.Physics(kinetic=p.m * dq.x**2 / 2, potential=0 * q.x, forces=[u.F - p.b * dq.x], outputs={"x": q.x})


def pd(case, known):
    timing = dict(sample_period=case.sample_period, sigma=case.derivative_time_constant)
    return {"PD": PID(known, "x", kp=5.0, kd=0.6, output_limit=LIMIT, name="PD", **timing)}


def _case(judged: Specs) -> CaseStudy:
    return CaseStudy(
        plant=NAME,
        numeral="IX",
        tracked="x",
        design_step=0.5,
        step=0.5,
        input_disturbance=0.0,
        duration=10.0,
        tracked_unit="m",
        input_unit="N",
        scenarios=(step(),),
        providers=(pd,),
        answer_providers=(),
        known_rel=0.0,
        specs={"*": judged},
    )


def _python_control_margins(case):
    """Phase margin (deg) and bandwidth (rad/s) of the PD's loop by python-control, on the loop
    `studies.loops` forms at the step's final rest point."""
    plant = models.get(NAME)
    block = pd(case, plant)["PD"]
    run = case.scenarios[0].run(case, 0.0)
    result = models.simulate_closed_loop(plant, block, run.reference, run.duration, substeps=case.substeps)
    L = loops.loop(plant, block, loops.final_point(plant, block, result)).system()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        _, pm, *_ = control.stability_margins(L)
    closed = control.feedback(L, 1)
    # The closed loop's -3 dB frequency on a fine grid of e^{jωTs} (python-control's `bandwidth` evaluates
    # a sampled system at z = jω), refined by bisection on python-control's frequency response.
    dc = abs(complex(closed(1.0)))
    grid = np.linspace(1e-3, 0.99 * np.pi / L.dt, 5001)
    mag = np.abs(closed.frequency_response(grid).complex).ravel()
    i = int(np.flatnonzero(mag < dc * 10 ** (-3 / 20))[0])
    lo, hi = grid[i - 1], grid[i]
    for _ in range(60):
        mid = (lo + hi) / 2
        if abs(closed.frequency_response([mid]).complex.ravel()[0]) < dc * 10 ** (-3 / 20):
            hi = mid
        else:
            lo = mid
    return float(pm), (lo + hi) / 2


def test_a_margin_the_loop_misses_is_in_the_verdict_with_python_controls_number():
    pm, bandwidth = _python_control_margins(_case(Specs()))
    case = _case(Specs(min_phase_margin_deg=pm + 5.0, max_bandwidth_rad_s=0.9 * bandwidth, source="test"))
    row = runner.run_study(case, runner.Options(mc=0)).table.set_index("controller").loc["PD"]
    assert row.verdict == specs.VIOLATES
    found = re.search(r"phase margin ([0-9.]+) deg < ([0-9.]+) deg", row.verdict_detail)
    assert found and float(found.group(1)) == pytest.approx(pm, rel=2e-3), row.verdict_detail
    found = re.search(r"bandwidth ([0-9.]+) rad/s > ([0-9.]+) rad/s", row.verdict_detail)
    assert found and float(found.group(1)) == pytest.approx(bandwidth, rel=2e-3), row.verdict_detail


def test_margins_the_loop_has_are_met():
    pm, bandwidth = _python_control_margins(_case(Specs()))
    case = _case(Specs(min_phase_margin_deg=pm - 5.0, min_bandwidth_rad_s=0.9 * bandwidth, source="test"))
    row = runner.run_study(case, runner.Options(mc=0)).table.set_index("controller").loc["PD"]
    assert row.verdict == specs.MEETS, row.verdict_detail


def test_the_measures_judge_run_uses_are_python_controls():
    case = _case(Specs(min_disk_margin=0.1, source="test"))
    plant = models.get(NAME)
    block = pd(case, plant)["PD"]
    run = case.scenarios[0].run(case, 0.0)
    result = models.simulate_closed_loop(plant, block, run.reference, run.duration, substeps=case.substeps)
    measured = judging.linear_loop_measures(plant, block, result)
    pm, bandwidth = _python_control_margins(case)
    assert measured["phase_margin_deg"] == pytest.approx(pm, rel=1e-6)
    assert measured["bandwidth_rad_s"] == pytest.approx(bandwidth, rel=1e-6)
    assert judging.linear_loop_measures(plant, object(), result) is None  # no linear loop: not judged


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("min_phase_margin_deg", -10.0, "min_phase_margin_deg must be a finite number > 0 or None, got -10.0"),
        ("min_disk_margin", 2.5, "min_disk_margin must be at most 2"),
    ],
)
def test_a_frequency_spec_out_of_range_is_refused(field, value, message):
    with pytest.raises(ValueError, match=message):
        Specs(**{field: value})


def test_contradicting_bandwidths_are_refused():
    with pytest.raises(ValueError, match=r"min_bandwidth_rad_s = 5.0 must be below Specs.max_bandwidth_rad_s = 2.0"):
        Specs(min_bandwidth_rad_s=5.0, max_bandwidth_rad_s=2.0)
