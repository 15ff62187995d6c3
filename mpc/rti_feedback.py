"""The real-time iteration's feedback phase as CasADi Functions around the QP.

Once x0 is known, Δs_0 = x0 / scale − s̄_0, and the QP's gradient and row
bounds are affine in it (`vectors`); after the QP, the states are recovered
by the linearized dynamics Δs_{k+1} = A_k Δs_k + B_k Δd_k + a_k and the QP's
residuals measured (`recover`). `whole` chains both around CasADi's DAQP
node (`daqp_conic`), the whole QP in one Function.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import casadi as ca
import numpy as np

import models

from .condensed_qp import DataLayout
from .qp_fast import PRIMAL_TOLERANCE


def daqp_flags(optimization=models.compile.FLAGS) -> tuple[str, ...]:
    """Compiler flags for generated code that calls DAQP through CasADi's conic: `optimization`, then
    the headers and the library shipped with CasADi (the library's path recorded in the result)."""
    root = os.path.dirname(ca.__file__)
    return (
        *optimization,
        f"-I{os.path.join(root, 'include')}",
        f"-L{root}",
        f"-Wl,-rpath,{root}",
        "-Wl,--no-as-needed",
        "-ldaqp",
    )


def daqp_conic(n: int, m: int, name: str) -> ca.Function:
    """(H, g, A, lba, uba, lbx, ubx) -> (x, lam_a, lam_x) of DAQP on a dense QP of n variables, m rows
    (CasADi's conic; a failed solve is not an error here, the residuals judge it)."""
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


@dataclass(frozen=True)
class Feedback:
    """The feedback's Functions.

    vectors : (data, x0) -> (h, lba, uba), the QP's vectors for this x0 (physical, (nx,))
    recover : (data, x0, dv, lam_a, lam_x) -> (w_next, qp), the new decisions and
        qp = (stationarity, violation), the QP's residuals at (dv, lam_a, lam_x)
    whole : (data, x0) -> (w_next, qp), the QP solved by CasADi's DAQP node in between
    """

    vectors: ca.Function
    recover: ca.Function
    whole: ca.Function


def _product(M: ca.MX, v: ca.MX) -> ca.MX:
    """M v for a dense M stored row by row (M is the transpose of a column-major reshape, `DataLayout.unpack`),
    written (vᵀ Mᵀ)ᵀ: CasADi then reads Mᵀ where it lies, along its columns, instead of copying M into column
    order and striding across it; the same products summed in the same order, so the same doubles."""
    return (v.T @ M.T).T


def feedback_functions(layout: DataLayout, state_scale, first_state) -> Feedback:
    """The feedback's Functions on data laid out as `layout` says.

    state_scale : (nx,);  first_state : the indices of s_0 in w
    """
    dims, m = layout.dims, layout.m
    N, nx, nq, nD, nQ = dims.intervals, dims.nx, dims.nq, dims.n_dynamic, dims.n_variables
    data, x0m = ca.MX.sym("data", layout.size), ca.MX.sym("x0", nx)
    p = layout.unpack(data)
    w_bar = p["w"]
    ds0 = x0m / ca.DM(state_scale) - w_bar[list(first_state)]
    h = p["h"] + p["H_v0"] @ ds0
    lba, uba = p["row_lower"] - p["C_0"] @ ds0, p["row_upper"] - p["C_0"] @ ds0
    vectors = ca.Function("rti_qp_vectors", [data, x0m], [h, lba, uba], ["data", "x0"], ["h", "lba", "uba"])
    dv, lam_a, lam_x = ca.MX.sym("dv", nQ), ca.MX.sym("lam_a", m), ca.MX.sym("lam_x", nQ)
    dv_d, dv_s = dv[:nD], dv[nD:]
    H_dd, H_sd, H_ss, C_d, C_s = p["H_dd"], p["H_sd"], p["H_ss"], p["C_d"], p["C_s"]
    H_dv = ca.vertcat(_product(H_dd, dv_d) + H_sd.T @ dv_s, _product(H_sd, dv_d) + H_ss @ dv_s)
    C_dv = _product(C_d, dv_d) + C_s @ dv_s
    stationarity = ca.mmax(ca.fabs(H_dv + h + ca.vertcat(C_d.T @ lam_a, C_s.T @ lam_a) + lam_x))
    violation = ca.mmax(ca.vertcat(0, lba - C_dv, C_dv - uba, p["lbv"] - dv, dv - p["ubv"]))
    d_of_q, s_of_q = dims.variable_order()
    v_of_q = np.empty(nQ, dtype=int)
    v_of_q[d_of_q + s_of_q] = np.arange(nQ)
    dq = dv[list(map(int, v_of_q))]
    ds, pieces_w = ds0, []
    for k in range(N):
        dq_k = dq[k * nq : (k + 1) * nq]
        pieces_w += [ds, dq_k]
        ds = p["A"][k] @ ds + p["B"][k] @ dq_k[list(dims.dynamic)] + p["a"][k]
    pieces_w.append(ds)
    delta = ca.vertcat(*pieces_w)
    recover = ca.Function(
        "rti_recover",
        [data, x0m, dv, lam_a, lam_x],
        [w_bar + delta, ca.vertcat(stationarity, violation)],
        ["data", "x0", "dv", "lam_a", "lam_x"],
        ["w_next", "qp"],
    )
    H_whole = ca.vertcat(ca.horzcat(H_dd, H_sd.T), ca.horzcat(H_sd, H_ss))
    answer = daqp_conic(nQ, m, "rti_qp")(
        ca.densify(H_whole), h, ca.densify(ca.horzcat(C_d, C_s)), lba, uba, p["lbv"], p["ubv"]
    )
    whole = ca.Function(
        "rti_feedback_whole", [data, x0m], list(recover(data, x0m, *answer)), ["data", "x0"], ["w_next", "qp"]
    )
    return Feedback(vectors, recover, whole)


def step_function(prepare: ca.Function, whole: ca.Function, nw: int, n_p: int, nx: int) -> ca.Function:
    """``step(w, P, x0) -> (w_next, qp)``: `prepare` (w, P) -> data, then `whole` (data, x0)."""
    w_s, P_s, x_s = ca.MX.sym("w", nw), ca.MX.sym("P", n_p), ca.MX.sym("x0", nx)
    step = whole(prepare(w_s, P_s), x_s)
    return ca.Function("rti_step", [w_s, P_s, x_s], list(step), ["w", "P", "x0"], ["w_next", "qp"])
