"""The exported nonlinear MPC's QP in C: DAQP on the condensed QP, slack first as the Python path.

`mpc.export_nmpc` writes the real-time iteration as C; this module writes its
QP: the whole condensed QP in v = (d, σ) by DAQP, or, where the Python path
solves it slack first (`mpc.slack_first.SlackFirstQP`: slacks of soft bounds
that do not couple with the inputs, finite lower bounds), the same sequence of
restricted QPs with the same optimality test: the QP in the dynamic inputs
with the slacks at their lower bounds and the soft rows near a bound, then
the slacks of violated rows and of negative Lagrangian gradients freed, until
the test holds. Both give the QP's unique optimum; the sequence's first QP,
of N nd variables, is the one most samples need (docs/export.md).

DAQP's workspace is set up once for the whole QP's sizes (``setup``, in
``name_init``); every restricted QP is written into the same arrays with its
own sizes and DAQP's transformation redone in place, as the Python path's
`daqp.solve` sets one up from an empty working set. The cubic part of that
transformation (the Cholesky factor R of H, R⁻¹ and M = A R⁻¹) runs component
by component of H's nonzero pattern (``ldp``): a scenario tree's condensed H
is block diagonal by branch (its branches couple only through the shared
moves' equality rows), so S branches cost S (n/S)³ instead of n³, with the
same doubles as DAQP's ``update_ldp`` (tests/mpc/test_tree_export.py builds
both; benchmarks/tree_qp.py times both).
"""

from __future__ import annotations

import numpy as np

from models.export import c_array, c_number

from .nonlinear import NonlinearMPCProblem
from .qp_fast import PRIMAL_TOLERANCE


def constants(nlp: NonlinearMPCProblem) -> str:
    """The C constants of the QP of `nlp`'s real-time iteration: the split of v into ND dynamic inputs
    and NSL slacks, the patterns of H_σσ (H_ROW, H_COLUMN) and C_σ (C_ROW, C_COLUMN) in the order their
    values sit in the prepared data, the soft rows, the data's offsets, and the sequence's settings."""
    rti = nlp.rti
    qp, at = rti.qp_solver, rti.layout.slice
    soft = np.zeros(qp.m, dtype=int)
    soft[qp.soft_rows] = 1
    return "".join(
        [
            f"#define ND {qp.n_dynamic}\n#define NSL {qp.n_static}\n",
            f"#define SLACK_FIRST {int(qp.slack_first)}\n",
            f"#define NEAR_FIRST {int(qp.near is not None)}\n",
            f"#define NEAR {c_number(qp.near if qp.near is not None else 0.0)}\n",
            f"#define SEQUENCE_TOLERANCE {c_number(qp.tolerance)}\n",
            f"#define NHV {len(qp.hessian_rows)}\n#define NCV {len(qp.row_rows)}\n",
            "".join(
                f"#define AT_{key.upper()} {at(key).start}\n"
                for key in ("H_dd", "hessian_values", "C_d", "row_values", "lbv", "ubv")
            ),
            c_array("H_ROW", qp.hessian_rows, "int"),
            c_array("H_COLUMN", qp.hessian_columns, "int"),
            c_array("C_ROW", qp.row_rows, "int"),
            c_array("C_COLUMN", qp.row_columns, "int"),
            c_array("SOFT_ROW", soft, "int"),
        ]
    )


def settings() -> str:
    """DAQP's settings of every solve, as the Python path's (`mpc.rti`: primal_tol)."""
    return f"    m->settings.primal_tol = {c_number(PRIMAL_TOLERANCE)};\n"


