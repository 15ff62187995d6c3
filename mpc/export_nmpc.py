"""Nonlinear MPC exported as C: the real-time iteration, its QP by DAQP, the estimator and the fallback.

`export_nonlinear_mpc(controller, name, references)` writes the whole
`NonlinearMPC.step` as C with fixed sizes:

- the estimator: the prediction x̂⁺ = F(x̂, u + d̂) and the correction with
  y − h(x̂) by the disturbance-augmented gain (`mpc.estimator`);
- the target (x_s, v_s, P) of each reference in `references`, computed at
  export by `NonlinearMPC.target` (the plant's equilibrium and the Riccati
  terminal weight need a Newton solve and a Riccati solve the C does not
  repeat): a reference outside that table is refused by the step (status 9);
- the real-time iteration of `mpc.rti.RealTimeIteration`: the preparation
  as the Python path runs it (the linearization, ``rti.linearize_expression``,
  as CasADi's generated C, then the generated condensing of `mpc.condensing`;
  ``rti.prepare_function`` whole where the RTI has no condensing), and the
  feedback's two halves around the QP (``vectors_function``,
  ``recover_function``) as CasADi's generated C; the dense condensed QP
  solved by DAQP's C API from CasADi's installation (`mpc.export.build_flags`)
  as the Python path solves it (`mpc.export_nmpc_qp`): slack first where
  `mpc.slack_first.SlackFirstQP` is, else whole, each QP from an empty working
  set in one workspace set up in ``name_init``; the first sample, and the first
  after a failure, iterates to convergence from the plan rolled out through
  the model, as the Python controller does;
- the fallback to the shifted plan, exact clipping and the rate limit.

A `mpc.ScenarioTreeMPC` is exported the same way: the C solves its stacked
problem (`ScenarioTreeProblem.inner`) with the estimate, disturbance estimate,
previous input and plan repeated over the S branches, the stacked targets
and terminal weights of its `target`, and commands branch 1's moves; the
shared moves are equality rows, which DAQP keeps in its working set (active
and immutable, as CasADi's DAQP node marks them).

Memory is one struct per controller (``name_state``), owned by the caller and
zero before its first ``name_init``; DAQP's arrays are allocated once, in
``name_init``, and released by ``name_free``. Nothing else allocates.
"""

from __future__ import annotations

import re
import string
from dataclasses import dataclass

import casadi as ca
import numpy as np

from models.export import UnsupportedExport, c_array, c_name, c_number, generated_code

from . import condensing, export, export_nmpc_qp
from .controller import NonlinearMPC
from .nonlinear import NonlinearMPCProblem
from .rti import QP_TOLERANCE
from .scenario_tree import ScenarioTreeMPC

#: Status codes of ``name_step`` and ``name_init``; a non-finite command adds 16.
STATUS = {
    0: "optimal",
    1: "non-finite measurement",
    2: "non-finite estimate",
    3: "QP failed",
    4: "not converged",
    5: "non-finite iterate",
    6: "non-finite solution",
    7: "non-finite reference",
    8: "QP setup failed",
    9: "reference not exported",
}
NONFINITE_COMMAND = export.NONFINITE_COMMAND


def status_text(code: int) -> str:
    """The meaning of a status code of the exported step."""
    text = STATUS.get(code & ~NONFINITE_COMMAND, f"unknown code {code}")
    return f"non-finite command ({text})" if code & NONFINITE_COMMAND else text


@dataclass(frozen=True)
class ExportedNMPC(export.ExportedMPC):
    """An exported nonlinear MPC: `models.export.ExportedC` built with DAQP (`mpc.export.build_flags`)."""


