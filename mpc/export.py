"""Linear and tube MPC exported as C: estimator, target and the condensed QP solved by DAQP.

`export_linear_mpc(controller, name)` writes the whole `LinearMPC.step` as C
with fixed sizes: the disturbance observer's update, the steady-state target,
the condensed QP of `mpc.qp_fast.condense` (the problem the Python path
solves, in the same scaled variables), the fallback to the shifted plan,
exact clipping and the rate limit, and the one-sample prediction of the
estimate. The first state comes from the first measurement as in Python
(``name_init``).

A `mpc.TubeMPC` goes through the same function and the same C around its QP
(DAQP's setup and warm-started solve): its condensed QP (`TubeMPC.qp`, whose
parameters are the nominal state z_0 and, tracking, the reference), the ancillary law u = ue + v_0 +
K (x − xe − z) and the nominal update z⁺ = A z + B v_0 replace the estimator,
the target and the fallback; a failed solve returns its status with a NaN
command, where the Python step raises.

The QP is solved by DAQP, the dual active-set solver the Python path
(`mpc.qp_fast.CondensedDaqpSolver`) uses, called the same way: its matrices
set up once (``setup_daqp``: DAQP's workspace and the factorization of H,
in ``name_init``), then every sample the linear term and the bounds for the
new parameters (``update_ldp``) and a solve warm-started from the last
working set (``daqp_solve``), with the Python path's settings. DAQP comes
from CasADi's installation, the same build the real-time iteration links
(its headers in ``include/daqp`` and the static library ``libdaqpstat.a``
beside CasADi's Python module; `build_flags` names them): nothing of DAQP is
copied into the generated files, and a program linked with the static
library needs no CasADi at run time. CasADi's own code generation of its
``conic("daqp")`` is not used: its generated call sets DAQP up and frees it
again in every call (allocation and a factorization of H every sample) and
keeps its memory in a global array (docs/notes/mpc.md has the measurement).

Memory is one struct per controller (``name_state``), owned by the caller and
zero before its first ``name_init`` (static storage, or cleared): the
controller state, the QP's vectors and DAQP's workspace record. DAQP
allocates its arrays once, in ``name_init`` (or in the first ``name_step`` or
``name_solve_qp`` of a struct never initialized); ``name_free`` releases
them. The constant data (H, the constraint rows, the parameter maps) is
``static const``.
"""

from __future__ import annotations

import os
import string
from dataclasses import dataclass

import casadi as ca
import daqp
import numpy as np

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
from .qp_fast import PRIMAL_TOLERANCE, CondensedDaqpSolver, CondensedQP, condense
from .tube_mpc import TubeMPC

#: Status codes of ``name_step`` (and ``name_init``, ``name_solve_qp``); a non-finite command adds 16.
#: 5 is every DAQP failure but infeasibility and the iteration limit (cycling, an overdetermined
#: working set); 8 a failed DAQP setup (no memory, or H not positive definite).
STATUS = {
    0: "optimal",
    1: "non-finite measurement",
    2: "non-finite estimate",
    3: "QP infeasible",
    4: "QP iteration limit",
    5: "QP degenerate active set",
    6: "non-finite solution",
    7: "non-finite reference",
    8: "QP setup failed",
}
NONFINITE_COMMAND = 16

#: DAQP's functions the exported C calls (the linker pulls them, and what they call, from the library).
DAQP_ENTRY_POINTS = (
    "setup_daqp",
    "update_ldp",
    "update_v",
    "normalize_M",
    "normalize_Rinv",
    "daqp_solve",
    "daqp_default_settings",
    "free_daqp_workspace",
    "free_daqp_ldp",
    "deactivate_constraints",
    "reset_daqp_workspace",
    "activate_constraints",
)
#: DAQP settings the exported C takes from the Python path's solver (the others stay DAQP's defaults;
#: no proximal iterations: H is positive definite).
DAQP_SETTINGS = ("primal_tol", "dual_tol", "zero_tol", "pivot_tol", "progress_tol", "cycle_tol", "fval_bound")


def status_text(code: int) -> str:
    """The meaning of a status code of the exported step."""
    text = STATUS.get(code & ~NONFINITE_COMMAND, f"unknown code {code}")
    return f"non-finite command ({text})" if code & NONFINITE_COMMAND else text


