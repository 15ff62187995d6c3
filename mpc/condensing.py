"""The real-time iteration's condensing as generated C with the problem's sizes built in.

`mpc.rti.RealTimeIteration` condenses the linearized multiple-shooting QP with
CasADi expressions (the reference). Those run every stage's products on the
whole dense Γ_k (nx × nz, nz = nx + 1 + N nd), although Γ_k's columns of the
inputs from interval k on are zero, and move every intermediate through
CasADi's work vectors, which took most of the crane's preparation
(docs/notes/mpc.md). Here the same recursions run in C on Γ_k's nonzero
columns only (half the products), with the sizes, the dynamic and static
columns and the QP's row order as constants, over many samples in one call.
The linearization stays a compiled CasADi Function; its outputs, stacked
per sample (`layout`), are this kernel's input, and its output is the
preparation's data, entry for entry as `RealTimeIteration` lays it out.

The recursions (z = (Δs_0, 1, Δd_0, ..., Δd_{N-1}), c_k = Γ_k's constant column):

    Γ_0 = [I 0],  Γ_{k+1} = A_k Γ_k + B_k E_k + a_k e_c
    P_N = Q_N, λ_N = Q_N c_N + q_N
    row_k = B_kᵀ P_{k+1} Γ_{k+1} + S_k Γ_k + R_k E_k,  gradient r_k + S_k c_k + B_kᵀ λ_{k+1}
    P_k = Q_k + A_kᵀ P_{k+1} A_k,  λ_k = Q_k c_k + q_k + A_kᵀ λ_{k+1}

with the stage Hessian's blocks Q (states), S (dynamic inputs × states), R
(dynamic inputs); a constraint row of interval k is J (s_k, q_k, s_{k+1},
q_{k-1}) with Δs = Γ z and Δd = E z.
"""

from __future__ import annotations

import ctypes
from dataclasses import dataclass

import numpy as np

import models

#: Compiler flags of the kernel (the sizes are constants, so the loops vectorize).
FLAGS = models.compile.FLAGS


@dataclass(frozen=True)
class Structure:
    """What the kernel needs to know of one RealTimeIteration's QP.

    N, nx, nq : intervals, states, inputs and controls per interval
    dynamic, static : columns of q entering the dynamics (d) and not (σ: slacks)
    stage_rows : (N + 1,) constraint rows of each interval and of the end
    row_order : (m, 2) the QP's rows as (interval, row within it), in the QP's order
    coupled : the static controls couple with the states or dynamic inputs in the Hessian
    hessian_nonzeros : (rows, columns) of H_σσ's nonzeros in the QP (block k: interval k)
    row_nonzeros : (rows, columns) of C_σ's nonzeros (row: QP row; column: interval k's block)
    decisions : nw
    """

    N: int
    nx: int
    nq: int
    dynamic: tuple
    static: tuple
    stage_rows: tuple
    row_order: np.ndarray
    coupled: bool
    hessian_nonzeros: tuple
    row_nonzeros: tuple
    decisions: int

    def layout(self) -> dict:
        """Offsets of the kernel's input: per interval k < N, A_k (nx, nx), B_k's dynamic columns
        (nx, nd), a_k (nx,), H_k (nv, nv), its gradient (nv,), J_k (r_k, 2 nv), g_k (r_k,), nv = nx + nq;
        the end's H_N (nx, nx), gradient (nx,), J_N (r_N, nv), g_N (r_N,); then lbv, ubv (N nq),
        lbg, ubg (m), w (nw). Matrices column-major, as CasADi stores them."""
        N, nx, nq = self.N, self.nx, self.nq
        nd, nv, nQ, m = len(self.dynamic), nx + nq, N * nq, len(self.row_order)
        sizes: dict = {}
        for k in range(N):
            r = self.stage_rows[k]
            sizes |= {
                ("A", k): nx * nx,
                ("B", k): nx * nd,
                ("a", k): nx,
                ("H", k): nv * nv,
                ("grad", k): nv,
                ("J", k): r * 2 * nv,
                ("g", k): r,
            }
        r = self.stage_rows[N]
        sizes |= {("H", N): nx * nx, ("grad", N): nx, ("J", N): r * nv, ("g", N): r}
        sizes |= {"lbv": nQ, "ubv": nQ, "lbg": m, "ubg": m, "w": self.decisions}
        offsets, at = {}, 0
        for key, size in sizes.items():
            offsets[key] = at
            at += size
        offsets["size"] = at
        return offsets


