"""Real-time iteration: one Gauss-Newton SQP step per sample on a multiple-shooting transcription.

The NLP of `mpc.transcription.Transcription` (multiple shooting, the initial
state fixed to the parameter x0 by `OptimalControlProblem.start_from`) is, with
scaled stage states s_k, stage inputs and controls q_k and the shooting gaps
s_{k+1} = φ_k(s_k, q_k), linearized at a point w̄ (the previous solution
shifted by one sample) and solved as one quadratic program:

    minimize    ½ Δwᵀ ∇²f(w̄) Δw + ∇f(w̄)ᵀ Δw                   (Gauss-Newton: the constraints'
    subject to  Δs_{k+1} = A_k Δs_k + B_k Δq_k + a_k              curvature is dropped)
                Δs_0 = x0 / scale − s̄_0
                lbg − g(w̄) ≤ J(w̄) Δw ≤ ubg − g(w̄)                 (every other row)
                lbx − q̄ ≤ Δq ≤ ubx − q̄

The work is split as in Diehl's real-time iteration:

- **preparation** (`prepare`, before the measurement): linearize, and
  condense: eliminate the states with the forward recursion
  Γ_{k+1} = A_k Γ_k + B_k E_k + a_k e₁ᵀ over z = (Δs_0, 1, Δd) (Δd: the
  inputs and controls that enter the dynamics) and form the dense Hessian
  with the backward recursion P_k = Q_k + A_kᵀ P_{k+1} A_k (the row of Δd_k
  is then B_kᵀ P_{k+1} Γ_{k+1} + S_k Γ_k + R_k E_k), O(N² nx nd + N nx³)
  instead of the O(N³) of multiplying the stacked matrices;
- **feedback** (`feedback`, once x0 is known): the gradient and row bounds are
  affine in Δs_0 (two matrix-vector products), DAQP's dual active-set method
  solves the dense QP, slacks first held at their bounds (`SlackFirstQP`), and
  the states are recovered by the linear recursion.

Why condensing and DAQP rather than HPIPM's Riccati recursion on the sparse QP:
measured on the pendulum (N = 50, nx = 4, Ts = 0.01 s), `casadi.conic("hpipm")`
took 0.41 ms per QP with input bounds only and 0.80 ms with the soft |θ| bound
(its interface copies and converts the sparse matrices each call), more than
this whole step; the condensed QP has N (nu + ns) = 50-100 variables, which a
dense active-set method solves in tens of microseconds, and rows coupling
neighbouring intervals (a rate limit) cost nothing extra there while HPIPM's
stage structure cannot express them.

The preparation and the feedback's two halves around the QP are CasADi
Functions (SX for the linearization, MX for the recursions), generated as C
and compiled once through `models.compile` (cached between runs; CasADi's
virtual machine when no compiler is available). With soft bounds the QPs are
solved from Python by the `daqp` package, which a sequence of QPs of changing
size needs (a CasADi Function has fixed sizes); without, the whole feedback is
one compiled Function with the QP as a `casadi.conic("daqp")` node.
`step_function` chains both phases into one CasADi Function with the whole QP
as that node, a second path to the same answer.

Iterating preparation and feedback at a fixed x0 is the full-step
Gauss-Newton SQP (`solve`), which converges to a KKT point of the NLP (the
converged SQP option).
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass
from typing import cast

import casadi as ca
import daqp
import numpy as np

import models
from models import interrupts
from models.checks import integer, positive

from . import condensing
from .qp_fast import DAQP_STATUS, PRIMAL_TOLERANCE
from .transcription import Transcription

#: Compiler flags of the generated phases: models.compile's -O3 -march=native. Measured on the pendulum
#: (N = 50, a loaded 2-core machine) when the whole preparation was CasADi's code: 1.7x faster than
#: with -O1 (0.31 against 0.53 ms, interleaved), its first compile 2x longer (99 against 54 s).
COMPILE_FLAGS = models.compile.FLAGS

#: The linearization is straight-line code (one CasADi SX Function per group of alike intervals); past
#: LARGE_CODE instructions in those Functions it is compiled with LARGE_CODE_FLAGS. Measured (loaded
#: machine, 20 samples per call): the crane's (7 groups, 32,700 instructions, 943 kB of C) compiles in
#: 57.5 s with -O3 -march=native and 7.9 s with -O1 -march=native, both 0.17 ms per sample; the
#: pendulum's (one group, 2,100) in 5.9 and 2.1 s, 0.042 against 0.057 ms: there -O3 stays.
LARGE_CODE = 10_000
LARGE_CODE_FLAGS = ("-O1", "-march=native")

#: Largest QP residual (stationarity and bound violation, in scaled units) a solve may leave.
QP_TOLERANCE = 1e-6
#: Soft rows closer than this to a bound at the linearization point (scaled units) enter the slack-first
#: sequence's first QP with their slacks fixed (`SlackFirstQP.near`). Measured on 1,900-2,100 recorded
#: QPs per plant (20 % of a 6 s Monte Carlo run's, the same answers to 1e-13): mean time per QP against
#: none kept, pendulum 0.21 -> 0.14 ms, satellite 1.94 -> 0.31, crane 1.15 -> 0.43 (two QPs -> 1.01 on
#: average; 0.01 and 0.05 were slower on one plant or another), ball on beam 0.10 -> 0.13.
NEAR = 0.03


@dataclass(frozen=True)
class QPReport:
    """What the feedback phase's QP reported: status text, success, stationarity and violation residuals."""

    status: str
    success: bool
    stationarity: float
    violation: float


@dataclass
class IterationResult:
    """One preparation + feedback (or a converged SQP) at x0.

    decision : (nw,) the new scaled decisions w̄ + Δw;  step : max |Δw| (scaled)
    qp : QPReport of the last QP;  iterations : SQP iterations done
    preparation_time, feedback_time : s, summed over the iterations
    converged : the last step was below the tolerance (always True for one real-time iteration)
    """

    decision: np.ndarray
    step: float
    qp: QPReport
    iterations: int
    preparation_time: float
    feedback_time: float
    converged: bool


def _daqp_flags() -> tuple[str, ...]:
    """Compiler flags for generated code that calls DAQP through CasADi's conic (headers and
    library shipped with CasADi; the library path is recorded in the compiled library)."""
    root = os.path.dirname(ca.__file__)
    return (
        *COMPILE_FLAGS,
        f"-I{os.path.join(root, 'include')}",
        f"-L{root}",
        f"-Wl,-rpath,{root}",
        "-Wl,--no-as-needed",
        "-ldaqp",
    )


