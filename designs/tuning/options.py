"""The two records a tuning takes: what is tuned (`TuningSetup`) and how it is solved (`SolveOptions`)."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from models import Block, Plant
from models.checks import boolean, integer, positive

from .problem import TuningProblem
from .scenarios import Cost, Scenario, Specs
from .settings import COARSE_SUBSTEPS, HESSIANS, MAX_ITER, METHODS, TOL, WIDTHS, check_widths


@dataclass(frozen=True)
class SolveOptions:
    """How a tuning problem is solved: IPOPT's settings, the smoothing continuation, the extra solves.

    Checked (and normalized: integers, floats, a tuple of widths) when made.

    max_iter : IPOPT iterations per solve, >= 1: a cap that is reported when hit
        (`converged` False), never the intended stop
    tol : IPOPT's convergence tolerance (it also stops at 100 tol held for 10 iterations)
    hessian : "limited-memory" (L-BFGS, one gradient per iteration) or "exact"
        (CasADi's second derivatives; fewer iterations, each costlier)
    jit : compile the NLP's functions to machine code (pays off for long runs)
    method : "smooth" (the continuation over `widths`, see `designs.tuning`) or "exact"
        (one solve on the exact loop)
    widths : the continuation's relative smoothing widths, strictly decreasing
    ipopt_options : dict of further IPOPT options (for example ``{"print_level": 5}``); they
        override `IPOPT_OPTIONS` and the ones set from the fields above
    phase : when the start misses a spec, run a phase one first (`phase_one`) and tune from its
        answer; off by default, since on a two-scenario, four-sample PID tuning it took half an hour
    phase_hessian : the phase one's Hessian (`phase_one`), as `hessian`; the case studies' tuner takes
        "limited-memory" (docs/guide.md's tuning section says why)
    phase_max_iter : the phase one's IPOPT iterations per solve, >= 1; None: `max_iter` (a phase one
        that needs many more iterations than the cost's stages)
    until_feasible : with `phase`, stop at the first decision that meets the specs (a verdict on the
        specs, not a tuned cost: what an outer search over the plant needs, `size_actuator`)
    coarse_substeps : RK4 sub-steps per sample of a coarser problem whose continuation runs first and
        starts this one's (`COARSE_SUBSTEPS`, only on problems without specs and only where it agrees
        with the problem at the start, `COARSE_AGREEMENT`); None: none
    relaxed : on a problem with specs, first solve it without them and keep that answer if it meets
        them (a local minimum over the bounds alone that meets the specs is one under them too)
    progress : optional callable(iteration, objective, seconds) after each IPOPT iteration
    """

    max_iter: int = MAX_ITER
    tol: float = TOL
    hessian: str = "limited-memory"
    jit: bool = False
    method: str = "smooth"
    widths: Sequence[float] = WIDTHS
    ipopt_options: Mapping[str, Any] | None = None
    phase: bool = False
    phase_hessian: str = "exact"
    phase_max_iter: int | None = None
    until_feasible: bool = False
    coarse_substeps: int | None = COARSE_SUBSTEPS
    relaxed: bool = False
    progress: Callable[[int, float, float], None] | None = None

    def __post_init__(self):
        normalized = object.__setattr__
        normalized(self, "max_iter", integer(self.max_iter, "max_iter", minimum=1))
        normalized(self, "tol", positive(self.tol, "tol"))
        if self.phase_max_iter is not None:
            normalized(self, "phase_max_iter", integer(self.phase_max_iter, "phase_max_iter", minimum=1))
        for name in ("hessian", "phase_hessian"):
            if getattr(self, name) not in HESSIANS:
                raise ValueError(f"{name} must be 'limited-memory' or 'exact', got {getattr(self, name)!r}")
        normalized(self, "jit", boolean(self.jit, "jit"))
        if self.progress is not None and not callable(self.progress):
            raise TypeError(f"progress must be callable(iteration, objective, seconds) or None, got {self.progress!r}")
        if self.method not in METHODS:
            raise ValueError(f"method must be 'smooth' or 'exact', got {self.method!r}")
        normalized(self, "widths", check_widths(self.widths))
        normalized(self, "phase", boolean(self.phase, "phase"))
        normalized(self, "until_feasible", boolean(self.until_feasible, "until_feasible"))
        if self.coarse_substeps is not None:
            normalized(self, "coarse_substeps", integer(self.coarse_substeps, "coarse_substeps", minimum=1))
        normalized(self, "relaxed", boolean(self.relaxed, "relaxed"))
        if self.until_feasible and not self.phase:
            raise ValueError("until_feasible needs phase=True: the verdict comes from the phase one")
        if self.ipopt_options is not None and not isinstance(self.ipopt_options, Mapping):
            raise TypeError(f"ipopt_options must be a dict of IPOPT options, got {self.ipopt_options!r}")

    @property
    def phase_iterations(self) -> int:
        """The phase one's IPOPT iterations per solve: `phase_max_iter`, else `max_iter`."""
        return self.max_iter if self.phase_max_iter is None else self.phase_max_iter

    @property
    def smooth(self) -> bool:
        """The continuation over `widths` (method "smooth")."""
        return self.method == "smooth"


@dataclass(frozen=True, eq=False)
class TuningSetup:
    """What is tuned: the plant, the starting block, the scenarios, and what they are judged by.

    Checked when the problem is built (`problem()`, and `tune`).

    plant, block, scenarios, specs, cost, samples, robust, free, substeps, paths
        As in `TuningProblem`.
    bounds : dict gain name -> (low, high), optional box bounds on the free gains
        (scalars or arrays shaped like the gain; ±inf for none), see `gain_bounds`
    """

    plant: Plant
    block: Block
    scenarios: Scenario | Sequence[Scenario]
    specs: Specs | None = None
    cost: Cost | None = None
    samples: np.ndarray | Sequence | None = None
    robust: str = "mean"
    free: Sequence[str] | None = None
    bounds: Mapping[str, Any] | None = None
    substeps: int = 10
    paths: str = "pointwise"

    def problem(self, extra_params: Sequence[str] = ()) -> TuningProblem:
        """The `TuningProblem` of this setup, deciding `extra_params` (plant parameters) after the gains."""
        return TuningProblem(
            self.plant,
            self.block,
            self.scenarios,
            specs=self.specs,
            cost=self.cost,
            samples=self.samples,
            robust=self.robust,
            free=self.free,
            substeps=self.substeps,
            extra_params=extra_params,
            paths=self.paths,
        )
