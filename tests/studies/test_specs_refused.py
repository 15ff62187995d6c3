"""Bad specs are refused before any run, with a message naming the field and its value: specs that
contradict themselves, their scenario (a step spec without a step, a time after the run's end, a bound
that excludes the commanded level) or their plant (a state it does not have)."""

import dataclasses

import pytest

import models
import studies
from models.specs import Specs
from models.state_limits import StateLimit
from studies import judging, runner
from studies.case import TableScenario

STATES = ("z", "theta", "dz", "dtheta")


@pytest.mark.parametrize(
    ("field", "value"),
    [("max_overshoot_pct", -1.0), ("max_rise_time_s", -0.5), ("max_settling_time_s", float("nan"))],
)
def test_a_negative_or_non_finite_bound_is_refused(field, value):
    with pytest.raises(ValueError, match=rf"Specs\.{field} must be .* got {value!r}"):
        Specs(**{field: value})


@pytest.mark.parametrize("band", [0.0, 100.0, 150.0, -2.0])
def test_a_settling_band_outside_0_100_percent_is_refused(band):
    with pytest.raises(ValueError, match=rf"settling_band_pct must be a percentage in \(0, 100\), got {band!r}"):
        Specs(settling_band_pct=band)


def test_a_final_value_outside_its_states_bound_or_limit_is_refused():
    with pytest.raises(ValueError, match=r"final_values\['z'\] = \(1, 0.1\) lies outside Specs.state_bounds\['z'\]"):
        Specs(state_bounds={"z": 0.5}, final_values={"z": (1.0, 0.1)})
    travel = StateLimit("cart travel", "z", -0.5, 0.5, source="test", unit="m")
    with pytest.raises(ValueError, match="lies outside Specs.state_limits 'cart travel'"):
        Specs(final_values={"z": (1.0, 0.1)}).with_limits([travel])
    Specs(state_bounds={"z": 0.5}, final_values={"z": (0.55, 0.1)})  # overlapping: possible, accepted


def test_a_step_spec_without_a_step_is_refused():
    with pytest.raises(ValueError, match=r"Specs.max_settling_time_s = 3.0 needs a step, .* stays at z = 0"):
        Specs(max_settling_time_s=3.0).validate(STATES, tracked="z", targets=[0.0, 0.0], duration=10.0)
    Specs(max_settling_time_s=3.0).validate(STATES, tracked="z", targets=[0.0, 1.0], duration=10.0)
    with pytest.raises(ValueError, match="max_overshoot_pct = 5.0 needs a step, .* it tracks no coordinate"):
        Specs(max_overshoot_pct=5.0).validate(STATES)


def test_a_time_after_the_end_of_the_run_is_refused():
    with pytest.raises(ValueError, match=r"Specs.max_rise_time_s = 12 s is after the end of the scenario \(10 s\)"):
        Specs(max_rise_time_s=12.0).validate(STATES, tracked="z", targets=[0.0, 1.0], duration=10.0)


@pytest.mark.parametrize(
    ("specs", "message"),
    [
        (Specs(state_bounds={"q": 1.0}), r"Specs.state_bounds\['q'\]: the plant has no state 'q'"),
        (Specs(final_values={"x": (0.0, 0.1)}), r"Specs.final_values\['x'\]: the plant has no state 'x'"),
        (
            Specs(state_limits=(StateLimit("deflection", "z", -1, 1, source="test", relative_to="phi"),)),
            "Specs.state_limits 'deflection' reads the state 'phi', which the plant does not have",
        ),
    ],
)
def test_a_requirement_on_a_signal_the_plant_does_not_have_is_refused(specs, message):
    with pytest.raises(ValueError, match=message):
        specs.validate(STATES)


def test_a_rise_time_spec_on_a_disturbance_only_scenario_is_refused_before_any_work():
    """A case asking a rise time of a run whose reference never moves: run_study refuses it before it
    designs anything (the provider is never called)."""
    asked = []

    def provider(case, known):
        asked.append(case)
        return {}

    quiet = TableScenario("quiet", "the input disturbance alone", levels=(0.0,), input_disturbance=True)
    case = dataclasses.replace(
        studies.get("pendulum"),
        scenarios=(quiet,),
        specs={"quiet": Specs(max_rise_time_s=1.0, source="test")},
        providers=(provider,),
        answer_providers=(),
    )
    message = r"Specs.max_rise_time_s = 1.0 needs a step, and the scenario 'quiet' of pendulum has none"
    with pytest.raises(ValueError, match=message):
        runner.run_study(case, runner.Options(mc=0))
    assert asked == []


def test_a_track_shorter_than_the_commanded_step_is_refused():
    """The pendulum's 2 m step on a ±0.5 m track (the swing-up's travel): no row could meet it."""
    short = StateLimit("cart travel", "z", -0.5, 0.5, source="test", unit="m")
    case = dataclasses.replace(studies.get("pendulum"), state_limits=(short,))
    message = (
        r"Specs.state_limits 'cart travel' = \(-0.5, 0.5\) excludes the scenario 'step' of pendulum's commanded z = 2"
    )
    with pytest.raises(ValueError, match=message):
        judging.check_specs(case, models.get("pendulum"))


@pytest.mark.parametrize("name", studies.names())
def test_every_registered_case_passes_its_own_checks(name):
    judging.check_specs(studies.get(name), models.get(name))
