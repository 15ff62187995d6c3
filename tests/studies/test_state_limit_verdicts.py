"""Physical state limits in the one verdict: a Monte Carlo sample (or a nominal run) that leaves a case's
limit makes its row violate, by the excess, counted over the samples. The limit is placed between the
peaks of the samples, which are simulated here one by one on their own (not through the table), so a
known number of samples must leave it."""

import re

import numpy as np
import pytest

import models
import studies
from designs.pid import PID
from models import specs
from models.state_limits import StateLimit
from studies import runner
from studies.case import CaseStudy, parameter_monte_carlo, step

NAME = "test_travel_limited_mass"
M, B, LIMIT = 1.0, 1.2, 20.0
SAMPLES, REL = 12, 0.3


@models.declare(
    name=NAME,
    title="mass with a damper on a limited track (test)",
    coordinates=("x",),
    inputs=("F",),
    params=(models.Param("m", M, "kg"), models.Param("b", B, "N s/m")),
    input_limit=LIMIT,
    uncertain=("m", "b"),
)
def limited_mass(q, dq, u, p):
    return models.Physics(kinetic=p.m * dq.x**2 / 2, potential=0 * q.x, forces=[u.F - p.b * dq.x], outputs={"x": q.x})


def lightly_damped_pd(case, known):
    """A PD with ζ ≈ 0.4 on the nominal mass (no spring: it comes to rest at the command): its overshoot,
    so its peak, moves with the parameters."""
    return {
        "PD": PID(
            known,
            "x",
            kp=5.0,
            kd=0.6,
            output_limit=LIMIT,
            name="PD",
            sample_period=case.sample_period,
            sigma=case.derivative_time_constant,
        )
    }


def _case(limit: StateLimit) -> CaseStudy:
    return CaseStudy(
        plant=NAME,
        numeral="VIII",
        tracked="x",
        design_step=0.5,
        step=0.5,
        input_disturbance=0.0,
        duration=10.0,
        tracked_unit="m",
        input_unit="N",
        scenarios=(step(), parameter_monte_carlo(REL)),
        providers=(lightly_damped_pd,),
        answer_providers=(),
        known_rel=0.0,
        state_limits=(limit,),
    )


def _peaks(case: CaseStudy, rows) -> np.ndarray:
    """The largest x of the step on the plant with each parameter row, each simulated on its own."""
    plant = models.get(NAME)
    block = lightly_damped_pd(case, case.known_plant())["PD"]
    run = case.scenarios[0].run(case, 0.0)
    peaks = []
    for row in rows:
        result = models.simulate_closed_loop(
            plant, block, run.reference, run.duration, params=row, substeps=case.substeps, allow_divergence=True
        )
        peaks.append(float(np.max(result.x[:, 0])))
    return np.array(peaks)


def _excess(detail: str, name: str) -> float:
    found = re.search(rf"leaves {name} by ([0-9.e+-]+) m", detail)
    assert found, detail
    return float(found.group(1))


def test_a_sample_that_leaves_the_track_makes_the_monte_carlo_row_violate_by_its_excess():
    plant = models.get(NAME)
    placeholder = _case(StateLimit("travel", "x", -1.0, 1.0, source="test", unit="m"))
    samples = models.sample_params(plant, SAMPLES, rel=REL, seed=0)  # the runner's samples (seed 0)
    peaks = _peaks(placeholder, samples)
    nominal = _peaks(placeholder, [list(plant.params.values())])[0]
    ordered = np.sort(peaks)
    k = SAMPLES // 2
    assert ordered[k + 1] - ordered[k] > 1e-4  # a gap to put the limit in: the count cannot be off by one
    upper = float((ordered[k] + ordered[k + 1]) / 2)
    leaving = int(np.sum(peaks > upper))
    assert 0 < leaving < SAMPLES
    case = _case(StateLimit("travel", "x", -1.0, upper, source="test", unit="m"))

    result = runner.run_study(case, runner.Options(mc=SAMPLES, jit=False))
    rows = result.table.set_index("scenario")
    mc = rows.loc["mc"]
    assert mc.verdict == specs.VIOLATES
    assert f"in {leaving} of {SAMPLES} samples" in mc.verdict_detail
    assert _excess(mc.verdict_detail, "travel") == pytest.approx(peaks.max() - upper, rel=5e-3)
    # Each sample's own row says whether it left, and by how much.
    frame = result.samples.sort_values("sample")
    for detail, peak in zip(frame.verdict_detail, peaks):
        if peak > upper:
            assert _excess(detail, "travel") == pytest.approx(peak - upper, rel=5e-3)
        else:
            assert "travel" not in detail
    # The nominal step is judged by the same limit.
    nominal_row = rows.loc["step"]
    if nominal > upper:
        assert _excess(nominal_row.verdict_detail, "travel") == pytest.approx(nominal - upper, rel=5e-3)
    else:
        assert nominal_row.verdict == specs.MEETS


def test_a_limit_above_every_peak_is_met_and_is_written_in_the_specs():
    plant = models.get(NAME)
    placeholder = _case(StateLimit("travel", "x", -1.0, 1.0, source="test", unit="m"))
    samples = models.sample_params(plant, 4, rel=REL, seed=0)
    upper = 1.01 * float(_peaks(placeholder, samples).max())
    case = _case(StateLimit("travel", "x", -1.0, upper, source="test", unit="m"))
    table = runner.run_study(case, runner.Options(mc=4, jit=False)).table
    assert set(table.verdict) == {specs.MEETS}
    assert f"travel: -1 ≤ x ≤ {upper:g} m" in case.specs_for("step", plant.params).describe()


@pytest.mark.parametrize("name", ["pendulum", "satellite", "ballbeam", "crane"])
def test_each_case_judges_its_limits(name):
    case = studies.get(name)
    plant = models.get(name)
    judged = case.specs_for("mc", plant.params)
    assert case.state_limits and [lim.name for lim in case.state_limits] == [lim.name for lim in judged.state_limits]
    for limit in judged.state_limits:
        assert set(limit.states) <= set(plant.state_names) and limit.source and limit.unit


def test_the_pendulums_track_holds_the_texts_own_steps():
    """The commanded positions (the step and the series of steps, both ways) are on the track."""
    case = studies.get("pendulum")
    (travel,) = case.state_limits
    farthest = max(abs(level) for scenario in case.scenarios for level in scenario.levels) * case.step
    assert travel.lower < -farthest and farthest < travel.upper


def test_the_beam_length_follows_the_sampled_plant():
    case = studies.get("ballbeam")
    params = dict(models.get("ballbeam").params, ell=0.525)
    (beam,) = case.specs_for("mc", params).state_limits
    assert (beam.lower, beam.upper) == (0.0, 0.525)
