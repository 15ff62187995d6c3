"""Gain tuning through the compiled nonlinear closed loop, with exact derivatives.

The decision variables are a block's gains; the cost is a time-domain
criterion of the nonlinear closed loop (`models.closed_loop_function`, one
CasADi mapaccum, so its gradient is exact) over a weighted set of scenarios
(a step, a series of steps, an input disturbance, measurement noise, a
regulation from an initial state) and parameter samples; the constraints are
each scenario's specs on every parameter sample. IPOPT solves it from the
hand design.

    setup = TuningSetup(plant, block, [Scenario(0.8, 5.0, tracked="theta", name="step"),
                                       Scenario(0.8, 5.0, input_disturbance=0.2, tracked="theta")],
                        specs=Specs(max_overshoot_pct=5.0, max_settling_time_s=2.0))
    result = tune(setup, SolveOptions(max_iter=500))
    result.block          # the tuned block; result.converged, result.status, result.violations

Saturation, conditional integration and anti-windup make the closed-loop
cost piecewise smooth in the gains (its gradient jumps wherever a sample
enters or leaves a limit). `tune` therefore solves a continuation of smoothed
problems (`models.smooth`: every switch blended over a band of relative width
w, w = 0.01, 0.001, ..., each solve warm-started from the last and solved to
`STAGE_TOL_FACTOR` times the tolerance, the last one to the tolerance itself;
`continuation.Continuation`) and stops when IPOPT has converged on a stage
where the exact nonsmooth loop's objective agrees with the smoothed one to
`AGREEMENT` with the same specs violated, and whose answer either no longer
moves the exact objective (the change from the previous stage's answer is
within `AGREEMENT`, relative) or has every switch outside its band (smoothed
and exact objectives equal: near that answer the two problems are one). An
intermediate stage stopped at IPOPT's iteration cap hands its last point to
the next width, cold (the verdict rests on the last stage); two capped stages
in a row end the continuation, unconverged. Only the switches are blended, not
the criteria's |e|, which carry their own fixed resolution (`Cost.resolution`).

On a problem without specs the continuation runs twice: first on the same loop
integrated coarsely (`COARSE_SUBSTEPS` RK4 steps per sample, every stage
loose), then on the problem's own loop from the coarse answer, starting at the
width where the coarse one settled; only the second decides convergence.
Skipped where the coarse loop's objective at the start is off by more than
`COARSE_AGREEMENT`.

A spec on a run is one inequality per sample (``paths="pointwise"``, the
default). With ``paths="aggregated"`` the smoothed stages replace each spec's
inequalities on one run by one soft maximum of their relative excesses
(`excess.soft_max_excess`), which lies within the width below their maximum,
so the relaxation shrinks with the width and the exact pointwise specs still
judge every stage: for problems with many samples and long runs.

With `SolveOptions.phase` a start that misses a spec is first moved by a phase
one (`phase_one`: minimize the largest relative excess of the specs, a problem
every decision is feasible for), and the tuning starts from its answer. A
phase one that converges with the specs still missed is a local certificate
of infeasibility (`TuningResult.stopped_on_test`).

Why these choices (against the exact loop in single and multiple shooting, a
complementarity reformulation, smoothing |e| too), and the measurements behind
the defaults, are in docs/notes/tuning.md.
"""

from .continuation import Continuation, Judgement, Kept, Level
from .excess import relative_excess, soft_max_excess
from .iterations import IterationLog, IterationRecorder
from .options import SolveOptions, TuningSetup
from .phase_one import PhaseOne, decision_scale, phase_one
from .problem import ScenarioRun, TuningProblem, gain_bounds
from .result import TuningResult
from .scenarios import COSTS, Cost, Scenario, Specs, final_value, state_bound
from .settings import (
    AGGREGATED_IPOPT_OPTIONS,
    AGREEMENT,
    CAPPED,
    COARSE_AGREEMENT,
    COARSE_SUBSTEPS,
    CONVERGED,
    HESSIANS,
    INFEASIBLE,
    IPOPT_OPTIONS,
    MAX_ITER,
    METHODS,
    PATHS,
    PATIENCE,
    PHASE_ONE_MARGIN,
    RETRIED,
    ROBUST,
    SLACK,
    STAGE_TOL_FACTOR,
    STOPPED,
    TOL,
    WARM_START,
    WATCH_MARGIN,
    WIDTHS,
    check_widths,
)
from .solving import checked_options, solve, tune
from .spectral import closed_loop_spectral_abscissa, missed_specs, spectral_violations

__all__ = [
    "AGGREGATED_IPOPT_OPTIONS",
    "AGREEMENT",
    "CAPPED",
    "COARSE_AGREEMENT",
    "COARSE_SUBSTEPS",
    "CONVERGED",
    "COSTS",
    "HESSIANS",
    "INFEASIBLE",
    "IPOPT_OPTIONS",
    "MAX_ITER",
    "METHODS",
    "PATHS",
    "PHASE_ONE_MARGIN",
    "PATIENCE",
    "RETRIED",
    "ROBUST",
    "SLACK",
    "STAGE_TOL_FACTOR",
    "STOPPED",
    "TOL",
    "WARM_START",
    "WATCH_MARGIN",
    "WIDTHS",
    "Continuation",
    "Cost",
    "IterationLog",
    "IterationRecorder",
    "Judgement",
    "Kept",
    "Level",
    "PhaseOne",
    "Scenario",
    "ScenarioRun",
    "SolveOptions",
    "Specs",
    "TuningProblem",
    "TuningResult",
    "TuningSetup",
    "check_widths",
    "checked_options",
    "closed_loop_spectral_abscissa",
    "decision_scale",
    "final_value",
    "gain_bounds",
    "missed_specs",
    "phase_one",
    "relative_excess",
    "soft_max_excess",
    "solve",
    "spectral_violations",
    "state_bound",
    "tune",
]