def daqp_include_directory() -> str:
    """The folder holding DAQP's headers (``daqp/api.h``) in CasADi's installation."""
    return os.path.join(os.path.dirname(ca.__file__), "include")


def daqp_library() -> str:
    """DAQP's static library in CasADi's installation."""
    return os.path.join(os.path.dirname(ca.__file__), "libdaqpstat.a")


def build_flags() -> tuple[str, ...]:
    """Compiler arguments that build the exported C with DAQP, valid before the source files (as
    `models.compile.build_library` places flags): the header folder, the DAQP functions named as
    undefined (``-Wl,-u,``) so that the static library, given before the sources, is searched for
    them, and the library. After the sources, ``-I`` and the library alone do."""
    undefined = tuple(f"-Wl,-u,{symbol}" for symbol in DAQP_ENTRY_POINTS)
    return (f"-I{daqp_include_directory()}", *undefined, daqp_library())


@dataclass(frozen=True)
class ExportedMPC(ExportedC):
    """An exported linear MPC: `models.export.ExportedC` whose C is built with DAQP (`build_flags`)."""

    def build_flags(self) -> tuple[str, ...]:
        """DAQP's header folder and library (`build_flags`)."""
        return build_flags()


def daqp_settings(controller: LinearMPC | TubeMPC) -> dict[str, float]:
    """The DAQP settings of `controller`'s Python path: `DAQP_SETTINGS` from the `daqp` package's
    defaults, its primal tolerance, and its solver's iteration limit (a TubeMPC's own; 1000 when a
    LinearMPC solves with another solver)."""
    defaults = daqp.Model().settings
    settings = {key: defaults[key] for key in DAQP_SETTINGS}
    settings["primal_tol"] = PRIMAL_TOLERANCE
    if isinstance(controller, TubeMPC):
        settings["iter_limit"] = controller.iteration_limit
    else:
        solver = controller.solver
        settings["iter_limit"] = int(solver.iteration_limit if isinstance(solver, CondensedDaqpSolver) else 1000)
    return settings


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


#: The methods of TubeMPC whose law the exported C writes out; a subclass that overrides one is refused.
TUBE_METHODS = ("step", "solve", "initial_state", "check_feasible", "_vectors")


def check_exportable(controller) -> None:
    """Raise `UnsupportedExport` unless `controller` is a LinearMPC tracking one coordinate per input,
    or a TubeMPC whose law is TubeMPC's own (no method of `TUBE_METHODS` overridden)."""
    if isinstance(controller, TubeMPC):
        changed = [
            method for method in TUBE_METHODS if getattr(type(controller), method) is not getattr(TubeMPC, method)
        ]
        if changed:
            raise UnsupportedExport(
                f"{controller.name}: {type(controller).__name__} overrides TubeMPC.{', TubeMPC.'.join(changed)}; "
                "the export writes TubeMPC's own plan, ancillary law and nominal update, not a changed one"
            )
        return
    if not isinstance(controller, LinearMPC):
        kind = type(controller).__name__
        raise UnsupportedExport(
            f"{getattr(controller, 'name', kind)}: only mpc.LinearMPC and mpc.TubeMPC are exported here; "
            f"{kind} is not one"
            + (
                " (mpc.export_nmpc.export_nonlinear_mpc exports its real-time iteration)"
                if kind == "NonlinearMPC"
                else ""
            )
        )
    if controller.n_reference != controller.plant.nu:
        raise UnsupportedExport(
            f"{controller.name}: the export tracks as many coordinates as inputs; "
            f"reference {controller.n_reference}, inputs {controller.plant.nu}"
        )


def qp_data(qp: CondensedQP) -> str:
    """The condensed QP's constants as C arrays: H (n, n) and the rows (m, n) row-major as DAQP reads
    them, the linear term F p + f and the row bounds' constants and matrices on p, the simple bounds."""
    np.linalg.cholesky(qp.H)  # positive definite, as DAQP's setup needs (LinAlgError if not)
    return "".join(
        [
            c_array("HESSIAN", qp.H),
            c_array("LINEAR_MATRIX", qp.F),
            c_array("LINEAR_CONSTANT", qp.f),
            c_array("VARIABLE_LOWER", qp.lower),
            c_array("VARIABLE_UPPER", qp.upper),
            c_array("ROWS", qp.rows if qp.rows.size else [0.0]),
            c_array("ROW_LOWER_CONSTANT", qp.row_lower_constant),
            c_array("ROW_LOWER_MATRIX", qp.row_lower_matrix),
            c_array("ROW_UPPER_CONSTANT", qp.row_upper_constant),
            c_array("ROW_UPPER_MATRIX", qp.row_upper_matrix),
        ]
    )


