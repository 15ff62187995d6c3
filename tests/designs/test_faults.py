"""Issue 12, class 5: a spec the optimizer cannot see is an error, not a pass.

Every argument of `tune`, `codesign` and `size_actuator` is checked before any
solve; each case asserts the error type and that the message names the
culprit. The first block reproduces the cases seen in the issue.
"""

import dataclasses
import math
import time

import casadi as ca
import numpy as np
import pytest

import models
from designs.codesign import SizingProblem, codesign, size_actuator, size_actuator_simultaneous
from designs.tuning import Cost, Scenario, SolveOptions, Specs, TuningProblem, TuningSetup, tune

#: What `TuningSetup` and `SolveOptions` take: a case's keywords below go to the record that takes them.
SETUP_FIELDS = {f.name for f in dataclasses.fields(TuningSetup)}
SOLVE_FIELDS = {f.name for f in dataclasses.fields(SolveOptions)}


class PD(models.Block):
    """τ = kp (r − θ) − kd θ', saturated at 1; reads the state (the arm)."""

    def __init__(self, kp=0.3, kd=0.1):
        super().__init__(
            sample_period=0.01,
            n_state=0,
            n_measured=2,
            n_reference=1,
            n_input=1,
            gains={"kp": kp, "kd": kd},
            measures="state",
        )

    def expr(self, xc, y, r, g):
        return xc, models.saturate(g["kp"] * (r[0] - y[0]) - g["kd"] * y[1], 1.0)


@pytest.fixture(scope="module")
def arm():
    return models.get("arm")


STEP = Scenario(reference=0.5, duration=2.0, tracked="theta")


def _never_solves(monkeypatch):
    """Make any IPOPT solve fail the test: the checks must come first."""

    def refuse(*args, **kwargs):
        raise AssertionError("a solve started before the arguments were checked")

    monkeypatch.setattr(ca, "nlpsol", refuse)


# ----------------------------------------------------------------- the examples seen in the issue
def test_settling_time_after_the_end_of_the_scenario_is_refused(arm, monkeypatch):
    _never_solves(monkeypatch)
    with pytest.raises(ValueError, match=r"max_settling_time_s = 7 s is after the end of the scenario \(2 s\)"):
        tune(TuningSetup(arm, PD(), STEP, specs=Specs(max_settling_time_s=7.0)))


@pytest.mark.parametrize("name", ["max_settling_time_s", "max_rise_time_s"])
def test_nan_times_are_refused(name):
    with pytest.raises(ValueError, match=f"Specs.{name} must be a finite number >= 0 or None, got nan"):
        Specs(**{name: math.nan})


def test_negative_overshoot_is_refused():
    with pytest.raises(ValueError, match="Specs.max_overshoot_pct must be a finite number >= 0 or None, got -10.0"):
        Specs(max_overshoot_pct=-10.0)


def test_zero_samples_are_refused(arm, monkeypatch):
    _never_solves(monkeypatch)
    with pytest.raises(ValueError, match="samples has no rows"):
        tune(TuningSetup(arm, PD(), STEP, samples=np.zeros((0, arm.n_params))))


@pytest.mark.parametrize(
    "pair,message",
    [((1.0, 0.5), "bounds\\['kp'\\] has low > high"), ((math.nan, 1.0), "bounds\\['kp'\\] must not be NaN")],
)
def test_inverted_or_nan_bounds_are_refused(arm, monkeypatch, pair, message):
    _never_solves(monkeypatch)
    with pytest.raises(ValueError, match=message):
        tune(TuningSetup(arm, PD(), STEP, bounds={"kp": pair}))


@pytest.mark.parametrize(
    "value,error,message",
    [
        (0, ValueError, "max_iter must be an integer >= 1, got 0"),
        (2.5, ValueError, "max_iter must be an integer, got 2.5"),
        ("10", TypeError, "max_iter must be an integer, got str"),
    ],
)
def test_bad_max_iter_is_refused(arm, monkeypatch, value, error, message):
    _never_solves(monkeypatch)
    with pytest.raises(error, match=message):
        tune(TuningSetup(arm, PD(), STEP), SolveOptions(max_iter=value))