def check_exportable(controller, references) -> np.ndarray:
    """The references as an array; raise `UnsupportedExport` naming what the export cannot do."""
    if not isinstance(controller, NonlinearMPC):
        kind = type(controller).__name__
        raise UnsupportedExport(
            f"{getattr(controller, 'name', kind)}: only mpc.NonlinearMPC is exported here; {kind} is not one"
            " (use mpc.export.export_linear_mpc for a LinearMPC)"
        )
    if controller.nlp.iteration != "rti":
        raise UnsupportedExport(
            f"{controller.name}: iteration={controller.nlp.iteration!r} (SQP to convergence at every sample has "
            "no bounded step time; the export runs one real-time iteration per sample)"
        )
    if controller.plant.nu != 1 or controller.n_reference != 1:
        raise UnsupportedExport(f"{controller.name}: more than one input or reference")
    values = np.atleast_1d(np.asarray(references, dtype=float)).ravel()
    if values.size == 0 or not np.all(np.isfinite(values)):
        raise UnsupportedExport(
            f"{controller.name}: references must be finite and at least one (the targets are computed at export)"
        )
    return values


def problem(controller: NonlinearMPC) -> tuple[NonlinearMPCProblem, int]:
    """The NLP the C solves and the branches S it repeats the estimate, disturbance, previous input
    and plan over: a scenario tree's stacked problem (`ScenarioTreeProblem.inner`) and its S, else
    the controller's own problem and 1."""
    if isinstance(controller, ScenarioTreeMPC):
        return controller.nlp.inner, controller.nlp.branches
    return controller.nlp, 1


def kernels(controller: NonlinearMPC, name: str) -> list[ca.Function]:
    """The CasADi Functions the C calls, named ``name_*``, the known plant's parameters baked in:
    output (x) -> y, predict (x, v) -> x⁺, guess (x̂, d̂, plan) -> w (the rolled-out start, scaled),
    prepare (w, P) -> lin (the linearization, which the condensing turns into the QP's data; the data
    itself where the RTI has no condensing), vectors (data, x0) -> (h, lba, uba), recover (data, x0, dv,
    lam_a, lam_x) -> (w⁺, residuals), and, where the QP is solved whole (not slack first), qp (data) ->
    (H, Aᵀ, lbv, ubv), the dense QP as DAQP reads it.
    For a scenario tree, guess repeats (x̂, d̂, plan) over the branches, as `ScenarioTreeProblem.solve` does."""
    plant = controller.plant
    nlp, S = problem(controller)
    rti, tr = nlp.rti, nlp.transcription
    p = ca.DM(plant.param_vector())
    nx, nu, N = plant.nx, plant.nu, controller.horizon
    x, v = ca.MX.sym("x", nx), ca.MX.sym("v", nu)
    output = ca.Function(f"{name}_output", [x], [plant.casadi_h(x, p)])
    predict = ca.Function(f"{name}_predict", [x, v], [controller.step_model(x, v, p)])
    d, plan = ca.MX.sym("d", nu), ca.MX.sym("plan", N * nu)
    limit = ca.DM(controller.input_limit)
    clipped = ca.fmin(ca.fmax(ca.reshape(plan, nu, N), -limit), limit)  # (nu, N): the plan transposed
    X = nlp._rollout(ca.repmat(x, S), ca.repmat(clipped + ca.repmat(d, 1, N), S, 1), ca.DM(nlp._known))
    X = ca.horzcat(ca.repmat(x, S), X)
    clipped = ca.repmat(clipped, S, 1)
    w = ca.MX.zeros(tr.layout.size)
    w[np.asarray(nlp._states).ravel().tolist()] = ca.vec(X / ca.repmat(ca.DM(rti.state_scale), 1, N + 1))
    w[np.asarray(nlp._inputs).T.ravel().tolist()] = ca.vec(clipped / ca.repmat(ca.DM(nlp._input_scale), 1, N))
    guess = ca.Function(f"{name}_guess", [x, d, plan], [w])
    # The Python path's preparation: the linearization, then the generated condensing (`condensing_c`).
    expanded = rti.linearize_expression if rti.condensing is not None else rti.prepare_function
    prepare = rename(expanded, f"{name}_prepare")
    vectors = rename(rti.vectors_function, f"{name}_vectors")
    recover = rename(rti.recover_function, f"{name}_recover")
    data = ca.MX.sym("data", rti.layout.size)
    pieces = rti.layout.unpack(data)
    H = ca.vertcat(
        ca.horzcat(pieces["H_dd"], pieces["H_sd"].T),
        ca.horzcat(pieces["H_sd"], pieces["H_ss"]),
    )
    A = ca.horzcat(pieces["C_d"], pieces["C_s"])
    qp = ca.Function(
        f"{name}_qp", [data], [ca.densify(H), ca.densify(A.T), ca.densify(pieces["lbv"]), ca.densify(pieces["ubv"])]
    )
    y = ca.SX.sym("y", plant.ny)
    q0 = plant.casadi_configuration(y, p)
    x0 = ca.vertcat(q0, ca.SX.zeros(nx - plant.nq))
    u0 = ca.fmin(ca.fmax(plant.casadi_equilibrium_input(q0, p), -limit), limit)
    start = ca.Function(f"{name}_start", [y], [x0, u0])
    # The QP's vectors as SX: as MX they move the whole data through the work vector every instance's
    # struct holds (the pendulum's: 22,824 doubles, 407 as SX). The recovery and the preparation stay MX:
    # as SX their code takes gcc minutes and gigabytes to compile.
    vectors = vectors.expand()
    if rti.qp_solver.slack_first:  # the whole QP's dense H and A are not needed
        return [output, predict, guess, prepare, vectors, recover, start]
    return [output, predict, guess, prepare, vectors, recover, qp, start]


