"""A plant's declaration checked (issue 31): its name is a safe identifier, its title free text; a physics
function reading a name the plant does not declare, or holding a non-finite number (an infinite mass),
gets an error naming the plant and what is wrong (`models.declare`, `models.physics`)."""

import math

import pytest

import models


def _declare(physics, *, coordinates=("q1",), **kwargs):
    """The plant "user" of `physics`, with one parameter m (kg) and one input u, not registered."""
    decl = models.declare(
        name="user",
        title="user plant",
        coordinates=coordinates,
        inputs=("u",),
        params=(models.Param("m", 1.0, "kg"),),
        input_limit=1.0,
        register=False,
        **kwargs,
    )(physics)
    return models.Plant(decl)


@pytest.mark.parametrize(
    "name", ["../evil<b>x</b>;rm -rf ~", "my plant", "my-plant", "2fast", "_hidden", "é", "a" * 65]
)
def test_a_plant_name_must_be_a_safe_identifier(name):
    """The name reaches file names, pages and C: before, '../evil<b>x</b>;rm -rf ~' was accepted."""
    with pytest.raises(
        ValueError, match=r"name must be a safe identifier \(a letter, then letters, digits or underscores"
    ):
        models.declare(
            name=name,
            title="user plant",
            coordinates=("q1",),
            inputs=("u",),
            params=(models.Param("m", 1.0, "kg"),),
            input_limit=1.0,
            register=False,
        )


def test_the_title_is_free_text():
    decl = models.declare(
        name="user_2",
        title="<b>My</b> arm & co; rm -rf ~",
        coordinates=("q1",),
        inputs=("u",),
        params=(models.Param("m", 1.0, "kg"),),
        input_limit=1.0,
        register=False,
    )(lambda q, dq, u, p: models.Physics(kinetic=p.m * dq.q1**2 / 2, forces=[u.u], outputs={"q1": q.q1}))
    assert models.Plant(decl).title == "<b>My</b> arm & co; rm -rf ~"


@pytest.mark.parametrize(
    "physics, message",
    [
        (
            lambda q, dq, u, p: models.Physics(kinetic=p.mass * dq.q1**2 / 2, forces=[u.u]),
            r"user: the physics function uses p\.mass, which is not declared; the parameters of user are: m$",
        ),
        (
            lambda q, dq, u, p: models.Physics(kinetic=p.m * dq.x**2 / 2, forces=[u.u]),
            r"user: the physics function uses dq\.x, which is not declared; the coordinates of user are: q1$",
        ),
        (
            lambda q, dq, u, p: models.Physics(kinetic=p.m * dq.q1**2 / 2, forces=[u.force]),
            r"user: the physics function uses u\.force, which is not declared; the inputs of user are: u$",
        ),
    ],
)
def test_an_undeclared_name_in_the_physics_is_named_with_the_declared_ones(physics, message):
    """Before: 'types.SimpleNamespace' object has no attribute 'mass', naming neither plant nor parameters."""
    with pytest.raises(AttributeError, match=message):
        _declare(physics, coordinates=("q1",))


def test_an_undeclared_parameter_in_the_operating_point_is_named():
    def physics(q, dq, u, p):
        return models.Physics(kinetic=p.m * dq.q1**2 / 2, potential=q.q1**2, forces=[u.u], outputs={"q1": q.q1})

    plant = _declare(physics, coordinates=("q1",), operating_point=lambda p: {"q1": p.length / 2})
    with pytest.raises(AttributeError, match=r"user: the operating point uses p\.length, which is not declared"):
        plant.equilibrium()


@pytest.mark.parametrize(
    "kinetic, potential, where",
    [
        (lambda dq, p: math.inf * dq.q1**2 / 2, 0.0, "the kinetic energy"),  # before: accepted, q1'' = 0
        (lambda dq, p: dq.q1**2 / (2 / math.inf), 0.0, "the kinetic energy"),  # before: "no kinetic energy term"
        (lambda dq, p: p.m * dq.q1**2 / 2, float("nan"), "the potential energy"),
    ],
)
def test_an_infinite_mass_is_refused_as_non_finite(kinetic, potential, where):
    def physics(q, dq, u, p):
        return models.Physics(kinetic=kinetic(dq, p), potential=potential * q.q1, forces=[u.u], outputs={"q1": q.q1})

    with pytest.raises(ValueError, match=rf"user: {where} holds the non-finite number (inf|nan)") as refused:
        _declare(physics, coordinates=("q1",))
    assert "must be finite" in str(refused.value) and "kinetic energy term" not in str(refused.value)


def test_a_non_finite_force_or_output_is_named():
    def physics(q, dq, u, p):
        return models.Physics(
            kinetic=p.m * dq.q1**2 / 2, forces=[u.u - math.inf * dq.q1], outputs={"q1": q.q1 * float("nan")}
        )

    with pytest.raises(ValueError, match=r"user: the generalized force of 'q1' holds the non-finite number inf"):
        _declare(physics, coordinates=("q1",))
