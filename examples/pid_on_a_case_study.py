"""Design a PD, a PID and an LQR for the single-link arm, then run them on the nonlinear arm.

The designs see the model the case study says the controller knows (the arm's
mass and length 5 % off); the simulations run the true nonlinear arm, gravity
and the 1 N m actuator limit included.

    python examples/pid_on_a_case_study.py
"""

import numpy as np

import models
import studies
from designs import statespace_design
from designs.pid import PID, pd_design
from designs.statespace import second_order_poles
from models.metrics import run_metrics

REFERENCE = np.deg2rad(50)  # rad, the text's step
DURATION = 8.0  # s
WN, ZETA = 10.0, 0.707  # rad/s and damping ratio of the PD's closed loop


def main() -> None:
    case = studies.get("arm")
    known = case.known_plant()  # m and ell 5 % off: what the controller believes
    truth = models.get("arm")
    limit = float(known.input_limit[0])
    timing = dict(sample_period=case.sample_period, sigma=case.derivative_time_constant)  # s: the case's Ts and σ

    G = known.linearize().tf("theta", "tau")  # about theta = 0 (level)
    pd = pd_design(G, zeta=ZETA, wn=WN)
    print(f"PD gains: kp = {pd.kp:.10g} N m/rad, kd = {pd.kd:.10g} N m s/rad")
    controllers = {
        # No gravity feedforward: the PD settles where k_p (r − θ) holds the arm up.
        "PD": PID(known, "theta", kp=pd.kp, kd=pd.kd, output_limit=limit, name="PD", **timing),
        "PID": PID(known, "theta", kp=pd.kp, kd=pd.kd, ki=2.0, output_limit=limit, name="PID", **timing),
    }
    # LQR with an integrator, Bryson's rule: 0.2 rad of error, 5 rad/s, 0.1 rad s of integral, the full torque.
    lqr = statespace_design.design(
        known,
        "theta",
        poles=second_order_poles(WN, ZETA),
        Q=np.diag([1 / 0.2**2, 1 / 5.0**2, 1 / 0.1**2]),
        R=[[1 / limit**2]],
        sample_period=case.sample_period,
    )
    controllers["LQR"] = statespace_design.controllers(lqr)["LQR"]

    print(
        f"{'controller':<11}{'rise s':>9}{'settle s':>10}{'overshoot %':>13}{'peak |u| N m':>14}{'final theta rad':>17}"
    )
    for label, controller in controllers.items():
        run = models.simulate_closed_loop(truth, controller, REFERENCE, DURATION)
        m = run_metrics(run, "theta")
        final = run.x[-1, truth.state_names.index("theta")]
        print(
            f"{label:<11}{m['rise_time_s']:>9.3f}{m['settling_time_s']:>10.3f}{m['overshoot_pct']:>13.2f}"
            f"{m['peak_u']:>14.3f}{final:>17.10f}"
        )


if __name__ == "__main__":
    main()