def controller_data(controller: LinearMPC, qp: CondensedQP) -> str:
    """The estimator's, the target's and the limits' constants as C arrays."""
    model, observer, target, nu = controller.model, controller.observer, controller.target, controller.plant.nu
    rate = controller.problem.rate_limit  # per sample
    return "".join(
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
        ]
    )


def export_linear_mpc(controller: LinearMPC | TubeMPC, name: str) -> ExportedMPC:
    """A `LinearMPC` or a `TubeMPC` as C with the same commands (see the module docstring).

    A TubeMPC's C holds its condensed QP (`TubeMPC.qp`, parameters p = z_0, or (z_0, r − H xe) when
    it tracks, with θ among its decisions), the ancillary law u = ue + v_0 + K (x − xe − z) and the
    nominal update z⁺ = A z + B v_0 (z = x − xe with `replan`);
    ``name_init`` starts z at the first state and refuses it (status 3) where the tightened problem
    is infeasible. Where the Python step raises (a failed solve), the C step returns the status with
    a NaN command and the state unchanged: no fallback.

    Parameters
    ----------
    controller : the LinearMPC or TubeMPC, as designed now
    name : C prefix of the files (``name.h``, ``name.c``) and functions (``name_step`` ...)

    Raises
    ------
    UnsupportedExport
        For a controller that is neither (a nonlinear MPC is exported by
        `mpc.export_nmpc.export_nonlinear_mpc`), or a TubeMPC whose law a subclass changed.
    """
    name = c_name(name)
    check_exportable(controller)
    if isinstance(controller, TubeMPC):
        return _export_tube(controller, name)
    qp = condense(controller.problem)
    plant, N = controller.plant, controller.horizon
    nx, nu, ny = plant.nx, plant.nu, plant.ny
    init = init_kernel(controller, name)
    work = work_sizes(init)
    sizes = dict(NX=nx, NU=nu, NY=ny, NE=nx + nu, NH=N, NI=N * nu, NSTATE=nx + nu + N * nu)
    defines = {
        "HAS_RATE": int(controller.problem.rate_limit is not None),
        "REFERENCE_OFFSET": c_number(controller.model.xe[controller.tracked_index]),
    }
    kernels = _LINEAR_KERNELS.substitute(p=name, work_arg=work["arg"], work_res=work["res"])
    text = dict(
        kind="linear MPC",
        signals=f"{nx} states, {ny} outputs ({', '.join(plant.output_names)})",
        state="(x_hat - xe, d_hat, plan): one-sample predictions and the input plan",
        init=_LINEAR_INIT_DOC,
        step="outputs y (${P}_N_MEASURED), reference r (absolute tracked coordinate) -> command u "
        "(${P}_N_INPUT), within the actuator limit",
        parameters="p = (x0, d, x_s, u_s, u_previous)",
        fallback="Any status but ${P}_OPTIMAL means the shifted previous plan was followed.",
    )
    data = controller_data(controller, qp)
    casadi = generated_code([init], f"{name}_casadi")
    return _exported(controller, name, qp, sizes, defines, data + casadi, kernels, text, work, n_reference=nu)


