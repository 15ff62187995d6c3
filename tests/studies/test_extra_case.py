"""Adding a plant to the studies is one case file: a mass-spring-damper declared and registered here,
run end to end by `studies.run`, its rows checked against closed forms of the linear plant; and the same
plant as a case that is never registered, run with a provider of its own."""

import dataclasses
import math

import numpy as np
import pytest

import models
import studies
from designs.analysis import Loop, dc_gain
from designs.pid import PID, pd_design
from designs.statespace import second_order_poles
from mpc import MPCSettings
from studies import providers, runner
from studies.case import CaseStudy, input_disturbance, step
from studies.homework import ClassicalDesign, StateSpaceChoices, record

NAME = "test_mass_spring_damper"
M, K, B, LIMIT = 1.0, 4.0, 1.2, 20.0


@models.declare(
    name=NAME,
    title="mass on a spring and damper (test)",
    coordinates=("x",),
    inputs=("F",),
    params=(models.Param("m", M, "kg"), models.Param("k", K, "N/m"), models.Param("b", B, "N s/m")),
    input_limit=LIMIT,
    uncertain=("m", "k", "b"),
)
def mass_spring_damper(q, dq, u, p):
    return models.Physics(
        kinetic=p.m * dq.x**2 / 2, potential=p.k * q.x**2 / 2, forces=[u.F - p.b * dq.x], outputs={"x": q.x}
    )


def classical(known: models.Plant) -> ClassicalDesign:
    """PD by pole placement (ω_n = 3 rad/s, ζ = 0.8) and the same PD with an integrator."""
    G = known.linearize().tf("x", "F")
    pd = pd_design(G, zeta=0.8, wn=3.0)
    timing = dict(sample_period=CASE.sample_period, sigma=CASE.derivative_time_constant)  # the case's Ts, σ (s)
    limit = float(known.input_limit[0])
    blocks = {
        "PD": PID(known, "x", kp=pd.kp, kd=pd.kd, output_limit=limit, name="PD", **timing),
        "PID": PID(known, "x", kp=pd.kp, kd=pd.kd, ki=12.0, output_limit=limit, name="PID", **timing),
    }
    answers = {"VII.8": record(kp=pd.kp, kd=pd.kd, dc_gain=dc_gain(Loop.pid(G, pd.kp, 0, pd.kd).reference_to_output()))}
    return ClassicalDesign(answers, blocks)


CASE = CaseStudy(
    plant=NAME,
    numeral="VII",
    tracked="x",
    design_step=0.5,
    step=0.5,
    input_disturbance=2.0,
    duration=10.0,
    tracked_unit="m",
    input_unit="N",
    scenarios=(step(), input_disturbance()),
    providers=providers.STANDARD,
    answer_providers=providers.STANDARD_ANSWERS,
    known_rel=0.0,
    classical=classical,
    statespace=StateSpaceChoices(
        poles=lambda known: second_order_poles(3.0, 0.8),
        bryson_maxima={"x": 0.5},
        items=lambda r: {"VII.15(f)": r["feedback"], "LQR": r["LQR"]},
    ),
    mpc=MPCSettings(0.05, 40, (100.0, 1.0), 1e-2),
)


@pytest.fixture(scope="module")
def table():
    studies.register(CASE)
    try:
        return studies.run(NAME, mc=0)
    finally:
        studies.unregister(NAME)


def _row(table, controller, scenario):
    rows = table[(table.controller == controller) & (table.scenario == scenario)]
    assert len(rows) == 1, (controller, scenario)
    return rows.iloc[0]


def test_every_kind_of_controller_runs_on_the_new_case(table):
    assert set(table.controller) >= {
        "PD",
        "PID",
        "pole placement",
        "pole placement + integrator",
        "LQR",
        "LQR + Kalman",
        "linear MPC",
        "nonlinear MPC",
    }
    assert set(table.status) == {"ok"}
    # No stored tuned gains: no "tuned" row, and a note saying why.
    assert "tuned" not in set(table.controller)
    assert any("no tuned gains stored for" in note for note in table.attrs["notes"])


