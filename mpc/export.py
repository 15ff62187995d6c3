"""Linear MPC exported as self-contained C: estimator, target, condensed QP and its solver.

`export_linear_mpc(controller, name)` writes the whole `LinearMPC.step` as C
with fixed sizes and no allocation: the disturbance observer's update, the
steady-state target, the condensed QP of `mpc.qp_fast.condense` (the problem
the DAQP path solves, in the same scaled variables) solved by a dense dual
active-set method, the fallback to the shifted plan, exact clipping and the
rate limit, and the one-sample prediction of the estimate. The first state
comes from the first measurement as in Python (`name_init`).

The QP solver is Goldfarb and Idnani's dual method (Math. Programming 27,
1983), in the form of Di Gaspero's QuadProg++: from a minimizer over an
active set with nonnegative multipliers it adds the most violated constraint
until none is violated, keeping H = L Lᵀ's factor J = L⁻ᵀ orthogonally
updated (Givens rotations). A strictly convex QP has one solution, so the
command equals DAQP's to rounding (the tests hold them to 1e-9 over closed
loops). Each solve starts from the unconstrained minimum of the inputs
(precomputed as an affine map of the parameters) with every soft-bound slack
at its bound s = 0: the slacks' Hessian block is diagonal and apart from the
inputs', so that start's factorization is J with the slack columns moved to
the front and its multipliers are the slacks' linear weights (>= 0) — a
valid start that saves one O(n²) update per slack. Each further active
constraint costs O(n²).

Memory is one struct per controller (``name_state``): the controller state
and the solver's work arrays, two n×n of them (n = N nu + N ns decision
variables); the constant data is ``static const``.
"""

from __future__ import annotations

import string

import casadi as ca
import numpy as np

from models import deferred
from models.export import (
    ExportedC,
    UnsupportedExport,
    c_array,
    c_name,
    c_number,
    generated_code,
    work_sizes,
)

from .controller import LinearMPC
from .linear import INFINITY
from .qp_fast import CondensedQP, condense

scipy = deferred.module("scipy")

#: Status codes of ``name_step`` (and ``name_init``, ``name_solve_qp``); a non-finite command adds 16.
STATUS = {
    0: "optimal",
    1: "non-finite measurement",
    2: "non-finite estimate",
    3: "QP infeasible",
    4: "QP iteration limit",
    5: "QP degenerate active set",
    6: "non-finite solution",
    7: "non-finite reference",
}
NONFINITE_COMMAND = 16
#: A constraint counts as violated below -TOLERANCE (1 + |bound|), in the scaled variables.
TOLERANCE = 1e-12


def status_text(code: int) -> str:
    """The meaning of a status code of the exported step."""
    text = STATUS.get(code & ~NONFINITE_COMMAND, f"unknown code {code}")
    return f"non-finite command ({text})" if code & NONFINITE_COMMAND else text


def constraints(qp: CondensedQP) -> dict[str, np.ndarray]:
    """The QP's bounds as one-sided constraints sign · (c_k · z̄) >= b0_k + bm_k · p.

    c_k is the unit vector of variable `variable[k]` when `row[k]` < 0, else row `row[k]`.
    """
    entries: list[tuple[int, int, float, float, np.ndarray]] = []  # (row, variable, sign, b0, bm) per constraint
    zero = np.zeros(qp.n_parameters)
    for i in range(qp.n):
        for s, bound in ((1.0, qp.lower[i]), (-1.0, qp.upper[i])):
            if abs(bound) < INFINITY:
                entries.append((-1, i, s, s * bound, zero))
    for j in range(qp.rows.shape[0]):
        for s, constant, matrix in (
            (1.0, qp.row_lower_constant[j], qp.row_lower_matrix[j]),
            (-1.0, qp.row_upper_constant[j], qp.row_upper_matrix[j]),
        ):
            if abs(constant) < INFINITY:
                entries.append((j, -1, s, s * constant, s * matrix))
    row, variable, sign, b0, bm = ([entry[k] for entry in entries] for k in range(5))
    return {
        "row": np.array(row, dtype=int),
        "variable": np.array(variable, dtype=int),
        "sign": np.array(sign),
        "b0": np.array(b0),
        "bm": np.array(bm).reshape(len(b0), qp.n_parameters),
    }


