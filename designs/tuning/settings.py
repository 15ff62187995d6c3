"""The tuning's defaults: IPOPT's options and statuses, the continuation's widths and tolerances.

The measurements behind each value are in docs/notes/tuning.md.
"""

from __future__ import annotations

import numpy as np

from models.checks import real_array

#: How the parameter samples' totals make the objective: their mean, or their largest (an epigraph).
ROBUST = ("mean", "worst")
#: The specs' form on the smoothed stages: one inequality per sample, or one soft maximum per spec and run.
PATHS = ("pointwise", "aggregated")
#: "smooth": the continuation over the widths; "exact": one solve on the exact (nonsmooth) loop.
METHODS = ("smooth", "exact")
#: IPOPT's Hessian: L-BFGS, or CasADi's exact second derivatives.
HESSIANS = ("limited-memory", "exact")
#: Relative smoothing widths of the continuation (see `models.smooth`), largest first; a start far from
#: the answer may need a wider first one (0.1).
WIDTHS = (1e-2, 1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8)
#: The continuation stops when the exact and smoothed objectives agree to this, relative.
AGREEMENT = 1e-6
#: IPOPT statuses that mean it converged (to `tol`, or to 100 `tol` held for 10 iterations).
CONVERGED = ("Solve_Succeeded", "Solved_To_Acceptable_Level")
#: IPOPT's status at its iteration cap.
CAPPED = "Maximum_Iterations_Exceeded"
#: IPOPT's verdict of local infeasibility (its restoration converged outside the constraints).
INFEASIBLE = "Infeasible_Problem_Detected"
#: IPOPT's status when the iteration callback stopped it: a stage making the exact cost worse (`PATIENCE`).
STOPPED = "User_Requested_Stop"
#: A stage is stopped during its solve once the objective IPOPT sees has stayed more than `WATCH_MARGIN`
#: (relative) above the best exact cost seen so far for this many iterations in a row and the exact loop at
#: its iterate confirms the point is worse by that much; its start is kept. Each confirmation costs one
#: exact closed-loop evaluation. Smaller rises are judged at the stage's end (`AGREEMENT`): an interior
#: point method leaves a start on a constraint's boundary uphill before it converges.
PATIENCE = 20
WATCH_MARGIN = 0.01
#: How far (relative excess) a smoothed stage's answer may miss the specs on the exact loop, from a point
#: meeting them, without counting as worse for a lower cost: the widest default width.
SLACK = 1e-2
#: IPOPT statuses of a numerical failure, retried once from the failed solve's last point.
RETRIED = ("Error_In_Step_Computation", "Restoration_Failed", "Search_Direction_Becomes_Too_Small")
#: IPOPT iterations per solve: a safety cap, not the stopping rule (a stop here is reported).
MAX_ITER = 3000
#: IPOPT's convergence tolerance (scaled NLP error): at 1e-8 L-BFGS stalls on the narrow blends.
TOL = 1e-6
#: The continuation's intermediate stages only start the next one: solved to this times `tol` (the stage
#: that ends the continuation is finished at `tol`), which reaches the same answer sooner.
STAGE_TOL_FACTOR = 1000.0
#: RK4 sub-steps per sample of the coarser level solved first on problems without specs: an objective and
#: its gradient several times cheaper, whose answer starts the problem's own continuation.
COARSE_SUBSTEPS = 1
#: The coarser level runs only where its objective at the start is within this (relative) of the problem's:
#: a sample period too long for one RK4 step (a fast or stiff plant) fails it and is tuned at full fidelity.
COARSE_AGREEMENT = 1e-2
#: IPOPT options of every solve (`tol` sets tol and acceptable_tol = 100 tol). MUMPS orders the KKT system
#: by QAMD (6), which detects the dense columns of constraints that all depend on every gain.
IPOPT_OPTIONS = {"print_level": 0, "sb": "yes", "acceptable_iter": 10, "mumps_pivot_order": 6}
#: IPOPT's constraint tolerances (unscaled) on aggregated specs, whose values are relative excesses: well
#: inside the 1e-6 the exact specs are judged to.
AGGREGATED_IPOPT_OPTIONS = {"constr_viol_tol": 1e-8, "acceptable_constr_viol_tol": 1e-8}
#: IPOPT options of the continuation's later stages, which start at the last answer and multipliers.
WARM_START = {
    "warm_start_init_point": "yes",
    "mu_init": 1e-6,
    "warm_start_bound_push": 1e-9,
    "warm_start_slack_bound_push": 1e-9,
    "warm_start_mult_bound_push": 1e-9,
}
#: Compiler flags of the phase one's NLP (`models.compile.jit_nlpsols`): gcc at -O1 builds it in less than
#: half the time of -O3 and the solves it runs are as fast (docs/guide.md's tuning section).
PHASE_ONE_FLAGS = ("-O1", "-march=native")
#: Compiler flags of the continuation's NLP (`Continuation.build`): as the phase one's, -O1. On the ball on
#: beam's tuner problem gcc took 248 CPU-s at -O1 against 583 at -O3, and 40 IPOPT iterations 12.7 CPU-s
#: against 10.0 (docs/notes/tuning.md): less in all below about 5,000 iterations.
TUNING_FLAGS = ("-O1", "-march=native")
#: Phase one stops improving once every spec holds with this relative margin (its lower bound on s).
PHASE_ONE_MARGIN = 1e-3


def check_widths(widths) -> tuple[float, ...]:
    """The continuation's widths as a tuple; ValueError unless a non-empty, strictly decreasing
    sequence of finite numbers > 0."""
    values = real_array(widths, "widths")
    if (
        values.ndim != 1
        or values.size == 0
        or not np.all(np.isfinite(values))
        or np.any(values <= 0)
        or np.any(np.diff(values) >= 0)
    ):
        raise ValueError(
            f"widths must be a non-empty, strictly decreasing sequence of numbers > 0, got {values.tolist()}"
        )
    return tuple(float(w) for w in values)


def converged(status: str) -> bool:
    """IPOPT's `status` is one of `CONVERGED`."""
    return status in CONVERGED
