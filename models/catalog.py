"""The case studies' plants, each declared once by its energies and forces.

Parameter values are the case study's. Angles in rad, SI units throughout.
Dissipation enters as generalized forces; nothing here is an equation of
motion: `models.lagrangian` derives those.
"""

from __future__ import annotations

from casadi import cos, sin

from .plant import Param, Physics, declare


def _damping(value: float, unit: str) -> Param:
    """The viscous damping parameter b, which may be zero."""
    return Param("b", value, unit, "viscous damping", positive=False)


@declare(
    name="arm",
    title="Single link robot arm (case study I)",
    coordinates=("theta",),
    inputs=("tau",),
    params=(
        Param("m", 0.5, "kg", "arm mass"),
        Param("ell", 0.3, "m", "arm length"),
        Param("g", 9.8, "m/s^2", "gravity"),
        _damping(0.01, "N m s/rad"),
    ),
    input_limit=1.0,
    operating_point=lambda p: {"theta": 0.0},
    uncertain=("m", "ell"),
)
def arm(q, dq, u, p):
    """Uniform rod of mass m, length ell, pivoted at one end; theta from level."""
    inertia = p.m * p.ell**2 / 3
    return Physics(
        kinetic=inertia * dq.theta**2 / 2,
        potential=p.m * p.g * p.ell / 2 * sin(q.theta),
        forces=[u.tau - p.b * dq.theta],
        outputs={"theta": q.theta},
    )


@declare(
    name="pendulum",
    title="Pendulum on a cart (case study II)",
    coordinates=("z", "theta"),
    inputs=("F",),
    params=(
        Param("m1", 0.25, "kg", "bob (point) mass"),
        Param("m2", 1.0, "kg", "cart mass"),
        Param("ell", 0.5, "m", "massless rod length"),
        Param("g", 9.8, "m/s^2", "gravity"),
        _damping(0.05, "N s/m"),
    ),
    input_limit=5.0,
    operating_point=lambda p: {"z": 0.0, "theta": 0.0},
    uncertain=("m1", "m2", "ell", "b"),
)
def pendulum(q, dq, u, p):
    """Cart at z; bob at (z + ell sin theta, ell cos theta), theta from straight up."""
    bob_vx = dq.z + p.ell * cos(q.theta) * dq.theta
    bob_vy = -p.ell * sin(q.theta) * dq.theta
    return Physics(
        kinetic=p.m2 * dq.z**2 / 2 + p.m1 * (bob_vx**2 + bob_vy**2) / 2,
        potential=p.m1 * p.g * p.ell * cos(q.theta),
        forces=[u.F - p.b * dq.z, 0],
        outputs={"z": q.z, "theta": q.theta},
    )


@declare(
    name="satellite",
    title="Satellite with flexible panels (case study III)",
    coordinates=("theta", "phi"),
    inputs=("tau",),
    params=(
        Param("Js", 5.0, "kg m^2", "body inertia"),
        Param("Jp", 1.0, "kg m^2", "panel inertia"),
        Param("k", 0.15, "N m/rad", "panel stiffness"),
        _damping(0.05, "N m s/rad"),
    ),
    input_limit=5.0,
    operating_point=lambda p: {"theta": 0.0, "phi": 0.0},
    uncertain=("Js", "Jp", "k", "b"),
)
def satellite(q, dq, u, p):
    """Body angle theta and panel angle phi from inertial; spring and damper between them."""
    twist_rate = dq.phi - dq.theta
    return Physics(
        kinetic=p.Js * dq.theta**2 / 2 + p.Jp * dq.phi**2 / 2,
        potential=p.k * (q.phi - q.theta) ** 2 / 2,
        forces=[u.tau + p.b * twist_rate, -p.b * twist_rate],
        outputs={"theta": q.theta, "phi_minus_theta": q.phi - q.theta},
    )


@declare(
    name="uuv",
    title="UUV roll (case study IV)",
    coordinates=("phi",),
    inputs=("tau",),
    params=(
        Param("J", 45.0, "kg m^2", "roll inertia"),
        Param("m", 200.0, "kg", "mass"),
        Param("L", 0.03, "m", "centre of mass to centre of buoyancy"),
        _damping(5.0, "N m s/rad"),
        Param("g", 9.81, "m/s^2", "gravity"),
    ),
    input_limit=50.0,
    operating_point=lambda p: {"phi": 0.0},
    uncertain=("m", "b", "L"),
)
def uuv(q, dq, u, p):
    """Roll phi; the gravity-buoyancy couple m g L sin(phi) restores it."""
    return Physics(
        kinetic=p.J * dq.phi**2 / 2,
        potential=p.m * p.g * p.L * (1 - cos(q.phi)),
        forces=[u.tau - p.b * dq.phi],
        outputs={"phi": q.phi},
    )


