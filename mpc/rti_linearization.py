"""The real-time iteration's first steps: check the transcription, linearize it interval by interval.

`check` verifies that a `Transcription` is one the real-time iteration can
condense (multiple shooting, w = (x_0, u_0, c_0, ..., x_N), x(0) = x0 fixed by
`ocp.start_from()` alone, no later state bound) and returns its pieces as a
`Checked`. `stage_functions` writes one CasADi SX Function per interval:
the shooting gap's value and Jacobians, the interval's other constraint rows
and their Jacobian, and the objective's gradient and Gauss-Newton Hessian
(the Hessian of the cost alone; the constraints' curvature is dropped).
Intervals whose Functions agree share one, so the generated code holds it
once. `evaluate_stages` calls them on MX symbols of w and P, one `map` per
group of alike intervals.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from .transcription import Transcription

#: Names of an interval Function's outputs (the end's has g, J_g, grad, H).
INTERVAL_OUTPUTS = ("a", "A", "B", "I", "g", "J_g", "grad", "H")


@dataclass(frozen=True)
class Checked:
    """A transcription the real-time iteration accepts, with the pieces the later steps use.

    Attributes
    ----------
    transcription : Transcription
    intervals, nx, nq : N, states, inputs and controls per interval
    stage_q : (N, nq) int, indices into w of interval k's inputs, then its controls
    state_scale : (nx,), physical state = state_scale * scaled state
    dynamics : (N nx,) int, the rows of g holding the shooting gaps, interval by interval
    others : int array, every other row of g
    lbx, ubx, lbg, ubg : SX in P, the NLP's bounds
    probe_lower : (nw,) lbx at the random parameter values the bounds were checked at
    """

    transcription: Transcription
    intervals: int
    nx: int
    nq: int
    stage_q: np.ndarray
    state_scale: np.ndarray
    dynamics: np.ndarray
    others: np.ndarray
    lbx: ca.SX
    ubx: ca.SX
    lbg: ca.SX
    ubg: ca.SX
    probe_lower: np.ndarray

    @property
    def states(self) -> np.ndarray:
        """(N + 1, nx) int, indices into w of the states at the mesh points."""
        return self.transcription.layout.states

    @property
    def decisions(self) -> int:
        """nw, the number of decisions."""
        return int(self.transcription.layout.size)

    @property
    def parameters(self) -> int:
        """n_p, the number of NLP parameters."""
        return int(self.transcription.nlp["p"].numel())

    def stage_of(self) -> np.ndarray:
        """(nw,) int, the interval each decision belongs to (x_N: N)."""
        N, states = self.intervals, self.states
        stage_of = np.empty(self.decisions, int)
        for k in range(N):
            stage_of[states[k]] = k
            stage_of[self.stage_q[k]] = k
        stage_of[states[N]] = N
        return stage_of


def check(transcription: Transcription) -> Checked:
    """`transcription` as a `Checked`, or the error naming what the real-time iteration cannot condense.

    Raises
    ------
    TypeError
        For anything but a `mpc.Transcription`.
    ValueError
        For collocation, chosen plant parameters, a free final time, no x0 parameter, another
        decision order, x(0) not fixed to x0, or a state bound after t = 0.
    """
    if not isinstance(transcription, Transcription):
        raise TypeError(f"transcription must be a mpc.Transcription, got {type(transcription).__name__}")
    tr = transcription
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
    expected = np.concatenate([np.concatenate([layout.states[k], stage_q[k]]) for k in range(N)] + [layout.states[N]])
    if not np.array_equal(expected, np.arange(layout.size)):
        raise ValueError("unexpected decision layout: the real-time iteration needs w = (x_0, u_0, c_0, ..., x_N)")
    state_scale = tr.scale[layout.states[0]]
    P = tr.nlp["p"]
    dynamics = tr.dynamics_rows.ravel()
    others = np.setdiff1d(np.arange(tr.nlp["g"].numel()), dynamics)
    lbx, ubx, lbg, ubg = tr.bounds(P)
    # x_0 = x0 exactly and no other state bound, checked on random parameter values.
    probe = ca.Function("probe", [P], [lbx, ubx])
    values = np.random.default_rng(0).normal(size=P.numel())
    low, high = (np.asarray(v, dtype=float).ravel() for v in probe(values))
    x0 = values[tr.parameter_slices["x0"]] / state_scale
    if not (np.allclose(low[layout.states[0]], x0) and np.allclose(high[layout.states[0]], x0)):
        raise ValueError("the real-time iteration needs x(0) = x0 fixed by ocp.start_from() alone")
    later = layout.states[1:].ravel()
    if np.any(np.isfinite(low[later])) or np.any(np.isfinite(high[later])):
        raise ValueError(
            "the real-time iteration takes no state bounds after t = 0: write them as soft "
            "constraints with a slack control"
        )
    return Checked(tr, N, nx, stage_q.shape[1], stage_q, state_scale, dynamics, others, lbx, ubx, lbg, ubg, low)


@dataclass(frozen=True)
class Stages:
    """The linearization's Functions (see `stage_functions`).

    functions : N interval Functions, then the end's (a group's first made with CSE: the one evaluated)
    groups : lists of intervals whose Functions agree (evaluated together with `map`)
    rows : N + 1 lists, the rows of g (besides the gaps) each interval holds
    hessian : the sparsity of the objective's Hessian in w
    """

    functions: list
    groups: list
    rows: list
    hessian: ca.Sparsity


def assign_rows(pattern: ca.Sparsity, others, states: np.ndarray, stage_q: np.ndarray, stage_of) -> list[list[int]]:
    """The rows `others` of g as N + 1 lists: each row goes to the last interval it fits in.

    pattern : sparsity of ∂g[others]/∂w;  states : (N + 1, nx), stage_q : (N, nq) decision indices;
    stage_of : (nw,) the interval of each decision. A row fits interval k when it reads only
    s_k, q_k, s_{k+1} and q_{k-1} (the end, k = N: s_N and q_{N-1}); a rate limit on q_k - q_{k-1}
    thus goes to interval k, a row on s_{k+1} alone to interval k + 1.

    Raises
    ------
    ValueError
        For a row that fits no interval, naming the mesh points it spans.
    """
    N = stage_q.shape[0]
    rows_by_stage: list[list[int]] = [[] for _ in range(N + 1)]

    def allowed(k):
        inside = set(states[k]) | (set(stage_q[k]) | set(states[k + 1]) if k < N else set())
        return inside | (set(stage_q[k - 1]) if k > 0 else set())

    if not len(others):
        return rows_by_stage
    allowed_sets = [allowed(k) for k in range(N + 1)]
    rows_of, cols_of = pattern.get_triplet()
    touched: list[set] = [set() for _ in others]
    for r, c in zip(rows_of, cols_of):
        touched[r].add(int(c))
    for position, row in enumerate(others):
        columns = touched[position]
        candidates = [k for k in range(N + 1) if columns <= allowed_sets[k]]
        if not candidates:
            owners = sorted({int(stage_of[c]) for c in columns})
            raise ValueError(
                f"the real-time iteration needs each constraint on one interval (with x_{{k+1}} "
                f"and u_{{k-1}}); row {row} spans mesh points {owners}"
            )
        rows_by_stage[max(candidates)].append(int(row))
    return rows_by_stage


def _indices(array) -> list[int]:
    return list(map(int, array))


def interval_function(
    checked: Checked, k: int, rows: list[int], grad: ca.SX, hessian: ca.SX, *, cse: bool = True
) -> ca.Function:
    """Interval k's Function (s_k, q_k, s_{k+1}, q_{k-1}, P) -> (a, A, B, I, g, J_g, grad, H).

    a = -(gap), A, B = -∂gap/∂(s_k, q_k), I = ∂gap/∂s_{k+1} (the identity for a shooting gap
    s_{k+1} - φ(s_k, q_k)), g = the interval's other `rows` and J_g their Jacobian in
    (s_k, q_k, s_{k+1}, q_{k-1}), grad and H the objective's gradient and Hessian in (s_k, q_k).
    All in scaled decisions; grad and hessian are the whole objective's, in w. `cse`: CasADi's common
    subexpression elimination (the same values; most of the Function's making, and a smaller graph to
    evaluate and generate).
    """
    tr, states, stage_q, nx = checked.transcription, checked.states, checked.stage_q, checked.nx
    w, P, g = tr.nlp["x"], tr.nlp["p"], tr.nlp["g"]
    s_k, q_k, s_next = w[_indices(states[k])], w[_indices(stage_q[k])], w[_indices(states[k + 1])]
    q_prev = w[_indices(stage_q[k - 1])] if k else ca.SX.sym("q_before", stage_q.shape[1])
    v = _indices(np.concatenate([states[k], stage_q[k]]))
    gap = g[_indices(checked.dynamics[k * nx : (k + 1) * nx])]
    g_k = g[rows] if rows else ca.SX(0, 1)
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
    return ca.Function(
        f"rti_interval_{k}",
        [s_k, q_k, s_next, q_prev, P],
        outputs,
        ["s", "q", "s_next", "q_prev", "P"],
        list(INTERVAL_OUTPUTS),
        {"cse": cse},
    )


def end_function(checked: Checked, rows: list[int], grad: ca.SX, hessian: ca.SX) -> ca.Function:
    """The end's Function (s_N, q_{N-1}, P) -> (g, J_g, grad, H): its `rows` of g, their Jacobian in
    (s_N, q_{N-1}), the objective's gradient and Hessian in s_N."""
    tr, states, stage_q, N = checked.transcription, checked.states, checked.stage_q, checked.intervals
    w, P, g = tr.nlp["x"], tr.nlp["p"], tr.nlp["g"]
    s_N, v = w[_indices(states[N])], _indices(states[N])
    q_last = w[_indices(stage_q[N - 1])]
    g_N = g[rows] if rows else ca.SX(0, 1)
    return ca.Function(
        "rti_end",
        [s_N, q_last, P],
        [g_N, ca.jacobian(g_N, ca.vertcat(s_N, q_last)), grad[v], ca.densify(hessian[v, v])],
        ["s", "q_prev", "P"],
        ["g", "J_g", "grad", "H"],
        {"cse": True},
    )