@pytest.mark.parametrize(
    "rel_tol,message",
    [
        (0.0, "rel_tol must be a fraction in \\(0, 1\\), got 0.0"),
        (math.nan, "rel_tol must be a fraction in \\(0, 1\\), got nan"),
        (1.5, "rel_tol must be a fraction in \\(0, 1\\), got 1.5"),
        (1e-300, "needs .* limits, more than 60"),
    ],
)
def test_size_actuator_refuses_a_tolerance_that_never_ends_or_ends_at_once(arm, rel_tol, message):
    started = time.perf_counter()
    with pytest.raises(ValueError, match=message):
        size_actuator(
            SizingProblem(arm, lambda p: PD(), STEP, Specs(max_rise_time_s=1.0), low=0.5, high=2.0),
            retune=False,
            rel_tol=rel_tol,
        )
    assert time.perf_counter() - started < 1.0


def test_size_actuator_tries_a_bounded_number_of_limits(arm):
    """rel_tol = 1e-6 over [0.8, 3] needs 24 limits: the loop ends there, every limit tried is recorded."""
    from tests.designs.test_tuning import ArmPD

    sized = size_actuator(
        SizingProblem(arm, lambda p: ArmPD(p, kp=2.0, kd=0.2), STEP, Specs(max_rise_time_s=1.0), low=0.8, high=3.0),
        retune=False,
        rel_tol=1e-6,
    )
    assert sized["evaluations"] == len(sized["history"]) <= 25


# ----------------------------------------------------------------- the rest of the class: tune
@pytest.mark.parametrize(
    "kwargs,error,message",
    [
        ({"specs": Specs(max_rise_time_s=5.0)}, ValueError, "max_rise_time_s = 5 s is after the end of the scenario"),
        ({"robust": "median"}, ValueError, "robust must be 'mean' or 'worst', got 'median'"),
        ({"free": "kp"}, TypeError, "free must be a sequence of gain names, got 'kp'"),
        ({"free": ["kq"]}, ValueError, "has no gain \\['kq'\\]"),
        ({"free": []}, ValueError, "nothing to decide"),
        ({"bounds": {"kq": (0, 1)}}, ValueError, "bounds given for 'kq', which is not a free gain"),
        ({"bounds": {"kp": (0, 1, 2)}}, ValueError, "bounds\\['kp'\\] must be a pair \\(low, high\\)"),
        ({"bounds": {"kp": ((0, 1), 2)}}, ValueError, "bounds\\['kp'\\] must be numbers or arrays shaped like"),
        ({"bounds": [("kp", 0, 1)]}, TypeError, "bounds must be a dict gain name"),
        ({"tol": 0.0}, ValueError, "tol must be a finite number > 0, got 0.0"),
        ({"tol": math.nan}, ValueError, "tol must be a finite number > 0, got nan"),
        ({"hessian": "bfgs"}, ValueError, "hessian must be 'limited-memory' or 'exact', got 'bfgs'"),
        ({"method": "slack"}, ValueError, "method must be 'smooth' or 'exact', got 'slack'"),
        ({"widths": (1e-2, 1e-1)}, ValueError, "widths must be a non-empty, strictly decreasing"),
        ({"widths": (0.1, 0.0)}, ValueError, "widths must be a non-empty, strictly decreasing"),
        ({"widths": ()}, ValueError, "widths must be a non-empty"),
        ({"jit": "yes"}, TypeError, "jit must be True or False, got str"),
        ({"progress": 3}, TypeError, "progress must be callable"),
        ({"substeps": 2.7}, ValueError, "substeps must be an integer, got 2.7"),
        ({"samples": np.full((2, 4), math.nan)}, ValueError, "samples has a non-finite entry"),
        ({"samples": np.zeros((1, 2))}, ValueError, "samples must have shape"),
        ({"specs": "fast"}, TypeError, "specs must be a models.specs.Specs, got str"),
        ({"cost": "itae"}, TypeError, "cost must be a designs.tuning.Cost, got str"),
    ],
)
def test_tune_refuses_before_solving(arm, monkeypatch, kwargs, error, message):
    _never_solves(monkeypatch)
    setup = {k: v for k, v in kwargs.items() if k in SETUP_FIELDS}
    with pytest.raises(error, match=message):
        tune(TuningSetup(arm, PD(), STEP, **setup), SolveOptions(**{k: v for k, v in kwargs.items() if k not in setup}))


def test_a_sample_the_plant_refuses_is_named_by_row(arm, monkeypatch):
    _never_solves(monkeypatch)
    rows = np.tile(arm.param_vector(), (3, 1))
    rows[2, 0] = -1.0
    with pytest.raises(ValueError, match="samples row 2: .*m"):
        tune(TuningSetup(arm, PD(), STEP, samples=rows))