def slack_start(qp: CondensedQP, table: dict, J0: np.ndarray) -> dict[str, np.ndarray]:
    """The solver's start with every slack at its bound s >= 0 active (see the module docstring).

    column : J's columns in order (the slacks' first);  active : constraint indices of s_j >= 0;
    variable : their variables;  r : R's diagonal (J0's slack diagonal);  multiplier : f at the slacks.
    """
    slacks = np.arange(qp.n_inputs, qp.n)
    lower_bound = {
        int(v): k
        for k, (row, v, sign) in enumerate(zip(table["row"], table["variable"], table["sign"]))
        if row < 0 and sign > 0
    }
    if (
        np.any(qp.H[: qp.n_inputs, qp.n_inputs :])
        or np.any(qp.H[qp.n_inputs :, qp.n_inputs :] - np.diag(np.diag(qp.H[qp.n_inputs :, qp.n_inputs :])))
        or np.any(qp.lower[slacks] != 0)
        or np.any(qp.f[slacks] < 0)
    ):
        raise UnsupportedExport("the QP's slacks are not separate with bounds s >= 0 and weights >= 0")
    return {
        "column": np.concatenate([slacks, np.arange(qp.n_inputs)]).astype(int),
        "active": np.array([lower_bound[int(v)] for v in slacks], dtype=int),
        "variable": slacks,
        "r": np.diag(J0)[slacks],
        "multiplier": qp.f[slacks],
    }


def init_kernel(controller: LinearMPC, name: str) -> ca.Function:
    """(y0) -> (x̂0 − xe, u0): `LinearMPC.initial_state`'s start, at rest at the measured configuration."""
    plant = controller.plant
    p = ca.DM(plant.param_vector())
    y = ca.SX.sym("y", plant.ny)
    q0 = plant.casadi_configuration(y, p)
    x0 = ca.vertcat(q0, ca.SX.zeros(plant.nx - plant.nq))
    limit = ca.DM(controller.input_limit)
    u0 = ca.fmin(ca.fmax(plant.casadi_equilibrium_input(q0, p), -limit), limit)
    return ca.Function(f"{name}_init_kernel", [y], [x0 - ca.DM(controller.model.xe), u0], ["y"], ["x0", "u0"])


