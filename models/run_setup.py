"""The checked inputs every closed-loop simulator shares, as one record.

`simulate_closed_loop`, `simulate_closed_loop_many`, `monte_carlo` and
`monte_carlo_chunks` take the same group of keywords beyond the plant, the
controller, the reference and the duration: the initial state, the RK4
sub-steps, the input disturbance, the measurement noise and its seed. Each
builds one `RunSetup` from them at its entry (`RunSetup.build`, which checks
every one and samples the signals on the run's time grid t_k = k * Ts); the
steps after it read the record and check nothing again.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .block import Block, Controller
from .checks import as_vector, check_memory, integer, positive, real_array
from .plant import Plant
from .signals import sample

#: The seeds numpy's `default_rng` takes and the simulators pass on to it.
Seed = int | np.random.SeedSequence | np.random.Generator | np.random.BitGenerator | None


def n_measured(plant: Plant, controller) -> int:
    """How many numbers `controller` reads each sample: the plant's outputs (ny) or its state (nx)."""
    return plant.ny if controller.measures == "outputs" else plant.nx


def check_sizes(plant: Plant, controller) -> None:
    """Refuse a `Block` whose measurement or input count does not fit `plant` (ValueError naming both).

    Other controllers declare no sizes; their commands are checked when they come.
    """
    n_meas = n_measured(plant, controller)
    if isinstance(controller, Block):
        if controller.n_measured != n_meas:
            raise ValueError(
                f"{controller.name} reads {controller.n_measured} measurements but "
                f"{plant.name} provides {n_meas} ({controller.measures})"
            )
        if controller.n_input != plant.nu:
            raise ValueError(f"{controller.name} gives {controller.n_input} inputs, {plant.name} takes {plant.nu}")


def doubles_per_step(plant: Plant, controller) -> int:
    """Doubles one closed-loop sample stores, for the memory estimate of `check_memory`.

    The results (x, y, xc, r, u, d, measured, t, step time) plus CasADi's work arrays of the
    compiled run (its state and output buffers, the mapped controller step that times the run):
    about twice the results alone.
    """
    nc = int(getattr(controller, "n_state", 0))
    n_meas = n_measured(plant, controller)
    results = plant.nx + plant.ny + nc + controller.n_reference + 2 * plant.nu + n_meas + 2
    work = 2 * (plant.nx + nc) + plant.nu + 2 * n_meas + nc + controller.n_reference
    return results + work


def check_seed(seed, what: str = "seed") -> Seed:
    """A seed numpy's `default_rng` takes: None, an integer >= 0, a SeedSequence or a Generator.

    An integer is returned as an int; anything else raises as `models.checks.integer` does.
    """
    if seed is None or isinstance(seed, (np.random.SeedSequence, np.random.Generator, np.random.BitGenerator)):
        return seed
    return integer(seed, what, minimum=0)


