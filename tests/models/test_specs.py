"""The verdict rule on synthetic responses whose properties are known in closed form:
a clean step, a limit cycle, a slow drift, a divergence, bounds and final values."""

import dataclasses
import math
import re

import control
import numpy as np
import pytest

from models import metrics, specs
from models.closed_loop import ClosedLoopResult, first_faults

DT = 0.01
SPECS = specs.Specs(max_rise_time_s=1.5, max_settling_time_s=4.0, max_overshoot_pct=10.0, max_ss_error_pct=2.0)


def response(y, t=None, u=None, limit=1.0, extra=None) -> ClosedLoopResult:
    """A recorded unit-step response as a ClosedLoopResult; divergence found by the simulators' rule."""
    t = DT * np.arange(len(y)) if t is None else t
    columns = [y] + ([extra] if extra is not None else [])
    x = np.column_stack(columns)
    u = np.zeros((len(t) - 1, 1)) if u is None else np.asarray(u, dtype=float).reshape(-1, 1)
    first = int(first_faults(x[None], u[None])[0])
    names = ("y",) + (("w",) if extra is not None else ())
    return ClosedLoopResult(
        t=t,
        x=x,
        y=x,
        r=np.ones((len(t), 1)),
        u=u,
        d=np.zeros_like(u),
        measured=x[:-1],
        xc=None,
        step_time=np.zeros(len(t) - 1),
        status=None,
        input_limit=np.array([limit]),
        state_names=names,
        output_names=names,
        input_names=("u",),
        diverged_at=None if first < 0 else float(t[first]),
    )


def second_order(zeta, wn, duration=10.0):
    t = DT * np.arange(int(round(duration / DT)) + 1)
    wd = wn * math.sqrt(1 - zeta**2)
    y = 1 - np.exp(-zeta * wn * t) * (np.cos(wd * t) + zeta / math.sqrt(1 - zeta**2) * np.sin(wd * t))
    return t, y


def test_a_clean_step_meets_specs_and_tight_specs_name_the_closed_form_overshoot():
    zeta, wn = 0.7, 2.0
    t, y = second_order(zeta, wn)
    run = response(y, t)
    assert specs.judge(SPECS, run, "y", 1.0) == specs.Verdict(specs.MEETS)
    tight = specs.Specs(max_overshoot_pct=2.0)
    found = specs.judge(tight, run, "y", 1.0)
    assert found.label == specs.VIOLATES
    (violation,) = found.violations
    overshoot = 100 * math.exp(-math.pi * zeta / math.sqrt(1 - zeta**2))  # 4.60 %
    assert violation.spec == "overshoot" and violation.value == pytest.approx(overshoot, rel=1e-4)
    assert violation.excess == pytest.approx(overshoot - 2.0, rel=1e-4)
    assert found.detail == "overshoot 4.6 % > 2 %"


def test_a_limit_cycle_is_labelled_with_its_amplitude_and_period():
    t = DT * np.arange(1001)
    amplitude, period = 0.1, 1.5
    y = 1 - np.exp(-3 * t) + amplitude * np.sin(2 * np.pi * t / period)
    found = specs.judge(SPECS, response(y, t), "y", 1.0)
    assert found.label == specs.LIMIT_CYCLE
    m = metrics.oscillation(t, y, np.ones_like(t))
    assert m["oscillation_amplitude"] == pytest.approx(amplitude, rel=0.03)
    assert m["oscillation_period_s"] == pytest.approx(period, rel=0.1)
    # It never settles in the 2 % band either: both are said.
    assert any(v.spec == "settling time" and math.isinf(v.value) for v in found.violations)
    assert found.detail.startswith("amplitude 0.1")
    with_units = specs.judge(SPECS, response(y, t), "y", 1.0, units={"y": "m"})
    assert re.match(r"amplitude 0\.1\d* m, period 1\.\d+ s at the end of the run", with_units.detail)
    # The same oscillation riding on a drift is still a limit cycle (the quadratic trend is removed).
    drifting = specs.judge(SPECS, response(y + 0.05 * t, t), "y", 1.0)
    assert drifting.label == specs.LIMIT_CYCLE


