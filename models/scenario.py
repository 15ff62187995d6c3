"""One closed-loop run: its reference, duration, start, disturbance, noise, and what it is judged by.

`Scenario` is the run the gain tuner and co-design simulate and optimize
(`designs.tuning`, which re-exports it). Its `specs` are a `models.specs.Specs`,
its `cost` a `designs.tuning.Cost` (checked by the tuner, which models does not
import).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .checks import integer, positive
from .specs import Specs


@dataclass(frozen=True)
class Scenario:
    """One closed-loop run of a tuning problem.

    reference : constant, callable t -> r, or array (N+1, n_reference): the block's reference
        (absolute tracked value); None for a regulation (the block's reference held at zero)
    duration : s
    x0 : initial plant state (nx,), default the plant's standard equilibrium
    input_disturbance : constant, callable or array (N, nu), added at the plant input
    tracked : state name of the coordinate that follows the reference (needed by the
        "error" signal and the step specs; keyword only)
    noise_std : standard deviation of Gaussian measurement noise, one number or one per
        measurement; parameter sample j draws it from the generator seeded (seed, j)
    seed : integer >= 0, the noise seed
    weight : > 0, the scenario's weight in the objective
    specs : this scenario's own `models.specs.Specs` (default: the problem's)
    cost : this scenario's own `designs.tuning.Cost` (default: the problem's; checked by the tuner)
    name : label in violation messages
    """

    reference: object
    duration: float
    x0: np.ndarray | None = None
    input_disturbance: object = 0.0
    tracked: str | None = field(default=None, kw_only=True)
    noise_std: object = field(default=0.0, kw_only=True)
    seed: int = field(default=0, kw_only=True)
    weight: float = field(default=1.0, kw_only=True)
    specs: Specs | None = field(default=None, kw_only=True)
    cost: Any = field(default=None, kw_only=True)
    name: str = field(default="", kw_only=True)

    def __post_init__(self):
        positive(self.duration, "duration (s)")
        positive(self.weight, "scenario weight")
        integer(self.seed, "seed", minimum=0)
        if self.tracked is not None and not isinstance(self.tracked, str):
            raise TypeError(f"tracked must be a state name, got {self.tracked!r}")
        if self.specs is not None and not isinstance(self.specs, Specs):
            raise TypeError(f"specs must be a models.specs.Specs, got {type(self.specs).__name__}")
        if not isinstance(self.name, str):
            raise TypeError(f"name must be a string, got {self.name!r}")
