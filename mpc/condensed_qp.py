"""The real-time iteration's condensed QP as CasADi expressions: recursions, Hessian, rows, data.

The linearized multiple-shooting QP (`mpc.rti_linearization`) is condensed
over z = (Δs_0, 1, Δd_0, ..., Δd_{N-1}), where d are the inputs and controls
that enter the dynamics (`Dimensions.dynamic`); the others (σ, soft bounds'
slacks, `Dimensions.static`) need no eliminating and stay as they are:

- `forward`: Γ_0 = [I 0], Γ_{k+1} = A_k Γ_k + B_k E_k + a_k e_cᵀ (Δs_k = Γ_k z; E_k picks Δd_k
  out of z, e_c is z's constant entry);
- `backward`: P_k = Q_k + A_kᵀ P_{k+1} A_k, λ_k = Q_k c_k + q_k + A_kᵀ λ_{k+1} (c_k = Γ_k's
  constant column), and the condensed Hessian's row of Δd_k, B_kᵀ P_{k+1} Γ_{k+1} + S_k Γ_k + R_k E_k,
  with its gradient r_k + S_k c_k + B_kᵀ λ_{k+1}: O(N² nx nd + N nx³), against O(N³) for
  multiplying the stacked matrices (Q, S, R: the stage Hessian's state, cross and input blocks);
- `hessian_blocks`: the QP's Hessian H = [[H_dd, H_σdᵀ], [H_σd, H_σσ]], its gradient's part
  affine in Δs_0 and its constant part;
- `constraint_rows`: every other constraint row J (s_k, q_k, s_{k+1}, q_{k-1}) with Δs = Γ z;
- `DataLayout`: all of it stacked into the one data vector the preparation returns
  (``rti_prepare``), and its pieces read back by the feedback.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import cast

import casadi as ca
import numpy as np

from .rti_linearization import Stages


@dataclass(frozen=True)
class Dimensions:
    """Sizes of the condensed QP.

    intervals : N;  nx : states;  nq : inputs and controls per interval
    dynamic, static : the columns of q that enter the dynamics (d) and those that do not (σ)
    """

    intervals: int
    nx: int
    nq: int
    dynamic: tuple
    static: tuple

    @property
    def nd(self) -> int:
        """Dynamic inputs per interval."""
        return len(self.dynamic)

    @property
    def nst(self) -> int:
        """Static controls (slacks) per interval."""
        return len(self.static)

    @property
    def nz(self) -> int:
        """Size of z = (Δs_0, 1, Δd_0, ..., Δd_{N-1})."""
        return self.nx + 1 + self.intervals * self.nd

    @property
    def n_dynamic(self) -> int:
        """nD = N nd, the QP's variables in d."""
        return self.intervals * self.nd

    @property
    def n_static(self) -> int:
        """nS = N nst, the QP's variables in σ."""
        return self.intervals * self.nst

    @property
    def n_variables(self) -> int:
        """N nq, all the QP's variables."""
        return self.intervals * self.nq

    def variable_order(self) -> tuple[list[int], list[int]]:
        """Positions in (q_0, ..., q_{N-1}) of the QP's variables: the d's, then the σ's."""
        N, nq = self.intervals, self.nq
        d_of_q = [k * nq + i for k in range(N) for i in self.dynamic]
        s_of_q = [k * nq + i for k in range(N) for i in self.static]
        return d_of_q, s_of_q


def dimensions(stages: Stages, intervals: int, nx: int, nq: int) -> Dimensions:
    """The dimensions, with the dynamic columns those of q that some interval's B has nonzeros in."""
    entering: set = set()
    for fun in stages.functions[:intervals]:
        entering |= set(fun.sparsity_out("B").get_col())
    dynamic = sorted(entering)
    static = [i for i in range(nq) if i not in entering]
    return Dimensions(intervals, nx, nq, tuple(dynamic), tuple(static))


def couples(hessian: ca.Sparsity, stage_q: np.ndarray, static) -> bool:
    """Whether the objective's Hessian couples a static control with a state or a dynamic input
    (else H_σs = 0 and H_σd = 0). hessian : sparsity in w; stage_q : (N, nq) decision indices."""
    static_entries = set(stage_q[:, list(static)].ravel().tolist())
    return any((i in static_entries) != (j in static_entries) for i, j in zip(*hessian.get_triplet()))


