"""One rule for showing a state (studies.style.display_unit), used by the trajectory plots and the animation."""

import math

import pytest

import models
from studies import animation, style


@pytest.mark.parametrize(
    "name, expected",
    [
        ("theta", (180 / math.pi, "deg")),
        ("dphi", (180 / math.pi, "deg/s")),
        ("theta2", (180 / math.pi, "deg")),
        ("z", (1.0, "m")),
        ("dx", (1.0, "m/s")),
    ],
)
def test_angles_show_in_degrees_and_lengths_in_metres(name, expected):
    assert style.display_unit(name) == expected


def test_the_animation_readout_uses_the_same_units():
    plant = models.get("pendulum")  # q = (z, theta)
    x = [0.12345, math.pi / 4, 3.0, -2.0]
    assert animation.readout(plant, x) == "z = 0.123 m, theta = 45.0 deg"
