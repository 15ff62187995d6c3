"""Plant models against independent references: finite differences, hand-derived
linearizations, the power balance of a Lagrangian system, and equilibrium residuals."""

import numpy as np
import pytest

import models
from models.plant import declaration

#: The catalog's plants: the references below are theirs. Not every registered name: a test module may
#: register a plant of its own at collection (tests/studies/test_extra_case.py), before or after this one.
ALL = [name for name in models.names() if declaration(name).physics.__module__ == "models.catalog"]


def _random_points(plant, rng, n=20):
    for _ in range(n):
        q = rng.uniform(-1.0, 1.0, plant.nq)
        if plant.name == "ballbeam":
            q[0] = rng.uniform(0.05, 0.5)
        dq = rng.uniform(-1.0, 1.0, plant.nq)
        u = rng.uniform(-1.0, 1.0, plant.nu) * plant.input_limit
        yield np.concatenate([q, dq]), u


@pytest.mark.parametrize("name", ALL)
def test_jacobians_equal_central_differences(name):
    plant = models.get(name)
    rng = np.random.default_rng(1)
    for x, u in _random_points(plant, rng):
        lin = plant.linearize(x, u, check=False)
        h = 1e-6
        A_fd = np.column_stack([(plant.f(x + h * e, u) - plant.f(x - h * e, u)) / (2 * h) for e in np.eye(plant.nx)])
        B_fd = np.column_stack([(plant.f(x, u + h * e) - plant.f(x, u - h * e)) / (2 * h) for e in np.eye(plant.nu)])
        C_fd = np.column_stack(
            [(plant.output(x + h * e) - plant.output(x - h * e)) / (2 * h) for e in np.eye(plant.nx)]
        )
        for exact, fd in ((lin.A, A_fd), (lin.B, B_fd), (lin.C, C_fd)):
            scale = max(1.0, np.max(np.abs(exact)))
            np.testing.assert_allclose(exact, fd, rtol=1e-6, atol=1e-6 * scale)


@pytest.mark.parametrize("name", ALL)
def test_power_balance(name):
    """dE/dt = q̇ᵀ Q_nc for a Lagrangian system: checks M, C and ∂V/∂q together.

    Q_nc here is written from the physics (input and damping work), not read
    from the model; dE/dt is a finite difference of the energy along f.
    """
    plant = models.get(name)
    p = plant.params
    rng = np.random.default_rng(2)
    for x, u in _random_points(plant, rng):
        dq = x[plant.nq :]
        power = {
            "arm": lambda u, dq: (u[0] - p["b"] * dq[0]) * dq[0],
            "pendulum": lambda u, dq: (u[0] - p["b"] * dq[0]) * dq[0],
            "satellite": lambda u, dq: u[0] * dq[0] - p["b"] * (dq[1] - dq[0]) ** 2,
            "uuv": lambda u, dq: (u[0] - p["b"] * dq[0]) * dq[0],
            # The tip moves at ell * dtheta normal to the beam, along F.
            "ballbeam": lambda u, dq: u[0] * p["ell"] * dq[1],
            "crane": lambda u, dq: (u[0] - p["b"] * dq[0]) * dq[0],
            "crane1": lambda u, dq: (u[0] - p["b"] * dq[0]) * dq[0],
        }[name](u, dq)
        h = 1e-6
        xdot = plant.f(x, u)
        dE = (plant.energy(x + h * xdot) - plant.energy(x - h * xdot)) / (2 * h)
        assert dE == pytest.approx(power, rel=1e-6, abs=1e-6 * max(1.0, abs(plant.energy(x))))