#: The state struct's fields of the QP (the header's ``name_state``), in the header's size macros.
FIELDS = """    double H[${P}_NQ * ${P}_NQ], A[${P}_NROWS > 0 ? ${P}_NROWS * ${P}_NQ : 1];
    double f[${P}_NQ], bupper[${P}_NB], blower[${P}_NB];
    int sense[${P}_NB];
    double x[${P}_NQ], y[${P}_NB];  /* DAQP's solution and multipliers of the last QP solved */
    double dv[${P}_NQ], lam_x[${P}_NQ], lam_a[${P}_NROWS > 0 ? ${P}_NROWS : 1];
    double hq[${P}_NQ], lba[${P}_NROWS > 0 ? ${P}_NROWS : 1], uba[${P}_NROWS > 0 ? ${P}_NROWS : 1];
    /* the slack-first sequence: slacks' values, freed, place among the free (or -1), fixed, free;
     * the rows kept, their list and places (or -1); per slack and per row sums */
    double sigma[${P}_NSTATIC], gradient[${P}_NSTATIC], column[${P}_NSTATIC];
    double shift[${P}_NROWS > 0 ? ${P}_NROWS : 1];
    int freed[${P}_NSTATIC], at[${P}_NSTATIC], fixed[${P}_NSTATIC], free_list[${P}_NSTATIC], fresh[${P}_NSTATIC];
    int kept[${P}_NROWS > 0 ? ${P}_NROWS : 1], rows[${P}_NROWS > 0 ? ${P}_NROWS : 1];
    int row_at[${P}_NROWS > 0 ? ${P}_NROWS : 1], violated[${P}_NROWS > 0 ? ${P}_NROWS : 1];
    int check[${P}_NROWS > 0 ? ${P}_NROWS : 1];  /* the left-out soft rows the sequence's test reads */
    /* H's components (ldp): parent (union-find), cursor, the variables by component (order), each one's
     * place in it, and its component's range [begin, end) of order, at the component's root */
    int parent[${P}_NQ], cursor[${P}_NQ], order[${P}_NQ], place[${P}_NQ], begin[${P}_NQ], end[${P}_NQ];
    double block[${P}_NQ * ${P}_NQ];  /* one component's R, then R^-1, dense and row-major (ldp) */
    double gathered[${P}_NQ], product[${P}_NQ];  /* a row of A and of M on one component's columns (ldp) */
"""

