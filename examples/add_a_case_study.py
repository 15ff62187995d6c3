"""Add a seventh case study, a mass on a spring and a damper, and compare every controller on it.

A case study is one `studies.CaseStudy`: the plant's registry name, the text's
numbers (tracked coordinate, step, disturbance), the scenarios, the specs the
rows are judged by and the designs (here a PD and a PID, the state-space
family and MPC). `studies.register` adds it; `studies.run_study` runs every
controller on the nonlinear plant and, with `out=`, writes the tables, answers,
plots and animation (see docs/layout.md for a case kept in studies/cases/).

    python examples/add_a_case_study.py [OUT]
"""

import sys

import models
import studies
from designs.pid import PID, pd_design
from designs.statespace import second_order_poles
from models.specs import Specs
from mpc import MPCSettings
from studies import providers
from studies.case import CaseStudy, input_disturbance, step
from studies.homework import ClassicalDesign, StateSpaceChoices, record

M, K, B, LIMIT = 1.0, 4.0, 1.2, 20.0  # kg, N/m, N s/m, N
STEP, DISTURBANCE = 0.5, 2.0  # m, N


@models.declare(
    name="example_mass_spring_damper",
    title="mass on a spring and a damper",
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
    """PD placing the poles at ω_n = 3 rad/s, ζ = 0.8; the same PD with an integrator."""
    G = known.linearize().tf("x", "F")
    pd = pd_design(G, zeta=0.8, wn=3.0)
    timing = dict(sample_period=CASE.sample_period, sigma=CASE.derivative_time_constant)  # the case's Ts, σ (s)
    blocks = {
        "PD": PID(known, "x", kp=pd.kp, kd=pd.kd, output_limit=LIMIT, name="PD", **timing),
        "PID": PID(known, "x", kp=pd.kp, kd=pd.kd, ki=12.0, output_limit=LIMIT, name="PID", **timing),
    }
    return ClassicalDesign({"VII.8": record(kp=pd.kp, kd=pd.kd)}, blocks)


CASE = CaseStudy(
    plant="example_mass_spring_damper",
    numeral="VII",
    tracked="x",
    design_step=STEP,
    step=STEP,
    input_disturbance=DISTURBANCE,
    duration=10.0,
    tracked_unit="m",
    input_unit="N",
    scenarios=(step(), input_disturbance()),
    providers=providers.STANDARD,  # its own designs below, by kind: classical, state space, MPC, tuned
    answer_providers=providers.STANDARD_ANSWERS,
    known_rel=0.05,  # the designs see m, k and b 5 % off, as in the six case studies
    specs={
        "*": Specs(
            max_settling_time_s=3.0, max_overshoot_pct=10.0, max_ss_error_pct=2.0, source="this example's choice"
        )
    },
    classical=classical,
    statespace=StateSpaceChoices(
        poles=lambda known: second_order_poles(3.0, 0.8),
        bryson_maxima={"x": 0.5},
        items=lambda r: {"VII.15(f)": r["feedback"], "LQR": r["LQR"]},
    ),
    mpc=MPCSettings(0.05, 40, (100.0, 1.0), 1e-2),
)


def main(out: str | None = None) -> None:
    studies.register(CASE)
    result = studies.run_study(CASE.name, mc=0, out=out)
    table = result.table
    with_columns = table[["controller", "scenario", "verdict", "settling_time_s", "overshoot_pct", "ss_error"]]
    print(with_columns.to_string(index=False, float_format=lambda v: f"{v:.6g}"))
    pd_step = table[(table.controller == "PD") & (table.scenario == "step")].iloc[0]
    print(f"PD steady-state error on the step = {pd_step.ss_error:.10g} m")
    print("PD designed on the nominal plant (the answers):", result.answers["VII.8"])
    if out:
        print(f"files written to {out}/{CASE.name}/ (open table.md and answers.md)")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else None)