def test_a_decaying_oscillation_and_measurement_noise_are_not_limit_cycles():
    t, y = second_order(0.1, 3.0, duration=10.0)  # decays by e^{-0.3 * 2.5} = 0.47 between the window's halves
    decaying = specs.judge(SPECS, response(y, t), "y", 1.0)
    assert decaying.label == specs.VIOLATES
    assert math.isnan(metrics.oscillation(t, y, np.ones_like(t))["oscillation_amplitude"])
    t, y = second_order(0.7, 2.0)
    noisy = y + np.random.default_rng(0).normal(0, 0.2 * metrics.SETTLING_BAND, len(t))
    assert math.isnan(metrics.oscillation(t, noisy, np.ones_like(t))["oscillation_amplitude"])


def test_a_slow_drift_violates_settling_and_steady_state_error_without_a_limit_cycle():
    t = DT * np.arange(1001)
    y = 1 - np.exp(-t / 0.3) + 0.01 * t  # 10 % past the command at 10 s, still moving
    found = specs.judge(SPECS, response(y, t), "y", 1.0)
    assert found.label == specs.VIOLATES
    by_name = {v.spec: v for v in found.violations}
    assert math.isinf(by_name["settling time"].value)
    # ss error: mean of the last 5 % of y minus 1, i.e. 0.01 × mean(t over the window) (e^{-t/0.3} is gone).
    window = t[-math.ceil(0.05 * len(t)) :]
    assert by_name["ss error"].value == pytest.approx(100 * 0.01 * window.mean(), rel=1e-6)


def test_a_divergence_is_labelled_diverged_at_the_simulators_time():
    t = DT * np.arange(1001)
    y = 1e-3 * np.exp(3 * t)  # passes the simulators' 1e6 bound at ln(1e9)/3 s
    found = specs.judge(SPECS, response(y, t), "y", 1.0)
    assert found.label == specs.DIVERGED
    crossing = math.log(1e9) / 3
    assert f"t = {math.ceil(crossing / DT) * DT:.3g} s" in found.detail


def test_state_bounds_final_values_and_the_actuator_limit():
    t, y = second_order(0.7, 2.0)
    swing = np.sin(t) * np.exp(-t)  # peaks at t* = π/4 (tan t* = 1)
    peak = math.sin(math.pi / 4) * math.exp(-math.pi / 4)
    limited = specs.Specs(state_bounds={"w": (-0.2, 0.2)}, final_values={"w": (0.0, 0.01)})
    found = specs.judge(limited, response(y, t, extra=swing), "y", 1.0)
    assert found.label == specs.VIOLATES
    (bound,) = [v for v in found.violations if v.spec.startswith("w leaves")]
    assert bound.value == pytest.approx(peak - 0.2, abs=1e-4)
    assert not any(v.spec.startswith("final") for v in found.violations)  # below e^{-9.5} over the last 5 %
    late = specs.Specs(final_values={"w": (0.0, 0.01)})
    stuck = specs.judge(late, response(y, t, extra=np.full_like(t, 0.05)), "y", 1.0)
    assert [v.spec for v in stuck.violations] == ["final |w − 0|"] and stuck.violations[0].value == pytest.approx(0.05)
    u = np.full(len(t) - 1, 0.5)
    u[10] = 1.5
    over = specs.judge(specs.Specs(), response(y, t, u=u, limit=1.0), "y", 1.0)
    assert over.label == specs.VIOLATES and over.violations[0].value == 1.5


