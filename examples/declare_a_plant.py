"""Declare your own plant, then linearize, simulate and design a PD for it.

A mass on a spring and a damper, declared by its energies: CasADi derives the
equation of motion m ẍ = F − k x − b ẋ, its Jacobians and the simulators.

    python examples/declare_a_plant.py
"""

import numpy as np

import models
from designs.pid import pd_design

M, K, B = 2.0, 8.0, 1.6  # kg, N/m, N s/m: ω_n = 2 rad/s, ζ = 0.2
FORCE = 4.0  # N, the step of force applied from rest
DURATION = 6.0  # s


@models.declare(
    name="my_mass_spring_damper",
    title="mass on a spring and a damper",
    coordinates=("x",),
    inputs=("F",),
    params=(models.Param("m", M, "kg"), models.Param("k", K, "N/m"), models.Param("b", B, "N s/m")),
    input_limit=50.0,
    register=False,
)  # register=False: a plant of your own, not in models.get
def mass_spring_damper(q, dq, u, p):
    return models.Physics(
        kinetic=p.m * dq.x**2 / 2, potential=p.k * q.x**2 / 2, forces=[u.F - p.b * dq.x], outputs={"x": q.x}
    )


def main() -> None:
    plant = models.Plant(mass_spring_damper)
    xe, ue = plant.equilibrium(x=0.0)
    lin = plant.linearize(xe, ue)
    print("A =", lin.A.tolist())
    print("B =", lin.B.tolist())
    G = lin.tf("x", "F")
    print("G(s) =", models.linear.tf_string(G))
    poles = np.linalg.eigvals(lin.A)
    wn = float(np.sqrt(np.prod(poles).real))
    print(f"natural frequency = {wn:.10g} rad/s")
    print(f"damping ratio = {-poles.real.sum() / (2 * wn):.10g}")

    # A constant force from rest, held for DURATION s (RK4, 10 steps per 0.01 s sample).
    steps = int(round(DURATION / 0.01))
    run = models.simulate(plant, xe, np.full((steps, 1), FORCE), 0.01)
    print(f"x at {DURATION:g} s = {run.state('x')[-1]:.10g} m")

    # A PD placing the closed-loop poles at ω_n = 4 rad/s, ζ = 0.7 (u = k_p (r − x) − k_d ẋ).
    pd = pd_design(G, zeta=0.7, wn=4.0)
    print(f"kp = {pd.kp:.10g} N/m")
    print(f"kd = {pd.kd:.10g} N s/m")


if __name__ == "__main__":
    main()