def group_intervals(functions: list, rows: list, nx: int) -> list[list[int]]:
    """The intervals 0..N-1 in groups whose Functions agree: the same sparsity and the same values
    (to 1e-10) at one random point common to all; checks every gap's ∂/∂s_{k+1} is the identity.

    Raises
    ------
    ValueError
        When a gap is not x_{k+1} - F(x_k, u_k) in scaled units.
    """
    rng = np.random.default_rng(1)
    common: dict = {}
    groups: dict = {}
    for k, fun in enumerate(functions[:-1]):
        point = [common.setdefault(fun.size1_in(i), rng.normal(size=fun.size1_in(i))) for i in range(5)]
        out = fun(*point)
        if not np.allclose(np.asarray(out[3], dtype=float), np.eye(nx), atol=1e-12):
            raise ValueError(f"shooting gap {k} is not x_{{k+1}} - F(x_k, u_k) (scaled)")
        key = (
            len(rows[k]),
            tuple(str(fun.sparsity_out(i)) for i in range(fun.n_out())),
            tuple(np.round(np.asarray(o, dtype=float).ravel(), 10).tobytes() for o in out),
        )
        groups.setdefault(key, []).append(k)
    return list(groups.values())


def stage_functions(checked: Checked) -> Stages:
    """Per interval its Function (`interval_function`), the end's (`end_function`), grouped.

    Raises
    ------
    ValueError
        When the objective couples decisions of different intervals (the Gauss-Newton Hessian
        must be block diagonal by interval), or a row spans intervals (`assign_rows`).
    """
    tr, N = checked.transcription, checked.intervals
    w, f, g = tr.nlp["x"], tr.nlp["f"], tr.nlp["g"]
    stage_of = checked.stage_of()
    grad = ca.gradient(f, w)
    hessian = ca.hessian(f, w)[0]
    rows_h, cols_h = hessian.sparsity().get_triplet()
    if any(stage_of[i] != stage_of[j] for i, j in zip(rows_h, cols_h)):
        raise ValueError(
            "the objective couples decisions of different intervals; the real-time iteration "
            "needs a stage-wise objective (sum, integral, end terms)"
        )
    others = checked.others
    pattern = ca.jacobian(g[_indices(others)], w).sparsity() if len(others) else ca.Sparsity(0, 0)
    rows = assign_rows(pattern, others, checked.states, checked.stage_q, stage_of)
    # Grouped on Functions made without CSE (a small fraction of the time, docs/performance.md); only a group's
    # first interval's Function is evaluated after, so only it is made again, with CSE.
    functions = [interval_function(checked, k, rows[k], grad, hessian, cse=False) for k in range(N)]
    functions.append(end_function(checked, rows[N], grad, hessian))
    groups = group_intervals(functions, rows, checked.nx)
    for group in groups:
        functions[group[0]] = interval_function(checked, group[0], rows[group[0]], grad, hessian)
    return Stages(functions, groups, rows, hessian.sparsity())


