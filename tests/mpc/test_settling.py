"""Every plant, both MPCs, on the case study's step with ±5 % parameter error and the
text's input disturbance, run on the nonlinear plant: the command stays within the
actuator limit at every sample (exactly), the tracked coordinate settles to |e| < 1e-3
over the last 10 % of the case's duration, and the physical soft bounds hold on the
true plant. Slow (about two minutes): run with ``-m slow``."""

import numpy as np
import pytest

import models
import studies
from mpc import physical_soft_bounds

RUNS = [(name, kind, sign) for name in models.names() for kind in ("linear", "nonlinear") for sign in (1, -1)]


@pytest.mark.slow
@pytest.mark.parametrize("name, kind, sign", RUNS)
def test_step_settles_within_limits_under_mismatch_and_disturbance(name, kind, sign, build_mpc, mpc_settings):
    plant = models.get(name)
    case = studies.get("crane" if name == "crane1" else name)
    known = models.perturbed(plant, 0.05, sign)
    controller = build_mpc(kind, name, known)
    index = plant.state_names.index(case.tracked)
    reference = plant.equilibrium()[0][index] + case.step
    result = models.simulate_closed_loop(
        plant, controller, reference, case.duration, input_disturbance=case.input_disturbance
    )

    limit = plant.input_limit
    assert np.all(np.abs(result.u) <= limit)
    error = result.x[:, index] - reference
    settled = result.t >= 0.9 * case.duration
    assert np.max(np.abs(error[settled])) < 1e-3
    for bound, row, lower, upper in physical_soft_bounds(mpc_settings(name)[0], plant):
        value = result.x @ row
        assert lower <= value.min() and value.max() <= upper, bound
    failed = sum(not s["success"] for s in result.status)
    assert failed <= 0.01 * len(result.status)