def selections(dims: Dimensions) -> ca.DM:
    """E = (E_0, ..., E_{N-1}) side by side, (nd, N nz): E_k z = Δd_k."""
    N, nx, nd, nz = dims.intervals, dims.nx, dims.nd, dims.nz
    E = ca.DM(nd, N * nz)
    for k in range(N):
        for i in range(nd):
            E[i, k * nz + nx + 1 + k * nd + i] = 1
    return E


def forward(A_seq, B_seq, a_seq, E_seq, dims: Dimensions) -> list:
    """Γ_0, ..., Γ_N, (nx, nz) each: Δs_k = Γ_k z under Δs_{k+1} = A_k Δs_k + B_k Δd_k + a_k.

    A_seq (nx, N nx), B_seq (nx, N nd), a_seq (nx, N): the intervals' A_k, B_k (dynamic columns)
    and a_k side by side; E_seq from `selections`. MX or DM (numbers in, numbers out).
    """
    N, nx, nd, nz = dims.intervals, dims.nx, dims.nd, dims.nz
    G, Am, Bm, am, Em = (
        ca.MX.sym("Gamma", nx, nz),
        ca.MX.sym("A", nx, nx),
        ca.MX.sym("B", nx, nd),
        ca.MX.sym("a", nx),
        ca.MX.sym("E", nd, nz),
    )
    one = ca.DM(1, nz)
    one[0, nx] = 1  # z's constant entry: a_k enters Γ_{k+1} as a_k e₁ᵀ
    step = ca.Function("rti_forward", [G, Am, Bm, am, Em], [Am @ G + Bm @ Em + am @ one])
    Gamma0 = ca.horzcat(ca.DM.eye(nx), ca.DM(nx, nz - nx))
    Gammas = step.mapaccum("rti_forward_all", N)(Gamma0, A_seq, B_seq, a_seq, E_seq)
    return [Gamma0] + ca.horzsplit(Gammas, nz)


def backward(Gamma, A_seq, B_seq, E_seq, hessians, gradients, dims: Dimensions, coupled: bool):
    """The condensed Hessian's rows of d and σ by the backward recursion (module docstring).

    Gamma : N + 1 from `forward`;  A_seq, B_seq, E_seq as there;  hessians : N stage Hessians
    (nx + nq, nx + nq) over (s_k, q_k), then the end's (nx, nx);  gradients : likewise (nx + nq,)
    and (nx,);  coupled : see `couples`.

    Returns (Hd_all, Hs_all), interval 0 first: Hd_all (N nd, nz), row k·nd + i the Hessian's row of
    Δd_{k,i} over z with its gradient in the constant's column nx (only the columns of Δs_0 and of
    Δd_j, j <= k, are nonzero); Hs_all (N nst, nz + 1), the static controls' rows
    [H_σs Γ_k + H_σd E_k, ∇_σ f] (zero blocks unless `coupled`).
    """
    N, nx, nq, nd, nst, nz = dims.intervals, dims.nx, dims.nq, dims.nd, dims.nst, dims.nz
    dyn, stat = list(dims.dynamic), list(dims.static)
    Yn, Hm, gm = ca.MX.sym("Y", nx, nx + 1), ca.MX.sym("H", nx + nq, nx + nq), ca.MX.sym("grad", nx + nq)
    Gk, Gn = ca.MX.sym("Gamma", nx, nz), ca.MX.sym("Gamma_next", nx, nz)
    Am, Bm, Em = ca.MX.sym("A", nx, nx), ca.MX.sym("B", nx, nd), ca.MX.sym("E", nd, nz)
    sx, sd, ss = list(range(nx)), [nx + i for i in dyn], [nx + i for i in stat]
    # Y = (P_{k+1}, λ_{k+1}) is carried from interval k + 1 to k.
    P_next, lam_next, offset = Yn[:, :nx], Yn[:, nx], Gk[:, nx]
    row = Bm.T @ P_next @ Gn + Hm[sd, sx] @ Gk + Hm[sd, sd] @ Em
    gradient_d = gm[sd] + Hm[sd, sx] @ offset + Bm.T @ lam_next
    step = ca.Function(
        "rti_backward",
        [Yn, Gk, Gn, Am, Bm, Em, Hm, gm],
        [
            ca.horzcat(Hm[sx, sx] + Am.T @ P_next @ Am, Hm[sx, sx] @ offset + gm[sx] + Am.T @ lam_next),
            ca.horzcat(row[:, :nx], gradient_d, row[:, nx + 1 :]),
            ca.horzcat(Hm[ss, sx] @ Gk + Hm[ss, sd] @ Em if coupled else ca.MX(nst, nz), gm[ss]),
        ],
    )
    Q_N = hessians[N]
    Y_N = ca.horzcat(Q_N, Q_N @ Gamma[N][:, nx] + gradients[N])
    order = list(reversed(range(N)))
    reverse = lambda blocks, width: ca.horzcat(*[blocks[:, k * width : (k + 1) * width] for k in order])
    _, Hd_all, Hs_all = step.mapaccum("rti_backward_all", N)(
        Y_N,
        ca.horzcat(*[Gamma[k] for k in order]),
        ca.horzcat(*[Gamma[k + 1] for k in order]),
        reverse(A_seq, nx),
        reverse(B_seq, nd),
        reverse(E_seq, nz),
        ca.horzcat(*[hessians[k] for k in order]),
        ca.horzcat(*[gradients[k] for k in order]),
    )
    # cast: CasADi's stubs give vertcat a union with Sparsity
    Hd_all = cast(ca.MX, ca.vertcat(*reversed(ca.horzsplit(Hd_all, nz))))
    Hs_all = cast(ca.MX, ca.vertcat(*reversed(ca.horzsplit(Hs_all, nz + 1))) if nst else ca.MX(0, nz + 1))
    return Hd_all, Hs_all