@pytest.mark.parametrize(
    "scenario,specs,message",
    [
        (
            Scenario(reference=None, duration=2.0, tracked="theta"),
            Specs(max_overshoot_pct=10.0),
            "max_overshoot_pct need a step, and the scenario has none: it regulates",
        ),
        (
            Scenario(reference=0.0, duration=2.0, tracked="theta"),
            Specs(max_rise_time_s=1.0),
            "max_rise_time_s need a step.*its reference never changes from the initial tracked value",
        ),
        (
            Scenario(reference=lambda t: 0.5 * (t > 1.0), duration=2.0, tracked="theta", name="late step"),
            Specs(max_settling_time_s=2.5),
            "max_settling_time_s = 2.5 s is after the end of the scenario \\(late step\\) \\(2 s\\)",
        ),
        (Scenario(reference=0.5, duration=2.0), Specs(max_overshoot_pct=10.0), "it names no tracked state"),
        (STEP, Specs(state_bounds={"phi": 1.0}), "state_bounds: arm has no state 'phi'"),
        (STEP, Specs(final_values={"omega": (0.0, 0.1)}), "final_values: arm has no state 'omega'"),
        (Scenario(reference=0.5, duration=2.0, tracked="phi"), None, "arm has no state 'phi'"),
        (Scenario(reference=0.5, duration=0.001, tracked="theta"), None, "shorter than one sample"),
        (
            Scenario(reference=0.5, duration=2.0, x0=[0.0, math.nan], tracked="theta"),
            None,
            "arm initial state x0 has non-finite entries",
        ),
        (Scenario(reference=0.5, duration=2.0, tracked="theta", noise_std=-1.0), None, "noise_std must be one number"),
    ],
)
def test_specs_the_scenario_cannot_judge_are_refused(arm, monkeypatch, scenario, specs, message):
    _never_solves(monkeypatch)
    with pytest.raises(ValueError, match=message):
        tune(TuningSetup(arm, PD(), scenario, specs=specs))


@pytest.mark.parametrize(
    "build,error,message",
    [
        (
            lambda: Specs(settling_band_pct=0.0),
            ValueError,
            "settling_band_pct must be a percentage in \\(0, 100\\), got 0.0",
        ),
        (
            lambda: Specs(settling_band_pct=150.0),
            ValueError,
            "settling_band_pct must be a percentage in \\(0, 100\\), got 150.0",
        ),
        (
            lambda: Specs(max_overshoot_pct=math.inf),
            ValueError,
            "max_overshoot_pct must be a finite number >= 0 or None, got inf",
        ),
        (lambda: Specs(max_overshoot_pct="5 %"), ValueError, "max_overshoot_pct must be a finite number >= 0 or None"),
        (
            lambda: Specs(max_rise_time_s=-1.0),
            ValueError,
            "max_rise_time_s must be a finite number >= 0 or None, got -1.0",
        ),
        (
            lambda: Specs(max_spectral_abscissa=math.nan),
            ValueError,
            "max_spectral_abscissa must be a finite number \\(1/s\\)",
        ),
        (
            lambda: Specs(state_bounds={"theta": (1.0, -1.0)}),
            ValueError,
            "state_bounds\\['theta'\\] must be .* low < high",
        ),
        (
            lambda: Specs(state_bounds={"theta": -0.2}),
            ValueError,
            "state_bounds\\['theta'\\] must be a bound > 0",
        ),
        (lambda: Specs(state_bounds={"theta": (math.nan, 1.0)}), ValueError, "state_bounds\\['theta'\\]"),
        (lambda: Specs(state_bounds=[("theta", 1.0)]), TypeError, "state_bounds must be a dict"),
        (lambda: Specs(final_values={"theta": (0.0, 0.0)}), ValueError, "final_values\\['theta'\\] must be a pair"),
        (lambda: Specs(final_values={"theta": 0.5}), ValueError, "final_values\\['theta'\\] must be a pair"),
        (lambda: Scenario(0.5, math.nan, tracked="theta"), ValueError, "duration \\(s\\) must be a finite number > 0"),
        (lambda: Scenario(0.5, 2.0, tracked="theta", weight=0.0), ValueError, "scenario weight must be a finite"),
        (lambda: Scenario(0.5, 2.0, tracked="theta", seed=-1), ValueError, "seed must be an integer >= 0, got -1"),
        (lambda: Scenario(0.5, 2.0, tracked=3), TypeError, "tracked must be a state name"),
        (lambda: Cost("l1"), ValueError, "unknown cost 'l1'"),
        (lambda: Cost(energy_weight=math.nan), ValueError, "energy_weight must be finite and >= 0, got nan"),
        (lambda: Cost(energy_weight=-1.0), ValueError, "energy_weight must be finite and >= 0, got -1.0"),
        (lambda: Cost(smoothing=0.0), ValueError, "smoothing must be a finite number > 0, got 0.0"),
        (lambda: Cost(resolution=-1e-4), ValueError, "resolution must be finite and >= 0, got -0.0001"),
        (lambda: Cost(resolution=math.inf), ValueError, "resolution must be finite and >= 0, got inf"),
        (lambda: Cost(kind=None), ValueError, "the cost has no term"),
    ],
)
def test_records_refuse_bad_values_when_made(build, error, message):
    with pytest.raises(error, match=message):
        build()