def _array(name: str, values, kind: str = "int") -> str:
    values = [int(v) for v in values] or [0]
    return f"static const {kind} {name}[{len(values)}] = {{{', '.join(map(str, values))}}};\n"


def source(s: Structure, data_offsets) -> str:
    """The kernel's C source: ``condense(count, lin, data, work)`` over `count` samples, lin (count,
    layout()["size"]) and data (count, data_offsets[-1]) row-major, work of `work_size(s)` doubles."""
    N, nx, nq = s.N, s.nx, s.nq
    nd, nst, nv, m = len(s.dynamic), len(s.static), nx + nq, len(s.row_order)
    nz = nx + 1 + N * nd
    L = s.layout()
    at = lambda key, count=N + 1: [L[(key, k)] for k in range(count)]
    rows_of = list(s.stage_rows)
    # The static controls' nonzeros gathered straight from the input: H_σσ from H_k, C_σ from J_k.
    hr, hc = s.hessian_nonzeros
    hessian_source = [
        L[("H", r // nst)] + (nx + s.static[c % nst]) * nv + nx + s.static[r % nst] for r, c in zip(hr, hc)
    ]
    row_source = []
    for row, column in zip(*s.row_nonzeros):
        k, local = s.row_order[row]
        block, i = divmod(int(column), nst)
        if block == k or k == N:  # this interval's static controls (the end's: interval N - 1's)
            j = nx + s.static[i]
        else:  # block k - 1: the interval before's, read by J's q_{k-1} columns
            j = 2 * nx + nq + s.static[i]
        row_source.append(L[("J", k)] + j * rows_of[k] + int(local))
    o = [int(v) for v in data_offsets]
    return (
        "#include <string.h>\n"
        f"#define N {N}\n#define NX {nx}\n#define NQ {nq}\n#define ND {nd}\n#define NST {nst}\n"
        f"#define NV {nv}\n#define NZ {nz}\n#define M {m}\n#define NLIN {L['size']}\n#define NDATA {o[-1]}\n"
        f"#define COUPLED {int(s.coupled)}\n#define NHS {len(hessian_source)}\n#define NCS {len(row_source)}\n"
        f"#define NW {s.decisions}\n"
        + _array("DYN", s.dynamic)
        + _array("STAT", s.static)
        + _array("ROWS", rows_of)
        + _array("OFF_A", at("A", N))
        + _array("OFF_B", at("B", N))
        + _array("OFF_a", at("a", N))
        + _array("OFF_H", at("H"))
        + _array("OFF_G", at("grad"))
        + _array("OFF_J", at("J"))
        + _array("OFF_g", at("g"))
        + _array("ROW_K", s.row_order[:, 0])
        + _array("ROW_L", s.row_order[:, 1])
        + _array("HS_SRC", hessian_source)
        + _array("CS_SRC", row_source)
        + _array("OUT", o)
        + f"#define OFF_LBV {L['lbv']}\n#define OFF_UBV {L['ubv']}\n#define OFF_LBG {L['lbg']}\n"
        f"#define OFF_UBG {L['ubg']}\n#define OFF_W {L['w']}\n" + KERNEL
    )


def work_size(s: Structure) -> int:
    """Doubles of the kernel's work vector: the Γ_k, the condensed rows of H, P (with its next value and
    P A) and λ (with its next value), one row, Bᵀ P."""
    N, nx, nd, nst = s.N, s.nx, len(s.dynamic), len(s.static)
    nz = nx + 1 + N * nd
    return (N + 1) * nx * nz + N * nd * nz + N * nst * nz + 3 * nx * nx + 2 * nx + nz + nd * nx


# Γ_k row-major (NX, NZ), its columns from NCOL(k) on zero and never read; HD row k*ND+i: the condensed
# Hessian's row of Δd_k over z with the gradient in the constant's column; HS likewise for the static
# controls (when COUPLED). A row update whose multiplier is 0 is skipped (adding 0 × finite changes
# nothing): a stacked plant's A_k, B_k and rows are block diagonal by branch (`mpc.scenario_tree`), so
# a tree's Γ recursion and rows cost S times less.
KERNEL = r"""
#define NCOL(k) (NX + 1 + (k) * ND)
#define NQV (N * NQ)
#define ND_ALL (N * ND)
#define NS_ALL (N * NST)

static void one(const double* L, double* D, double* w) {
    double* G = w;                              /* (N+1) x NX x NZ */
    double* HD = G + (N + 1) * NX * NZ;         /* N*ND x NZ */
    double* HS = HD + N * ND * NZ;              /* N*NST x NZ */
    double* P = HS + N * NST * NZ;              /* NX x NX, row-major */
    double* Pn = P + NX * NX;
    double* PA = Pn + NX * NX;
    double* lam = PA + NX * NX;
    double* lamn = lam + NX;
    double* row = lamn + NX;                    /* NZ */
    double* BP = row + NZ;                      /* ND x NX */
    int k, r, t, c, i, l;
    /* forward: Γ_0 = [I 0], Γ_{k+1} = A_k Γ_k + B_k E_k + a_k e_c */
    for (r = 0; r < NX; ++r)
        for (c = 0; c < NX + 1; ++c) G[r * NZ + c] = (r == c);
    for (k = 0; k < N; ++k) {
        const double* A = L + OFF_A[k];
        const double* B = L + OFF_B[k];
        const double* a = L + OFF_a[k];
        const double* G0 = G + k * NX * NZ;
        double* G1 = G0 + NX * NZ;
        const int n0 = NCOL(k);
        for (r = 0; r < NX; ++r) {
            double* out = G1 + r * NZ;
            for (c = 0; c < n0; ++c) out[c] = 0.0;
            for (t = 0; t < NX; ++t) {
                const double at = A[t * NX + r];
                const double* in = G0 + t * NZ;
                if (at == 0.0) continue;
                for (c = 0; c < n0; ++c) out[c] += at * in[c];
            }
            out[NX] += a[r];
            for (i = 0; i < ND; ++i) out[n0 + i] = B[i * NX + r];
        }
    }
    /* backward */
    {
        const double* H = L + OFF_H[N];
        const double* q = L + OFF_G[N];
        const double* GN = G + N * NX * NZ;
        for (r = 0; r < NX; ++r) {
            double s = q[r];
            for (t = 0; t < NX; ++t) {
                P[r * NX + t] = H[t * NX + r];
                s += H[t * NX + r] * GN[t * NZ + NX];
            }
            lam[r] = s;
        }
    }
    for (k = N - 1; k >= 0; --k) {
        const double* A = L + OFF_A[k];
        const double* B = L + OFF_B[k];
        const double* H = L + OFF_H[k];
        const double* q = L + OFF_G[k];
        const double* G0 = G + k * NX * NZ;
        const double* G1 = G0 + NX * NZ;
        const int n0 = NCOL(k), n1 = NCOL(k + 1);
        for (i = 0; i < ND; ++i)
            for (t = 0; t < NX; ++t) {
                double s = 0.0;
                for (r = 0; r < NX; ++r) s += B[i * NX + r] * P[r * NX + t];
                BP[i * NX + t] = s;
            }
        for (i = 0; i < ND; ++i) {
            const int di = NX + DYN[i];
            double* out = HD + (k * ND + i) * NZ;
            double gradient = q[di];
            for (c = 0; c < NZ; ++c) out[c] = 0.0;
            for (t = 0; t < NX; ++t) {
                const double bp = BP[i * NX + t], st = H[t * NV + di];
                const double* g1 = G1 + t * NZ;
                const double* g0 = G0 + t * NZ;
                if (bp != 0.0)
                    for (c = 0; c < n1; ++c) out[c] += bp * g1[c];
                if (st != 0.0)
                    for (c = 0; c < n0; ++c) out[c] += st * g0[c];
                gradient += st * g0[NX] + B[i * NX + t] * lam[t];
            }
            for (l = 0; l < ND; ++l) out[n0 + l] += H[(NX + DYN[l]) * NV + di];
            out[NX] = gradient;
        }
        for (i = 0; i < NST; ++i) {
            const int si = NX + STAT[i];
            double* out = HS + (k * NST + i) * NZ;
            for (c = 0; c < NZ; ++c) out[c] = 0.0;
            if (COUPLED) {
                for (t = 0; t < NX; ++t) {
                    const double h = H[t * NV + si];
                    const double* g0 = G0 + t * NZ;
                    if (h == 0.0) continue;
                    for (c = 0; c < n0; ++c) out[c] += h * g0[c];
                }
                for (l = 0; l < ND; ++l) out[n0 + l] += H[(NX + DYN[l]) * NV + si];
            }
        }
        /* P_k = Q_k + A_kᵀ P_{k+1} A_k,  λ_k = Q_k c_k + q_k + A_kᵀ λ_{k+1} */
        for (r = 0; r < NX; ++r)
            for (c = 0; c < NX; ++c) {
                double s = 0.0;
                for (t = 0; t < NX; ++t) s += P[r * NX + t] * A[c * NX + t];
                PA[r * NX + c] = s;
            }
        for (r = 0; r < NX; ++r) {
            double s = 0.0, u = 0.0;
            for (c = 0; c < NX; ++c) {
                double v = 0.0;
                for (t = 0; t < NX; ++t) v += A[r * NX + t] * PA[t * NX + c];
                Pn[r * NX + c] = H[c * NV + r] + v;
                s += H[c * NV + r] * G0[c * NZ + NX];
                u += A[r * NX + c] * lam[c];
            }
            lamn[r] = s + q[r] + u;
        }
        memcpy(P, Pn, sizeof(double) * NX * NX);
        memcpy(lam, lamn, sizeof(double) * NX);
    }
    /* the condensed Hessian (row-major), its lower blocks mirrored */
    {
        double* Hdd = D + OUT[0];
        for (int a = 0; a < ND_ALL; ++a)
            for (int b = 0; b < ND_ALL; ++b)
                Hdd[a * ND_ALL + b] = (b / ND <= a / ND) ? HD[a * NZ + NX + 1 + b] : HD[b * NZ + NX + 1 + a];
        if (COUPLED)
            for (int a = 0; a < NS_ALL; ++a)
                for (int b = 0; b < ND_ALL; ++b) D[OUT[1] + a * ND_ALL + b] = HS[a * NZ + NX + 1 + b];
        for (int j = 0; j < NHS; ++j) D[OUT[2] + j] = L[HS_SRC[j]];
        for (int a = 0; a < ND_ALL; ++a) D[OUT[3] + a] = HD[a * NZ + NX];
        for (k = 0; k < N; ++k)
            for (i = 0; i < NST; ++i)
                D[OUT[3] + ND_ALL + k * NST + i] = L[OFF_G[k] + NX + STAT[i]] + HS[(k * NST + i) * NZ + NX];
        for (t = 0; t < NX; ++t) {
            for (int a = 0; a < ND_ALL; ++a) D[OUT[4] + t * NQV + a] = HD[a * NZ + t];
            for (int a = 0; a < NS_ALL; ++a) D[OUT[4] + t * NQV + ND_ALL + a] = HS[a * NZ + t];
        }
    }
    /* the constraint rows: J (s_k, q_k, s_{k+1}, q_{k-1}) with Δs = Γ z, Δd = E z */
    for (int x = 0; x < M; ++x) {
        const int kk = ROW_K[x], rho = ROW_L[x], R = ROWS[kk];
        const double* J = L + OFF_J[kk];
        const double* G0 = G + kk * NX * NZ;
        const int n0 = NCOL(kk);
        for (c = 0; c < NZ; ++c) row[c] = 0.0;
        for (t = 0; t < NX; ++t) {
            const double j0 = J[t * R + rho];
            const double* g0 = G0 + t * NZ;
            if (j0 == 0.0) continue;
            for (c = 0; c < n0; ++c) row[c] += j0 * g0[c];
        }
        if (kk < N) {
            const int n1 = NCOL(kk + 1);
            for (t = 0; t < NX; ++t) {
                const double j1 = J[(NV + t) * R + rho];
                const double* g1 = G0 + NX * NZ + t * NZ;
                if (j1 == 0.0) continue;
                for (c = 0; c < n1; ++c) row[c] += j1 * g1[c];
            }
            for (i = 0; i < ND; ++i) row[n0 + i] += J[(NX + DYN[i]) * R + rho];
            if (kk > 0)
                for (i = 0; i < ND; ++i) row[NCOL(kk - 1) + i] += J[(NV + NX + DYN[i]) * R + rho];
        } else {
            for (i = 0; i < ND; ++i) row[NCOL(N - 1) + i] += J[(NX + DYN[i]) * R + rho];
        }
        for (int b = 0; b < ND_ALL; ++b) D[OUT[5] + x * ND_ALL + b] = row[NX + 1 + b];
        const double g = L[OFF_g[kk] + rho];
        D[OUT[7] + x] = L[OFF_LBG + x] - g - row[NX];
        D[OUT[8] + x] = L[OFF_UBG + x] - g - row[NX];
        for (t = 0; t < NX; ++t) D[OUT[9] + t * M + x] = row[t];
    }
    for (int j = 0; j < NCS; ++j) D[OUT[6] + j] = L[CS_SRC[j]];
    memcpy(D + OUT[10], L + OFF_LBV, sizeof(double) * NQV);
    memcpy(D + OUT[11], L + OFF_UBV, sizeof(double) * NQV);
    for (k = 0; k < N; ++k) {
        memcpy(D + OUT[12] + k * NX * NX, L + OFF_A[k], sizeof(double) * NX * NX);
        memcpy(D + OUT[13] + k * NX * ND, L + OFF_B[k], sizeof(double) * NX * ND);
        memcpy(D + OUT[14] + k * NX, L + OFF_a[k], sizeof(double) * NX);
    }
    memcpy(D + OUT[15], L + OFF_W, sizeof(double) * NW);
}

void condense(long count, const double* lin, double* data, double* work) {
    for (long s = 0; s < count; ++s) one(lin + s * NLIN, data + s * NDATA, work);
}
"""


class Condensing:
    """The compiled kernel of one `Structure`: ``condense(lin)`` -> data, lin (m, layout size) row-major.

    Build with `Condensing.compiled(...)`, which returns None when no library can be built (no
    compiler, no private cache: `models.compile.build_library`'s fallback). Not re-entrant: one
    call at a time per instance (the work vector is the instance's)."""

    def __init__(self, library: models.compile.CompiledLibrary, structure: Structure, data_size: int):
        self._library = library
        self._call = library.function("condense", [ctypes.c_long, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p])
        self.structure, self.data_size = structure, int(data_size)
        self.lin_size = structure.layout()["size"]
        self._work = np.empty(work_size(structure))

    @classmethod
    def compiled(cls, structure: Structure, data_offsets) -> Condensing | None:
        """The kernel of `structure` compiled (`models.compile`, cached); None when no library can
        be built. data_offsets : the prepared data's field offsets (`condensed_qp.DataLayout.offsets`)."""
        library = models.compile.load_library({"condense.c": source(structure, data_offsets)}, FLAGS)
        return None if library is None else cls(library, structure, data_offsets[-1])

    def __call__(self, lin: np.ndarray) -> np.ndarray:
        lin = np.ascontiguousarray(lin, dtype=float)
        if lin.ndim != 2 or lin.shape[1] != self.lin_size:
            raise ValueError(f"condensing takes (samples, {self.lin_size}) values, got {lin.shape}")
        data = np.empty((lin.shape[0], self.data_size))
        self._call(lin.shape[0], lin.ctypes.data, data.ctypes.data, self._work.ctypes.data)
        return data
