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

- **preparation** (`prepare`, before the measurement): linearize
  (`mpc.rti_linearization`) and condense (`mpc.condensed_qp`): eliminate the
  states by a forward recursion over z = (Δs_0, 1, Δd) (Δd: the inputs and
  controls that enter the dynamics) and form the dense Hessian by a backward
  recursion, O(N² nx nd + N nx³) instead of the O(N³) of multiplying the
  stacked matrices;
- **feedback** (`feedback`, once x0 is known): the gradient and row bounds are
  affine in Δs_0 (two matrix-vector products), DAQP's dual active-set method
  solves the dense QP, slacks first held at their bounds
  (`mpc.slack_first.SlackFirstQP`), and the states are recovered by the linear
  recursion (`mpc.rti_feedback`).

Condensing and a dense active-set method rather than a Riccati-based sparse
QP solver: the condensed QP has only N (nu + ns) variables, which DAQP solves
in tens of microseconds, and rows coupling neighbouring intervals (a rate
limit) cost nothing extra (docs/notes/mpc.md has the measurement).

The preparation and the feedback's two halves around the QP are CasADi
Functions (SX for the linearization, MX for the recursions), generated as C
and compiled once through `models.compile` (cached between runs; CasADi's
virtual machine when no compiler is available); the condensing runs as
`mpc.condensing`'s generated C. With soft bounds the QPs are solved from
Python by the `daqp` package, which a sequence of QPs of changing size needs
(a CasADi Function has fixed sizes); without, the whole feedback is one
compiled Function with the QP as a `casadi.conic("daqp")` node.
`step_function` chains both phases into one CasADi Function with the whole QP
as that node, a second path to the same answer.

Iterating preparation and feedback at a fixed x0 is the full-step
Gauss-Newton SQP (`solve`), which converges to a KKT point of the NLP (the
converged SQP option).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import casadi as ca
import numpy as np

import models
from models import interrupts
from models.checks import integer, positive

from . import condensed_qp, condensing, rti_feedback, rti_linearization
from .condensed_qp import DataLayout, Dimensions, HessianBlocks, Rows
from .qp_fast import DAQP_STATUS, PRIMAL_TOLERANCE
from .rti_linearization import Checked, Stages
from .slack_first import NEAR, SlackFirstQP
from .transcription import Transcription

__all__ = ["NEAR", "IterationResult", "QPReport", "RealTimeIteration", "SlackFirstQP"]

#: Compiler flags of the generated phases: models.compile's -O3 -march=native.
COMPILE_FLAGS = models.compile.FLAGS

#: The linearization is straight-line code (one CasADi SX Function per group of alike intervals); past
#: LARGE_CODE instructions in those Functions it is compiled with LARGE_CODE_FLAGS: -O3 took 7x as long
#: to compile the crane's for no faster code (docs/notes/mpc.md).
LARGE_CODE = 10_000
LARGE_CODE_FLAGS = ("-O1", "-march=native")

#: Largest QP residual (stationarity and bound violation, in scaled units) a solve may leave.
QP_TOLERANCE = 1e-6


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


@dataclass(frozen=True)
class _Linearized:
    """The linearization at MX symbols: w, P, each interval's outputs (`evaluate_stages`) and the
    bounds of the stage inputs (N nq,) and of g, as MX in P."""

    w: ca.MX
    P: ca.MX
    lin: list
    input_lower: ca.MX
    input_upper: ca.MX
    row_lower: ca.MX
    row_upper: ca.MX


@dataclass(frozen=True)
class _Condensed:
    """The condensing's results: dimensions, whether σ couples, Γ_0..Γ_N, E_0..E_{N-1}, the
    Hessian's blocks, and the intervals' A_k, B_k (dynamic columns), a_k."""

    dims: Dimensions
    coupled: bool
    Gamma: list
    E: list
    blocks: HessianBlocks
    A: list
    B: list
    a: list