@pytest.mark.parametrize(
    "cost,message",
    [
        (Cost(kind=None, state_weights=[[1.0, 2.0], [0.0, 1.0]]), "state_weights must be symmetric"),
        (Cost(kind=None, state_weights=[[1.0, 0.0], [0.0, -1.0]]), "state_weights must be positive semidefinite"),
        (Cost(kind=None, state_weights={"phi": 1.0}), "state_weights: no signal named \\['phi'\\]"),
        (Cost(kind=None, input_weights=[1.0, 2.0]), "input_weights must be a dict, a scalar, 1 diagonal entries"),
        (Cost(kind=None, output_weights=[math.nan]), "output_weights has non-finite entries"),
        (Cost("itae", signal="omega"), "the cost's signal 'omega' is not 'error' nor a state"),
        (Cost(kind=None, state_weights={"theta": 1.0}, target={"phi": 0.0}), "target: no signal named 'phi'"),
    ],
)
def test_costs_the_plant_cannot_evaluate_are_refused(arm, monkeypatch, cost, message):
    _never_solves(monkeypatch)
    with pytest.raises(ValueError, match=message):
        tune(TuningSetup(arm, PD(), STEP, cost=cost))


def test_the_error_signal_needs_a_reference(arm):
    with pytest.raises(ValueError, match="the cost's signal 'error' needs a reference and a tracked state"):
        TuningProblem(arm, PD(), Scenario(reference=None, duration=2.0, tracked="theta"))


def test_scenarios_must_be_scenarios(arm):
    with pytest.raises(ValueError, match="scenarios is empty"):
        TuningProblem(arm, PD(), [])
    with pytest.raises(TypeError, match="scenarios must all be models.scenario.Scenario"):
        TuningProblem(arm, PD(), [STEP, {"reference": 0.5}])
    with pytest.raises(TypeError, match="plant must be a models.Plant"):
        TuningProblem("arm", PD(), STEP)
    with pytest.raises(TypeError, match="block must be a models.Block"):
        TuningProblem(arm, object(), STEP)