def export_linear_mpc(controller: LinearMPC, name: str) -> ExportedC:
    """A `LinearMPC` as C with the same commands (see the module docstring).

    Raises
    ------
    UnsupportedExport
        For a controller that is not a LinearMPC (a nonlinear MPC, whose SQP over the
        plant's equations is not exported: export a LinearMPC or a Block instead).
    """
    name = c_name(name)
    if not isinstance(controller, LinearMPC):
        kind = type(controller).__name__
        raise UnsupportedExport(
            f"{getattr(controller, 'name', kind)}: only mpc.LinearMPC is exported here; "
            f"{kind} is not one"
            + (
                " (its SQP over the plant's equations has no C export; export a LinearMPC or a Block)"
                if kind == "NonlinearMPC"
                else ""
            )
        )
    if controller.n_reference != controller.plant.nu:
        raise UnsupportedExport(
            f"{controller.name}: the export tracks as many coordinates as inputs; "
            f"reference {controller.n_reference}, inputs {controller.plant.nu}"
        )
    qp = condense(controller.problem)
    table = constraints(qp)
    plant, model, observer, target = controller.plant, controller.model, controller.observer, controller.target
    nx, nu, ny, N = plant.nx, plant.nu, plant.ny, controller.horizon
    init = init_kernel(controller, name)
    work = work_sizes(init)
    # The unconstrained minimizer z̄ = −H⁻¹(F p + f) as an affine map of p, and J = L⁻ᵀ (H = L Lᵀ).
    L = np.linalg.cholesky(qp.H)
    J0 = scipy.linalg.solve_triangular(L, np.eye(qp.n), lower=True).T
    H_inverse = J0 @ J0.T
    start = slack_start(qp, table, J0)
    sizes = dict(
        NX=nx,
        NU=nu,
        NY=ny,
        NE=nx + nu,
        NH=N,
        NI=N * nu,
        NZ=qp.n,
        NP=qp.n_parameters,
        NSTART=len(start["active"]),
        NM=max(1, qp.rows.shape[0]),
        NC=max(1, len(table["b0"])),
        NCON=len(table["b0"]),
        NSTATE=nx + nu + N * nu,
    )
    rate = controller.problem.rate_limit  # per sample
    data = "".join(
        [
            c_array("A_AUG", observer.A_aug),
            c_array("B_AUG", np.vstack([model.B, np.zeros((nu, nu))])),
            c_array("GAIN", observer.gain),
            c_array("C_AUG", observer.C_aug),
            c_array("YE", model.ye),
            c_array("UE", model.ue),
            c_array("S_X", target.state_per_reference),
            c_array("S_V", target.input_per_reference),
            c_array("LIMIT", controller.input_limit),
            c_array("RATE", rate if rate is not None else np.zeros(nu)),
            c_array("SCALE", qp.scale),
            c_array("J0", J0),
            c_array("Z_P", -H_inverse @ qp.F),
            c_array("Z_F", -H_inverse @ qp.f),
            c_array("ROWS", qp.rows if qp.rows.size else [0.0]),
            c_array("CON_ROW", table["row"], kind="int"),
            c_array("CON_VARIABLE", table["variable"], kind="int"),
            c_array("CON_SIGN", table["sign"]),
            c_array("CON_B0", table["b0"]),
            c_array("CON_BM", table["bm"]),
            c_array("START_COLUMN", start["column"], kind="int"),
            c_array("START_ACTIVE", start["active"], kind="int"),
            c_array("START_VARIABLE", start["variable"], kind="int"),
            c_array("START_R", start["r"]),
            c_array("START_MULTIPLIER", start["multiplier"]),
        ]
    )
    upper = name.upper()
    header = _HEADER.substitute(
        p=name,
        P=upper,
        controller=controller.name,
        nx=nx,
        nu=nu,
        ny=ny,
        N=N,
        nz=qp.n,
        sizes="\n".join(
            f"#define {upper}_{key} {value}"
            for key, value in (
                ("N_STATE", sizes["NSTATE"]),
                ("N_MEASURED", ny),
                ("N_REFERENCE", nu),
                ("N_INPUT", nu),
                ("N_DECISIONS", qp.n),
                ("N_PARAMETERS", qp.n_parameters),
                ("N_CONSTRAINTS", sizes["NC"]),
            )
        ),
        sample_period=c_number(controller.sample_period),
        outputs=", ".join(plant.output_names),
        statuses="\n".join(
            f"#define {upper}_{text.upper().replace(' ', '_').replace('-', '')} {code}" for code, text in STATUS.items()
        )
        + f"\n#define {upper}_NONFINITE_COMMAND "
        f"{NONFINITE_COMMAND}",
        work_w=work["w"],
        work_iw=work["iw"],
    )
    source = _SOURCE.substitute(
        p=name,
        P=upper,
        controller=controller.name,
        sizes="".join(f"#define {key} {value}\n" for key, value in sizes.items()),
        casadi=generated_code([init], f"{name}_casadi"),
        data=data,
        reference_offset=c_number(model.xe[controller.tracked_index]),
        has_rate=int(rate is not None),
        tolerance=c_number(TOLERANCE),
        work_arg=work["arg"],
        work_res=work["res"],
        max_iterations=10 * (qp.n + sizes["NC"]),
        nonfinite_command=NONFINITE_COMMAND,
    )
    return ExportedC(
        name=name,
        controller=controller.name,
        header=header,
        source=source,
        n_state=sizes["NSTATE"],
        n_measured=ny,
        n_reference=nu,
        n_input=nu,
        sample_period=controller.sample_period,
        measures="outputs",
        has_init=True,
        status_codes={code: status_text(code) for code in list(STATUS) + [c | NONFINITE_COMMAND for c in STATUS]},
    )