def _export_tube(controller: TubeMPC, name: str) -> ExportedMPC:
    """The C of a TubeMPC (see `export_linear_mpc`)."""
    qp, tube = controller.qp, controller.tube
    nx, nu = controller.n_state, controller.tube.feedback.shape[0]
    X_bar = tube.state_constraints
    sizes = dict(NX=nx, NU=nu, NG=len(X_bar.h), NR=controller.n_reference, NSTATE=nx)
    defines = {
        "REPLAN": int(controller.replan),
        "TRACKING": int(controller.tracking),
        "FEASIBILITY_TOLERANCE": c_number(FEASIBILITY_TOLERANCE),
    }
    data = "".join(
        [
            c_array("A_NOMINAL", controller.model.A),
            c_array("B_NOMINAL", controller.model.B),
            c_array("K_ANCILLARY", tube.feedback),
            c_array("XE", controller.model.xe),
            c_array("UE", controller.model.ue),
            c_array("G_TIGHT", X_bar.H),
            c_array("G_TIGHT_BOUND", X_bar.h),
            c_array("REFERENCE_OFFSET", controller.reference_offset if controller.tracking else [0.0]),
            c_array("SCALE", qp.scale),
        ]
    )
    reference = (
        "the absolute tracked coordinates (${P}_N_REFERENCE)"
        if controller.tracking
        else "not used: the tube regulates to its operating point"
    )
    text = dict(
        kind="tube MPC",
        signals=f"{nx} measured states",
        state="z - xe, the nominal state's deviation (the plan starts there)",
        init=_TUBE_INIT_DOC,
        step=f"the measured state x (${{P}}_N_MEASURED), reference r ({reference}) "
        "-> command u = ue + v_0 + K (x - xe - z) (${P}_N_INPUT)",
        parameters="p = (z_0 - xe, r - H xe)" if controller.tracking else "p = z_0 - xe",
        fallback="Any status but ${P}_OPTIMAL comes with a NaN command and the state unchanged (no fallback).",
    )
    kernels = _TUBE_KERNELS.substitute(p=name)
    work = dict(w=1, iw=1)
    return _exported(
        controller, name, qp, sizes, defines, data, kernels, text, work, n_reference=controller.n_reference
    )


#: The tube's C init accepts a first state whose tightened rows G z_0 <= g exceed their bound by at most this.
FEASIBILITY_TOLERANCE = 1e-9


def _exported(controller, name, qp, sizes, defines, data, kernels, text, work, *, n_reference) -> ExportedMPC:
    """The header and source of an MPC whose QP is `qp` (DAQP's setup and warm-started solve, shared)
    around its own `kernels` (``name_init``, ``name_step``), as an `ExportedMPC`."""
    upper = name.upper()
    n_rows = qp.rows.shape[0]
    sizes = sizes | dict(NZ=qp.n, NP=qp.n_parameters, NROWS=n_rows, NB=qp.n + n_rows)
    n_measured = sizes.get("NY", sizes["NX"])
    settings = "".join(
        f"    m->settings.{key} = {value if isinstance(value, int) else c_number(value)};\n"
        for key, value in daqp_settings(controller).items()
    )
    described = {key: string.Template(value).substitute(P=upper) for key, value in text.items()}
    header = _HEADER.substitute(
        p=name,
        P=upper,
        controller=controller.name,
        nu=sizes["NU"],
        N=controller.horizon,
        nz=qp.n,
        sizes=_header_sizes(upper, sizes, n_measured, n_reference, qp),
        sample_period=c_number(controller.sample_period),
        statuses=_header_statuses(upper),
        work_w=work["w"],
        work_iw=work["iw"],
        **described,
    )
    source = _SOURCE.substitute(
        p=name,
        kind=text["kind"],
        controller=controller.name,
        sizes="".join(f"#define {key} {value}\n" for key, value in (sizes | defines).items()),
        data=data + qp_data(qp),
        settings=settings,
        rows_vary=int(qp.rows_vary),
        nonfinite_command=NONFINITE_COMMAND,
        kernels=kernels,
    )
    return ExportedMPC(
        name=name,
        controller=controller.name,
        header=header,
        source=source,
        n_state=sizes["NSTATE"],
        n_measured=n_measured,
        n_reference=n_reference,
        n_input=sizes["NU"],
        sample_period=controller.sample_period,
        measures=controller.measures,
        has_init=True,
        status_codes={code: status_text(code) for code in list(STATUS) + [c | NONFINITE_COMMAND for c in STATUS]},
    )


def _header_sizes(upper: str, sizes: dict, n_measured: int, n_reference: int, qp: CondensedQP) -> str:
    named = (
        ("N_STATE", sizes["NSTATE"]),
        ("N_MEASURED", n_measured),
        ("N_REFERENCE", n_reference),
        ("N_INPUT", sizes["NU"]),
        ("N_DECISIONS", qp.n),
        ("N_PARAMETERS", qp.n_parameters),
        ("N_BOUNDS", max(1, sizes["NB"])),
    )
    return "\n".join(f"#define {upper}_{key} {value}" for key, value in named)