def evaluate_stages(stages: Stages, wm: ca.MX, Pm: ca.MX, s_idx: list, q_idx: list) -> list[dict]:
    """Every interval's and the end's Function at the MX symbols (wm, Pm), one `map` per group.

    s_idx : N + 1 lists of the states' indices into w;  q_idx : N lists of the stage inputs'
    Returns N + 1 dicts, output name -> MX (the end's: g, J_g, grad, H).
    """
    N = len(q_idx)
    lin: list[dict] = [{} for _ in range(N + 1)]
    for group in stages.groups:
        fun = stages.functions[group[0]]
        n = len(group)
        mapped = fun.map(f"{fun.name()}_map", "serial", n, [4], []) if n > 1 else fun
        s = ca.horzcat(*[wm[s_idx[k]] for k in group])
        q = ca.horzcat(*[wm[q_idx[k]] for k in group])
        s_next = ca.horzcat(*[wm[s_idx[k + 1]] for k in group])
        q_prev = ca.horzcat(*[wm[q_idx[k - 1]] if k else ca.MX.zeros(len(q_idx[0])) for k in group])
        outs = mapped(s, q, s_next, q_prev, Pm)
        for name, value in zip(INTERVAL_OUTPUTS, outs):
            width = value.size2() // n
            for i, k in enumerate(group):
                lin[k][name] = value[:, i * width : (i + 1) * width]
    g, J_g, grad, H = stages.functions[N](wm[s_idx[N]], wm[q_idx[N - 1]], Pm)
    lin[N] = {"g": g, "J_g": J_g, "grad": grad, "H": H}
    return lin