_HEADER = string.Template("""/* ${p}.h: linear MPC '${controller}' exported by codesign-control (mpc.export).
 * ${nx} states, ${nu} input(s), ${ny} outputs (${outputs}); horizon ${N}, ${nz} QP decisions.
 * Fixed sizes, no allocation; the QP solver is a dense dual active-set method (Goldfarb-Idnani). */
#ifndef ${P}_H
#define ${P}_H

#ifdef __cplusplus
extern "C" {
#endif

${sizes}
#define ${P}_SAMPLE_PERIOD ${sample_period}

/* Status codes of ${p}_step, ${p}_init and ${p}_solve_qp; a non-finite command adds
 * ${P}_NONFINITE_COMMAND. Any status but ${P}_OPTIMAL means the shifted previous plan was followed. */
${statuses}

/* One per controller instance, owned by the caller (sizeof: ${p}_state_size()). */
typedef struct {
    double xc[${P}_N_STATE];  /* (x_hat - xe, d_hat, plan): one-sample predictions and the input plan */
    double J[${P}_N_DECISIONS * ${P}_N_DECISIONS], R[${P}_N_DECISIONS * ${P}_N_DECISIONS];
    double z[${P}_N_DECISIONS], x_old[${P}_N_DECISIONS], d[${P}_N_DECISIONS], step[${P}_N_DECISIONS];
    double r[${P}_N_DECISIONS + 1], u[${P}_N_DECISIONS + 1], u_old[${P}_N_DECISIONS + 1];
    double s[${P}_N_CONSTRAINTS], b[${P}_N_CONSTRAINTS];
    int active[${P}_N_DECISIONS + 1], active_old[${P}_N_DECISIONS + 1];
    int inactive[${P}_N_CONSTRAINTS], excluded[${P}_N_CONSTRAINTS];
    double work[${work_w}];
    long long int iwork[${work_iw}];
    int iterations;        /* of the last QP solve */
    double input_excess;   /* what clipping removed from the plan's first input */
} ${p}_state;

/* The first state from the first measurement y0 (${P}_N_MEASURED) and reference r0: at rest at the
 * measured configuration, no disturbance, the holding input as plan. Returns 0 or a status code. */
int ${p}_init(${p}_state *state, const double *y0, const double *r0);
/* One sample, every ${P}_SAMPLE_PERIOD s: outputs y (${P}_N_MEASURED), reference r (absolute tracked
 * coordinate) -> command u (${P}_N_INPUT), within the actuator limit. Returns a status code. */
int ${p}_step(${p}_state *state, const double *y, const double *r, double *u);
/* The condensed QP alone for parameters p = (x0, d, x_s, u_s, u_previous) (${P}_N_PARAMETERS, deviation
 * coordinates): its solution z = (inputs, slacks) (${P}_N_DECISIONS). Returns a status code. */
int ${p}_solve_qp(${p}_state *state, const double *p, double *z);
void ${p}_set_state(${p}_state *state, const double *xc);
void ${p}_get_state(const ${p}_state *state, double *xc);
unsigned long ${p}_state_size(void);

#ifdef __cplusplus
}
#endif

#endif /* ${P}_H */
""")

