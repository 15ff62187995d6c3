"""What a tuning problem constrains beyond the step specs: a step shorter than its settling time, and the
specs it refuses (frequency fields, a limit it cannot read), each against the table's own measure."""

import numpy as np
import pytest

import models
from designs.tuning import Scenario, Specs, TuningProblem
from models import metrics
from models.state_limits import StateLimit
from tests.designs.test_tuning import ArmPD

STEP_AT, DURATION, SETTLING = 1.0, 2.0, 1.5


@pytest.fixture(scope="module")
def arm():
    return models.get("arm")


def _late_step():
    """A 0.5 rad step at 1 s in a 2 s run: its segment lasts 1 s, shorter than the 1.5 s settling time."""
    return Scenario(reference=lambda t: 0.5 * (t >= STEP_AT), duration=DURATION, tracked="theta", name="late step")


def _table_settling(arm, block) -> float:
    """The table's settling time (s) of the late step on a fresh simulation: `models.metrics.step_metrics` on
    its segment, as the table splits a run (`models.metrics.segments`)."""
    run = models.simulate_closed_loop(arm, block, _late_step().reference, DURATION, substeps=10)
    y = run.state("theta")
    (a, b, before, after), *_ = [s for s in metrics.segments(run.t, y, run.r[:, 0]) if s[3] != s[2]]
    return metrics.step_metrics(run.t[a:b], y[a:b], initial=before, target=after)["settling_time_s"]


@pytest.mark.parametrize("gains", [{"kp": 0.3, "kd": 0.1}, {"kp": 3.0, "kd": 0.6}, {"kp": 0.05, "kd": 0.05}])
def test_a_step_shorter_than_its_settling_time_is_judged_as_the_table_judges_it(arm, gains):
    """The table's settling time of a step that ends before the spec (`models.metrics.step_metrics` on the
    segment of a fresh simulation) meets the spec exactly when the tuning problem finds its settling rows
    met: the segment's last sample inside the band."""
    block = ArmPD(arm, **gains)
    problem = TuningProblem(arm, block, _late_step(), specs=Specs(max_settling_time_s=SETTLING))
    g = np.asarray(problem.evaluate(problem.start())[1]).ravel()
    settled_by_tuner = not [n for n in problem.violated_names(g, tol=0.0) if n.startswith("within")]
    settling = _table_settling(arm, block)
    assert settled_by_tuner == (settling <= SETTLING), settling


def test_the_late_step_cases_above_cover_both_sides(arm):
    """At least one of the gains above settles within its 1 s segment and one does not (by the table)."""
    fast, slow = ({"kp": 3.0, "kd": 0.6}, {"kp": 0.05, "kd": 0.05})
    settled = [_table_settling(arm, ArmPD(arm, **gains)) for gains in (fast, slow)]
    assert settled[0] <= SETTLING and settled[1] == np.inf, settled


STEP = Scenario(reference=0.5, duration=DURATION, tracked="theta")


@pytest.mark.parametrize(
    "specs,extra,message",
    [
        (Specs(min_phase_margin_deg=30.0), (), "min_phase_margin_deg: the tuning constrains the runs, not the"),
        (Specs(min_disk_margin=0.5, max_bandwidth_rad_s=10.0), (), "min_disk_margin, max_bandwidth_rad_s"),
        (
            Specs(state_limits=(StateLimit("twist", "phi", -1.0, 1.0, source="test"),)),
            (),
            "state_limits 'twist': arm has no state 'phi'",
        ),
        (
            Specs(state_limits=(StateLimit("lead", "theta", -1.0, 1.0, source="test", relative_to="phi"),)),
            (),
            "state_limits 'lead': arm has no state 'phi'",
        ),
        (
            Specs(state_limits=(StateLimit("reach", "theta", -1.0, 1.0, source="test", upper_parameter="m"),)),
            ("m",),
            "its bound is the parameter 'm', which this problem decides",
        ),
    ],
)
def test_specs_a_tuning_cannot_impose_are_refused_by_name(arm, specs, extra, message):
    with pytest.raises(ValueError, match=message):
        TuningProblem(arm, ArmPD(arm), STEP, specs=specs, extra_params=extra)
