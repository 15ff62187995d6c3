"""Least-effort transfer of a mass on a spring, posed as an optimal control problem.

Move the mass from rest at x = 0 to rest at x = 1 m in 2 s with the least
∫ F² dt: `mpc.OptimalControlProblem` on a plant of your own, transcribed by
direct collocation, solved by IPOPT, then re-simulated on the plant (see docs/ocp.md).

    python examples/optimal_control.py
"""

import models
import mpc

M, K = 1.0, 4.0  # kg, N/m
DISTANCE, FINAL_TIME, INTERVALS = 1.0, 2.0, 50  # m, s, held inputs


@models.declare(
    name="my_spring_mass",
    title="mass on a spring",
    coordinates=("x",),
    inputs=("F",),
    params=(models.Param("m", M, "kg"), models.Param("k", K, "N/m")),
    input_limit=100.0,
    register=False,
)
def spring_mass(q, dq, u, p):
    return models.Physics(kinetic=p.m * dq.x**2 / 2, potential=p.k * q.x**2 / 2, forces=[u.F], outputs={"x": q.x})


def main() -> None:
    plant = models.Plant(spring_mass)
    ocp = mpc.OptimalControlProblem(plant, final_time=FINAL_TIME)
    ocp.minimize(ocp.integral(ocp.u.F**2))
    ocp.subject_to(ocp.at_start(ocp.state) == [0.0, 0.0])
    ocp.subject_to(ocp.at_end(ocp.state) == [DISTANCE, 0.0])
    solution = ocp.solve(mpc.Collocation(intervals=INTERVALS, degree=3))
    print(f"status = {solution.status}")
    print(f"minimum effort = {solution.objective:.10g} N^2 s")
    print(f"largest force = {abs(solution.inputs).max():.6g} N")
    check = solution.verify()  # the optimal input re-simulated on the plant by CVODES
    print(f"largest state defect on re-simulation = {check.max_defect:.3g}")


if __name__ == "__main__":
    main()