def test_status_words_and_monte_carlo_combination():
    assert [
        specs.execution(s)
        for s in (
            "ok",
            "degraded (2)",
            "diverged at t = 3 s",
            "failed: boom",
            "skipped: budget",
            "3 of 20 diverged (first at t = 1 s)",
        )
    ] == ["ok", "degraded", "diverged", "failed", "skipped", "diverged"]
    assert specs.verdict(SPECS, {}, 1.0, "failed: solver").label == specs.FAILED
    meets = specs.Verdict(specs.MEETS)
    slow = specs.Verdict(specs.VIOLATES, (specs.Violation("settling time", 5, 4, "s"),), "settling time 5 s > 4 s")
    slower = specs.Verdict(specs.VIOLATES, (specs.Violation("settling time", 8, 4, "s"),), "settling time 8 s > 4 s")
    assert specs.combine([meets] * 3) == specs.Verdict(specs.MEETS, (), "in all 3 samples")
    mixed = specs.combine([meets, slow, slower, meets])
    assert mixed.label == specs.VIOLATES and mixed.detail == "in 2 of 4 samples (worst: settling time 8 s > 4 s)"
    cycle = specs.Verdict(specs.LIMIT_CYCLE, (), "amplitude 0.1")
    assert specs.combine([slow, cycle, meets]).label == specs.LIMIT_CYCLE
    with pytest.raises(ValueError, match="max_overshoot_pct must be a finite number >= 0"):
        specs.Specs(max_overshoot_pct=-1)
    with pytest.raises(ValueError, match=r"state_bounds\['z'\] must be \(low, high\)"):
        specs.Specs(state_bounds={"z": (1.0, 0.0)})


@pytest.mark.parametrize(
    "system",
    [
        control.tf([4.0], [1.0, 1.2, 4.0]),  # underdamped, overshoots
        control.tf([3.6], [1.0, 3.0, 4.0]),  # overdamped, dc gain 0.9: a steady-state error
        control.tf([2.0, 3.0], [1.0, 2.5, 3.0, 3.0]),  # third order with a zero
    ],
)
@pytest.mark.parametrize("band_pct", [2.0, 5.0])
def test_the_four_step_definitions_agree_with_python_control_step_info(system, band_pct):
    """Rise 10-90 %, settling in the specs' band, overshoot and steady-state error, as the table measures
    them (`models.metrics.run_metrics` on a finely sampled linear response), against `control.step_info`;
    and the verdict of specs just above / below each value."""
    t = np.linspace(0.0, 40.0, 40001)
    dt = t[1] - t[0]
    y = np.squeeze(control.step_response(system, t).outputs)
    final = float(np.real(control.dcgain(system)))
    info = control.step_info(system, t, SettlingTimeThreshold=band_pct / 100)
    n = len(t) - 1
    # A run of the tracked coordinate against the step command 1 (the steady-state error is 1 − dc gain),
    # and the same response scaled to end at the command (rise, settling and overshoot as step_info
    # measures them, against the final value).
    for scale, checks in ((1.0, ("ss",)), (1.0 / final, ("rise", "settling", "overshoot"))):
        x = np.column_stack([scale * y, np.zeros_like(t)])
        run = ClosedLoopResult(
            t=t,
            x=x,
            y=x[:, :1],
            r=np.ones((n + 1, 1)),
            u=np.zeros((n, 1)),
            d=np.zeros((n, 1)),
            measured=x[:-1, :1],
            xc=None,
            step_time=np.full(n, 1e-4),
            status=None,
            input_limit=np.array([1.0]),
            state_names=("theta", "omega"),
            output_names=("theta",),
            input_names=("tau",),
        )
        measured = metrics.run_metrics(run, "theta", band=band_pct / 100)
        expected = {
            "rise": ("rise_time_s", "max_rise_time_s", info["RiseTime"], dt),
            "settling": ("settling_time_s", "max_settling_time_s", info["SettlingTime"], dt),
            "overshoot": ("overshoot_pct", "max_overshoot_pct", info["Overshoot"], 1e-9),
            "ss": ("ss_error", "max_ss_error_pct", abs(1.0 - info["SteadyStateValue"]), 1e-6),
        }
        for name in checks:
            column, field, value, tolerance = expected[name]
            assert measured[column] == pytest.approx(value, abs=tolerance), name
            bound = 100 * value if name == "ss" else value
            room = 100 * tolerance if name == "ss" else tolerance
            above = specs.Specs(**{field: bound + 2 * room + 1e-6}, settling_band_pct=band_pct, limit_cycle=False)
            below = specs.Specs(**{field: max(0.0, bound - 2 * room - 1e-3)}, settling_band_pct=band_pct)
            assert specs.judge(above, run, "theta", 1.0).ok, name
            if bound > 2 * room + 1e-3:
                assert specs.judge(below, run, "theta", 1.0).label == specs.VIOLATES, name