@dataclass(frozen=True)
class HessianBlocks:
    """The QP's objective ½ vᵀ H v + (h_const + H_v0 Δs_0)ᵀ v in v = (Δd_0..Δd_{N-1}, Δσ_0..Δσ_{N-1}).

    H_dd (nD, nD);  H_sd (nS, nD), or (nS, 0) when not coupled;  H_ss (nS, nS) block diagonal,
    sparse;  H_v0 (nD + nS, nx), dense;  h_const (nD + nS,), dense
    """

    H_dd: ca.MX
    H_sd: ca.MX
    H_ss: ca.MX
    H_v0: ca.MX
    h_const: ca.MX


def hessian_blocks(Hd_all, Hs_all, hessians, dims: Dimensions, coupled: bool) -> HessianBlocks:
    """The Hessian's blocks from `backward`'s rows (Hd_all holds H_dd's lower block triangle, mirrored
    here) and the stage Hessians' σ blocks (`hessians` as for `backward`)."""
    N, nx, nd, nst, nz = dims.intervals, dims.nx, dims.nd, dims.nst, dims.nz
    ss = [nx + i for i in dims.static]
    dcols = list(range(nx + 1, nz))
    lower = Hd_all[:, dcols]
    diagonal = ca.diagcat(*[lower[k * nd : (k + 1) * nd, k * nd : (k + 1) * nd] for k in range(N)]) if nd else lower
    return HessianBlocks(
        H_dd=lower + (lower - diagonal).T,
        H_sd=Hs_all[:, dcols] if coupled else ca.MX(dims.n_static, 0),
        H_ss=ca.diagcat(*[hessians[k][ss, ss] for k in range(N)]) if nst else ca.MX(0, 0),
        H_v0=ca.densify(ca.vertcat(Hd_all[:, :nx], Hs_all[:, :nx])),
        h_const=ca.densify(ca.vertcat(Hd_all[:, nx], Hs_all[:, nz] + Hs_all[:, nx])),
    )


@dataclass(frozen=True)
class Rows:
    """The QP's constraint rows (every row of g but the shooting gaps), in the QP's order.

    matrix : (m, nz), J Γ over z (the d columns and Δs_0's, and the constant's column: J's
        contribution of the gaps' offsets);  static : (m, nS) sparse, C_σ;  values : (m,) g at w̄;
    lower, upper : (m,) lbg, ubg of those rows;  index : their rows of g;
    order : (interval, row within the interval) of each
    """

    matrix: ca.MX
    static: ca.MX
    values: ca.MX
    lower: ca.MX
    upper: ca.MX
    index: list
    order: list