#: C of the QP: ``setup`` (DAQP's workspace at the whole QP's sizes), ``daqp_on`` (one QP in the
#: workspace), ``whole`` and ``sequence`` (the condensed QP, whole or slack first) and ``solve_qp``.
SOURCE = """
/* DAQP's workspace for the whole QP (NQ variables, simple bounds, and NROWS rows), H = I until the
 * first solve writes one; every solve after writes its QP, of these sizes or fewer, into it. */
static int setup(${p}_state *m) {
    int i;
    ${p}_free(m);
    for (i = 0; i < NQ * NQ; ++i) m->H[i] = (i % (NQ + 1)) == 0 ? 1.0 : 0.0;
    for (i = 0; i < NQ; ++i) m->f[i] = 0.0;
    for (i = 0; i < NB; ++i) { m->bupper[i] = 1.0; m->blower[i] = -1.0; m->sense[i] = 0; }
    for (i = 0; i < (NROWS > 0 ? NROWS * NQ : 1); ++i) m->A[i] = 0.0;
    m->problem.n = NQ;
    m->problem.m = NB;
    m->problem.ms = NQ;
    m->problem.H = m->H;
    m->problem.f = m->f;
    m->problem.A = m->A;
    m->problem.bupper = m->bupper;
    m->problem.blower = m->blower;
    m->problem.sense = m->sense;
    return setup_workspace(m);
}

/* update_ldp's every part: DAQP's whole transformation of a new QP. */
#define WHOLE_LDP (UPDATE_Rinv | UPDATE_M | UPDATE_v | UPDATE_d | UPDATE_sense)

#ifdef DAQP_DENSE_LDP
static int ldp(${p}_state *m, int n, int mr) {
    (void) n;
    (void) mr;
    return update_ldp(WHOLE_LDP, &m->workspace);
}
#else
/* The root of i's component (path halving). */
static int root_of(int *parent, int i) {
    while (parent[i] != i) i = parent[i] = parent[parent[i]];
    return i;
}

/* H's variables (n) by the connected components of its nonzero pattern: m->order lists every
 * component's variables in ascending order, component after component; m->place[i] is i's index in
 * it and [m->begin[r], m->end[r]) its component's range, r = m->parent[i] its root. 1 when H is
 * diagonal by DAQP's test (no entry above the diagonal larger than 1e-12 in magnitude). */
static int components(${p}_state *m, int n) {
    const double *H = m->H;
    int i, j, a, c, at, size, diagonal = 1;
    for (i = 0; i < n; ++i) m->parent[i] = i;
    for (i = 0; i < n; ++i) {
        a = root_of(m->parent, i);  /* i's root, kept through the row's unions (a root is its set's least) */
        for (j = i + 1; j < n; ++j) {
            if (H[i * n + j] == 0.0) continue;
            if (H[i * n + j] > 1e-12 || H[i * n + j] < -1e-12) diagonal = 0;
            c = root_of(m->parent, j);
            if (a < c) m->parent[c] = a;
            else if (c < a) { m->parent[a] = c; a = c; }
        }
    }
    for (i = 0; i < n; ++i) m->cursor[i] = 0;
    for (i = 0; i < n; ++i) ++m->cursor[m->parent[i] = root_of(m->parent, i)];
    for (i = 0, at = 0; i < n; ++i)
        if (m->parent[i] == i) { size = m->cursor[i]; m->begin[i] = m->cursor[i] = at; m->end[i] = at += size; }
    for (i = 0; i < n; ++i) { m->place[i] = m->cursor[m->parent[i]]++; m->order[m->place[i]] = i; }
    return diagonal;
}

/* DAQP's transformation of the QP written for daqp_on (update_ldp with every part), with R (R'R = H +
 * eps I), R^-1 and M = A R^-1 computed component by component: neither R nor R^-1 has an entry between
 * two components of H (a scenario tree's branches; a free slack), and row a of M is 0 outside the
 * components its row of A touches. Every other term is DAQP's own, in DAQP's order, so Rinv and M equal
 * update_ldp's but for the sign of zeros, at the sum of the components' cubes instead of the cube of
 * their sum. Each component's R is worked on as a dense block (m->block), its rows contiguous, so the
 * inner loops run along rows (each entry's terms still summed in DAQP's order). A diagonal H is DAQP's
 * (its own path). 0, or DAQP's error. */
static int ldp(${p}_state *m, int n, int mr) {
    DAQPWorkspace *w = &m->workspace;
    const double *H = m->H;
    double *R, *B = m->block, *Mq, *gathered = m->gathered, *product = m->product, r, coefficient;
    const double *Aq, *Hi;
    int i, a, b, p, c, q, t, lo, s;
#define AT(i, j) ((i) * n - (i) * ((i) - 1) / 2 + (j) - (i))
    if (components(m, n)) return update_ldp(WHOLE_LDP, w);
    for (i = 0; i < n + mr; ++i) w->sense[i] = w->qp->sense[i];
    if (w->RinvD != NULL && w->Rinv == NULL) { w->Rinv = w->RinvD; w->RinvD = NULL; }
    R = w->Rinv;
    for (i = 0; i < n * (n + 1) / 2; ++i) R[i] = 0.0;
    for (c = 0; c < n; ++c) {
        if (m->parent[c] != c) continue;
        lo = m->begin[c], s = m->end[c] - lo;
        for (a = 0; a < s; ++a) {  /* Cholesky of the block, its diagonal stored as the reciprocal */
            i = m->order[lo + a], Hi = H + i * n;
            r = Hi[i] + w->settings->eps_prox;
            for (p = 0; p < a; ++p) r -= B[p * s + a] * B[p * s + a];
            if (r <= 0) return EXIT_NONCONVEX;
            r = sqrt(r);
            for (b = a + 1; b < s; ++b) B[a * s + b] = Hi[m->order[lo + b]];
            for (p = 0; p < a; ++p) {
                coefficient = B[p * s + a];
                for (b = a + 1; b < s; ++b) B[a * s + b] -= coefficient * B[p * s + b];
            }
            for (b = a + 1; b < s; ++b) B[a * s + b] /= r;
            B[a * s + a] = 1 / r;
        }
        for (a = 0; a < s; ++a) {  /* R^-1 in place, row a from the rows below it */
            for (b = a + 1; b < s; ++b) B[a * s + b] *= -B[a * s + a];
            for (b = a + 1; b < s; ++b) {
                B[a * s + b] *= B[b * s + b];
                coefficient = B[a * s + b];
                for (t = b + 1; t < s; ++t) B[a * s + t] -= B[b * s + t] * coefficient;
            }
        }
        for (a = 0; a < s; ++a)
            for (b = a, i = m->order[lo + a]; b < s; ++b) R[AT(i, m->order[lo + b])] = B[a * s + b];
        /* M = A R^-1 on the component's columns (every column is in one component): each row's entries
         * gathered in the component's order, A's columns last to first as DAQP, the block's rows contiguous */
        for (q = 0; q < mr; ++q) {
            Aq = m->A + q * n, Mq = w->M + q * n;
            for (a = 0; a < s; ++a) { gathered[a] = Aq[m->order[lo + a]]; product[a] = 0.0; }
            for (a = s - 1; a >= 0; --a) {
                if (gathered[a] == 0.0) continue;
                coefficient = gathered[a];
                product[a] = B[a * s + a] * coefficient;
                for (b = a + 1; b < s; ++b) product[b] += B[a * s + b] * coefficient;
            }
            for (a = 0; a < s; ++a) Mq[m->order[lo + a]] = product[a];
        }
    }
#undef AT
    reset_daqp_workspace(w);
    normalize_M(w);
    update_v(w->qp->f, w, UPDATE_Rinv);
    normalize_Rinv(w);
    return update_ldp(UPDATE_d, w);
}
#endif

/* DAQP on the QP of n variables and mr rows written in m->H (n x n), m->f (n), m->A (mr x n, row-major)
 * and the bounds (the n simple bounds, then the rows'), from an empty working set with the equalities
 * in it (active and immutable, as CasADi's DAQP node marks them), as the Python path's daqp.solve:
 * m->x, m->y; DAQP's exit flag, or its transformation's error. */
static int daqp_on(${p}_state *m, int n, int mr) {
    DAQPResult result;
    int i, flag;
    m->problem.n = m->workspace.n = n;
    m->problem.m = m->workspace.m = n + mr;
    m->problem.ms = m->workspace.ms = n;
    for (i = 0; i < n + mr; ++i) m->sense[i] = m->blower[i] == m->bupper[i] ? ACTIVE + IMMUTABLE : 0;
    reset_daqp_workspace(&m->workspace);
    flag = ldp(m, n, mr);
    if (flag >= 0) flag = activate_constraints(&m->workspace);
    if (flag < 0) return flag;
    result.x = m->x;
    result.lam = m->y;
    daqp_solve(&result, &m->workspace);
    return result.exitflag;
}

#if !SLACK_FIRST
/* The whole QP: v in m->dv, the multipliers in m->lam_x and m->lam_a; DAQP's exit flag. */
static int whole(${p}_state *m) {
    double lbv[NQ], ubv[NQ];
    int i, flag;
    call(m, (kernel) ${p}_qp, m->data, NONE, NONE, NONE, NONE, m->H, m->A, lbv, ubv);
    for (i = 0; i < NQ; ++i) { m->f[i] = m->hq[i]; m->blower[i] = lbv[i]; m->bupper[i] = ubv[i]; }
    for (i = 0; i < NROWS; ++i) { m->blower[NQ + i] = m->lba[i]; m->bupper[NQ + i] = m->uba[i]; }
    flag = daqp_on(m, NQ, NROWS);
    for (i = 0; i < NQ; ++i) { m->dv[i] = m->x[i]; m->lam_x[i] = m->y[i]; }
    for (i = 0; i < NROWS; ++i) m->lam_a[i] = m->y[NQ + i];
    return flag;
}
#else

/* The restricted QP of the sequence: the free slacks (m->free_list, k of them) and the kept rows (m->rows,
 * mr of them) with every other slack at m->sigma, written for daqp_on. */
static int restricted(${p}_state *m, int k, int mr) {
    const double *D = m->data, *Hdd = D + AT_H_DD, *hv = D + AT_HESSIAN_VALUES, *Cd = D + AT_C_D;
    const double *cv = D + AT_ROW_VALUES, *lbv = D + AT_LBV, *ubv = D + AT_UBV;
    const int n = ND + k;
    int i, j, q, t;
    for (i = 0; i < n * n; ++i) m->H[i] = 0.0;
    for (i = 0; i < ND; ++i)
        for (j = 0; j < ND; ++j) m->H[i * n + j] = Hdd[i * ND + j];
    for (t = 0; t < NHV; ++t)
        if (m->at[H_ROW[t]] >= 0 && m->at[H_COLUMN[t]] >= 0)
            m->H[(ND + m->at[H_ROW[t]]) * n + ND + m->at[H_COLUMN[t]]] = hv[t];
    /* the fixed slacks' contributions: to the free slacks' gradient (H_σσ σ) and to the rows (C_σ σ) */
    for (j = 0; j < NSL; ++j) m->gradient[j] = 0.0;
    for (t = 0; t < NHV; ++t) m->gradient[H_ROW[t]] += hv[t] * m->sigma[H_COLUMN[t]];
    for (i = 0; i < NROWS; ++i) m->shift[i] = 0.0;
    for (t = 0; t < NCV; ++t) m->shift[C_ROW[t]] += cv[t] * m->sigma[C_COLUMN[t]];
    for (i = 0; i < ND; ++i) { m->f[i] = m->hq[i]; m->blower[i] = lbv[i]; m->bupper[i] = ubv[i]; }
    for (q = 0; q < k; ++q) {
        j = m->free_list[q];
        m->f[ND + q] = m->hq[ND + j] + m->gradient[j];
        m->blower[ND + q] = lbv[ND + j];
        m->bupper[ND + q] = ubv[ND + j];
    }
    for (q = 0; q < mr; ++q) {
        i = m->rows[q];
        for (j = 0; j < ND; ++j) m->A[q * n + j] = Cd[i * ND + j];
        for (j = ND; j < n; ++j) m->A[q * n + j] = 0.0;
        m->blower[n + q] = m->lba[i] - m->shift[i];
        m->bupper[n + q] = m->uba[i] - m->shift[i];
    }
    for (t = 0; t < NCV; ++t)
        if (m->row_at[C_ROW[t]] >= 0 && m->at[C_COLUMN[t]] >= 0)
            m->A[m->row_at[C_ROW[t]] * n + ND + m->at[C_COLUMN[t]]] = cv[t];
    return daqp_on(m, n, mr);
}

/* The condensed QP slack first (mpc.slack_first.SlackFirstQP's sequence): v in m->dv, the multipliers in
 * m->lam_x and m->lam_a; the last QP's exit flag. near: the soft rows within NEAR of a bound at v = 0
 * start in the QP with their slacks fixed. */
static int sequence(${p}_state *m, int near) {
    const double *D = m->data, *hv = D + AT_HESSIAN_VALUES, *Cd = D + AT_C_D, *cv = D + AT_ROW_VALUES;
    const double *lbv = D + AT_LBV, *ubv = D + AT_UBV;
    int i, j, q, t, k, mr, n, n_fixed, n_freed = 0, soft_kept, flag, more, checked;
    double value;
    for (i = 0; i < NROWS; ++i)
        m->kept[i] = !SOFT_ROW[i] || (near && (m->lba[i] > -NEAR || m->uba[i] < NEAR));
    for (j = 0; j < NSL; ++j) { m->freed[j] = 0; m->sigma[j] = lbv[ND + j]; }
    for (;;) {
        k = n_fixed = 0;
        for (j = 0; j < NSL; ++j) {
            m->at[j] = m->freed[j] ? k : -1;
            if (m->freed[j]) m->free_list[k++] = j; else m->fixed[n_fixed++] = j;
        }
        mr = soft_kept = 0;
        for (i = 0; i < NROWS; ++i) {
            m->row_at[i] = m->kept[i] ? mr : -1;
            if (m->kept[i]) { m->rows[mr++] = i; soft_kept |= SOFT_ROW[i]; }
        }
        n = ND + k;
        flag = restricted(m, k, mr);
        for (q = 0; q < k; ++q) m->sigma[m->free_list[q]] = m->x[ND + q];
        for (i = 0; i < ND; ++i) { m->dv[i] = m->x[i]; m->lam_x[i] = m->y[i]; }
        for (j = 0; j < NSL; ++j) { m->dv[ND + j] = m->sigma[j]; m->lam_x[ND + j] = 0.0; }
        for (q = 0; q < k; ++q) m->lam_x[ND + m->free_list[q]] = m->y[ND + q];
        for (i = 0; i < NROWS; ++i) m->lam_a[i] = 0.0;
        for (q = 0; q < mr; ++q) m->lam_a[m->rows[q]] = m->y[n + q];
        if (flag < 0 || n_fixed == 0) return flag;
        /* the fixed slacks' Lagrangian gradients (the hard rows hold no slack) */
        for (j = 0; j < NSL; ++j) m->gradient[j] = 0.0;
        for (t = 0; t < NHV; ++t) m->gradient[H_ROW[t]] += hv[t] * m->sigma[H_COLUMN[t]];
        for (j = 0; j < NSL; ++j) m->gradient[j] += m->hq[ND + j];
        if (k || soft_kept) {
            for (j = 0; j < NSL; ++j) m->column[j] = 0.0;
            for (t = 0; t < NCV; ++t) m->column[C_COLUMN[t]] += cv[t] * m->lam_a[C_ROW[t]];
            for (j = 0; j < NSL; ++j) m->gradient[j] += m->column[j];
        }
        for (q = 0; q < n_fixed; ++q) m->lam_x[ND + m->fixed[q]] = -m->gradient[m->fixed[q]];
        /* the left-out soft rows' values at the answer */
        for (i = 0; i < NROWS; ++i) m->shift[i] = 0.0;
        for (t = 0; t < NCV; ++t) m->shift[C_ROW[t]] += cv[t] * m->sigma[C_COLUMN[t]];
        for (i = 0, checked = 0; i < NROWS; ++i) {
            m->violated[i] = 0;
            if (SOFT_ROW[i] && !m->kept[i]) m->check[checked++] = i;
        }
        for (q = 0; q < checked; q += 4) {  /* four rows' sums at once, each in its own order */
            double sums[4] = {0.0, 0.0, 0.0, 0.0};
            const double *c0, *c1, *c2, *c3;
            int count = checked - q < 4 ? checked - q : 4;
            c0 = Cd + m->check[q] * ND;
            c1 = Cd + m->check[q + (count > 1)] * ND;
            c2 = Cd + m->check[q + (count > 2) * 2] * ND;
            c3 = Cd + m->check[q + (count > 3) * 3] * ND;
            for (j = 0; j < ND; ++j) {
                sums[0] += c0[j] * m->x[j];
                sums[1] += c1[j] * m->x[j];
                sums[2] += c2[j] * m->x[j];
                sums[3] += c3[j] * m->x[j];
            }
            for (t = 0; t < count; ++t) {
                i = m->check[q + t];
                value = sums[t] + m->shift[i];
                m->violated[i] = value < m->lba[i] - SEQUENCE_TOLERANCE || value > m->uba[i] + SEQUENCE_TOLERANCE;
            }
        }
        for (j = 0; j < NSL; ++j) m->fresh[j] = 0;
        for (q = 0; q < n_fixed; ++q) {
            j = m->fixed[q];
            m->fresh[j] = m->gradient[j] < -SEQUENCE_TOLERANCE && ubv[ND + j] > lbv[ND + j];
        }
        for (t = 0; t < NCV; ++t) if (m->violated[C_ROW[t]]) m->fresh[C_COLUMN[t]] = 1;
        more = 0;
        for (j = 0; j < NSL; ++j)
            if (m->fresh[j] && !m->freed[j]) { m->freed[j] = 1; ++n_freed; more = 1; }
        if (!more) return flag;
        if (2 * n_freed > NSL)  /* about the whole QP already: solve it, not a sequence growing to it */
            for (j = 0, n_freed = NSL; j < NSL; ++j) m->freed[j] = 1;
        for (t = 0; t < NCV; ++t) if (m->freed[C_COLUMN[t]]) m->kept[C_ROW[t]] = 1;
        for (j = 0; j < NSL; ++j) if (m->freed[j]) m->sigma[j] = 0.0;
    }
}
#endif

/* The prepared QP (m->data) for the initial state x0, cold started as the Python path: m->dv, the
 * multipliers and m->residuals; 1 when DAQP and the residuals say solved. */
static int solve_qp(${p}_state *m, const double *x0) {
    int flag;
    call(m, (kernel) ${p}_vectors, m->data, x0, NONE, NONE, NONE, m->hq, m->lba, m->uba, NONE);
#if SLACK_FIRST
    flag = sequence(m, NEAR_FIRST);
    if (flag < 0 && NEAR_FIRST)  /* the soft rows kept may be infeasible together: without them */
        flag = sequence(m, 0);
#else
    flag = whole(m);
#endif
    if (flag <= 0) return 0;
    call(m, (kernel) ${p}_recover, m->data, x0, m->dv, m->lam_a, m->lam_x, m->w_next, m->residuals, NONE, NONE);
    return isfinite(m->residuals[0]) && isfinite(m->residuals[1])
           && m->residuals[0] <= QP_TOLERANCE && m->residuals[1] <= QP_TOLERANCE;
}
"""