def _hand_linearization(name, p):
    """Closed forms derived by hand (see the docstrings of models.catalog)."""
    if name == "arm":
        J = p["m"] * p["ell"] ** 2 / 3
        return np.array([[0, 1], [0, -p["b"] / J]]), np.array([[0], [1 / J]])
    if name == "pendulum":
        m1, m2, ell, g, b = (p[k] for k in ("m1", "m2", "ell", "g", "b"))
        # z'' = (F - b z' - m1 g θ)/m2 ; θ'' = (g θ - z'')/ell
        A = np.zeros((4, 4))
        A[0, 2] = A[1, 3] = 1
        A[2] = [0, -m1 * g / m2, -b / m2, 0]
        A[3] = [0, (g + m1 * g / m2) / ell, b / (m2 * ell), 0]
        return A, np.array([[0], [0], [1 / m2], [-1 / (m2 * ell)]])
    if name == "satellite":
        Js, Jp, k, b = (p[n] for n in ("Js", "Jp", "k", "b"))
        A = np.array(
            [[0, 0, 1, 0], [0, 0, 0, 1], [-k / Js, k / Js, -b / Js, b / Js], [k / Jp, -k / Jp, b / Jp, -b / Jp]]
        )
        return A, np.array([[0], [0], [1 / Js], [0]])
    if name == "uuv":
        J, m, L, b, g = (p[n] for n in ("J", "m", "L", "b", "g"))
        return np.array([[0, 1], [-m * g * L / J, -b / J]]), np.array([[0], [1 / J]])
    if name == "ballbeam":
        m1, m2, ell, g = (p[n] for n in ("m1", "m2", "ell", "g"))
        ze = ell / 2
        Jeq = m1 * ze**2 + m2 * ell**2 / 3
        A = np.zeros((4, 4))
        A[0, 2] = A[1, 3] = 1
        A[2, 1] = -g
        A[3, 0] = -m1 * g / Jeq
        return A, np.array([[0], [0], [0], [ell / Jeq]])
    if name == "crane":
        mc, m1, m2, b, l1, l2, g = (p[n] for n in ("mc", "m1", "m2", "b", "ell1", "ell2", "g"))
        # mc x'' = F - b x' + m1 g θ1 + m2 g θ2 ;  θi'' = (-g θi - x'')/ell_i
        xdd = np.array([0, m1 * g / mc, m2 * g / mc, -b / mc, 0, 0])
        A = np.zeros((6, 6))
        A[0:3, 3:6] = np.eye(3)
        A[3] = xdd
        A[4] = -xdd / l1 - np.array([0, g / l1, 0, 0, 0, 0])
        A[5] = -xdd / l2 - np.array([0, 0, g / l2, 0, 0, 0])
        B = np.array([[0], [0], [0], [1 / mc], [-1 / (mc * l1)], [-1 / (mc * l2)]])
        return A, B
    if name == "crane1":
        mc, m, ell, b, g = (p[n] for n in ("mc", "m", "ell", "b", "g"))
        xdd = np.array([0, m * g / mc, -b / mc, 0])
        A = np.zeros((4, 4))
        A[0:2, 2:4] = np.eye(2)
        A[2] = xdd
        A[3] = -xdd / ell - np.array([0, g / ell, 0, 0])
        return A, np.array([[0], [0], [1 / mc], [-1 / (mc * ell)]])
    raise KeyError(name)