class RealTimeIteration:
    """The condensed Gauss-Newton QP of a multiple-shooting transcription, built once.

    Construction runs the steps in order: validation (`rti_linearization.check`), linearization
    (`rti_linearization.stage_functions`, one SX Function per group of alike intervals), condensing
    (`condensed_qp.forward`, `backward`, `hessian_blocks`), rows (`condensed_qp.constraint_rows`),
    the prepared data's layout (`condensed_qp.DataLayout`), feedback
    (`rti_feedback.feedback_functions`), QP setup (`SlackFirstQP`) and compilation.

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
    progress : None, or called as progress(text) when the construction reaches its compilation

    Attributes
    ----------
    prepare_function : casadi.Function
        ``prepare(w, P) -> data``, the preparation as CasADi expressions; compiled when asked and
        `condensing` is None
    linearize_function : casadi.Function or None
        ``linearize(w, P) -> lin``, compiled: the preparation's first part, the intervals' Jacobians
        and Hessians (laid out as `mpc.condensing.Structure.layout` says)
    linearize_expression : casadi.Function
        `linearize_function` as CasADi expressions, not compiled (what an export generates as C)
    condensing : mpc.condensing.Condensing or None
        The preparation's second part in generated C, ``condensing(lin rows) -> data rows`` (the same
        numbers as `prepare_function`'s to rounding, faster: it skips Γ_k's zero columns); None when
        not compiled or no library can be built
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
    layout : condensed_qp.DataLayout, where each piece sits in the prepared data
    shift_index : (nw,) int, ``w[shift_index]`` is w one interval later (the last repeated)
    qp_variables : (N nq,) int, the decisions (indices into w) the QP's variables v step, in v's
        order: the inputs and controls that enter the dynamics, then the others (slacks)
    row_index : (m,) int, the NLP's constraint rows (indices into g) of the QP's rows, in order
    """

    def __init__(
        self, transcription: Transcription, *, compiled: bool = True, slack_shortcut: bool = True, progress=None
    ):
        checked = rti_linearization.check(transcription)
        self.transcription = transcription
        self.intervals, self.nx, self.nq = checked.intervals, checked.nx, checked.nq
        self.state_index, self.stage_index = checked.states, checked.stage_q
        self.state_scale = checked.state_scale
        self.parameter_size, self.decision_size = checked.parameters, checked.decisions
        stages = rti_linearization.stage_functions(checked)
        linearized = self._linearize(checked, stages)
        condensed = self._condense(checked, stages, linearized)
        rows = condensed_qp.constraint_rows(
            linearized.lin,
            stages,
            condensed.Gamma,
            condensed.E,
            condensed.dims,
            linearized.row_lower,
            linearized.row_upper,
        )
        prepare, structure, bounds = self._lay_out(checked, stages, linearized, condensed, rows, slack_shortcut)
        linearize = self._linearize_function(linearized, condensed, rows, bounds, structure)
        self.linearize_expression = linearize
        feedback = rti_feedback.feedback_functions(self.layout, self.state_scale, checked.states[0])
        self.step_function = rti_feedback.step_function(
            prepare, feedback.whole, self.decision_size, self.parameter_size, self.nx
        )
        self.qp_solver = SlackFirstQP(
            condensed.dims.n_dynamic,
            condensed.dims.n_static,
            self.n_rows,
            self.layout.hessian_pattern.get_triplet(),
            self.layout.row_pattern.get_triplet(),
            coupled=condensed.coupled,
            slack_first=self.reduced_first,
            settings={"primal_tol": PRIMAL_TOLERANCE},
            tolerance=10 * PRIMAL_TOLERANCE,
        )
        if progress is not None:  # progress(text): the phase done, before the longest one
            progress("linearized and condensed; compiling" if compiled else "linearized and condensed")
        self._compile(compiled, stages, structure, prepare, linearize, feedback)
        self.shift_index = shift_index(checked.states, checked.stage_q)

    # ------------------------------------------------------------------ construction steps
    def _linearize(self, checked: Checked, stages: Stages) -> _Linearized:
        """The stage Functions evaluated at MX symbols of w and P, and the bounds as MX in P."""
        tr, q = checked.transcription, checked.stage_q.ravel()
        bounds = ca.Function("rti_bounds", [tr.nlp["p"]], [checked.lbx[q], checked.ubx[q], checked.lbg, checked.ubg])
        wm, Pm = ca.MX.sym("w", checked.decisions), ca.MX.sym("P", checked.parameters)
        lbq, ubq, lbg, ubg = bounds(Pm)
        s_idx = [list(map(int, checked.states[k])) for k in range(checked.intervals + 1)]
        q_idx = [list(map(int, checked.stage_q[k])) for k in range(checked.intervals)]
        lin = rti_linearization.evaluate_stages(stages, wm, Pm, s_idx, q_idx)
        return _Linearized(wm, Pm, lin, lbq, ubq, lbg, ubg)

    def _condense(self, checked: Checked, stages: Stages, linearized: _Linearized) -> _Condensed:
        """Split q into the columns that enter the dynamics and the others, run the forward and
        backward recursions and form the Hessian's blocks (see `mpc.condensed_qp`)."""
        N, lin = checked.intervals, linearized.lin
        dims = condensed_qp.dimensions(stages, N, checked.nx, checked.nq)
        self.dynamic_columns, self.static_columns = list(dims.dynamic), list(dims.static)
        A = [lin[k]["A"] for k in range(N)]
        a = [lin[k]["a"] for k in range(N)]
        B = [lin[k]["B"][:, self.dynamic_columns] for k in range(N)]
        E_seq = condensed_qp.selections(dims)
        A_seq, B_seq, a_seq = ca.horzcat(*A), ca.horzcat(*B), ca.horzcat(*a)
        Gamma = condensed_qp.forward(A_seq, B_seq, a_seq, E_seq, dims)
        coupled = condensed_qp.couples(stages.hessian, checked.stage_q, dims.static)
        hessians = [lin[k]["H"] for k in range(N + 1)]
        gradients = [lin[k]["grad"] for k in range(N + 1)]
        Hd_all, Hs_all = condensed_qp.backward(Gamma, A_seq, B_seq, E_seq, hessians, gradients, dims, coupled)
        blocks = condensed_qp.hessian_blocks(Hd_all, Hs_all, hessians, dims, coupled)
        nz = dims.nz
        E = [E_seq[:, k * nz : (k + 1) * nz] for k in range(N)]
        return _Condensed(dims, coupled, Gamma, E, blocks, A, B, a)

    def _lay_out(
        self,
        checked: Checked,
        stages: Stages,
        linearized: _Linearized,
        condensed: _Condensed,
        rows: Rows,
        slack_shortcut: bool,
    ) -> tuple[ca.Function, condensing.Structure, tuple]:
        """The prepared data (`condensed_qp.DataLayout`), the preparation Function returning it, the
        `condensing.Structure` of the generated C that computes it from the linearization, and the QP
        variables' bounds (lbv, ubv) as MX in (w, P)."""
        dims, wm = condensed.dims, linearized.w
        d_of_q, s_of_q = dims.variable_order()
        self.qp_variables = checked.stage_q.ravel()[d_of_q + s_of_q]
        self.row_index = np.array(rows.index, dtype=int)
        q_idx = [list(map(int, checked.stage_q[k])) for k in range(dims.intervals)]
        w_q = ca.vertcat(*[wm[q_idx[k]] for k in range(dims.intervals)])
        lbv, ubv = (
            ca.densify(bound - w_q)[d_of_q + s_of_q] for bound in (linearized.input_lower, linearized.input_upper)
        )
        stacked = condensed_qp.data_pieces(
            dims, condensed.blocks, rows, lbv, ubv, condensed.A, condensed.B, condensed.a, wm
        )
        hessian_pattern, row_pattern = condensed.blocks.H_ss.sparsity(), rows.static.sparsity()
        self.n_rows = m = len(rows.index)
        self.layout = DataLayout([v.numel() for v in stacked], dims, m, condensed.coupled, hessian_pattern, row_pattern)
        # Rows that hold a static control (a soft bound's slack): the feedback first tries every static
        # control at its lower bound (see `SlackFirstQP`), where they do not couple with the rest.
        self.soft_rows = sorted(set(row_pattern.row()))
        static = checked.stage_q[:, self.static_columns].ravel()
        lower_static = checked.probe_lower[static] if dims.nst else []
        self.reduced_first = bool(
            slack_shortcut and dims.nst and not condensed.coupled and np.all(np.isfinite(lower_static))
        )
        prepare = ca.Function("rti_prepare", [wm, linearized.P], [ca.vertcat(*stacked)], ["w", "P"], ["data"])
        structure = condensing.Structure(
            N=dims.intervals,
            nx=dims.nx,
            nq=dims.nq,
            dynamic=dims.dynamic,
            static=dims.static,
            stage_rows=tuple(len(stages.rows[k]) for k in range(dims.intervals + 1)),
            row_order=np.array(rows.order, dtype=int).reshape(-1, 2),
            coupled=condensed.coupled,
            hessian_nonzeros=hessian_pattern.get_triplet(),
            row_nonzeros=row_pattern.get_triplet(),
            decisions=checked.decisions,
        )
        return prepare, structure, (lbv, ubv)

    def _linearize_function(
        self, linearized: _Linearized, condensed: _Condensed, rows: Rows, bounds: tuple, structure
    ) -> ca.Function:
        """``linearize(w, P) -> lin``: the linearization laid out as `condensing.Structure.layout` says,
        the generated condensing's input."""
        lin, wm = linearized.lin, linearized.w
        dense = lambda M: ca.vec(ca.densify(M))
        pieces: list = []  # MX (the stubs type ca.vec as DM)
        for k in range(condensed.dims.intervals):
            lk = lin[k]
            pieces += [dense(condensed.A[k]), dense(condensed.B[k]), dense(condensed.a[k])]
            pieces += [dense(lk["H"]), dense(lk["grad"]), dense(lk["J_g"]), dense(lk["g"])]
        pieces += [dense(lin[-1][name]) for name in ("H", "grad", "J_g", "g")]
        pieces += [*bounds, ca.densify(rows.lower), ca.densify(rows.upper), wm]
        linearize = ca.Function("rti_linearize", [wm, linearized.P], [ca.vertcat(*pieces)], ["w", "P"], ["lin"])
        assert linearize.size1_out(0) == structure.layout()["size"]
        return linearize

    def _compile(self, compiled: bool, stages: Stages, structure, prepare, linearize, feedback) -> None:
        """Compile what runs every sample (`models.compile`): the linearization and the generated
        condensing when both can be built, else the whole preparation; the feedback's halves around
        the Python QP, or the whole feedback with CasADi's DAQP node when the slack-first sequence
        does not apply (one call from Python per step instead of three; docs/notes/mpc.md)."""
        vectors, recover, whole = feedback.vectors, feedback.recover, feedback.whole
        self.compiled = bool(compiled)
        self.linearize_function, self.condensing = None, None
        if compiled and structure.dynamic:
            self.condensing = condensing.Condensing.compiled(structure, self.layout.offsets)
        if self.condensing is not None:
            size = sum(stages.functions[group[0]].n_instructions() for group in stages.groups)
            flags = COMPILE_FLAGS if size <= LARGE_CODE else LARGE_CODE_FLAGS
            self.linearize_function = models.compile.jit(linearize, flags)
            self._linearize_call = models.compile.NumpyCall(self.linearize_function)
        elif compiled:
            prepare = models.compile.jit(prepare, COMPILE_FLAGS)
            if self.reduced_first:
                vectors = models.compile.jit(vectors, COMPILE_FLAGS)
                recover = models.compile.jit(recover, COMPILE_FLAGS)
            else:
                whole = models.compile.jit(whole, rti_feedback.daqp_flags(COMPILE_FLAGS))
        self.prepare_function, self.vectors_function, self.recover_function = prepare, vectors, recover
        self.whole_feedback_function = None if self.reduced_first else whole
        self._prepare_call = models.compile.NumpyCall(prepare)
        self._vectors_call = models.compile.NumpyCall(vectors)
        self._recover_call = models.compile.NumpyCall(recover)
        self._whole_call = None if self.reduced_first else models.compile.NumpyCall(whole)

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
        at, qp = self.layout.slice, self.qp_solver
        nD, nS, m = qp.n_dynamic, qp.n_static, qp.m
        return {
            "H_dd": data[at("H_dd")].reshape(nD, nD),
            "H_sd": data[at("H_sd")].reshape(nS, nD) if qp.coupled else None,
            "hessian_values": data[at("hessian_values")],
            "C_d": data[at("C_d")].reshape(m, nD),
            "row_values": data[at("row_values")],
            "lbv": data[at("lbv")],
            "ubv": data[at("ubv")],
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


def shift_index(states: np.ndarray, stage_q: np.ndarray) -> np.ndarray:
    """(nw,) int: ``w[shift_index]`` is w one interval later, the last interval's inputs and controls
    repeated (x_{k+1}, q_{k+1} into interval k's places; x_N stays).

    states : (N + 1, nx), stage_q : (N, nq) decision indices, w = (x_0, q_0, ..., x_N)
    """
    N = len(stage_q)
    shift = []
    for k in range(N):
        source = min(k + 1, N - 1)
        shift += [*states[k + 1], *stage_q[source]]
    shift += list(states[N])
    return np.array(shift, dtype=int)