# ----------------------------------------------------------------- codesign
@pytest.mark.parametrize(
    "design_params,kwargs,error,message",
    [
        ({"m": 0.5}, {}, ValueError, "design_params\\['m'\\] must be a pair \\(low, high\\), got 0.5"),
        ({"m": (0.6, 0.4)}, {}, ValueError, "range of m must be finite with low < high"),
        ({"m": (math.nan, 0.6)}, {}, ValueError, "range of m must be finite with low < high"),
        ({"m": (0.4, math.inf)}, {}, ValueError, "range of m must be finite with low < high"),
        ({"m": ("0.4", 0.6)}, {}, TypeError, "design_params\\['m'\\] bound must be a real number, got str"),
        ({"m": (-1.0, 0.6)}, {}, ValueError, "m"),
        ({"m": (0.6, 0.8)}, {}, ValueError, "m = 0.5 starts outside its range"),
        ({"q": (0.4, 0.6)}, {}, ValueError, "arm has no parameter 'q'"),
        ({}, {}, ValueError, "design_params is empty"),
        ([("m", 0.4, 0.6)], {}, TypeError, "design_params must be a dict"),
        ({"m": (0.4, 0.6)}, {"plant_cost": None}, ValueError, "the sequential method needs a plant-only objective"),
        ({"m": (0.4, 0.6)}, {"methods": ("joint",)}, ValueError, "unknown co-design method \\['joint'\\]"),
        ({"m": (0.4, 0.6)}, {"methods": "nested"}, TypeError, "methods must be a non-empty sequence"),
        ({"m": (0.4, 0.6)}, {"methods": ("simultaneous from sequential",)}, ValueError, "needs 'sequential'"),
        ({"m": (0.4, 0.6)}, {"nested_tol": 0.0}, ValueError, "nested_tol must be a finite number > 0"),
        ({"m": (0.4, 0.6)}, {"nested_tol": 1.0}, ValueError, "nested_tol must be a fraction of the range below 1"),
        ({"m": (0.4, 0.6)}, {"max_iter": 0}, ValueError, "max_iter must be an integer >= 1, got 0"),
        ({"m": (0.4, 0.6)}, {"tol": -1.0}, ValueError, "tol must be a finite number > 0"),
        ({"m": (0.4, 0.6)}, {"plant_cost": 3.0}, TypeError, "plant_cost must be callable"),
        ({"m": (0.4, 0.6)}, {"bounds": {"kp": (1.0, 0.0)}}, ValueError, "bounds\\['kp'\\] has low > high"),
        (
            {"m": (0.4, 0.6)},
            {"specs": Specs(max_settling_time_s=9.0)},
            ValueError,
            "max_settling_time_s = 9 s is after the end",
        ),
        ({"m": (0.4, 0.6)}, {"samples": np.zeros((0, 4))}, ValueError, "samples has no rows"),
    ],
)
def test_codesign_refuses_before_solving(arm, monkeypatch, design_params, kwargs, error, message):
    _never_solves(monkeypatch)
    kwargs = {"plant_cost": lambda p: p["m"]} | kwargs
    setup = {k: v for k, v in kwargs.items() if k in SETUP_FIELDS}
    solve = {k: v for k, v in kwargs.items() if k in SOLVE_FIELDS}
    rest = {k: v for k, v in kwargs.items() if k not in setup and k not in solve}
    with pytest.raises(error, match=message):
        codesign(TuningSetup(arm, PD(), STEP, **setup), design_params, options=SolveOptions(**solve), **rest)


# ----------------------------------------------------------------- size_actuator
@pytest.mark.parametrize(
    "kwargs,error,message",
    [
        ({"low": 2.0, "high": 1.0}, ValueError, "need finite 0 < low < high, got low=2.0, high=1.0"),
        ({"low": math.nan}, ValueError, "need finite 0 < low < high, got low=nan"),
        ({"high": math.inf}, ValueError, "need finite 0 < low < high"),
        ({"low": 0.0}, ValueError, "need finite 0 < low < high, got low=0.0"),
        ({"low": "1"}, TypeError, "low must be a real number, got str"),
        ({"retune": "yes"}, TypeError, "retune must be True or False, got str"),
        ({"design": "PD"}, TypeError, "design must be callable Plant -> Block"),
        ({"specs": None}, TypeError, "specs must be a models.specs.Specs"),
        ({"options": ["bounds"]}, TypeError, "options must be a designs.tuning.SolveOptions, got list"),
    ],
)
def test_size_actuator_refuses_before_any_limit_is_tried(arm, kwargs, error, message):
    tried = []

    def design(plant):
        tried.append(plant.input_limit[0])
        return PD()

    args = {"design": design, "specs": Specs(max_rise_time_s=1.0), "low": 0.5, "high": 2.0, "retune": False} | kwargs
    with pytest.raises(error, match=message):
        range_ = {"low": args.pop("low"), "high": args.pop("high")}
        size_actuator(SizingProblem(arm, args.pop("design"), STEP, args.pop("specs"), **range_), **args)
    assert tried == []


@pytest.mark.parametrize(
    "kwargs,message",
    [
        ({"start_limit": 3.0}, "start_limit = 3 is outside \\[0.5, 2\\]"),
        ({"cost_weight": -1.0}, "cost_weight must be >= 0"),
        ({"low": 2.0, "high": 2.0}, "need finite 0 < low < high"),
    ],
)
def test_simultaneous_sizing_refuses_before_solving(arm, monkeypatch, kwargs, message):
    _never_solves(monkeypatch)
    args = {"low": 0.5, "high": 2.0, "start_limit": 1.0} | kwargs
    with pytest.raises(ValueError, match=message):
        problem = SizingProblem(
            arm, lambda p: PD(), STEP, Specs(max_rise_time_s=1.0), low=args.pop("low"), high=args.pop("high")
        )
        size_actuator_simultaneous(problem, **args)