def condensing_c(controller: NonlinearMPC, name: str) -> str:
    """The C of the Python path's condensing (`mpc.condensing.source`: linearization -> prepared data) as
    ``name_condense``, its macros undefined after it; empty when the controller has none (the CasADi
    preparation is generated whole then)."""
    rti = problem(controller)[0].rti
    if rti.condensing is None:
        return ""
    text = condensing.source(rti.condensing.structure, rti.layout.offsets)
    macros = sorted(set(re.findall(r"^#define (\w+)", text, flags=re.MULTILINE)))
    return f"#define condense {name}_condense\n#define one {name}_condense_one\n{text}\n" + "".join(
        f"#undef {macro}\n" for macro in [*macros, "condense", "one"]
    )


def rename(fun: ca.Function, name: str) -> ca.Function:
    """`fun` called from a Function named `name` (the generated C's symbol)."""
    args = [ca.MX.sym(fun.name_in(i), fun.sparsity_in(i)) for i in range(fun.n_in())]
    out = fun(*args)
    return ca.Function(name, args, list(out) if isinstance(out, (list, tuple)) else [out])


def targets(controller: NonlinearMPC, references: np.ndarray) -> str:
    """The target table: references, and per reference x_s, v_s and the terminal weight P (column-major)."""
    rows = [controller.target(r) for r in references]
    return "".join(
        [
            c_array("REFERENCES", references),
            c_array("X_TARGET", np.array([r[0] for r in rows])),
            c_array("V_TARGET", np.array([r[1] for r in rows])),
            c_array("P_TARGET", np.array([np.asarray(r[2], dtype=float).T.ravel() for r in rows])),
        ]
    )


def indices(controller: NonlinearMPC) -> str:
    """The decisions' places as C arrays: states (N+1, nx) and inputs (N, nu) in w, the shift, the
    parameters' offsets in P."""
    nlp, _ = problem(controller)
    s = nlp._slices
    return "".join(
        [
            c_array("STATE_INDEX", np.asarray(nlp._states).ravel(), "int"),
            c_array("INPUT_INDEX", np.asarray(nlp._inputs).ravel(), "int"),
            c_array("SHIFT_INDEX", nlp.rti.shift_index, "int"),
            c_array("STATE_SCALE", nlp.rti.state_scale),
            c_array("INPUT_SCALE", nlp._input_scale),
            c_array("P_DEFAULT", nlp._parameters),
            c_array("GAIN", controller.observer.gain),
            c_array("LIMIT", controller.input_limit),
            c_array("RATE", controller._rate_per_sample if controller._rate_per_sample is not None else [0.0]),
            "".join(
                f"#define OFFSET_{key.upper()} {s[key].start}\n" for key in ("x0", "d_hat", "x_s", "u_s", "P", "u_prev")
            ),
        ]
    )


