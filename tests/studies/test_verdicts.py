"""The case studies' specs and the verdicts of real rows: the pendulum's loopshaped loop, which drifts in a
limit cycle on the nonlinear plant (II.14's erratum), is flagged; its PD, which settles, is not."""

import math

import pytest

import models
import studies
from models import metrics, specs


@pytest.mark.parametrize("name", studies.names())
def test_every_case_states_its_specs_and_where_they_come_from(name):
    case = studies.get(name)
    plant = models.get(name)
    for scenario in case.scenarios:
        chosen = case.specs_for(scenario.name, plant.params)
        assert chosen.source, f"{name}/{scenario.name}: specs without a source"
        assert chosen.max_settling_time_s is not None and chosen.max_overshoot_pct is not None
        assert chosen.max_settling_time_s < scenario.duration(case)  # judgeable within the run
        for state in chosen.state_bounds:
            assert state in plant.state_names
    if case.bounds:  # the case's own bounds (the ball on the beam) are judged as specs
        assert case.state_bounds(plant.params).items() <= case.specs_for("step", plant.params).state_bounds.items()


def test_the_pendulums_loopshaped_row_is_a_limit_cycle_and_its_pd_meets_the_specs():
    table = studies.run("pendulum", scenarios=["step"], mc=0, providers=["studies.providers:classical"])
    rows = table.set_index("controller")
    loopshaped, pd = rows.loc["loopshaped"], rows.loc["PD"]
    assert loopshaped.status == "ok"  # it ran to the end without diverging ...
    assert loopshaped.verdict == specs.LIMIT_CYCLE  # ... but it does not come to rest
    step = studies.get("pendulum").step
    assert loopshaped.oscillation_amplitude > metrics.SETTLING_BAND * step
    assert "settling time ∞ > 10 s" in loopshaped.verdict_detail
    assert pd.verdict == specs.MEETS and math.isnan(pd.oscillation_amplitude)
