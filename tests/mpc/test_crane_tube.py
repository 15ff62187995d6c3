"""The crane's tube (docs/robust_mpc.md, "Tube MPC on the crane"): with the ±5 % box's parametric error
in W, the construction is refused at once, naming the swing bounds and the least margin each needs,
which the minimal RPI set's support (a truncated sum computed here) confirms is above 0.2 rad; with
the text's 500 N input disturbance alone, the tube (Z = F(α, s) as a zonotope) and a TubeMPC on the
case's MPC weights and horizon construct from rest."""

from __future__ import annotations

import re

import numpy as np
import pytest

import models
import studies
from models.uncertainty import corner_params
from mpc.sets import Polytope, Zonotope
from mpc.tube import TubeOptions, ancillary_feedback, build_tube, disturbance_set
from mpc.tube_mpc import TubeMPC

#: The region the tube holds (x, θ1, θ2, ẋ, θ̇1, θ̇2): the stated ±5 m travel, the ±0.2 rad swing limits
#: (crane.STATE_LIMITS), ±2 m/s and ±1 rad/s; the ancillary LQR is the case's MPC weights.
REGION = np.array([5.0, 0.2, 0.2, 2.0, 1.0, 1.0])
NAMES = [f"{s} {side}" for side in ("upper", "lower") for s in ("x", "theta1", "theta2", "dx", "dtheta1", "dtheta2")]


@pytest.fixture(scope="module")
def crane():
    plant, case = models.get("crane"), studies.get("crane")
    known = case.known_plant(plant)
    xe, ue = known.equilibrium()
    model = known.linearize(xe, ue).discretize(case.mpc.sample_period)
    K = ancillary_feedback(model.A, model.B, np.diag(case.mpc.state_weight), case.mpc.input_weight)
    corners = [plant.linearize(xe, ue, params=p).discretize(case.mpc.sample_period) for p in corner_params(plant)]
    return plant, case, model, K, corners


def minimal_rpi_support(closed_loop, W, d, terms: int = 4000) -> float:
    """h_{F_∞}(d) = Σ_i h_W((A_K^i)ᵀ d), truncated where ρ(A_K)^terms is below 1e-28 (ρ ≈ 0.984)."""
    total, d = 0.0, np.asarray(d, dtype=float)
    for _ in range(terms):
        total += float(W.support(d)[0])
        d = d @ closed_loop
    return total


def test_the_parametric_tube_is_refused_naming_the_swing_bounds_and_their_least_margins(crane):
    plant, case, model, K, corners = crane
    umax = plant.input_limit
    W = disturbance_set(
        model.A,
        model.B,
        input_bound=case.input_disturbance,
        vertex_models=[(m.A, m.B) for m in corners],
        state_lower=-REGION,
        state_upper=REGION,
        input_lower=-umax,
        input_upper=umax,
    ).plus(Zonotope.box(-1e-6 * np.ones(6), 1e-6 * np.ones(6)))
    X = Polytope.box(-REGION, REGION)
    with pytest.raises(ValueError, match="for every RPI set of this K and W") as refusal:
        build_tube(model.A, model.B, W, X, -umax, umax, feedback=K, state_constraint_names=NAMES)
    message = str(refusal.value)
    for index, name in ((1, "theta1 upper"), (2, "theta2 upper")):
        found = re.search(
            rf"'{name}' lacks at least [\d.e-]+ \(bound 0\.2, needs a margin of at least ([\d.]+)\)", message
        )
        assert found, message
        least = minimal_rpi_support(model.A + model.B @ K, W, np.eye(6)[index])
        assert 0.2 < float(found.group(1)) <= least * (1 + 1e-9)  # true, and a bound the swing cannot hold
        assert float(found.group(1)) >= 0.99 * least


def test_the_disturbance_tube_and_its_mpc_construct(crane):
    plant, case, model, K, _ = crane
    umax = plant.input_limit
    W = disturbance_set(model.A, model.B, input_bound=case.input_disturbance)
    W = W.plus(Zonotope.box(-1e-6 * np.ones(6), 1e-6 * np.ones(6)))
    X = Polytope.box(-REGION, REGION)
    tube = build_tube(
        model.A,
        model.B,
        W,
        X,
        -umax,
        umax,
        feedback=K,
        state_constraint_names=NAMES,
        options=TubeOptions(zonotope=True),
    )
    for index in (1, 2):  # the swing margins: F(α, s)'s support, within 1 % above the minimal RPI set's
        least = minimal_rpi_support(tube.closed_loop, W, np.eye(6)[index])
        assert least <= tube.state_margins[index] <= least / (1 - 0.01)
        assert tube.state_margins[index] < 0.1 * 0.2  # the swing bound keeps over 90 % of its room
    controller = TubeMPC(
        model,
        tube,
        horizon=case.mpc.horizon,
        state_weight=np.diag(case.mpc.state_weight),
        input_weight=case.mpc.input_weight,
        initial_state=np.zeros(6),
    )
    z = controller.initial_state(np.zeros(6))
    z, u = controller.step(z, np.zeros(6))
    np.testing.assert_allclose(u, 0.0, atol=1e-6)  # at rest at the operating point: no move