class SlackFirstQP:
    """The condensed QP in v = (d, σ), dynamic inputs then slacks (static controls), slacks first
    held at their lower bounds: the exact optimum of the whole QP by a sequence of smaller QPs.

        minimize    ½ vᵀ H v + hᵀ v,        H = [[H_dd, H_σdᵀ], [H_σd, H_σσ]]
        subject to  lba ≤ C v ≤ uba,        C = [C_d, C_σ]
                    lbv ≤ v ≤ ubv

    H_σσ and C_σ are sparse with fixed patterns (their nonzeros change every sample); H_σd is
    absent (zero) unless the slacks couple with the inputs. A slack is held by the rows whose C_σ
    has an entry in its column (its soft rows).

    A restricted QP frees some slacks, keeps the soft rows holding them, and fixes every other
    slack at its lower bound, its soft rows left out (or kept, as rows with the slack fixed). Its
    answer is the whole QP's when (KKT of the whole QP; the restricted QP's own conditions hold already)

    - every left-out soft row holds (zero multiplier), and
    - every fixed slack's Lagrangian gradient (H v + h + Cᵀ λ)_j is >= 0 (its lower bound's
      multiplier has the right sign).

    Otherwise the slacks of the violated rows and those with a negative gradient are freed and the
    restricted QP solved again (all of them, the whole QP, once more than half are free): at most
    one QP per slack, usually one. The first is the QP in the dynamic inputs alone, with the soft
    rows that are within `near` of a bound at v = 0 kept, their slacks fixed: where the last sample's
    answer rode a soft bound without violating it, this one usually does too, and one QP in d with
    those rows replaces a second QP with their slacks free (when DAQP finds the kept rows infeasible
    together, the sequence starts over without them).

    This replaces solving the whole QP from DAQP's empty working set, where each of the N ns
    slack bounds that ends up active costs one active-set iteration of O(n²) on all N (nu + ns)
    variables. Measured on the 306 QPs of a 30 s crane run (N = 80, 240 variables, 320 soft rows;
    one or two QPs each here): 17 ms on average for DAQP on the whole QP, 1.1 ms for this
    sequence; the crane's largest feedback time over 300 samples fell from 24-70 ms to 2-10 ms
    (benchmarks/nmpc_steps.py, loaded machine).

    Without slacks, with slacks that couple with the inputs (H_σd), or with `slack_first` False,
    it is one DAQP call on the whole QP.

    Parameters
    ----------
    n_dynamic, n_static : sizes of d and σ;  m : rows of C
    hessian_pattern, row_pattern : (rows, columns) of the nonzeros of H_σσ and C_σ, in the order
        their values are passed to `solve`
    coupled : H_σd is given (else zero)
    slack_first : try the slacks at their lower bounds first (they must be finite)
    settings : DAQP settings of every solve
    tolerance : violation of a left-out row, and negative gradient of a fixed slack, accepted

    Attributes
    ----------
    near : float or None, `NEAR` when `slack_first`: the first QP's kept soft rows (None: none kept)
    """

    def __init__(
        self,
        n_dynamic: int,
        n_static: int,
        m: int,
        hessian_pattern,
        row_pattern,
        *,
        coupled: bool,
        slack_first: bool,
        settings: dict,
        tolerance: float,
    ):
        self.n_dynamic, self.n_static, self.m = int(n_dynamic), int(n_static), int(m)
        self.hessian_rows, self.hessian_columns = (np.asarray(v, dtype=int) for v in hessian_pattern)
        self.row_rows, self.row_columns = (np.asarray(v, dtype=int) for v in row_pattern)
        self.coupled = bool(coupled)
        self.slack_first = bool(slack_first and self.n_static and not coupled)
        self.soft_rows = np.unique(self.row_rows)
        self.hard_rows = np.setdiff1d(np.arange(self.m), self.soft_rows)
        self.hard_mask = np.zeros(self.m, dtype=bool)
        self.hard_mask[self.hard_rows] = True
        self.every_slack, self.no_slacks = np.arange(self.n_static), np.zeros(0, dtype=int)
        self.near = NEAR if slack_first else None
        self.settings, self.tolerance = dict(settings), float(tolerance)

    def _daqp(self, H, f, A, lower, upper, lba, uba):
        """DAQP on lower ≤ v ≤ upper, lba ≤ A v ≤ uba: (v, bound multipliers, row multipliers, exit flag)."""
        bounds = (np.concatenate([upper, uba]), np.concatenate([lower, lba])) if len(lba) else (upper, lower)
        H, A = np.ascontiguousarray(H), np.ascontiguousarray(A)  # DAQP reads the arrays' memory row by row
        x, _, flag, info = daqp.solve(H, f, A, *bounds, **self.settings)
        lam = info["lam"]
        return x, lam[: len(f)], lam[len(f) :], int(flag)

    def _sparse(self, pattern, values, rows, columns) -> np.ndarray:
        """The dense submatrix (rows, columns) of the sparse matrix with nonzeros `values` at `pattern`."""
        (r, c), n_rows = pattern, max(self.m, self.n_static)
        row_at, column_at = np.full(n_rows, -1), np.full(self.n_static, -1)
        row_at[rows], column_at[columns] = np.arange(len(rows)), np.arange(len(columns))
        keep = (row_at[r] >= 0) & (column_at[c] >= 0)
        out = np.zeros((len(rows), len(columns)))
        out[row_at[r[keep]], column_at[c[keep]]] = values[keep]
        return out

    def whole(self, H_dd, H_sd, hessian_values, C_d, row_values):
        """The whole QP's dense H and C."""
        everything, slacks = np.arange(self.m), np.arange(self.n_static)
        H_ss = self._sparse((self.hessian_rows, self.hessian_columns), hessian_values, slacks, slacks)
        H_sd = H_sd if self.coupled else np.zeros((self.n_static, self.n_dynamic))
        C_s = self._sparse((self.row_rows, self.row_columns), row_values, everything, slacks)
        return np.block([[H_dd, H_sd.T], [H_sd, H_ss]]), np.hstack([C_d, C_s])

    def solve(self, H_dd, H_sd, hessian_values, C_d, row_values, h, lba, uba, lbv, ubv):
        """(v, lam_a, lam_x, DAQP exit flag of the last QP, QPs solved) of the QP with these numbers
        (H_sd None unless `coupled`); multipliers in CasADi's convention (H v + h + Cᵀ lam_a + lam_x
        = 0, positive on an active upper bound)."""
        nS = self.n_static
        if not nS:
            x, lam_x, lam_a, flag = self._daqp(H_dd, h, C_d, lbv, ubv, lba, uba)
            return x, lam_a, lam_x, flag, 1
        if not self.slack_first:
            H, C = self.whole(H_dd, H_sd, hessian_values, C_d, row_values)
            x, lam_x, lam_a, flag = self._daqp(H, h, C, lbv, ubv, lba, uba)
            return x, lam_a, lam_x, flag, 1
        started = self._sequence(H_dd, hessian_values, C_d, row_values, h, lba, uba, lbv, ubv, self.near)
        if started[3] < 0 and self.near is not None:
            # The soft rows kept with their slacks fixed may be infeasible together: from the hard rows alone.
            *answer, solves = self._sequence(H_dd, hessian_values, C_d, row_values, h, lba, uba, lbv, ubv, None)
            return (*answer, solves + started[4])
        return started

    def _sequence(self, H_dd, hessian_values, C_d, row_values, h, lba, uba, lbv, ubv, near):
        """`solve`'s sequence of restricted QPs, the soft rows within `near` of a bound at v = 0 kept
        from the start (none when None)."""
        nD, nS, m, tol = self.n_dynamic, self.n_static, self.m, self.tolerance
        hr, hc, cr, cc = self.hessian_rows, self.hessian_columns, self.row_rows, self.row_columns
        h_d, h_s, low_s, high_s = h[:nD], h[nD:], lbv[nD:], ubv[nD:]
        # Masks, not index sets, so each round costs a few vector operations whatever is freed.
        freed = np.zeros(nS, dtype=bool)
        kept = self.hard_mask.copy()  # the rows in the QP: hard, holding a free slack, or near their bound
        if near is not None:
            # Soft rows within `near` of a bound at the linearization point (v = 0) start in the QP with
            # their slacks fixed: where the last answer rode a soft bound, this one likely does too.
            soft = self.soft_rows
            kept[soft[(lba[soft] > -near) | (uba[soft] < near)]] = True
        free, fixed, rows = self.no_slacks, self.every_slack, np.flatnonzero(kept)
        sigma = low_s.copy()  # the fixed slacks' values (the free ones' are set after each solve)
        solves = 0
        while True:
            solves += 1
            soft_kept = rows.size > self.hard_rows.size
            if free.size or soft_kept:
                # The fixed slacks' contributions: to the free slacks' gradient (H_σσ, within a stage)
                # and to the kept rows (C_σ).
                shift = np.bincount(cr, weights=row_values * sigma[cc], minlength=m)[rows]
                lower_rows, upper_rows = lba[rows] - shift, uba[rows] - shift
            else:
                lower_rows, upper_rows = lba[rows], uba[rows]
            if free.size:
                H_sigma = np.bincount(hr, weights=hessian_values * sigma[hc], minlength=nS)
                k = len(free)
                H = np.zeros((nD + k, nD + k))
                H[:nD, :nD] = H_dd
                H[nD:, nD:] = self._sparse((hr, hc), hessian_values, free, free)
                x, lam_v, lam_r, flag = self._daqp(
                    H,
                    np.concatenate([h_d, h_s[free] + H_sigma[free]]),
                    np.hstack([C_d[rows], self._sparse((cr, cc), row_values, rows, free)]),
                    np.concatenate([lbv[:nD], low_s[free]]),
                    np.concatenate([ubv[:nD], high_s[free]]),
                    lower_rows,
                    upper_rows,
                )
            else:  # the QP in d alone, with the hard rows and the kept soft rows
                x, lam_v, lam_r, flag = self._daqp(H_dd, h_d, C_d[rows], lbv[:nD], ubv[:nD], lower_rows, upper_rows)
            sigma[free] = x[nD:]
            v = np.concatenate([x[:nD], sigma])
            lam_a, lam_x = np.zeros(m), np.zeros(nD + nS)
            lam_a[rows] = lam_r
            lam_x[:nD], lam_x[nD + free] = lam_v[:nD], lam_v[nD:]
            if flag < 0 or not fixed.size:
                return v, lam_a, lam_x, flag, solves
            gradient = np.bincount(hr, weights=hessian_values * sigma[hc], minlength=nS) + h_s
            if free.size or soft_kept:  # multipliers only on kept rows, and the hard rows hold no slack
                gradient += np.bincount(cc, weights=row_values * lam_a[cr], minlength=nS)
            gradient = gradient[fixed]
            lam_x[nD + fixed] = -gradient
            left_out = self.soft_rows[~kept[self.soft_rows]]
            values = (C_d @ x[:nD] + np.bincount(cr, weights=row_values * sigma[cc], minlength=m))[left_out]
            violated = np.zeros(m, dtype=bool)
            violated[left_out] = (values < lba[left_out] - tol) | (values > uba[left_out] + tol)
            free_now = np.zeros(nS, dtype=bool)
            free_now[fixed[(gradient < -tol) & (high_s[fixed] > low_s[fixed])]] = True
            free_now[cc[violated[cr]]] = True  # the slacks the violated rows hold
            free_now &= ~freed
            if not free_now.any():
                return v, lam_a, lam_x, flag, solves
            freed |= free_now
            if 2 * freed.sum() > nS:  # about the whole QP already: solve it, not a sequence growing to it
                freed[:] = True
            free, fixed = np.flatnonzero(freed), np.flatnonzero(~freed)
            kept[cr[freed[cc]]] = True  # the rows holding a free slack
            rows = np.flatnonzero(kept)
            sigma[free] = 0.0  # σ holds the fixed slacks' values alone