def _header_statuses(upper: str) -> str:
    lines = [
        f"#define {upper}_{text.upper().replace(' ', '_').replace('-', '')} {code}" for code, text in STATUS.items()
    ]
    return "\n".join([*lines, f"#define {upper}_NONFINITE_COMMAND {NONFINITE_COMMAND}"])


_LINEAR_INIT_DOC = """The first state from the first measurement y0 (${P}_N_MEASURED) and reference r0: at rest at the
 * measured configuration, no disturbance, the holding input as plan"""
_TUBE_INIT_DOC = """The first state z_0 = y0 - xe from the first measured state y0 (${P}_N_MEASURED) and reference
 * r0 (tracking; feasibility does not depend on it), refused with ${P}_QP_INFEASIBLE where the tightened
 * problem is infeasible there (a row of X - Z at z_0 beyond its bound, or the QP)"""

_HEADER = string.Template("""/* ${p}.h: ${kind} '${controller}' exported by codesign-control (mpc.export).
 * ${signals}, ${nu} input(s); horizon ${N}, ${nz} QP decisions.
 * Fixed sizes; the QP is solved by DAQP, which allocates its workspace once, in ${p}_init.
 * Build with DAQP's headers and library (mpc.export.build_flags). */
#ifndef ${P}_H
#define ${P}_H

#include <daqp/types.h>

#ifdef __cplusplus
extern "C" {
#endif

${sizes}
#define ${P}_SAMPLE_PERIOD ${sample_period}

/* Status codes of ${p}_step, ${p}_init and ${p}_solve_qp; a non-finite command adds
 * ${P}_NONFINITE_COMMAND. ${fallback} */
${statuses}

/* One per controller instance, owned by the caller (sizeof: ${p}_state_size()); all zero before its
 * first ${p}_init (static storage, or cleared), and not copied once initialized (DAQP's workspace
 * points into it). */
typedef struct {
    double xc[${P}_N_STATE];  /* ${state} */
    double f[${P}_N_DECISIONS];  /* the QP's linear term for this sample */
    double bupper[${P}_N_BOUNDS], blower[${P}_N_BOUNDS];  /* simple bounds, then the rows' */
    int sense[${P}_N_BOUNDS];
    double z[${P}_N_DECISIONS], lam[${P}_N_BOUNDS];  /* DAQP's solution and multipliers (scaled) */
    DAQPProblem problem;
    DAQPSettings settings;
    DAQPWorkspace workspace;
    int set_up;            /* DAQP holds this QP: its factorization, workspace and working set */
    int iterations;        /* of the last QP solve */
    double input_excess;   /* what clipping removed from the plan's first input */
    double work[${work_w}];
    long long int iwork[${work_iw}];
} ${p}_state;

/* ${init}; sets DAQP up (its one
 * allocation; again on a struct already initialized, the old workspace freed). Returns 0 or a status code. */
int ${p}_init(${p}_state *state, const double *y0, const double *r0);
/* One sample, every ${P}_SAMPLE_PERIOD s: ${step}. Returns a status code. */
int ${p}_step(${p}_state *state, const double *y, const double *r, double *u);
/* The condensed QP alone for parameters ${parameters} (${P}_N_PARAMETERS, deviation
 * coordinates): its solution z (${P}_N_DECISIONS, unscaled). Returns a status code. */
int ${p}_solve_qp(${p}_state *state, const double *p, double *z);
void ${p}_set_state(${p}_state *state, const double *xc);
void ${p}_get_state(const ${p}_state *state, double *xc);
/* Release DAQP's workspace (a later ${p}_init sets it up again). */
void ${p}_free(${p}_state *state);
unsigned long ${p}_state_size(void);

#ifdef __cplusplus
}
#endif

#endif /* ${P}_H */
""")