@dataclass(frozen=True)
class RunSetup:
    """The inputs of closed-loop runs of one controller on one plant, checked and sampled.

    N = round(duration / Ts) samples at the controller's sample period Ts.

    Attributes
    ----------
    t : (N+1,) s, the sample times k * Ts
    x0 : (nx,) the plant's initial state
    r : (N+1, n_reference) the reference at every sample
    d : (N, nu) the input disturbance added at the plant input on [t_k, t_k+1)
    noise_std : (n_measured,) standard deviation of the Gaussian measurement noise, per measurement
    substeps : RK4 sub-steps per sample period (>= 1)
    seed : the noise generator's seed (see `check_seed`)
    """

    t: np.ndarray
    x0: np.ndarray
    r: np.ndarray
    d: np.ndarray
    noise_std: np.ndarray
    substeps: int
    seed: Seed

    @property
    def n_steps(self) -> int:
        """N, the number of samples (controller steps) of a run."""
        return len(self.t) - 1

    @property
    def n_measured(self) -> int:
        """How many numbers the controller reads each sample."""
        return self.noise_std.size

    @property
    def noisy(self) -> bool:
        """Whether any measurement gets noise."""
        return bool(np.any(self.noise_std))

    def noise(self, sample: int | None = None) -> np.ndarray:
        """The measurement noise n_k of a run, (N, n_measured); zeros, drawing nothing, when there is none.

        Drawn from ``numpy.random.default_rng(seed)``, or for Monte Carlo sample `sample` from the
        generator seeded with ``SeedSequence([seed, sample])``: each sample's noise depends on its
        index alone, not on which other samples run with it.
        """
        if not self.noisy:
            return np.zeros((self.n_steps, self.n_measured))
        seed = self.seed
        if sample is not None:
            if not isinstance(seed, int):
                raise TypeError(f"the noise of Monte Carlo samples needs an integer seed, got {seed!r}")
            seed = np.random.SeedSequence([seed, sample])
        return np.random.default_rng(seed).standard_normal((self.n_steps, self.n_measured)) * self.noise_std

    @classmethod
    def build(
        cls,
        plant: Plant,
        controller,
        reference,
        duration: float,
        *,
        x0=None,
        substeps: int = 10,
        input_disturbance=0.0,
        noise_std=0.0,
        seed=0,
    ) -> RunSetup:
        """Check the shared arguments of the closed-loop simulators and sample them on the time grid.

        Parameters
        ----------
        plant : Plant, the truth
        controller : a `Controller` (its sample period Ts sets the grid)
        reference : constant, callable t -> r, or array (N+1, n_reference)
        duration : s, > 0 and at least one sample period
        x0 : (nx,), default the plant's standard equilibrium state
        substeps : RK4 sub-steps per sample period
        input_disturbance : constant, callable or array (N, nu)
        noise_std : one number or (n_measured,) numbers, finite and >= 0
        seed : see `check_seed`

        Raises
        ------
        TypeError
            When `plant` is not a Plant or `controller` not a Controller, or an argument is not numbers.
        ValueError
            Naming the argument that is wrong (a size, a non-finite value, a duration under one sample).
        ResourceLimitError
            Before any work, when a run would need more than `models.checks.MEMORY_LIMIT_BYTES`.
        """
        if not isinstance(plant, Plant):
            raise TypeError(f"plant must be a models.Plant, got {type(plant).__name__} {plant!r}")
        if not isinstance(controller, Controller):
            raise TypeError(
                f"{controller!r} is not a controller: it needs sample_period, measures, n_reference, "
                "initial_state and step"
            )
        check_sizes(plant, controller)
        ts = controller.sample_period
        duration = positive(duration, "duration (s)")
        n = int(round(duration / ts))
        if n < 1:
            raise ValueError(f"duration {duration} s is shorter than one sample ({ts} s)")
        check_memory(
            8.0 * (n + 1) * doubles_per_step(plant, controller),
            f"a closed loop of {n} samples ({duration:g} s at Ts = {ts:g} s) of {plant.name}",
            "shorten the run or lengthen the sample period",
        )
        t = ts * np.arange(n + 1)
        x0 = plant.equilibrium()[0] if x0 is None else as_vector(x0, plant.nx, f"{plant.name} initial state")
        r = sample(reference, t, controller.n_reference, "reference")
        d = sample(input_disturbance, t[:-1], plant.nu, "input disturbance")
        std = _noise_std(noise_std, n_measured(plant, controller))
        substeps = integer(substeps, "substeps", minimum=1)
        return cls(t, x0, r, d, std, substeps, check_seed(seed))


def _noise_std(noise_std, n_meas: int) -> np.ndarray:
    """`noise_std` as (n_meas,) finite numbers >= 0, from one number or one per measurement."""
    std = real_array(noise_std, "noise_std")
    if std.ndim > 1 or std.size not in (1, n_meas):
        raise ValueError(
            f"noise_std must be one number or {n_meas} numbers (one per measurement), got shape {std.shape}"
        )
    std = np.broadcast_to(std, (n_meas,))
    if not np.all(np.isfinite(std)) or np.any(std < 0):
        raise ValueError(f"noise_std must be finite and >= 0, got {noise_std}")
    return np.array(std)