class RealTimeIteration:
    """The condensed Gauss-Newton QP of a multiple-shooting transcription, built once.

    Parameters
    ----------
    transcription : Transcription
        Of an `OptimalControlProblem` with `start_from()` and `MultipleShooting`; no chosen
        plant parameters, a fixed final time, a stage-wise objective (sums, integrals and an
        end term; the Gauss-Newton Hessian must not couple intervals) whose Hessian is positive
        definite in the inputs and controls; no finite state bounds except x(0) = x0
        (soften them with a control, as MPC does).
    compiled : compile the phases to machine code (`models.compile`); False evaluates them in
        CasADi's virtual machine (same numbers, slower)
    slack_shortcut : first solve the QP with every static control (slack) at its lower bound and the
        rows holding them left out, and solve the whole QP only when that answer is not its optimum
        (same answer; the small QP is what a sample with every soft bound inactive needs)

    Attributes
    ----------
    prepare_function : casadi.Function
        ``prepare(w, P) -> data``, the preparation as CasADi expressions; compiled when asked and
        `condensing` is None
    linearize_function : casadi.Function or None
        ``linearize(w, P) -> lin``, compiled: the preparation's first part, the intervals' Jacobians
        and Hessians (laid out as `mpc.condensing.Structure.layout` says)
    condensing : mpc.condensing.Condensing or None
        The preparation's second part in generated C, ``condensing(lin rows) -> data rows`` (the same
        numbers as `prepare_function`'s to rounding, about 4x faster on the crane); None when not
        compiled or no library can be built
    vectors_function, recover_function : casadi.Function
        The feedback's two compiled halves around the QP (`qp_solver`): ``vectors(data, x0) ->
        (h, lba, uba)``, the QP's vectors for this x0, and ``recover(data, x0, dv, lam_a, lam_x) ->
        (w_next, qp)``, the new decisions and `qp` = (stationarity, violation) residuals of the QP.
    qp_solver : SlackFirstQP
    whole_feedback_function : casadi.Function or None
        Where the slack-first sequence does not apply (no slacks, slacks coupled with the inputs,
        or `slack_shortcut` False): the whole feedback in one Function, ``(data, x0) -> (w_next, qp)``,
        the whole QP solved by CasADi's DAQP node (compiled when asked); None otherwise.
    step_function : casadi.Function
        ``step(w, P, x0) -> (w_next, qp)``, both phases at once with the whole QP solved by
        CasADi's DAQP node (not compiled; a second path to the feedback's answer).
    shift_index : (nw,) int, ``w[shift_index]`` is w one interval later (the last repeated)
    qp_variables : (N nq,) int, the decisions (indices into w) the QP's variables v step, in v's
        order: the inputs and controls that enter the dynamics, then the others (slacks)
    row_index : (m,) int, the NLP's constraint rows (indices into g) of the QP's rows, in order
    """

    def __init__(self, transcription: Transcription, *, compiled: bool = True, slack_shortcut: bool = True):
        if not isinstance(transcription, Transcription):
            raise TypeError(f"transcription must be a mpc.Transcription, got {type(transcription).__name__}")
        tr = self.transcription = transcription
        if tr.dynamics_rows is None:
            raise ValueError(
                "the real-time iteration needs a MultipleShooting transcription (collocation states "
                "cannot be eliminated stage by stage)"
            )
        if tr.layout.chosen or tr.layout.final_time is not None:
            raise ValueError("the real-time iteration needs a fixed final time and no chosen plant parameters")
        if "x0" not in tr.parameter_slices:
            raise ValueError("the real-time iteration needs the initial state as a parameter: call ocp.start_from()")
        layout, N = tr.layout, tr.intervals
        nx = layout.states.shape[1]
        stage_q = np.hstack([layout.inputs, layout.controls])
        nq = stage_q.shape[1]
        self.intervals, self.nx, self.nq = N, nx, nq
        expected = np.concatenate(
            [np.concatenate([layout.states[k], stage_q[k]]) for k in range(N)] + [layout.states[N]]
        )
        if not np.array_equal(expected, np.arange(layout.size)):
            raise ValueError("unexpected decision layout: the real-time iteration needs w = (x_0, u_0, c_0, ..., x_N)")
        self.state_index, self.stage_index = layout.states, stage_q
        self.state_scale = tr.scale[layout.states[0]]
        w, P = tr.nlp["x"], tr.nlp["p"]
        nw, n_p = w.numel(), P.numel()
        g = tr.nlp["g"]
        dynamics = tr.dynamics_rows.ravel()
        others = np.setdiff1d(np.arange(g.numel()), dynamics)
        lbx, ubx, lbg, ubg = tr.bounds(P)

        # Bounds: x_0 = x0 exactly; no other state bound (checked on random parameters).
        probe = ca.Function("probe", [P], [lbx, ubx])
        rng = np.random.default_rng(0)
        values = rng.normal(size=n_p)
        low, high = (np.asarray(v, dtype=float).ravel() for v in probe(values))
        x0 = values[tr.parameter_slices["x0"]] / self.state_scale
        if not (np.allclose(low[layout.states[0]], x0) and np.allclose(high[layout.states[0]], x0)):
            raise ValueError("the real-time iteration needs x(0) = x0 fixed by ocp.start_from() alone")
        later = layout.states[1:].ravel()
        if np.any(np.isfinite(low[later])) or np.any(np.isfinite(high[later])):
            raise ValueError(
                "the real-time iteration takes no state bounds after t = 0: write them as soft "
                "constraints with a slack control"
            )
        self.parameter_size, self.decision_size = n_p, nw

        # ------------------------------------------------------------- linearization (SX, per interval)
        f = tr.nlp["f"]
        stage_of = np.empty(nw, int)
        for k in range(N):
            stage_of[layout.states[k]] = k
            stage_of[stage_q[k]] = k
        stage_of[layout.states[N]] = N
        stages = self._stage_functions(w, P, f, g, dynamics, others, stage_of, layout, stage_q)
        bounds = ca.Function("rti_bounds", [P], [lbx[stage_q.ravel()], ubx[stage_q.ravel()], lbg, ubg])

        # ------------------------------------------------------------- condensing (MX)
        wm, Pm = ca.MX.sym("w", nw), ca.MX.sym("P", n_p)
        lbq, ubq, lbg_all, ubg_all = bounds(Pm)
        nz = nx + 1 + N * nq
        s_idx = [list(map(int, layout.states[k])) for k in range(N + 1)]
        q_idx = [list(map(int, stage_q[k])) for k in range(N)]
        lin = self._evaluate_stages(stages, wm, Pm, s_idx, q_idx)
        A = [lin[k]["A"] for k in range(N)]
        a = [lin[k]["a"] for k in range(N)]
        # Inputs and controls that enter the dynamics (d) and those that do not (σ: slacks): only d
        # needs eliminating, so the recursions run on z = (Δs_0, 1, Δd_0, ..., Δd_{N-1}).
        entering = set()
        for fun in stages["functions"][:N]:
            entering |= set(fun.sparsity_out("B").get_col())
        dyn = sorted(entering)
        stat = [i for i in range(nq) if i not in entering]
        nd, nst = len(dyn), len(stat)
        self.dynamic_columns, self.static_columns = dyn, stat
        nz = nx + 1 + N * nd
        B = [lin[k]["B"][:, dyn] for k in range(N)]
        # Dense recursions as one stage Function each, run by mapaccum (compact generated code).
        # E_k (nd x nz) selects interval k's Δd_k from z; as an input sequence.
        selections = ca.DM(nd, N * nz)
        for k in range(N):
            for i in range(nd):
                selections[i, k * nz + nx + 1 + k * nd + i] = 1
        G, Am, Bm, am, Em = (
            ca.MX.sym("Gamma", nx, nz),
            ca.MX.sym("A", nx, nx),
            ca.MX.sym("B", nx, nd),
            ca.MX.sym("a", nx),
            ca.MX.sym("E", nd, nz),
        )
        one = ca.DM(1, nz)
        one[0, nx] = 1  # z's constant entry: a_k enters Γ_{k+1} as a_k e₁ᵀ
        forward = ca.Function("rti_forward", [G, Am, Bm, am, Em], [Am @ G + Bm @ Em + am @ one])
        Gamma0 = ca.horzcat(ca.DM.eye(nx), ca.DM(nx, nz - nx))
        A_seq, B_seq, a_seq = ca.horzcat(*A), ca.horzcat(*B), ca.horzcat(*a)
        E_seq = ca.DM(selections)
        Gammas = forward.mapaccum("rti_forward_all", N)(Gamma0, A_seq, B_seq, a_seq, E_seq)
        Gamma = [Gamma0] + ca.horzsplit(Gammas, nz)
        # Backward, with the stage Hessian's blocks Q_k = H_ss, S_k = H_ds, R_k = H_dd and gradient (q_k, r_k)
        # over (s, d), and c_k = Γ_k's constant column (the states' offset from the gaps a_j):
        #   P_k = Q_k + A_kᵀ P_{k+1} A_k,   λ_k = Q_k c_k + q_k + A_kᵀ λ_{k+1}   (P_N = Q_N, λ_N = Q_N c_N + q_N).
        # The condensed Hessian's row of Δd_k over Δs_0 and Δd_j, j <= k, is
        #   B_kᵀ P_{k+1} Γ_{k+1} + S_k Γ_k + R_k E_k
        # (later stages see those columns only through Φ(m, k+1) Γ_{k+1}; the columns j > k of this
        # expression are zero), its gradient r_k + S_k c_k + B_kᵀ λ_{k+1}: O(N² nx nd) after the
        # O(N nx³) recursion, against O(N² nx²) for an adjoint of every column. The rows of the static
        # controls σ: [H_σs Γ_k + H_σd E_k, ∇_σ f] (no products where σ does not couple).
        Yn, Hm, gm = ca.MX.sym("Y", nx, nx + 1), ca.MX.sym("H", nx + nq, nx + nq), ca.MX.sym("grad", nx + nq)
        Gk, Gn = ca.MX.sym("Gamma", nx, nz), ca.MX.sym("Gamma_next", nx, nz)
        sx, sd, ss = list(range(nx)), [nx + i for i in dyn], [nx + i for i in stat]
        # Static controls that couple with states or dynamic inputs in the Hessian (else H_σs, H_σd = 0).
        static_entries = set(stage_q[:, stat].ravel().tolist())
        coupled = any((i in static_entries) != (j in static_entries) for i, j in zip(*stages["hessian"].get_triplet()))
        P_next, lam_next, offset = Yn[:, :nx], Yn[:, nx], Gk[:, nx]
        row = Bm.T @ P_next @ Gn + Hm[sd, sx] @ Gk + Hm[sd, sd] @ Em
        gradient_d = gm[sd] + Hm[sd, sx] @ offset + Bm.T @ lam_next
        backward = ca.Function(
            "rti_backward",
            [Yn, Gk, Gn, Am, Bm, Em, Hm, gm],
            [
                ca.horzcat(Hm[sx, sx] + Am.T @ P_next @ Am, Hm[sx, sx] @ offset + gm[sx] + Am.T @ lam_next),
                ca.horzcat(row[:, :nx], gradient_d, row[:, nx + 1 :]),
                ca.horzcat(Hm[ss, sx] @ Gk + Hm[ss, sd] @ Em if coupled else ca.MX(nst, nz), gm[ss]),
            ],
        )
        Q_N = lin[N]["H"]
        Y_N = ca.horzcat(Q_N, Q_N @ Gamma[N][:, nx] + lin[N]["grad"])
        order = list(reversed(range(N)))
        H_seq = ca.horzcat(*[lin[k]["H"] for k in order])
        g_seq = ca.horzcat(*[lin[k]["grad"] for k in order])
        reverse = lambda blocks, width: ca.horzcat(*[blocks[:, k * width : (k + 1) * width] for k in order])
        _, Hd_all, Hs_all = backward.mapaccum("rti_backward_all", N)(
            Y_N,
            ca.horzcat(*[Gamma[k] for k in order]),
            ca.horzcat(*[Gamma[k + 1] for k in order]),
            reverse(A_seq, nx),
            reverse(B_seq, nd),
            reverse(E_seq, nz),
            H_seq,
            g_seq,
        )
        # interval 0 first: Hd_all (N nd, nz) with the gradient in the constant's column, Hs_all (N nst, nz + 1);
        # cast: CasADi's stubs give vertcat a union with Sparsity
        Hd_all = cast(ca.MX, ca.vertcat(*reversed(ca.horzsplit(Hd_all, nz))))
        Hs_all = cast(ca.MX, ca.vertcat(*reversed(ca.horzsplit(Hs_all, nz + 1))) if nst else ca.MX(0, nz + 1))
        # The QP's variables v = (Δd_0, ..., Δd_{N-1}, Δσ_0, ..., Δσ_{N-1}): the dynamic inputs, then the
        # static controls. Every block of the Hessian and the rows is a slice of the recursions' results
        # or of the stage Jacobians, stored without selection products; H_σσ (block diagonal) and the
        # rows' σ columns C_σ (each row holds the static controls of its interval and the one before)
        # as their nonzeros.
        nD, nS = N * nd, N * nst
        dcols = list(range(nx + 1, nz))
        # Hd_all holds the lower block triangle of H_dd (zeros above): mirror it.
        lower = Hd_all[:, dcols]
        diagonal = ca.diagcat(*[lower[k * nd : (k + 1) * nd, k * nd : (k + 1) * nd] for k in range(N)]) if nd else lower
        H_dd = lower + (lower - diagonal).T
        H_sd = Hs_all[:, dcols] if coupled else ca.MX(nS, 0)
        H_ss = ca.diagcat(*[lin[k]["H"][ss, ss] for k in range(N)]) if nst else ca.MX(0, 0)
        H_v0 = ca.densify(ca.vertcat(Hd_all[:, :nx], Hs_all[:, :nx]))
        h_const = ca.densify(ca.vertcat(Hd_all[:, nx], Hs_all[:, nz] + Hs_all[:, nx]))
        E = [E_seq[:, k * nz : (k + 1) * nz] for k in range(N)]
        # Rows of interval k: J (s_k, q_k, s_{k+1}, q_{k-1}) with Δs = Γ z, Δd = E z and Δσ in place;
        # the end's rows J (s_N, q_{N-1}).
        qd = lambda offset: [offset + i for i in dyn]
        qs = lambda offset: [offset + i for i in stat]

        def static_part(k, J, current, previous):
            """Interval k's rows' entries on the static controls, in their columns of C_σ (r, N nst):
            q_k's read from J's column `current` on, q_{k-1}'s from `previous` (None: not in J)."""
            r = J.size1()
            if not nst:
                return ca.MX(r, 0)
            before = ca.MX(r, (k - 1) * nst) if previous is not None else ca.MX(r, k * nst)
            mine = [J[:, qs(previous)]] if previous is not None else []
            return ca.horzcat(before, *mine, J[:, qs(current)], ca.MX(r, (N - k - 1) * nst))

        row_blocks, row_static, row_values, row_index = [], [], [], []
        row_order: list[tuple[int, int]] = []  # each QP row's (interval, row within it)

        interior = {k for k in range(1, N) if stages["rows"][k]}
        # Intervals 1..N-1 whose Functions agree share one mapped row Function (compact code).
        for group in stages["groups"]:
            members = [k for k in group if k in interior]
            if not members:
                continue
            pattern = stages["functions"][members[0]].sparsity_out("J_g")
            J, Gk, Gn = ca.MX.sym("J", pattern), ca.MX.sym("Gamma", nx, nz), ca.MX.sym("Gamma_next", nx, nz)
            Ek, Ep = ca.MX.sym("E", nd, nz), ca.MX.sym("E_prev", nd, nz)
            block = J[:, :nx] @ Gk + J[:, qd(nx)] @ Ek + J[:, nx + nq : 2 * nx + nq] @ Gn + J[:, qd(2 * nx + nq)] @ Ep
            rows_fn = ca.Function("rti_rows", [J, Gk, Gn, Ek, Ep], [block.T])
            mapped = rows_fn.map("rti_rows_map", "serial", len(members), [], []) if len(members) > 1 else rows_fn
            blocks_t = mapped(
                ca.horzcat(*[lin[k]["J_g"] for k in members]),
                ca.horzcat(*[Gamma[k] for k in members]),
                ca.horzcat(*[Gamma[k + 1] for k in members]),
                ca.horzcat(*[E[k] for k in members]),
                ca.horzcat(*[E[k - 1] for k in members]),
            )
            row_blocks.append(blocks_t.T)
            row_static += [static_part(k, lin[k]["J_g"], nx, 2 * nx + nq) for k in members]
            row_values += [lin[k]["g"] for k in members]
            for k in members:
                row_index += stages["rows"][k]
                row_order += [(k, i) for i in range(len(stages["rows"][k]))]
        for k in (0, N):
            J, value, index = lin[k]["J_g"], lin[k]["g"], stages["rows"][k]
            if not index:
                continue
            block = J[:, :nx] @ Gamma[k]
            if k < N:
                block = block + J[:, qd(nx)] @ E[k] + J[:, nx + nq : 2 * nx + nq] @ Gamma[k + 1]
            else:
                block = block + J[:, qd(nx)] @ E[N - 1]
            row_blocks.append(block)
            row_static.append(static_part(min(k, N - 1), J, nx, None))
            row_values.append(value)
            row_index += index
            row_order += [(k, i) for i in range(len(index))]
        m = len(row_index)
        if m:
            rows, C_s = ca.vertcat(*row_blocks), ca.vertcat(*row_static)
            g_o = ca.vertcat(*row_values)
            lbg_o, ubg_o = lbg_all[row_index], ubg_all[row_index]
        else:
            rows, C_s, g_o, lbg_o, ubg_o = ca.MX(0, nz), ca.MX(0, nS), ca.MX(0, 1), ca.MX(0, 1), ca.MX(0, 1)
        C_d = rows[:, dcols]
        C_0 = ca.densify(rows[:, :nx])
        row_lo = ca.densify(lbg_o - g_o - rows[:, nx])
        row_hi = ca.densify(ubg_o - g_o - rows[:, nx])
        d_of_q = [k * nq + i for k in range(N) for i in dyn]
        s_of_q = [k * nq + i for k in range(N) for i in stat]
        self.qp_variables = stage_q.ravel()[d_of_q + s_of_q]
        self.row_index = np.array(row_index, dtype=int)
        w_q = ca.vertcat(*[wm[q_idx[k]] for k in range(N)])
        lbv, ubv = (ca.densify(bound - w_q)[d_of_q + s_of_q] for bound in (lbq, ubq))
        nonzeros = lambda M: M.nz[:] if M.nnz() else ca.MX(0, 1)
        stacked = [
            ca.vec(ca.densify(H_dd).T),  # row-major, as numpy reads it
            ca.vec(ca.densify(H_sd).T),
            nonzeros(H_ss),
            h_const,
            ca.vec(H_v0),
            ca.vec(ca.densify(C_d).T),
            nonzeros(C_s),
            row_lo,
            row_hi,
            ca.vec(C_0),
            lbv,
            ubv,
            ca.vertcat(*[ca.vec(ca.densify(m)) for m in A]),
            ca.vertcat(*[ca.vec(ca.densify(m)) for m in B]),
            ca.vertcat(*a),
            wm,
        ]
        sizes = [int(v.numel()) for v in stacked]
        self._data_sizes = sizes
        self._offsets = np.concatenate([[0], np.cumsum(sizes)]).astype(int)
        self.n_rows = m
        # Rows that hold a static control (a soft bound's slack): the feedback first tries every static
        # control at its lower bound (see `SlackFirstQP`), where they do not couple with the rest.
        hessian_pattern, row_pattern = H_ss.sparsity(), C_s.sparsity()
        self.soft_rows = sorted(set(row_pattern.row()))
        lower_static = np.asarray(probe(values)[0], dtype=float).ravel()[stage_q[:, stat].ravel()] if nst else []
        self.reduced_first = bool(slack_shortcut and nst and not coupled and np.all(np.isfinite(lower_static)))
        prepare = ca.Function("rti_prepare", [wm, Pm], [ca.vertcat(*stacked)], ["w", "P"], ["data"])
        # The same preparation in two compiled parts: the linearization (CasADi) and the condensing
        # (generated C, `mpc.condensing`), whose input is the linearization laid out by `Structure.layout`.
        structure = condensing.Structure(
            N=N,
            nx=nx,
            nq=nq,
            dynamic=tuple(dyn),
            static=tuple(stat),
            stage_rows=tuple(len(stages["rows"][k]) for k in range(N + 1)),
            row_order=np.array(row_order, dtype=int).reshape(-1, 2),
            coupled=coupled,
            hessian_nonzeros=H_ss.sparsity().get_triplet(),
            row_nonzeros=C_s.sparsity().get_triplet(),
            decisions=nw,
        )
        dense = lambda M: ca.vec(ca.densify(M))
        pieces_lin: list = []  # MX (the stubs type ca.vec as DM)
        for k in range(N):
            lk = lin[k]
            pieces_lin += [dense(A[k]), dense(B[k]), dense(a[k]), dense(lk["H"]), dense(lk["grad"])]
            pieces_lin += [dense(lk["J_g"]), dense(lk["g"])]
        pieces_lin += [dense(lin[N][name]) for name in ("H", "grad", "J_g", "g")]
        pieces_lin += [lbv, ubv, ca.densify(lbg_o), ca.densify(ubg_o), wm]
        linearize = ca.Function("rti_linearize", [wm, Pm], [ca.vertcat(*pieces_lin)], ["w", "P"], ["lin"])
        assert linearize.size1_out(0) == structure.layout()["size"]

        # ------------------------------------------------------------- feedback (MX around the QP)
        data, x0m = ca.MX.sym("data", sum(sizes)), ca.MX.sym("x0", nx)
        pieces = ca.vertsplit(data, list(self._offsets))
        nQ = N * nq
        H_dd_f = ca.reshape(pieces[0], nD, nD).T
        H_sd_f = ca.reshape(pieces[1], nD, nS).T if coupled else ca.MX(nS, nD)  # structurally zero if not
        H_ss_f = ca.MX(hessian_pattern, pieces[2])
        h_c, H_v0_f = pieces[3], ca.reshape(pieces[4], nQ, nx)
        C_d_f, C_s_f = ca.reshape(pieces[5], nD, m).T, ca.MX(row_pattern, pieces[6])
        lo_f, hi_f, C_0_f = pieces[7], pieces[8], ca.reshape(pieces[9], m, nx)
        lbv_f, ubv_f = pieces[10], pieces[11]
        A_f = [ca.reshape(v, nx, nx) for v in ca.vertsplit(pieces[12], nx * nx)] if N else []
        B_f = [ca.reshape(v, nx, nd) for v in ca.vertsplit(pieces[13], nx * nd)] if nd else [ca.MX(nx, 0)] * N
        a_f = ca.vertsplit(pieces[14], nx)
        w_bar = pieces[15]
        ds0 = x0m / ca.DM(self.state_scale) - w_bar[s_idx[0]]
        h = h_c + H_v0_f @ ds0
        lba, uba = lo_f - C_0_f @ ds0, hi_f - C_0_f @ ds0
        vectors = ca.Function("rti_qp_vectors", [data, x0m], [h, lba, uba], ["data", "x0"], ["h", "lba", "uba"])
        dv, lam_a, lam_x = ca.MX.sym("dv", nQ), ca.MX.sym("lam_a", m), ca.MX.sym("lam_x", nQ)
        dv_d, dv_s = dv[:nD], dv[nD:]
        H_dv = ca.vertcat(H_dd_f @ dv_d + H_sd_f.T @ dv_s, H_sd_f @ dv_d + H_ss_f @ dv_s)
        C_dv = C_d_f @ dv_d + C_s_f @ dv_s
        stationarity = ca.mmax(ca.fabs(H_dv + h + ca.vertcat(C_d_f.T @ lam_a, C_s_f.T @ lam_a) + lam_x))
        violation = ca.mmax(ca.vertcat(0, lba - C_dv, C_dv - uba, lbv_f - dv, dv - ubv_f))
        v_of_q = np.empty(nQ, dtype=int)
        v_of_q[d_of_q + s_of_q] = np.arange(nQ)
        dq = dv[list(map(int, v_of_q))]
        ds, pieces_w = ds0, []
        for k in range(N):
            dq_k = dq[k * nq : (k + 1) * nq]
            pieces_w += [ds, dq_k]
            ds = A_f[k] @ ds + B_f[k] @ dq_k[self.dynamic_columns] + a_f[k]
        pieces_w.append(ds)
        delta = ca.vertcat(*pieces_w)
        recover = ca.Function(
            "rti_recover",
            [data, x0m, dv, lam_a, lam_x],
            [w_bar + delta, ca.vertcat(stationarity, violation)],
            ["data", "x0", "dv", "lam_a", "lam_x"],
            ["w_next", "qp"],
        )
        # The whole QP by CasADi's DAQP node in one Function: a second path to the same answer.
        H_whole = ca.vertcat(ca.horzcat(H_dd_f, H_sd_f.T), ca.horzcat(H_sd_f, H_ss_f))
        whole = self._qp(nQ, m, "rti_qp")(
            ca.densify(H_whole), h, ca.densify(ca.horzcat(C_d_f, C_s_f)), lba, uba, lbv_f, ubv_f
        )
        whole_feedback = ca.Function(
            "rti_feedback_whole", [data, x0m], list(recover(data, x0m, *whole)), ["data", "x0"], ["w_next", "qp"]
        )
        w_s, P_s, x_s = ca.MX.sym("w", nw), ca.MX.sym("P", n_p), ca.MX.sym("x0", nx)
        step = whole_feedback(prepare(w_s, P_s), x_s)
        self.step_function = ca.Function("rti_step", [w_s, P_s, x_s], list(step), ["w", "P", "x0"], ["w_next", "qp"])
        self.qp_solver = SlackFirstQP(
            nD,
            nS,
            m,
            hessian_pattern.get_triplet(),
            row_pattern.get_triplet(),
            coupled=coupled,
            slack_first=self.reduced_first,
            settings={"primal_tol": PRIMAL_TOLERANCE},
            tolerance=10 * PRIMAL_TOLERANCE,
        )
        # Without the slack-first sequence the feedback is one compiled Function, the whole QP solved by
        # CasADi's DAQP node: the same QP as `qp_solver` would solve whole, without the two calls from
        # Python around it (measured: 0.05 ms less per step on the arm, N = 50, no soft bounds).
        self.compiled = bool(compiled)
        self.linearize_function, self.condensing = None, None
        if compiled and nd:
            self.condensing = condensing.Condensing.compiled(structure, self._offsets)
        if self.condensing is not None:
            size = sum(stages["functions"][group[0]].n_instructions() for group in stages["groups"])
            flags = COMPILE_FLAGS if size <= LARGE_CODE else LARGE_CODE_FLAGS
            self.linearize_function = models.compile.jit(linearize, flags)
            self._linearize_call = models.compile.NumpyCall(self.linearize_function)
        elif compiled:
            prepare = models.compile.jit(prepare, COMPILE_FLAGS)
            if self.reduced_first:
                vectors = models.compile.jit(vectors, COMPILE_FLAGS)
                recover = models.compile.jit(recover, COMPILE_FLAGS)
            else:
                whole_feedback = models.compile.jit(whole_feedback, _daqp_flags())
        self.prepare_function, self.vectors_function, self.recover_function = prepare, vectors, recover
        self.whole_feedback_function = None if self.reduced_first else whole_feedback
        self._prepare_call = models.compile.NumpyCall(prepare)
        self._vectors_call = models.compile.NumpyCall(vectors)
        self._recover_call = models.compile.NumpyCall(recover)
        self._whole_call = None if self.reduced_first else models.compile.NumpyCall(whole_feedback)

        shift = []
        for k in range(N):
            source = min(k + 1, N - 1)
            shift += [*layout.states[k + 1], *stage_q[source]]
        shift += list(layout.states[N])
        self.shift_index = np.array(shift, dtype=int)

    @staticmethod
    def _stage_functions(w, P, f, g, dynamics, others, stage_of, layout, stage_q) -> dict:
        """Per interval k, a Function (s_k, q_k, s_{k+1}, q_{k-1}, P) -> (a, A, B, I, g, J_g, grad, H): its
        gap -(x_{k+1} - F) and -∂/∂(s_k, q_k), the gap's ∂/∂s_{k+1} (checked to be I), its other rows
        and their Jacobian in (s_k, q_k, s_{k+1}, q_{k-1}), the objective's gradient and Gauss-Newton
        Hessian in (s_k, q_k); and the end's Function (s_N, q_{N-1}, P) -> (g, J_g, grad, H). Intervals whose Functions
        agree (same sparsity, same values at a common random point) share one, evaluated with `map`,
        so the generated code holds it once.
        """
        N, nx = stage_q.shape[0], layout.states.shape[1]
        grad = ca.gradient(f, w)
        hessian = ca.hessian(f, w)[0]
        rows_h, cols_h = hessian.sparsity().get_triplet()
        if any(stage_of[i] != stage_of[j] for i, j in zip(rows_h, cols_h)):
            raise ValueError(
                "the objective couples decisions of different intervals; the real-time iteration "
                "needs a stage-wise objective (sum, integral, end terms)"
            )
        # Which interval each other row belongs to: its decisions' (a row on x_{k+1} and interval k's
        # input belongs to interval k).
        rows_by_stage: list[list[int]] = [[] for _ in range(N + 1)]

        def allowed(k):
            inside = set(layout.states[k]) | (set(stage_q[k]) | set(layout.states[k + 1]) if k < N else set())
            return inside | (set(stage_q[k - 1]) if k > 0 else set())

        if len(others):
            pattern = ca.jacobian(g[list(map(int, others))], w).sparsity()
            rows_of, cols_of = pattern.get_triplet()
            touched: list[set] = [set() for _ in others]
            for r, c in zip(rows_of, cols_of):
                touched[r].add(int(c))
            for position, row in enumerate(others):
                columns = touched[position]
                candidates = [k for k in range(N + 1) if columns <= allowed(k)]
                if not candidates:
                    owners = sorted({int(stage_of[c]) for c in columns})
                    raise ValueError(
                        f"the real-time iteration needs each constraint on one interval (with x_{{k+1}} "
                        f"and u_{{k-1}}); row {row} spans mesh points {owners}"
                    )
                rows_by_stage[max(candidates)].append(int(row))
        indices = lambda array: list(map(int, array))
        functions = []
        for k in range(N):
            s_k, q_k, s_next = w[indices(layout.states[k])], w[indices(stage_q[k])], w[indices(layout.states[k + 1])]
            q_prev = w[indices(stage_q[k - 1])] if k else ca.SX.sym("q_before", stage_q.shape[1])
            v = indices(np.concatenate([layout.states[k], stage_q[k]]))
            gap = g[indices(dynamics[k * nx : (k + 1) * nx])]
            g_k = g[rows_by_stage[k]] if rows_by_stage[k] else ca.SX(0, 1)
            outputs = [
                -gap,
                -ca.jacobian(gap, s_k),
                -ca.jacobian(gap, q_k),
                ca.jacobian(gap, s_next),
                g_k,
                ca.jacobian(g_k, ca.vertcat(s_k, q_k, s_next, q_prev)),
                grad[v],
                ca.densify(hessian[v, v]),
            ]
            functions.append(
                ca.Function(
                    f"rti_interval_{k}",
                    [s_k, q_k, s_next, q_prev, P],
                    outputs,
                    ["s", "q", "s_next", "q_prev", "P"],
                    ["a", "A", "B", "I", "g", "J_g", "grad", "H"],
                    {"cse": True},
                )
            )
        s_N, v = w[indices(layout.states[N])], indices(layout.states[N])
        q_last = w[indices(stage_q[N - 1])]
        g_N = g[rows_by_stage[N]] if rows_by_stage[N] else ca.SX(0, 1)
        functions.append(
            ca.Function(
                "rti_end",
                [s_N, q_last, P],
                [g_N, ca.jacobian(g_N, ca.vertcat(s_N, q_last)), grad[v], ca.densify(hessian[v, v])],
                ["s", "q_prev", "P"],
                ["g", "J_g", "grad", "H"],
                {"cse": True},
            )
        )
        rng = np.random.default_rng(1)
        common: dict = {}
        groups: dict = {}
        for k in range(N):
            fun = functions[k]
            point = [common.setdefault(fun.size1_in(i), rng.normal(size=fun.size1_in(i))) for i in range(5)]
            out = fun(*point)
            if not np.allclose(np.asarray(out[3], dtype=float), np.eye(nx), atol=1e-12):
                raise ValueError(f"shooting gap {k} is not x_{{k+1}} - F(x_k, u_k) (scaled)")
            key = (
                len(rows_by_stage[k]),
                tuple(str(fun.sparsity_out(i)) for i in range(fun.n_out())),
                tuple(np.round(np.asarray(o, dtype=float).ravel(), 10).tobytes() for o in out),
            )
            groups.setdefault(key, []).append(k)
        return {
            "functions": functions,
            "groups": list(groups.values()),
            "rows": rows_by_stage,
            "hessian": hessian.sparsity(),
        }

    @staticmethod
    def _evaluate_stages(stages, wm, Pm, s_idx, q_idx) -> list[dict]:
        """MX outputs of every interval's and the end's Function at (wm, Pm), one `map` per group."""
        N = len(q_idx)
        lin: list[dict] = [{} for _ in range(N + 1)]
        names = ["a", "A", "B", "I", "g", "J_g", "grad", "H"]
        for group in stages["groups"]:
            fun = stages["functions"][group[0]]
            n = len(group)
            mapped = fun.map(f"{fun.name()}_map", "serial", n, [4], []) if n > 1 else fun
            s = ca.horzcat(*[wm[s_idx[k]] for k in group])
            q = ca.horzcat(*[wm[q_idx[k]] for k in group])
            s_next = ca.horzcat(*[wm[s_idx[k + 1]] for k in group])
            q_prev = ca.horzcat(*[wm[q_idx[k - 1]] if k else ca.MX.zeros(len(q_idx[0])) for k in group])
            outs = mapped(s, q, s_next, q_prev, Pm)
            for name, value in zip(names, outs):
                width = value.size2() // n
                for i, k in enumerate(group):
                    lin[k][name] = value[:, i * width : (i + 1) * width]
        g, J_g, grad, H = stages["functions"][N](wm[s_idx[N]], wm[q_idx[N - 1]], Pm)
        lin[N] = {"g": g, "J_g": J_g, "grad": grad, "H": H}
        return lin

    @staticmethod
    def _qp(n: int, m: int, name: str) -> ca.Function:
        """(H, g, A, lba, uba, lbx, ubx) -> (x, lam_a, lam_x) of DAQP on a dense QP of n variables, m rows."""
        solver = ca.conic(
            name,
            "daqp",
            {"h": ca.Sparsity.dense(n, n), "a": ca.Sparsity.dense(m, n)},
            {"error_on_fail": False, "daqp": {"primal_tol": PRIMAL_TOLERANCE}},
        )
        H, g, A = ca.MX.sym("H", n, n), ca.MX.sym("g", n), ca.MX.sym("A", m, n)
        lba, uba, lbx, ubx = ca.MX.sym("lba", m), ca.MX.sym("uba", m), ca.MX.sym("lbx", n), ca.MX.sym("ubx", n)
        answer = solver(h=H, g=g, a=A, lba=lba, uba=uba, lbx=lbx, ubx=ubx)
        return ca.Function(name, [H, g, A, lba, uba, lbx, ubx], [answer["x"], answer["lam_a"], answer["lam_x"]])

    # ------------------------------------------------------------------ phases
    def prepare(self, decision, P) -> np.ndarray:
        """Linearize at `decision` (scaled, (nw,)) with parameters P and condense: the QP data."""
        if self.condensing is not None:
            return self.condensing(self._linearize_call(decision, P)[0].T)[0]
        return self._prepare_call(decision, P)[0].ravel()

    def feedback(self, data, x0) -> tuple[np.ndarray, QPReport]:
        """Solve the prepared QP for the initial state x0 (physical, (nx,)): new decisions and the QP report."""
        data = np.asarray(data, dtype=float).ravel()
        if self._whole_call is not None:
            w_next, residuals = self._whole_call(data, x0)
            return w_next.ravel(), self.report(np.append(residuals.ravel(), np.nan))
        h, lba, uba = (v.ravel() for v in self._vectors_call(data, x0))
        dv, lam_a, lam_x, flag = self._solve_qp(data, h, lba, uba)
        w_next, residuals = self._recover_call(data, x0, dv, lam_a, lam_x)
        return w_next.ravel(), self.report(np.append(residuals.ravel(), flag))

    def qp_pieces(self, data) -> dict:
        """The QP's fixed pieces in one sample's prepared `data` (views, no copies): H_dd (nD, nD), H_sd
        (nS, nD) or None, hessian_values (H_σσ's nonzeros), C_d (m, nD), row_values (C_σ's nonzeros),
        lbv, ubv (nD + nS,): the arguments of `qp_solver`'s `solve` besides h, lba, uba."""
        o, qp = self._offsets, self.qp_solver
        nD, nS, m = qp.n_dynamic, qp.n_static, qp.m
        return {
            "H_dd": data[o[0] : o[1]].reshape(nD, nD),
            "H_sd": data[o[1] : o[2]].reshape(nS, nD) if qp.coupled else None,
            "hessian_values": data[o[2] : o[3]],
            "C_d": data[o[5] : o[6]].reshape(m, nD),
            "row_values": data[o[6] : o[7]],
            "lbv": data[o[10] : o[11]],
            "ubv": data[o[11] : o[12]],
        }

    def _solve_qp(self, data, h, lba, uba) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
        """The QP of one sample's `data` with the vectors h, lba, uba: (dv, lam_a, lam_x, DAQP exit flag)."""
        p = self.qp_pieces(data)
        dv, lam_a, lam_x, flag, _ = self.qp_solver.solve(
            p["H_dd"], p["H_sd"], p["hessian_values"], p["C_d"], p["row_values"], h, lba, uba, p["lbv"], p["ubv"]
        )
        return dv, lam_a, lam_x, flag

    def prepare_many(self, decisions, P) -> np.ndarray:
        """`prepare` of m samples at once: decisions (m, nw), P (m, np) -> QP data (m, n_data).

        The compiled preparation mapped over the samples: each row's numbers are `prepare`'s."""
        decisions, P = np.asarray(decisions, dtype=float), np.asarray(P, dtype=float)
        if self.condensing is not None:
            assert self.linearize_function is not None  # built with the condensing
            return self.condensing(self._mapped(self.linearize_function, len(decisions))(decisions.T, P.T)[0].T)
        return self._mapped(self.prepare_function, len(decisions))(decisions.T, P.T)[0].T

    def feedback_many(self, data, x0) -> tuple[np.ndarray, np.ndarray]:
        """`feedback` of m samples at once: data (m, n_data), x0 (m, nx) -> (decisions (m, nw),
        residuals (m, 3)); `report(residuals[i])` is sample i's QPReport.

        The compiled parts mapped over the samples, the QPs one by one: each row's numbers are `feedback`'s."""
        data, x0 = np.asarray(data, dtype=float), np.asarray(x0, dtype=float)
        count = len(data)
        if self.whole_feedback_function is not None:
            w_next, residuals = self._mapped(self.whole_feedback_function, count)(data.T, x0.T)
            return w_next.T, np.column_stack([residuals.T, np.full(count, np.nan)])
        h, lba, uba = (v.T for v in self._mapped(self.vectors_function, count)(data.T, x0.T))
        solved = [self._solve_qp(data[i], h[i], lba[i], uba[i]) for i in range(count)]
        dv, lam_a, lam_x = (np.array([s[j] for s in solved]).reshape(count, -1) for j in range(3))
        w_next, residuals = self._mapped(self.recover_function, count)(data.T, x0.T, dv.T, lam_a.T, lam_x.T)
        return w_next.T, np.column_stack([residuals.T, [s[3] for s in solved]])

    def _mapped(self, fun: ca.Function, m: int) -> models.compile.NumpyCall:
        calls = self.__dict__.setdefault("_mapped_calls", {})
        key = (fun.name(), m)
        if key not in calls:
            calls[key] = models.compile.NumpyCall(fun.map(m))
        return calls[key]

    @staticmethod
    def report(residuals) -> QPReport:
        """QPReport from the (stationarity, violation, DAQP exit flag) a feedback returns; the flag is NaN
        where CasADi's DAQP node solved the QP (it reports none): the residuals judge alone."""
        stationarity, violation, flag = float(residuals[0]), float(residuals[1]), float(residuals[2])
        finite = np.isfinite(stationarity) and np.isfinite(violation)
        failed = not np.isnan(flag) and flag <= 0
        success = not failed and finite and stationarity <= QP_TOLERANCE and violation <= QP_TOLERANCE
        if success:
            status = "solved"
        elif failed:
            code = int(flag)
            status = f"QP failed: DAQP {DAQP_STATUS.get(code, f'exit flag {code}')}"
        elif not finite:
            status = "QP failed: non-finite residuals"
        else:
            status = f"QP not solved (stationarity {stationarity:.1e}, violation {violation:.1e})"
        return QPReport(status, bool(success), stationarity, violation)

    def iterate(self, decision, P, x0) -> IterationResult:
        """One real-time iteration: preparation at `decision`, feedback with x0."""
        started = time.perf_counter()
        data = self.prepare(decision, P)
        prepared = time.perf_counter()
        w_next, qp = self.feedback(data, x0)
        done = time.perf_counter()
        step = float(np.max(np.abs(w_next - decision))) if w_next.size else 0.0
        return IterationResult(w_next, step, qp, 1, prepared - started, done - prepared, True)

    def solve(self, decision, P, x0, *, tolerance: float = 1e-8, max_iterations: int = 50) -> IterationResult:
        """Full-step Gauss-Newton SQP from `decision`: iterate until max |Δw| <= tolerance (scaled units).

        Returns the last iterate; `converged` False when the iteration limit came first
        or a QP failed.
        """
        tolerance = positive(tolerance, "tolerance")
        max_iterations = integer(max_iterations, "max_iterations", minimum=1)
        w = np.asarray(decision, dtype=float).ravel().copy()
        prep = back = 0.0
        result = None
        for i in range(max_iterations):
            interrupts.check()
            result = self.iterate(w, P, x0)
            prep, back = prep + result.preparation_time, back + result.feedback_time
            w = result.decision
            if not result.qp.success or not np.all(np.isfinite(w)):
                return IterationResult(w, result.step, result.qp, i + 1, prep, back, False)
            if result.step <= tolerance:
                return IterationResult(w, result.step, result.qp, i + 1, prep, back, True)
        assert result is not None
        return IterationResult(w, result.step, result.qp, max_iterations, prep, back, False)

    def shift(self, decision) -> np.ndarray:
        """`decision` one interval later: stages move up, the last input and control repeated;
        (nw,) or a batch (m, nw)."""
        return np.asarray(decision)[..., self.shift_index]