#: C every exported DAQP controller holds (the linear, tube and nonlinear MPC's sources): a finiteness
#: test, ${p}_free, the release of DAQP's workspace, and setup_workspace, its setup (templated on the
#: controller's prefix ${p} and DAQP's settings ${settings}).
DAQP_HELPERS_C = """static int all_finite(const double *v, int n) {
    int i;
    for (i = 0; i < n; ++i) if (!isfinite(v[i])) return 0;
    return 1;
}

void ${p}_free(${p}_state *m) {
    if (!m->set_up) return;
    m->workspace.settings = 0;  /* the settings are the struct's, not DAQP's to free */
    free_daqp_workspace(&m->workspace);
    free_daqp_ldp(&m->workspace);
    m->set_up = 0;
}

/* DAQP's workspace for m->problem (filled in by the caller) with the Python path's settings; 8 when
 * DAQP's setup fails. */
static int setup_workspace(${p}_state *m) {
    static const DAQPWorkspace empty;
    double setup_time;
    daqp_default_settings(&m->settings);
${settings}    m->workspace = empty;
    m->workspace.settings = &m->settings;
    if (setup_daqp(&m->problem, &m->workspace, &setup_time) < 0) {
        m->workspace.settings = 0;
        free_daqp_workspace(&m->workspace);  /* both guard against what is freed already */
        free_daqp_ldp(&m->workspace);
        return 8;
    }
    m->set_up = 1;
    return 0;
}
"""