@declare(
    name="ballbeam",
    title="Ball on beam (case study V)",
    coordinates=("z", "theta"),
    inputs=("F",),
    params=(
        Param("m1", 0.35, "kg", "ball (point) mass"),
        Param("m2", 2.0, "kg", "beam mass"),
        Param("ell", 0.5, "m", "beam length"),
        Param("g", 9.8, "m/s^2", "gravity"),
    ),
    input_limit=15.0,
    operating_point=lambda p: {"z": p.ell / 2},
    uncertain=("m1", "m2", "ell"),
)
def ballbeam(q, dq, u, p):
    """Ball at z along a uniform beam pivoted at one end; F at the tip, normal to the beam."""
    beam_inertia = p.m2 * p.ell**2 / 3
    return Physics(
        kinetic=p.m1 * (dq.z**2 + (q.z * dq.theta) ** 2) / 2 + beam_inertia * dq.theta**2 / 2,
        potential=(p.m1 * q.z + p.m2 * p.ell / 2) * p.g * sin(q.theta),
        # Virtual work of F normal to the beam at distance ell: F ell dtheta.
        forces=[0, u.F * p.ell],
        outputs={"z": q.z, "theta": q.theta},
    )


# The text gives no force limit for the crane. 5 kN accelerates the 2.2 t of
# cart and loads at up to 2.3 m/s^2, an industrial gantry's range, and makes the
# text's 10 m step (VI.14(e)) saturate the classical and pole-placement designs.
CRANE_FORCE_LIMIT = 5000.0


@declare(
    name="crane",
    title="Gantry crane with two slung loads (case study VI)",
    coordinates=("x", "theta1", "theta2"),
    inputs=("F",),
    params=(
        Param("mc", 1500.0, "kg", "car mass"),
        Param("m1", 500.0, "kg", "load 1 mass"),
        Param("m2", 200.0, "kg", "load 2 mass"),
        _damping(200.0, "N s/m"),
        Param("ell1", 10.0, "m", "cable 1 length"),
        Param("ell2", 24.0, "m", "cable 2 length"),
        Param("g", 9.81, "m/s^2", "gravity"),
    ),
    input_limit=CRANE_FORCE_LIMIT,
    operating_point=lambda p: {"x": 0.0, "theta1": 0.0, "theta2": 0.0},
    uncertain=("mc", "m1", "m2", "b", "ell1", "ell2"),
)
def crane(q, dq, u, p):
    """Car at x; load i at (x + ell_i sin theta_i, -ell_i cos theta_i), theta from downward vertical."""
    kinetic = p.mc * dq.x**2 / 2
    potential = 0
    for m, ell, th, dth in ((p.m1, p.ell1, q.theta1, dq.theta1), (p.m2, p.ell2, q.theta2, dq.theta2)):
        kinetic += m * ((dq.x + ell * cos(th) * dth) ** 2 + (ell * sin(th) * dth) ** 2) / 2
        potential += -m * p.g * ell * cos(th)
    return Physics(
        kinetic=kinetic,
        potential=potential,
        forces=[u.F - p.b * dq.x, 0, 0],
        outputs={"x": q.x, "theta1": q.theta1, "theta2": q.theta2},
    )


@declare(
    name="crane1",
    title="Gantry crane with one slung load (case study VI.8)",
    coordinates=("x", "theta"),
    inputs=("F",),
    params=(
        Param("mc", 1500.0, "kg", "car mass"),
        Param("m", 500.0, "kg", "load mass"),
        Param("ell", 10.0, "m", "cable length"),
        _damping(200.0, "N s/m"),
        Param("g", 9.81, "m/s^2", "gravity"),
    ),
    input_limit=CRANE_FORCE_LIMIT,
    operating_point=lambda p: {"x": 0.0, "theta": 0.0},
    uncertain=("mc", "m", "ell", "b"),
)
def crane1(q, dq, u, p):
    """Car at x; load at (x + ell sin theta, -ell cos theta), theta from downward vertical."""
    return Physics(
        kinetic=p.mc * dq.x**2 / 2
        + p.m * ((dq.x + p.ell * cos(q.theta) * dq.theta) ** 2 + (p.ell * sin(q.theta) * dq.theta) ** 2) / 2,
        potential=-p.m * p.g * p.ell * cos(q.theta),
        forces=[u.F - p.b * dq.x, 0],
        outputs={"x": q.x, "theta": q.theta},
    )


# Not a case study's plant: the spring and mass whose stiffness `studies.codesign_open_loop` decides
# together with the force history. Declared without registering it, so `models.names()` (and every
# study, test and sweep over the registry) still lists the case studies' plants only.
@declare(
    name="spring_mass",
    title="spring and mass (issue 13)",
    coordinates=("s",),
    inputs=("u",),
    params=(Param("m", 1.0, "kg", "mass"), Param("k", 0.5, "N/m", "stiffness")),
    input_limit=1.0,
    register=False,
)
def spring_mass(q, dq, u, p):
    """Mass m on a spring of stiffness k, pushed by the force u: m s'' = −k s + u, s from the spring at rest."""
    return Physics(kinetic=p.m * dq.s**2 / 2, potential=p.k * q.s**2 / 2, forces=[u.u], outputs={"s": q.s})
