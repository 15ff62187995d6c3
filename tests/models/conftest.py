import pytest

import models


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
