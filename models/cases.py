"""What each case study asks of its plant: the tracked coordinate, step sizes,
input disturbance and sample periods, as the text gives them.

Where the text gives no number, the choice is stated next to it: an input
disturbance of 10 % of the actuator limit, and a comparison step that keeps
the ball on the beam.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Case:
    """The text's numbers for one plant (SI units, angles in rad).

    Attributes
    ----------
    plant : registry name of the plant
    numeral : the case study's Roman numeral, prefix of its homework items ("I")
    tracked : the coordinate that follows the reference
    design_step : step on the tracked coordinate used by the saturation rules (.8)
    step : step commanded in the comparisons, from the standard equilibrium
    input_disturbance : constant input disturbance of the .16/.17 problems
    sample_period : controller sample period (.11)
    observer_sample_period : sample period of the observer problems (.15), where different
    duration : length of a step scenario, s
    source : where each number comes from
    """

    plant: str
    numeral: str
    tracked: str
    design_step: float
    step: float
    input_disturbance: float
    sample_period: float = 0.01
    observer_sample_period: float = 0.01
    duration: float = 10.0
    source: str = ""


CASES = {
    "arm": Case("arm", "I", "theta", np.deg2rad(50), np.deg2rad(50), 0.2, duration=5.0,
                source="I.8(c) step 50 deg; I.17(e) disturbance 0.2 N m; I.11 Ts = 0.01 s"),
    "pendulum": Case("pendulum", "II", "z", 2.0, 2.0, 0.5, duration=20.0,
                     source="II.8(h) step 2 m; II.16(c) disturbance 0.5 N; II.11 Ts = 0.01 s"),
    "satellite": Case("satellite", "III", "phi", np.deg2rad(30), np.deg2rad(30), 0.5, duration=60.0,
                      source="III.8(g) step 30 deg; III.16(c) disturbance 0.5 N m; III.11 Ts = 0.01 s"),
    "uuv": Case("uuv", "IV", "phi", np.deg2rad(30), np.deg2rad(30), 5.0, duration=10.0,
                source="IV.8(b) step 30 deg; no disturbance given: 10 % of 50 N m; IV.12 Ts = 0.01 s"),
    "ballbeam": Case("ballbeam", "V", "z", 0.25, 0.15, 1.5, observer_sample_period=0.001, duration=10.0,
                     source="V.8(h) design step 0.25 m; comparison step 0.25 -> 0.40 m keeps the ball "
                            "on the 0.5 m beam; no disturbance given: 10 % of 15 N; V.12 Ts = 0.01 s, "
                            "V.15 Ts = 0.001 s"),
    "crane": Case("crane", "VI", "x", 10.0, 10.0, 500.0, observer_sample_period=0.001, duration=60.0,
                  source="VI.14(e) step 10 m; no disturbance given: 10 % of 5 kN; VI.11 Ts = 0.01 s, "
                         "VI.15 Ts = 0.001 s"),
    "crane1": Case("crane1", "VI", "x", 10.0, 10.0, 500.0, observer_sample_period=0.001, duration=60.0,
                   source="as crane (VI.8 single load)"),
}


def case(name: str) -> Case:
    """The case record of plant `name` (ValueError listing the valid names otherwise)."""
    if name not in CASES:
        raise ValueError(f"no case study for {name!r}; valid: {', '.join(CASES)}")
    return CASES[name]
