import control
import pytest

import models
from models.linear_plant import LinearPlant


@pytest.fixture
def blow_up_plant():
    """A user-declared plant with q'' = 4 q³: from q = 1 at rest it escapes in finite time.

    E = q'²/2 − q⁴ = −1, so the escape time is ∫₁^∞ dq / √(2 (q⁴ − 1)) ≈ 0.927 s.
    """

    @models.declare(
        name="blowup",
        title="q'' = 4 q^3",
        coordinates=("q",),
        inputs=("u",),
        params=(models.Param("k", 1.0, "1"),),
        input_limit=1.0,
        register=False,
    )
    def blowup(q, dq, u, p):
        return models.Physics(kinetic=dq.q**2 / 2, potential=-p.k * q.q**4, forces=[u.u], outputs={"q": q.q})

    return models.Plant(blowup)


@pytest.fixture(scope="module")
def pendulum_plants():
    """The declared pendulum on a cart and a python-control StateSpace of its linearization (a models.LinearPlant),
    same limit."""
    declared = models.get("pendulum")
    lin = declared.linearize()
    sys = control.ss(
        lin.A,
        lin.B,
        lin.C,
        lin.D,
        states=list(lin.state_names),
        inputs=list(lin.input_names),
        outputs=list(lin.output_names),
        name="pendulum",
    )
    user = LinearPlant(sys, declared.input_limit, xe=lin.xe, ue=lin.ue)
    return declared, user
