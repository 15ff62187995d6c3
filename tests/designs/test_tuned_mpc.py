"""The weight-parameterized MPC settings: θ round-trips through the settings record."""

import numpy as np
import pytest

from designs import tuned_mpc
from mpc import MPCSettings, SoftSpec

SOFT = (SoftSpec("cart", {"z": 1.0}, -1.0, 1.0),)


@pytest.mark.parametrize("soft", [(), SOFT])
def test_settings_round_trip(soft):
    base = MPCSettings(0.05, 20, (10.0, 0.5), 0.2, soft=soft, soft_linear_weight=300.0, soft_quadratic_weight=20.0)
    theta = tuned_mpc.log_weights(base)
    assert theta.size == tuned_mpc.size(base) == (5 if soft else 3)
    again = tuned_mpc.settings(base, theta)
    assert again.state_weight == pytest.approx(base.state_weight) and again.input_weight == pytest.approx(0.2)
    moved = tuned_mpc.settings(base, theta + np.log(2.0))
    assert moved.state_weight == pytest.approx((20.0, 1.0)) and moved.input_weight == pytest.approx(0.4)
    assert moved.horizon == 20 and moved.soft == soft
    if soft:
        assert (moved.soft_linear_weight, moved.soft_quadratic_weight) == pytest.approx((600.0, 40.0))
    else:
        assert moved.soft_linear_weight == base.soft_linear_weight


def test_bad_weights_are_refused():
    with pytest.raises(ValueError, match="> 0"):
        tuned_mpc.log_weights(MPCSettings(0.05, 20, (10.0, 0.0), 0.2))
    with pytest.raises(ValueError, match="entries"):
        tuned_mpc.settings(MPCSettings(0.05, 20, (10.0, 1.0), 0.2), [0.0, 0.0])