@pytest.mark.parametrize("name", ALL)
def test_linearization_equals_hand_derivation(name):
    plant = models.get(name)
    lin = plant.linearize()
    A, B = _hand_linearization(name, plant.params)
    np.testing.assert_allclose(lin.A, A, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(lin.B, B, rtol=1e-12, atol=1e-14)


def test_hand_linearization_holds_off_nominal_parameters():
    plant = models.get("crane", m1=321.0, ell2=17.0, b=0.0)
    A, B = _hand_linearization("crane", plant.params)
    lin = plant.linearize()
    np.testing.assert_allclose(lin.A, A, atol=1e-12)
    np.testing.assert_allclose(lin.B, B, atol=1e-14)


def test_arm_linearization_at_a_raised_angle():
    arm = models.get("arm")
    p = arm.params
    theta = 0.5
    xe, ue = arm.equilibrium(theta=theta)
    assert ue[0] == pytest.approx(p["m"] * p["g"] * p["ell"] / 2 * np.cos(theta), rel=1e-12)
    J = p["m"] * p["ell"] ** 2 / 3
    lin = arm.linearize(xe, ue)
    np.testing.assert_allclose(
        lin.A, [[0, 1], [p["m"] * p["g"] * p["ell"] / 2 * np.sin(theta) / J, -p["b"] / J]], rtol=1e-12
    )


@pytest.mark.parametrize(
    "name,fixed",
    [
        ("arm", {"theta": 0.5}),
        ("arm", {}),
        ("pendulum", {}),
        ("pendulum", {"theta": np.pi}),
        ("satellite", {}),
        ("uuv", {}),
        ("uuv", {"phi": 0.3}),
        ("ballbeam", {"z": 0.25}),
        ("ballbeam", {"z": 0.4}),
        ("crane", {}),
        ("crane1", {"x": 3.0}),
    ],
)
def test_equilibrium_residual(name, fixed):
    plant = models.get(name)
    xe, ue = plant.equilibrium(**fixed)
    assert np.max(np.abs(plant.f(xe, ue))) < 1e-10
    for key, value in fixed.items():
        assert xe[plant.coordinate_names.index(key)] == pytest.approx(value)
    assert np.all(xe[plant.nq :] == 0)


def test_ballbeam_equilibrium_force_is_the_moment_balance():
    plant = models.get("ballbeam")
    p = plant.params
    _, ue = plant.equilibrium(z=0.4)
    # Moments about the pivot: F ell = m1 g z + m2 g ell / 2.
    assert ue[0] == pytest.approx((p["m1"] * p["g"] * 0.4 + p["m2"] * p["g"] * p["ell"] / 2) / p["ell"], rel=1e-12)


def test_uuv_equilibrium_torque_balances_the_righting_moment():
    plant = models.get("uuv")
    p = plant.params
    _, ue = plant.equilibrium(phi=0.3)
    assert ue[0] == pytest.approx(p["m"] * p["g"] * p["L"] * np.sin(0.3), rel=1e-12)


def test_equilibrium_input_is_the_static_feedforward():
    arm = models.get("arm")
    p = arm.params
    assert arm.equilibrium_input([0.7])[0] == pytest.approx(p["m"] * p["g"] * p["ell"] / 2 * np.cos(0.7), rel=1e-12)


def test_no_equilibrium_is_reported():
    with pytest.raises(ValueError, match="no equilibrium.*theta=0.3"):
        models.get("ballbeam").equilibrium(theta=0.3)


def test_output_map_of_the_satellite():
    sat = models.get("satellite")
    np.testing.assert_allclose(sat.output([0.1, 0.4, 0, 0]), [0.1, 0.3])
    np.testing.assert_allclose(sat.linearize().C, [[1, 0, 0, 0], [-1, 1, 0, 0]])


@pytest.mark.parametrize(
    "call,message",
    [
        (lambda: models.get("robot"), "unknown plant 'robot'; valid plants: arm, pendulum"),
        (lambda: models.get("arm", M=1.0), "arm has no parameter 'M'; its parameters are m, ell, g, b"),
        (lambda: models.get("arm", m=-0.5), r"parameter m \(kg\) must be finite and > 0"),
        (lambda: models.get("arm", m=0.0), r"must be finite and > 0"),
        (lambda: models.get("arm", b=-1e-3), r"parameter b .* >= 0"),
        (lambda: models.get("arm", ell=float("nan")), "must be finite"),
        (lambda: models.get("arm").f([0.0], [0.0]), r"state \('theta', 'dtheta'\) must have 2 entries"),
        (lambda: models.get("arm").f([0.0, np.inf], [0.0]), "non-finite"),
        (lambda: models.get("arm").f([0.0, 0.0], [0.0, 1.0]), "input .* must have 1 entries"),
        (lambda: models.get("arm").equilibrium(phi=0.1), "cannot fix 'phi'"),
        (lambda: models.get("arm").linearize([0.3, 0.0], [0.0]), "not an equilibrium"),
        (lambda: models.get("arm", input_limit=-1), "input_limit must be finite and > 0"),
    ],
)
def test_bad_input_names_the_culprit(call, message):
    with pytest.raises(ValueError, match=message):
        call()


def test_overrides_and_variants():
    assert models.get("uuv", input_limit=250).input_limit[0] == 250
    heavy = models.get("arm", m=0.6)
    assert heavy.params["m"] == 0.6 and models.get("arm").params["m"] == 0.5
    assert heavy.with_params(ell=0.4).params == {"m": 0.6, "ell": 0.4, "g": 9.8, "b": 0.01}


@pytest.mark.parametrize("name", ALL)
def test_configuration_is_recovered_from_the_outputs(name):
    plant = models.get(name)
    q = np.random.default_rng(3).uniform(-1, 1, plant.nq)
    y = plant.output(np.concatenate([q, np.zeros(plant.nq)]))
    np.testing.assert_allclose(np.asarray(plant.casadi_configuration(y, plant.param_vector())).ravel(), q, atol=1e-14)


def test_equilibrium_input_jacobian_of_the_ball_on_beam_and_the_arm():
    beam = models.get("ballbeam")
    p = beam.params
    # F_e ell = (m1 z + m2 ell / 2) g cos(theta): ∂/∂z = m1 g / ell, ∂/∂theta = 0 at theta = 0.
    np.testing.assert_allclose(beam.equilibrium_input_jacobian(), [[p["m1"] * p["g"] / p["ell"], 0.0]], atol=1e-14)
    arm = models.get("arm")
    a = arm.params
    np.testing.assert_allclose(
        arm.equilibrium_input_jacobian([0.4]), [[-a["m"] * a["g"] * a["ell"] / 2 * np.sin(0.4)]], rtol=1e-12
    )