_SOURCE = string.Template("""/* ${p}.c: linear MPC '${controller}', generated by codesign-control (mpc.export). */
#include "${p}.h"
#include <float.h>
#include <math.h>

${sizes}#define HAS_RATE ${has_rate}
#define TOLERANCE ${tolerance}
#define MAX_ITERATIONS ${max_iterations}
#define NONFINITE_COMMAND ${nonfinite_command}
#define REFERENCE_OFFSET ${reference_offset}

${casadi}
${data}
static int all_finite(const double *v, int n) {
    int i;
    for (i = 0; i < n; ++i) if (!isfinite(v[i])) return 0;
    return 1;
}

/* v limited to [low, high]; NaN stays NaN (fmin/fmax would turn it into a bound). */
static double clip(double v, double low, double high) {
    return v < low ? low : (v > high ? high : v);
}

/* sign_k (c_k . z) of one-sided constraint k. */
static double constraint_value(int k, const double *z) {
    int i;
    double sum = 0.0;
    if (CON_ROW[k] < 0) return CON_SIGN[k] * z[CON_VARIABLE[k]];
    for (i = 0; i < NZ; ++i) sum += ROWS[CON_ROW[k] * NZ + i] * z[i];
    return CON_SIGN[k] * sum;
}

/* d = J^T n_k with n_k = sign_k c_k. */
static void transform(int k, const double *J, double *d) {
    int i, j;
    double sum;
    if (CON_ROW[k] < 0) {
        for (j = 0; j < NZ; ++j) d[j] = CON_SIGN[k] * J[CON_VARIABLE[k] * NZ + j];
        return;
    }
    for (j = 0; j < NZ; ++j) {
        sum = 0.0;
        for (i = 0; i < NZ; ++i) sum += J[i * NZ + j] * ROWS[CON_ROW[k] * NZ + i];
        d[j] = CON_SIGN[k] * sum;
    }
}

/* Append the constraint whose d = J^T n is in m->d: rotate J so that d has no entries below iq,
 * extend R by that column. 0 when the constraint depends on the active ones. */
static int add_constraint(${p}_state *m, int *iq, double *r_norm) {
    double *J = m->J, *R = m->R, *d = m->d, cc, ss, h, xny, t1, t2;
    int i, j, k;
    for (j = NZ - 1; j >= *iq + 1; --j) {
        cc = d[j - 1];
        ss = d[j];
        h = hypot(cc, ss);
        if (h == 0.0) continue;
        d[j] = 0.0;
        ss /= h;
        cc /= h;
        if (cc < 0.0) { cc = -cc; ss = -ss; d[j - 1] = -h; } else { d[j - 1] = h; }
        xny = ss / (1.0 + cc);
        for (k = 0; k < NZ; ++k) {
            t1 = J[k * NZ + j - 1];
            t2 = J[k * NZ + j];
            J[k * NZ + j - 1] = t1 * cc + t2 * ss;
            J[k * NZ + j] = xny * (t1 + J[k * NZ + j - 1]) - t2;
        }
    }
    *iq += 1;
    for (i = 0; i < *iq; ++i) R[i * NZ + *iq - 1] = d[i];
    if (fabs(d[*iq - 1]) <= DBL_EPSILON * *r_norm) return 0;
    if (fabs(d[*iq - 1]) > *r_norm) *r_norm = fabs(d[*iq - 1]);
    return 1;
}

/* Drop constraint l from the active set and restore R to triangular form. */
static void delete_constraint(${p}_state *m, int *iq, int l) {
    double *J = m->J, *R = m->R, *u = m->u, cc, ss, h, xny, t1, t2;
    int *A = m->active, i, j, k, qq = -1;
    for (i = 0; i < *iq; ++i) if (A[i] == l) { qq = i; break; }
    if (qq < 0) return;
    for (i = qq; i < *iq - 1; ++i) {
        A[i] = A[i + 1];
        u[i] = u[i + 1];
        for (j = 0; j < NZ; ++j) R[j * NZ + i] = R[j * NZ + i + 1];
    }
    A[*iq - 1] = A[*iq];
    u[*iq - 1] = u[*iq];
    A[*iq] = 0;
    u[*iq] = 0.0;
    for (j = 0; j < *iq; ++j) R[j * NZ + *iq - 1] = 0.0;
    *iq -= 1;
    if (*iq == 0) return;
    for (j = qq; j < *iq; ++j) {
        cc = R[j * NZ + j];
        ss = R[(j + 1) * NZ + j];
        h = hypot(cc, ss);
        if (h == 0.0) continue;
        cc /= h;
        ss /= h;
        R[(j + 1) * NZ + j] = 0.0;
        if (cc < 0.0) { R[j * NZ + j] = -h; cc = -cc; ss = -ss; } else { R[j * NZ + j] = h; }
        xny = ss / (1.0 + cc);
        for (k = j + 1; k < *iq; ++k) {
            t1 = R[j * NZ + k];
            t2 = R[(j + 1) * NZ + k];
            R[j * NZ + k] = t1 * cc + t2 * ss;
            R[(j + 1) * NZ + k] = xny * (t1 + R[j * NZ + k]) - t2;
        }
        for (k = 0; k < NZ; ++k) {
            t1 = J[k * NZ + j];
            t2 = J[k * NZ + j + 1];
            J[k * NZ + j] = t1 * cc + t2 * ss;
            J[k * NZ + j + 1] = xny * (J[k * NZ + j] + t1) - t2;
        }
    }
}

/* Goldfarb-Idnani dual active set on the scaled QP: z holds the unconstrained minimizer on entry
 * and the solution on exit; m->b the constraints' right-hand sides. */
static int solve_scaled(${p}_state *m, double *z) {
    double *J = m->J, *s = m->s, *d = m->d, *step = m->step, *r = m->r, *u = m->u, *b = m->b;
    double t, t1, t2, sum, r_norm = 1.0;
    int *A = m->active, *inactive = m->inactive, *excluded = m->excluded;
    int i, j, k, l, ip, iq = 0;
    m->iterations = 0;
    /* Start: the slacks at their bounds (see mpc.export), the inputs at their unconstrained minimum. */
    for (i = 0; i < NZ; ++i)
        for (j = 0; j < NZ; ++j) J[i * NZ + j] = J0[i * NZ + START_COLUMN[j]];
    for (i = 0; i < NCON; ++i) inactive[i] = i;
    for (k = 0; k < NSTART; ++k) {
        for (i = 0; i <= k; ++i) m->R[i * NZ + k] = i == k ? START_R[k] : 0.0;
        A[k] = START_ACTIVE[k];
        u[k] = START_MULTIPLIER[k];
        z[START_VARIABLE[k]] = 0.0;
    }
    iq = NSTART;
    for (;;) {
        for (i = 0; i < iq; ++i) inactive[A[i]] = -1;
        for (i = 0; i < NCON; ++i) { excluded[i] = 0; s[i] = constraint_value(i, z) - b[i]; }
        for (i = 0; i < iq; ++i) { m->u_old[i] = u[i]; m->active_old[i] = A[i]; }
        for (i = 0; i < NZ; ++i) m->x_old[i] = z[i];
        /* The most violated constraint not active. */
        ip = -1;
        sum = 0.0;
        for (i = 0; i < NCON; ++i)
            if (inactive[i] != -1 && !excluded[i] && s[i] < -TOLERANCE * (1.0 + fabs(b[i])) && s[i] < sum) {
                sum = s[i];
                ip = i;
            }
        if (ip < 0) return 0;
        u[iq] = 0.0;
        A[iq] = ip;
        for (;;) {
            if (++m->iterations > MAX_ITERATIONS) return 4;
            transform(ip, J, d);
            for (i = 0; i < NZ; ++i) {  /* primal step direction J2 d2 */
                sum = 0.0;
                for (j = iq; j < NZ; ++j) sum += J[i * NZ + j] * d[j];
                step[i] = sum;
            }
            for (i = iq - 1; i >= 0; --i) {  /* dual step direction R^-1 d1 */
                sum = 0.0;
                for (j = i + 1; j < iq; ++j) sum += m->R[i * NZ + j] * r[j];
                r[i] = (d[i] - sum) / m->R[i * NZ + i];
            }
            t1 = INFINITY;  /* largest dual step keeping the multipliers >= 0 */
            l = -1;
            for (k = 0; k < iq; ++k)
                if (r[k] > 0.0 && u[k] / r[k] < t1) { t1 = u[k] / r[k]; l = A[k]; }
            sum = 0.0;
            for (i = 0; i < NZ; ++i) sum += step[i] * step[i];
            if (sum > DBL_EPSILON) {  /* primal step making constraint ip active */
                t2 = -s[ip] / constraint_value(ip, step);
                if (t2 < 0.0) t2 = INFINITY;
            } else {
                t2 = INFINITY;
            }
            t = t1 < t2 ? t1 : t2;
            if (t >= INFINITY) return 3;
            if (t2 >= INFINITY) {  /* dual step only: drop constraint l */
                for (k = 0; k < iq; ++k) u[k] -= t * r[k];
                u[iq] += t;
                inactive[l] = l;
                delete_constraint(m, &iq, l);
                continue;
            }
            for (k = 0; k < NZ; ++k) z[k] += t * step[k];
            for (k = 0; k < iq; ++k) u[k] -= t * r[k];
            u[iq] += t;
            if (t2 <= t1) {  /* full step: ip joins the active set */
                if (!add_constraint(m, &iq, &r_norm)) return 5;
                inactive[ip] = -1;
                break;
            }
            inactive[l] = l;  /* partial step: drop l, keep stepping towards ip */
            delete_constraint(m, &iq, l);
            s[ip] = constraint_value(ip, z) - b[ip];
        }
    }
}

/* The QP for parameters p: right-hand sides, unconstrained minimizer, solve. z: scaled solution. */
static int solve(${p}_state *m, const double *p, double *z) {
    int i, j;
    double sum;
    for (i = 0; i < NCON; ++i) {
        sum = CON_B0[i];
        for (j = 0; j < NP; ++j) sum += CON_BM[i * NP + j] * p[j];
        m->b[i] = sum;
    }
    for (i = 0; i < NZ; ++i) {
        sum = Z_F[i];
        for (j = 0; j < NP; ++j) sum += Z_P[i * NP + j] * p[j];
        z[i] = sum;
    }
    return solve_scaled(m, z);
}

int ${p}_solve_qp(${p}_state *m, const double *p, double *z) {
    int i, status = solve(m, p, z);
    for (i = 0; i < NZ; ++i) z[i] *= SCALE[i];
    return status;
}

int ${p}_init(${p}_state *m, const double *y0, const double *r0) {
    const casadi_real *arg[${work_arg}];
    casadi_real *res[${work_res}];
    double x0[NX], u0[NU];
    int i, k;
    if (!all_finite(y0, NY)) return 1;
    if (!all_finite(r0, NU)) return 1;
    arg[0] = y0;
    res[0] = x0;
    res[1] = u0;
    if (${p}_init_kernel(arg, res, m->iwork, m->work, 0)) return 1;
    for (i = 0; i < NX; ++i) m->xc[i] = x0[i];
    for (i = 0; i < NU; ++i) m->xc[NX + i] = 0.0;
    for (k = 0; k < NH; ++k)
        for (i = 0; i < NU; ++i) m->xc[NE + k * NU + i] = u0[i];
    m->iterations = 0;
    m->input_excess = 0.0;
    return 0;
}

int ${p}_step(${p}_state *m, const double *y, const double *r, double *u) {
    double estimate[NE], innovation[NY], p[NP], candidate[NI], excess, sum, low, high;
    const double *plan = m->xc + NE;
    int i, j, k, status = 0;
    for (i = 0; i < NE; ++i) estimate[i] = m->xc[i];
    if (!all_finite(r, NU)) {
        status = 7;
    } else if (!all_finite(y, NY)) {
        status = 1;  /* a lost measurement: the prediction stands as the estimate */
    } else if (!all_finite(estimate, NE)) {
        status = 2;
    } else {
        for (i = 0; i < NY; ++i) {
            sum = 0.0;
            for (j = 0; j < NE; ++j) sum += C_AUG[i * NE + j] * m->xc[j];
            innovation[i] = (y[i] - YE[i]) - sum;
        }
        for (i = 0; i < NE; ++i) {
            sum = 0.0;
            for (j = 0; j < NY; ++j) sum += GAIN[i * NY + j] * innovation[j];
            estimate[i] = m->xc[i] + sum;
        }
        if (!all_finite(estimate, NE)) status = 2;
    }
    if (status == 0) {
        /* p = (x_hat, d_hat, x_s, u_s, u_previous), deviation coordinates */
        for (i = 0; i < NE; ++i) p[i] = estimate[i];
        for (i = 0; i < NX; ++i) {
            sum = 0.0;
            for (j = 0; j < NU; ++j) sum += S_X[i * NU + j] * (r[j] - REFERENCE_OFFSET);
            p[NE + i] = sum;
        }
        for (i = 0; i < NU; ++i) {
            sum = 0.0;
            for (j = 0; j < NU; ++j) sum += S_V[i * NU + j] * (r[j] - REFERENCE_OFFSET);
            p[NE + NX + i] = sum - estimate[NX + i];
            p[NE + NE + i] = plan[i] - UE[i];
        }
        status = solve(m, p, m->z);
        if (status == 0) {
            for (k = 0; k < NI; ++k) candidate[k] = m->z[k] * SCALE[k] + UE[k % NU];
            if (!all_finite(candidate, NI)) status = 6;
        }
    }
    if (status != 0) {  /* follow the previous plan, shifted by one sample */
        for (k = 0; k < NI - NU; ++k) candidate[k] = plan[k + NU];
        for (i = 0; i < NU; ++i) candidate[NI - NU + i] = plan[NI - NU + i];
    }
    excess = 0.0;
    for (i = 0; i < NU; ++i)
        if (fabs(candidate[i]) - LIMIT[i] > excess) excess = fabs(candidate[i]) - LIMIT[i];
    m->input_excess = excess;
    for (k = 0; k < NI; ++k) candidate[k] = clip(candidate[k], -LIMIT[k % NU], LIMIT[k % NU]);
    if (HAS_RATE) {
        for (i = 0; i < NU; ++i) {
            low = plan[i] - RATE[i];
            high = plan[i] + RATE[i];
            candidate[i] = clip(candidate[i], low, high);
            candidate[i] = clip(candidate[i], -LIMIT[i], LIMIT[i]);
        }
    }
    for (i = 0; i < NU; ++i) u[i] = candidate[i];
    if (!all_finite(u, NU)) status |= NONFINITE_COMMAND;
    /* (x_hat, d_hat) one sample on under the command */
    for (i = 0; i < NE; ++i) {
        sum = 0.0;
        for (j = 0; j < NE; ++j) sum += A_AUG[i * NE + j] * estimate[j];
        for (j = 0; j < NU; ++j) sum += B_AUG[i * NU + j] * (u[j] - UE[j]);
        m->xc[i] = sum;
    }
    for (k = 0; k < NI; ++k) m->xc[NE + k] = candidate[k];
    return status;
}

void ${p}_set_state(${p}_state *m, const double *xc) {
    int i;
    for (i = 0; i < NSTATE; ++i) m->xc[i] = xc[i];
}

void ${p}_get_state(const ${p}_state *m, double *xc) {
    int i;
    for (i = 0; i < NSTATE; ++i) xc[i] = m->xc[i];
}

unsigned long ${p}_state_size(void) { return (unsigned long) sizeof(${p}_state); }
""")