def test_pd_settles_at_the_hand_computed_dc_gain(table):
    # At rest k x = k_p (r − x): x/r = k_p / (k + k_p), with k_p from ω_n² = (k + k_p)/m.
    kp = 3.0**2 * M - K
    row = _row(table, "PD", "step")
    assert row.ss_error == pytest.approx(0.5 * K / (K + kp), rel=1e-4)
    # Under the input disturbance d the rest point moves by d / (k + k_p).
    row = _row(table, "PD", "disturbance")
    assert row.ss_error == pytest.approx(abs(0.5 * K / (K + kp) - 2.0 / (K + kp)), rel=1e-4)


@pytest.mark.parametrize("controller", ["PID", "pole placement + integrator", "LQR", "linear MPC"])
def test_integral_action_removes_the_disturbance_error(table, controller):
    assert _row(table, controller, "disturbance").ss_error < 1e-3


def test_pole_placement_step_matches_the_linear_simulation(table):
    """The plant is linear: the pole-placement row's IAE equals that of the sampled linear closed loop."""
    design = studies.homework.statespace_design(CASE)
    plant = models.get(NAME)
    lin = plant.linearize().discretize(CASE.sample_period)
    x, errors = np.zeros(2), []
    steps = int(round(CASE.duration / CASE.sample_period))
    for _ in range(steps):
        errors.append(abs(0.5 - x[0]))
        u = float(np.clip(-design.K[0] @ x + design.kr * 0.5, -LIMIT, LIMIT))
        x = lin.A @ x + lin.B[:, 0] * u
    errors.append(abs(0.5 - x[0]))
    iae = np.trapezoid(errors, dx=CASE.sample_period)  # IAE = ∫|e| dt over the samples (models.metrics)
    assert _row(table, "pole placement", "step").iae == pytest.approx(iae, rel=1e-6)


def test_the_registry_lists_the_new_case_after_the_six_and_refuses_a_second():
    studies.register(CASE)
    try:
        assert studies.names()[-1] == NAME and studies.names()[:6] == (
            "arm",
            "pendulum",
            "satellite",
            "uuv",
            "ballbeam",
            "crane",
        )
        with pytest.raises(ValueError, match="registered already; pass replace=True"):
            studies.register(CASE)
        assert studies.register(CASE, replace=True) is CASE
        found = studies.homework.classical_answers(studies.get(NAME))
        assert found["VII.8"]["dc_gain"] == pytest.approx((9.0 - K) / 9.0, rel=1e-12)
        assert math.isclose(found["VII.8"]["kp"], 9.0 - K)
    finally:
        studies.unregister(NAME)
    assert NAME not in studies.names()


def test_an_unregistered_case_runs_with_a_callable_provider_that_receives_it():
    """A `CaseStudy` that is never registered, with one provider of its own (a function, not a name):
    `run_study` hands it the case and the known plant, and the PD's steady-state error is the hand
    derivation k / (k + k_p) of the step (as in the registered case above)."""
    asked = []

    def pd_only(case, known):
        asked.append((case, known))
        G = known.linearize().tf("x", "F")
        pd = pd_design(G, zeta=0.8, wn=3.0)
        timing = dict(sample_period=case.sample_period, sigma=case.derivative_time_constant)
        return {"PD": PID(known, "x", kp=pd.kp, kd=pd.kd, output_limit=LIMIT, name="PD", **timing)}

    case = dataclasses.replace(CASE, providers=(pd_only,), answer_providers=())
    assert NAME not in studies.names()
    result = runner.run_study(case, runner.Options(scenarios=("step",), mc=0))
    assert [(c, k.name) for c, k in asked] == [(case, NAME)] and asked[0][0] is case
    assert NAME not in studies.names()  # running it registered nothing
    row = result.table.set_index("controller").loc["PD"]
    kp = 3.0**2 * M - K  # ω_n² = (k + k_p) / m
    assert row.status == "ok" and row.ss_error == pytest.approx(0.5 * K / (K + kp), rel=1e-4)
    assert len(result.providers) == 1 and result.providers[0].endswith(":" + pd_only.__qualname__)
    # The answers of an unregistered case: the model's items, and no errata of its own.
    assert "VII.7" in result.answers and result.answers["errata"] == []
    # The same through `studies.run_study`, which also takes the case itself.
    table = studies.run_study(case, scenarios=["step"], mc=0).table
    assert table.set_index("controller").loc["PD"].ss_error == row.ss_error