def _static_part(dims: Dimensions, k: int, J, current: int, previous) -> ca.MX:
    """Interval k's rows' entries on the static controls, in their columns of C_σ (r, N nst):
    q_k's read from J's column `current` on, q_{k-1}'s from `previous` (None: not in J)."""
    N, nst = dims.intervals, dims.nst
    r = J.size1()
    if not nst:
        return ca.MX(r, 0)
    qs = [current + i for i in dims.static]
    before = ca.MX(r, (k - 1) * nst) if previous is not None else ca.MX(r, k * nst)
    mine = [J[:, [previous + i for i in dims.static]]] if previous is not None else []
    return ca.horzcat(before, *mine, J[:, qs], ca.MX(r, (N - k - 1) * nst))


def constraint_rows(lin: list, stages: Stages, Gamma: list, E: list, dims: Dimensions, lbg, ubg) -> Rows:
    """The rows of every interval with Δs = Γ z, Δd = E z and Δσ in place (J on (s_k, q_k, s_{k+1},
    q_{k-1}); the end's J on (s_N, q_{N-1})). Intervals 1..N-1 whose Functions agree share one mapped
    row Function (compact code); then interval 0's rows and the end's.

    lin : `evaluate_stages`' output;  Gamma : `forward`'s;  E : the N selections E_k (nd, nz);
    lbg, ubg : the bounds of all of g (MX in P).
    """
    N, nx, nq, nz = dims.intervals, dims.nx, dims.nq, dims.nz
    qd = lambda offset: [offset + i for i in dims.dynamic]
    row_blocks, row_static, row_values, row_index = [], [], [], []
    row_order: list[tuple[int, int]] = []  # each QP row's (interval, row within it)
    interior = {k for k in range(1, N) if stages.rows[k]}
    for group in stages.groups:
        members = [k for k in group if k in interior]
        if not members:
            continue
        pattern = stages.functions[members[0]].sparsity_out("J_g")
        J, Gk, Gn = ca.MX.sym("J", pattern), ca.MX.sym("Gamma", nx, nz), ca.MX.sym("Gamma_next", nx, nz)
        Ek, Ep = ca.MX.sym("E", dims.nd, nz), ca.MX.sym("E_prev", dims.nd, nz)
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
        row_static += [_static_part(dims, k, lin[k]["J_g"], nx, 2 * nx + nq) for k in members]
        row_values += [lin[k]["g"] for k in members]
        for k in members:
            row_index += stages.rows[k]
            row_order += [(k, i) for i in range(len(stages.rows[k]))]
    for k in (0, N):
        J, value, index = lin[k]["J_g"], lin[k]["g"], stages.rows[k]
        if not index:
            continue
        block = J[:, :nx] @ Gamma[k]
        if k < N:
            block = block + J[:, qd(nx)] @ E[k] + J[:, nx + nq : 2 * nx + nq] @ Gamma[k + 1]
        else:
            block = block + J[:, qd(nx)] @ E[N - 1]
        row_blocks.append(block)
        row_static.append(_static_part(dims, min(k, N - 1), J, nx, None))
        row_values.append(value)
        row_index += index
        row_order += [(k, i) for i in range(len(index))]
    if not row_index:
        empty = ca.MX(0, 1)
        return Rows(ca.MX(0, nz), ca.MX(0, dims.n_static), empty, empty, empty, [], [])
    matrix, static = ca.vertcat(*row_blocks), ca.vertcat(*row_static)
    return Rows(matrix, static, ca.vertcat(*row_values), lbg[row_index], ubg[row_index], row_index, row_order)


#: The prepared data's pieces in order: the QP's H_dd (row-major), H_sd (row-major), H_σσ's nonzeros,
#: the gradient's constant part and its matrix on Δs_0 (column-major), C_d (row-major), C_σ's
#: nonzeros, the rows' bounds at Δs_0 = 0 and their matrix on Δs_0 (column-major), the variables'
#: bounds, then the dynamics A_k, B_k (column-major) and a_k for the states' recovery, and w̄.
DATA_FIELDS = (
    "H_dd",
    "H_sd",
    "hessian_values",
    "h",
    "H_v0",
    "C_d",
    "row_values",
    "row_lower",
    "row_upper",
    "C_0",
    "lbv",
    "ubv",
    "A",
    "B",
    "a",
    "w",
)