_SOURCE = string.Template(
    """/* ${p}.c: ${kind} '${controller}', generated by codesign-control (mpc.export). */
#include "${p}.h"
#include <math.h>
#include <daqp/api.h>
#include <daqp/utils.h>
#undef NX  /* DAQP's constants.h: its workspace's size; here the plant's state count */

${sizes}#define ROWS_VARY ${rows_vary}
#define NONFINITE_COMMAND ${nonfinite_command}

${data}
"""
    + DAQP_HELPERS_C
    + """
/* DAQP's setup of the QP, as the Python path's: H and the rows fixed, the vectors at p = 0 (each
 * solve updates them); the settings of the Python path. */
static int setup(${p}_state *m) {
    int i;
    ${p}_free(m);
    for (i = 0; i < NZ; ++i) {
        m->f[i] = LINEAR_CONSTANT[i];
        m->bupper[i] = VARIABLE_UPPER[i];
        m->blower[i] = VARIABLE_LOWER[i];
    }
    for (i = 0; i < NROWS; ++i) {
        m->bupper[NZ + i] = ROW_UPPER_CONSTANT[i];
        m->blower[NZ + i] = ROW_LOWER_CONSTANT[i];
    }
    for (i = 0; i < NB; ++i) m->sense[i] = 0;
    m->problem.n = NZ;
    m->problem.m = NB;
    m->problem.ms = NZ;
    m->problem.H = (c_float *) HESSIAN;  /* DAQP reads H and the rows, never writes them */
    m->problem.f = m->f;
    m->problem.A = (c_float *) ROWS;
    m->problem.bupper = m->bupper;
    m->problem.blower = m->blower;
    m->problem.sense = m->sense;
    return setup_workspace(m);
}

/* The QP for parameters p: the linear term and the row bounds, then DAQP from the last working set.
 * m->z: the scaled solution. */
static int solve(${p}_state *m, const double *p) {
    DAQPResult result;
    int i, j, status;
    double sum;
    if (!m->set_up && (status = setup(m))) return status;
    for (i = 0; i < NZ; ++i) {
        sum = LINEAR_CONSTANT[i];
        for (j = 0; j < NP; ++j) sum += LINEAR_MATRIX[i * NP + j] * p[j];
        m->f[i] = sum;
    }
    for (i = 0; i < NROWS && ROWS_VARY; ++i) {
        sum = 0.0;
        for (j = 0; j < NP; ++j) sum += ROW_UPPER_MATRIX[i * NP + j] * p[j];
        m->bupper[NZ + i] = sum + ROW_UPPER_CONSTANT[i];
        sum = 0.0;
        for (j = 0; j < NP; ++j) sum += ROW_LOWER_MATRIX[i * NP + j] * p[j];
        m->blower[NZ + i] = sum + ROW_LOWER_CONSTANT[i];
    }
    if (update_ldp(ROWS_VARY ? UPDATE_v | UPDATE_d : UPDATE_v, &m->workspace) < 0) return 3;
    result.x = m->z;
    result.lam = m->lam;
    daqp_solve(&result, &m->workspace);
    m->iterations = result.iter;
    if (result.exitflag > 0) return 0;
    deactivate_constraints(&m->workspace);  /* the next solve starts from an empty working set, */
    reset_daqp_workspace(&m->workspace);    /* as after a failure in DAQP's Python interface */
    return result.exitflag == EXIT_INFEASIBLE ? 3 : (result.exitflag == EXIT_ITERLIMIT ? 4 : 5);
}

int ${p}_solve_qp(${p}_state *m, const double *p, double *z) {
    int i, status = solve(m, p);
    for (i = 0; i < NZ; ++i) z[i] = m->z[i] * SCALE[i];
    return status;
}
${kernels}
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

#: The tube MPC's init and step: z from the state (or the measurement with REPLAN), the plan's first
#: move v_0, the ancillary law and the nominal update.
_TUBE_KERNELS = string.Template("""
/* p = (z, r - H xe) tracking, z regulating; 0, or 7 for a non-finite reference. */
static int parameters(const double *z, const double *r, double *p) {
    int i;
    for (i = 0; i < NX; ++i) p[i] = z[i];
    if (!TRACKING) return 0;
    if (!all_finite(r, NR)) return 7;
    for (i = 0; i < NR; ++i) p[NX + i] = r[i] - REFERENCE_OFFSET[i];
    return 0;
}

int ${p}_init(${p}_state *m, const double *y0, const double *r0) {
    double row, p[NP];
    int i, j, status;
    if (!all_finite(y0, NX)) return 1;
    for (i = 0; i < NX; ++i) m->xc[i] = y0[i] - XE[i];
    m->iterations = 0;
    m->input_excess = 0.0;
    for (i = 0; i < NG; ++i) {  /* z_0 itself in X - Z */
        row = 0.0;
        for (j = 0; j < NX; ++j) row += G_TIGHT[i * NX + j] * m->xc[j];
        if (row > G_TIGHT_BOUND[i] + FEASIBILITY_TOLERANCE) return 3;
    }
    if ((status = parameters(m->xc, r0, p)) || (status = setup(m)) || (status = solve(m, p))) return status;
    return setup(m);  /* the first step starts DAQP afresh, as the Python path does */
}

int ${p}_step(${p}_state *m, const double *y, const double *r, double *u) {
    double z[NX], v[NU], p[NP], sum;
    int i, j, status = 0;
    for (i = 0; i < NX; ++i) z[i] = REPLAN ? y[i] - XE[i] : m->xc[i];
    if (!all_finite(y, NX)) {
        status = 1;
    } else if (!all_finite(z, NX)) {
        status = 2;
    } else if (!(status = parameters(z, r, p)) && !(status = solve(m, p))) {
        for (i = 0; i < NU; ++i) v[i] = m->z[i] * SCALE[i];
        if (!all_finite(v, NU)) status = 6;
    }
    if (status) {  /* the Python step raises here: no command, the state unchanged */
        for (i = 0; i < NU; ++i) u[i] = NAN;
        return status | NONFINITE_COMMAND;
    }
    for (i = 0; i < NU; ++i) {  /* u = ue + v_0 + K (x - xe - z) */
        sum = UE[i] + v[i];
        for (j = 0; j < NX; ++j) sum += K_ANCILLARY[i * NX + j] * (y[j] - XE[j] - z[j]);
        u[i] = sum;
    }
    for (i = 0; i < NX; ++i) {  /* z+ = A z + B v_0 */
        sum = 0.0;
        for (j = 0; j < NX; ++j) sum += A_NOMINAL[i * NX + j] * z[j];
        for (j = 0; j < NU; ++j) sum += B_NOMINAL[i * NU + j] * v[j];
        m->xc[i] = sum;
    }
    return all_finite(u, NU) ? 0 : NONFINITE_COMMAND;
}
""")

#: The linear MPC's init and step: the estimator, the target, the QP, the fallback, clipping and the rate limit.
_LINEAR_KERNELS = string.Template("""
/* v limited to [low, high]; NaN stays NaN (fmin/fmax would turn it into a bound). */
static double clip(double v, double low, double high) {
    return v < low ? low : (v > high ? high : v);
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
    return setup(m);
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
        status = solve(m, p);
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
""")