def export_nonlinear_mpc(controller: NonlinearMPC, name: str, references) -> ExportedNMPC:
    """A `NonlinearMPC` as C with the same commands (see the module docstring).

    Parameters
    ----------
    controller : the NonlinearMPC, as designed now
    name : C prefix of the files (``name.h``, ``name.c``) and functions (``name_step`` ...)
    references : the reference values (absolute tracked coordinate) the C may be given; their
        targets are computed here

    Raises
    ------
    UnsupportedExport
        For a controller that is not a NonlinearMPC (a `mpc.ScenarioTreeMPC` is one), one
        iterating to convergence at every sample (iteration="sqp"), with more than one input, no
        finite reference, or phases CasADi cannot generate as C.
    """
    name = c_name(name)
    values = check_exportable(controller, references)
    plant = controller.plant
    nlp, S = problem(controller)
    rti = nlp.rti
    nx, nu, ny, N = plant.nx, plant.nu, plant.ny, controller.horizon
    functions = kernels(controller, name)
    sizes = dict(
        NX=nx,
        NU=nu,
        NY=ny,
        NE=nx + nu,
        NH=N,
        NI=N * nu,
        NW=nlp.transcription.layout.size,
        NP=len(nlp._parameters),
        NDATA=rti.layout.size,
        NQ=rti.qp_solver.n_dynamic + rti.qp_solver.n_static,
        NROWS=rti.n_rows,
        NSTATE=nx + nu + N * nu,
        NREF=len(values),
        NS=S,
        NXS=S * nx,
        NUS=S * nu,
        NSTATIC=max(1, rti.qp_solver.n_static),
        HAS_CONDENSING=int(rti.condensing is not None),
        NLINEAR=rti.condensing.structure.layout()["size"] if rti.condensing is not None else 1,
        NCONDENSING=condensing.work_size(rti.condensing.structure) if rti.condensing is not None else 1,
    )
    sizes["NB"] = sizes["NQ"] + sizes["NROWS"]
    work = {key: max(max(1, getattr(f, f"sz_{key}")()) for f in functions) for key in ("arg", "res", "iw", "w")}
    upper = name.upper()
    header = _HEADER.substitute(
        p=name,
        P=upper,
        controller=controller.name,
        nx=nx,
        nu=nu,
        ny=ny,
        N=N,
        sizes="\n".join(f"#define {upper}_{key} {value}" for key, value in sizes.items()),
        sample_period=c_number(controller.sample_period),
        statuses="\n".join(
            f"#define {upper}_{text.upper().replace(' ', '_').replace('-', '')} {code}" for code, text in STATUS.items()
        ),
        nonfinite_command=NONFINITE_COMMAND,
        work_w=work["w"],
        work_iw=work["iw"],
    )
    source = _SOURCE.substitute(
        p=name,
        P=upper,
        controller=controller.name,
        sizes="".join(f"#define {key} {value}\n" for key, value in sizes.items()),
        casadi=generated_code(functions, f"{name}_casadi"),
        condensing=condensing_c(controller, name),
        data=indices(controller) + targets(controller, values) + export_nmpc_qp.constants(nlp),
        settings=export_nmpc_qp.settings(),
        has_rate=int(controller._rate_per_sample is not None),
        max_iterations=nlp.max_iterations,
        tolerance=c_number(nlp.tolerance),
        qp_tolerance=c_number(QP_TOLERANCE),
        work_arg=work["arg"],
        work_res=work["res"],
        nonfinite_command=NONFINITE_COMMAND,
    )
    return ExportedNMPC(
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


_HEADER = string.Template(
    """/* ${p}.h: nonlinear MPC '${controller}' exported by codesign-control (mpc.export_nmpc).
 * ${nx} states, ${nu} input(s), ${ny} outputs; horizon ${N}; one real-time iteration per sample.
 * Fixed sizes; the QP is solved by DAQP, which allocates its workspace once, in ${p}_init.
 * Build with DAQP's headers and library (mpc.export.build_flags). */
#ifndef ${P}_H
#define ${P}_H

#include <daqp/types.h>

#ifdef __cplusplus
extern "C" {
#endif

${sizes}
#define ${P}_N_STATE ${P}_NSTATE
#define ${P}_SAMPLE_PERIOD ${sample_period}

/* Status codes of ${p}_step and ${p}_init; a non-finite command adds ${nonfinite_command}.
 * Any status but ${P}_OPTIMAL means the shifted previous plan was followed. */
${statuses}

/* One per controller instance, owned by the caller (sizeof: ${p}_state_size()); all zero before its
 * first ${p}_init, and not copied once initialized (DAQP's workspace points into it). */
typedef struct {
    double xc[${P}_NSTATE];  /* (x_hat, d_hat, plan) */
    double w[${P}_NW], w_next[${P}_NW];  /* the warm start (scaled decisions) and the new iterate */
    double parameters[${P}_NP], data[${P}_NDATA];
    double lin[${P}_NLINEAR], condensing[${P}_NCONDENSING];  /* the linearization, the condensing's work */
"""
    + export_nmpc_qp.FIELDS
    + """    double residuals[2];
    DAQPProblem problem;
    DAQPSettings settings;
    DAQPWorkspace workspace;
    int set_up;        /* DAQP holds its workspace */
    int has_guess;     /* w holds the last solution shifted by one sample */
    int iterations;    /* SQP iterations of the last step */
    double work[${work_w}];
    long long int iwork[${work_iw}];
} ${p}_state;

/* The first state from the first measurement y0 and reference r0: at rest at the measured
 * configuration, no disturbance, the holding input as plan; sets DAQP up (its one allocation).
 * Returns 0 or a status code. */
int ${p}_init(${p}_state *state, const double *y0, const double *r0);
/* One sample, every ${P}_SAMPLE_PERIOD s: outputs y, reference r (one of the exported references)
 * -> command u, within the actuator limit. Returns a status code. */
int ${p}_step(${p}_state *state, const double *y, const double *r, double *u);
void ${p}_set_state(${p}_state *state, const double *xc);
void ${p}_get_state(const ${p}_state *state, double *xc);
void ${p}_free(${p}_state *state);
unsigned long ${p}_state_size(void);

#ifdef __cplusplus
}
#endif

#endif /* ${P}_H */
"""
)

_SOURCE = string.Template(
    """/* ${p}.c: nonlinear MPC '${controller}' by codesign-control (mpc.export_nmpc). */
#include "${p}.h"
#include <math.h>
#include <daqp/api.h>
#include <daqp/daqp.h>
#include <daqp/utils.h>
#undef NX  /* DAQP's constants.h: its workspace's size; here the plant's state count */

${condensing}
${sizes}#define HAS_RATE ${has_rate}
#define MAX_ITERATIONS ${max_iterations}
#define TOLERANCE ${tolerance}
#define QP_TOLERANCE ${qp_tolerance}
#define NONFINITE_COMMAND ${nonfinite_command}

${casadi}
${data}
"""
    + export.DAQP_HELPERS_C
    + """
static double clip(double v, double low, double high) {
    return v < low ? low : (v > high ? high : v);
}

/* One CasADi-generated function: inputs in, outputs out. */
typedef int (*kernel)(const casadi_real **, casadi_real **, casadi_int *, casadi_real *, int);
static int call(${p}_state *m, kernel f, const double *a0, const double *a1, const double *a2, const double *a3,
                const double *a4, double *r0, double *r1, double *r2, double *r3) {
    const casadi_real *arg[${work_arg}];
    casadi_real *res[${work_res}];
    arg[0] = a0; arg[1] = a1; arg[2] = a2; arg[3] = a3; arg[4] = a4;
    res[0] = r0; res[1] = r1; res[2] = r2; res[3] = r3;
    return f(arg, res, m->iwork, m->work, 0);
}
#define NONE 0

"""
    + export_nmpc_qp.SOURCE
    + """
/* The NLP at the estimate x (x0: x repeated over the branches; m->parameters set): one real-time
 * iteration from the warm start, or, without one, the SQP to convergence from the rolled-out plan.
 * 0 when solved (m->w the solution). */
static int solve_nlp(${p}_state *m, const double *x0, const double *x, const double *d, const double *plan) {
    int b, i, k, converged = 0;
    double step;
    if (!m->has_guess) {
        call(m, (kernel) ${p}_guess, x, d, plan, NONE, NONE, m->w, NONE, NONE, NONE);
        if (!all_finite(m->w, NW))
            for (k = 0; k <= NH; ++k)
                for (b = 0; b < NS; ++b)
                    for (i = 0; i < NX; ++i)
                        m->w[STATE_INDEX[k * NXS + b * NX + i]] = x[i] / STATE_SCALE[b * NX + i];
    }
    for (k = 0; k < (m->has_guess ? 1 : MAX_ITERATIONS); ++k) {
        m->iterations = k + 1;
#if HAS_CONDENSING  /* the linearization, then the condensing, as the Python path */
        call(m, (kernel) ${p}_prepare, m->w, m->parameters, NONE, NONE, NONE, m->lin, NONE, NONE, NONE);
        ${p}_condense(1, m->lin, m->data, m->condensing);
#else
        call(m, (kernel) ${p}_prepare, m->w, m->parameters, NONE, NONE, NONE, m->data, NONE, NONE, NONE);
#endif
        if (!solve_qp(m, x0)) return 3;
        if (!all_finite(m->w_next, NW)) return 5;
        step = 0.0;
        for (i = 0; i < NW; ++i) if (fabs(m->w_next[i] - m->w[i]) > step) step = fabs(m->w_next[i] - m->w[i]);
        for (i = 0; i < NW; ++i) m->w[i] = m->w_next[i];
        if (m->has_guess) { converged = 1; break; }
        if (step <= TOLERANCE) { converged = 1; break; }
    }
    return converged ? 0 : 4;
}

int ${p}_init(${p}_state *m, const double *y0, const double *r0) {
    double x0[NX], u0[NU];
    int i, k;
    if (!all_finite(y0, NY) || !all_finite(r0, NU)) return 1;
    for (i = 0; i < NREF && REFERENCES[i] != r0[0]; ++i) {}
    if (i == NREF) return 9;
    call(m, (kernel) ${p}_start, y0, NONE, NONE, NONE, NONE, x0, u0, NONE, NONE);
    if (!all_finite(x0, NX) || !all_finite(u0, NU)) return 1;
    for (i = 0; i < NX; ++i) m->xc[i] = x0[i];
    for (i = 0; i < NU; ++i) m->xc[NX + i] = 0.0;
    for (k = 0; k < NH; ++k)
        for (i = 0; i < NU; ++i) m->xc[NE + k * NU + i] = u0[i];
    m->has_guess = 0;
    m->iterations = 0;
    return setup(m);
}

int ${p}_step(${p}_state *m, const double *y, const double *r, double *u) {
    double x_hat[NX], d_hat[NU], y_hat[NY], innovation[NY], candidate[NI], inputs[NI], x_next[NX], v[NU];
    double plan[NI], x0[NXS], sum;
    int b, i, j, k, target = 0, status = 0;
    for (k = 0; k < NI; ++k) plan[k] = m->xc[NE + k];
    for (i = 0; i < NX; ++i) x_hat[i] = m->xc[i];
    for (i = 0; i < NU; ++i) d_hat[i] = m->xc[NX + i];
    if (!all_finite(r, NU)) {
        status = 7;
    } else {
        for (target = 0; target < NREF && REFERENCES[target] != r[0]; ++target) {}
        if (target == NREF) status = 9;
    }
    if (status == 0 && !all_finite(y, NY)) {
        status = 1;  /* a lost measurement: the prediction stands as the estimate */
    } else if (status == 0) {
        call(m, (kernel) ${p}_output, x_hat, NONE, NONE, NONE, NONE, y_hat, NONE, NONE, NONE);
        for (i = 0; i < NY; ++i) innovation[i] = y[i] - y_hat[i];
        for (i = 0; i < NE; ++i) {
            sum = 0.0;
            for (j = 0; j < NY; ++j) sum += GAIN[i * NY + j] * innovation[j];
            if (i < NX) x_hat[i] += sum; else d_hat[i - NX] += sum;
        }
        if (!all_finite(x_hat, NX) || !all_finite(d_hat, NU)) status = 2;
    }
    if (status == 0) {
        for (i = 0; i < NP; ++i) m->parameters[i] = P_DEFAULT[i];
        for (b = 0; b < NS; ++b) {  /* every branch starts at the estimate */
            for (i = 0; i < NX; ++i) x0[b * NX + i] = m->parameters[OFFSET_X0 + b * NX + i] = x_hat[i];
            for (i = 0; i < NU; ++i) {
                m->parameters[OFFSET_D_HAT + b * NU + i] = d_hat[i];
                m->parameters[OFFSET_U_S + b * NU + i] = V_TARGET[target * NUS + b * NU + i] - d_hat[i];
                m->parameters[OFFSET_U_PREV + b * NU + i] = plan[i];
            }
        }
        for (i = 0; i < NXS; ++i) m->parameters[OFFSET_X_S + i] = X_TARGET[target * NXS + i];
        for (i = 0; i < NXS * NXS; ++i) m->parameters[OFFSET_P + i] = P_TARGET[target * NXS * NXS + i];
        if (!m->set_up && (status = setup(m))) {
            m->has_guess = 0;
        } else {
            status = solve_nlp(m, x0, x_hat, d_hat, plan);
            if (status == 0) {  /* the first branch's moves (the first N_r are every branch's) */
                for (k = 0; k < NH; ++k)
                    for (i = 0; i < NU; ++i) inputs[k * NU + i] = m->w[INPUT_INDEX[k * NUS + i]] * INPUT_SCALE[i];
                if (!all_finite(inputs, NI)) status = 6;
            }
            m->has_guess = status == 0;
            if (status == 0) {
                for (i = 0; i < NW; ++i) m->w_next[i] = m->w[SHIFT_INDEX[i]];
                for (i = 0; i < NW; ++i) m->w[i] = m->w_next[i];
            }
        }
    }
    if (status == 0) {
        for (k = 0; k < NI; ++k) candidate[k] = inputs[k];
    } else {  /* follow the previous plan, shifted by one sample */
        for (k = 0; k < NI - NU; ++k) candidate[k] = plan[k + NU];
        for (i = 0; i < NU; ++i) candidate[NI - NU + i] = plan[NI - NU + i];
    }
    for (k = 0; k < NI; ++k) candidate[k] = clip(candidate[k], -LIMIT[k % NU], LIMIT[k % NU]);
    if (HAS_RATE) {
        for (i = 0; i < NU; ++i) {
            candidate[i] = clip(candidate[i], plan[i] - RATE[i], plan[i] + RATE[i]);
            candidate[i] = clip(candidate[i], -LIMIT[i], LIMIT[i]);
        }
    }
    for (i = 0; i < NU; ++i) u[i] = candidate[i];
    if (!all_finite(u, NU)) status |= NONFINITE_COMMAND;
    for (i = 0; i < NU; ++i) v[i] = u[i] + d_hat[i];
    call(m, (kernel) ${p}_predict, x_hat, v, NONE, NONE, NONE, x_next, NONE, NONE, NONE);
    if (!all_finite(x_next, NX) && all_finite(x_hat, NX) && all_finite(u, NU))
        for (i = 0; i < NX; ++i) x_next[i] = x_hat[i];  /* the model's prediction blew up: hold */
    for (i = 0; i < NX; ++i) m->xc[i] = x_next[i];
    for (i = 0; i < NU; ++i) m->xc[NX + i] = d_hat[i];
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
"""
)