def data_pieces(dims: Dimensions, blocks: HessianBlocks, rows: Rows, lbv, ubv, A: list, B: list, a: list, w) -> list:
    """The preparation's output as the MX columns of `DATA_FIELDS`, in order.

    lbv, ubv : (N nq,) the variables' bounds minus w̄, in the QP's order;  A, B, a : the intervals'
    dynamics (B: its dynamic columns);  w : the linearization point w̄ (nw,).
    """
    nx, nz = dims.nx, dims.nz
    nonzeros = lambda M: M.nz[:] if M.nnz() else ca.MX(0, 1)
    columns = rows.matrix
    C_d = columns[:, list(range(nx + 1, nz))]
    return [
        ca.vec(ca.densify(blocks.H_dd).T),  # row-major, as numpy reads it
        ca.vec(ca.densify(blocks.H_sd).T),
        nonzeros(blocks.H_ss),
        blocks.h_const,
        ca.vec(blocks.H_v0),
        ca.vec(ca.densify(C_d).T),
        nonzeros(rows.static),
        ca.densify(rows.lower - rows.values - columns[:, nx]),
        ca.densify(rows.upper - rows.values - columns[:, nx]),
        ca.vec(ca.densify(columns[:, :nx])),
        lbv,
        ubv,
        ca.vertcat(*[ca.vec(ca.densify(m)) for m in A]),
        ca.vertcat(*[ca.vec(ca.densify(m)) for m in B]),
        ca.vertcat(*a),
        w,
    ]


class DataLayout:
    """Where each of `DATA_FIELDS` sits in the prepared data vector, and its pieces read back.

    Parameters
    ----------
    sizes : the fields' sizes, in order;  dims : Dimensions;  m : the QP's rows
    coupled : H_σd is stored (else its piece is empty);  hessian_pattern, row_pattern : sparsity
        of H_σσ (nS, nS) and C_σ (m, nS), whose nonzeros are stored
    """

    def __init__(self, sizes, dims: Dimensions, m: int, coupled: bool, hessian_pattern, row_pattern):
        self.sizes = [int(s) for s in sizes]
        self.offsets = np.concatenate([[0], np.cumsum(self.sizes)]).astype(int)
        self.dims, self.m, self.coupled = dims, int(m), bool(coupled)
        self.hessian_pattern, self.row_pattern = hessian_pattern, row_pattern

    @property
    def size(self) -> int:
        """The data vector's length."""
        return int(self.offsets[-1])

    def slice(self, name: str) -> slice:
        """The field `name`'s entries in the data vector."""
        i = DATA_FIELDS.index(name)
        return slice(int(self.offsets[i]), int(self.offsets[i + 1]))

    def unpack(self, data: ca.MX) -> dict:
        """The fields of the MX `data` as matrices (H_dd (nD, nD), H_sd (nS, nD), H_ss (nS, nS),
        h (nQ,), H_v0 (nQ, nx), C_d (m, nD), C_s (m, nS), row_lower, row_upper (m,), C_0 (m, nx),
        lbv, ubv (nQ,), A, B, a: N matrices each, w (nw,))."""
        d, m = self.dims, self.m
        N, nx, nd, nD, nS, nQ = d.intervals, d.nx, d.nd, d.n_dynamic, d.n_static, d.n_variables
        pieces = dict(zip(DATA_FIELDS, ca.vertsplit(data, list(self.offsets))))
        return {
            "H_dd": ca.reshape(pieces["H_dd"], nD, nD).T,
            "H_sd": ca.reshape(pieces["H_sd"], nD, nS).T if self.coupled else ca.MX(nS, nD),  # zero if not
            "H_ss": ca.MX(self.hessian_pattern, pieces["hessian_values"]),
            "h": pieces["h"],
            "H_v0": ca.reshape(pieces["H_v0"], nQ, nx),
            "C_d": ca.reshape(pieces["C_d"], nD, m).T,
            "C_s": ca.MX(self.row_pattern, pieces["row_values"]),
            "row_lower": pieces["row_lower"],
            "row_upper": pieces["row_upper"],
            "C_0": ca.reshape(pieces["C_0"], m, nx),
            "lbv": pieces["lbv"],
            "ubv": pieces["ubv"],
            "A": [ca.reshape(v, nx, nx) for v in ca.vertsplit(pieces["A"], nx * nx)] if N else [],
            "B": [ca.reshape(v, nx, nd) for v in ca.vertsplit(pieces["B"], nx * nd)] if nd else [ca.MX(nx, 0)] * N,
            "a": ca.vertsplit(pieces["a"], nx),
            "w": pieces["w"],
        }