def test_one_class_specs_and_one_class_scenario_in_the_packages():
    """The tables, the tuner, co-design and the designer share `models.specs.Specs` and
    `models.scenario.Scenario`: no package defines another class of either name."""
    import ast
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    found: dict[str, list[str]] = {"Specs": [], "Scenario": []}
    for package in ("models", "designs", "mpc", "studies"):
        for path in sorted((root / package).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                if isinstance(node, ast.ClassDef) and node.name in found:
                    found[node.name].append(str(path.relative_to(root)))
    assert found == {"Specs": ["models/specs.py"], "Scenario": ["models/scenario.py"]}


def test_a_table_scenario_is_one_run_record():
    """A study's scenario describes its run as a `models.scenario.Scenario` (reference, duration, the case's
    disturbance, the tracked coordinate), the record the tuner takes."""
    import studies
    from designs import tuning
    from models.scenario import Scenario

    case = studies.get("arm")
    kinds = {s.name: s for s in case.scenarios}
    run = kinds["disturbance"].run(case, 0.25)
    assert isinstance(run, Scenario) and tuning.Scenario is Scenario
    assert (run.duration, run.input_disturbance, run.tracked, run.name) == (
        case.duration,
        case.input_disturbance,
        case.tracked,
        "disturbance",
    )
    assert float(run.reference(0.0)) == pytest.approx(0.25 + case.step)
    assert kinds["step"].run(case, 0.0).input_disturbance == 0.0


def test_every_violated_value_carries_its_unit():
    """The peak command in the input's unit, a bound's and a final value's excess in the state's."""
    bounded = specs.Specs(state_bounds={"x": (-1.0, 1.0)}, final_values={"x": (0.0, 0.01)}, limit_cycle=False)
    found = specs.verdict(
        bounded,
        {"peak_u": 2.0, "u_limit": 1.0},
        1.0,
        excursions={"x": 0.25},
        finals={"x": 0.5},
        units={"x": "m", "input": "N"},
    )
    assert found.detail == (
        "peak command 2 N > 1 N (+100 %); x leaves [-1, 1] by 0.25 m; final |x − 0| 0.5 m > 0.01 m (+4900 %)"
    )


def test_a_mean_that_moves_steadily_drifts_and_an_approach_to_rest_does_not():
    """0.05 /s on top of a settled step: "drifts 0.05 y/s"; with an oscillation on it, a limit cycle whose
    mean drifts; a slow exponential approach (slowing down) and a settled step: no drift."""
    t = DT * np.arange(1001)
    settled = 1 - np.exp(-3 * t)
    assert math.isnan(metrics.drift(t, settled, np.ones_like(t)))
    slowing = 1 - np.exp(-0.8 * t)  # still moving at t = 10 s, but slower and slower: not steady
    assert math.isnan(metrics.drift(t, slowing, np.ones_like(t)))
    drifting = settled + 0.05 * t
    assert metrics.drift(t, drifting, np.ones_like(t)) == pytest.approx(0.05, rel=1e-3)
    found = specs.judge(SPECS, response(drifting, t), "y", 1.0, units={"y": "m"})
    assert found.label == specs.VIOLATES and "drifts 0.05 m/s" in found.detail
    cycle = specs.judge(SPECS, response(drifting + 0.1 * np.sin(2 * np.pi * t / 1.5), t), "y", 1.0, units={"y": "m"})
    assert cycle.label == specs.LIMIT_CYCLE
    rate = float(re.search(r"its mean drifting ([0-9.]+) m/s", cycle.detail).group(1))
    assert rate == pytest.approx(0.05, rel=0.3)  # the oscillation biases the fitted line
    unjudged = specs.judge(dataclasses.replace(SPECS, limit_cycle=False), response(drifting, t), "y", 1.0)
    assert "drifts" not in unjudged.detail
