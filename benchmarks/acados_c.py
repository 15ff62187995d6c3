"""acados' generated SQP-RTI solver called from C: the C side of benchmarks/mpc.py's C-to-C comparison.

Run with the python of the acados environment (see benchmarks/acados_pendulum.py, whose problem it
poses: `build_ocp`)::

    <acados python> benchmarks/acados_c.py PROBLEM.json RESULT.json

acados generates and builds its solver (``libacados_ocp_solver_<model>.so``, no Python wrapper); a
small C program, compiled with -O3 -march=native, then runs every recorded sample: shifts the last
solution by one interval (the last state and input repeated, as our real-time iteration's warm start),
sets x̂ (the initial state's bounds), d̂ (the parameters) and the references of every stage, solves once
and reads u_0, timed inside C with clock_gettime around those calls (what a controller step pays): the
wall clock, and the thread's CPU time (without the time other processes took the core). The first
`warm_up` samples start cold and are iterated 50 times, untimed, as in acados_pendulum.py.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
import traceback

import numpy as np

DRIVER = r"""
#define _POSIX_C_SOURCE 199309L
#include <stdio.h>
#include <time.h>
#include "acados_solver_%(model)s.h"
#include "acados_c/ocp_nlp_interface.h"
#define STEPS %(steps)d
#define NX %(nx)d
#define NU %(nu)d
#define NH %(N)d
#define WARM %(warm)d
%(data)s
int main(void) {
    %(model)s_solver_capsule *capsule = %(model)s_acados_create_capsule();
    struct timespec began, ended, cpu_began, cpu_ended;
    double yref[NX + NU], u0[NU], shifted[NX + NU];
    int k, i, j, code;
    if (%(model)s_acados_create(capsule)) { printf("create failed\n"); return 1; }
    ocp_nlp_config *config = %(model)s_acados_get_nlp_config(capsule);
    ocp_nlp_dims *dims = %(model)s_acados_get_nlp_dims(capsule);
    ocp_nlp_in *in = %(model)s_acados_get_nlp_in(capsule);
    ocp_nlp_out *out = %(model)s_acados_get_nlp_out(capsule);
    for (k = 0; k < STEPS; ++k) {
        clock_gettime(CLOCK_THREAD_CPUTIME_ID, &cpu_began);
        clock_gettime(CLOCK_MONOTONIC, &began);
        for (j = 0; k > 0 && j < NH; ++j) {  /* the last solution one interval later, the last repeated */
            ocp_nlp_out_get(config, dims, out, j + 1, "x", shifted);
            ocp_nlp_out_set(config, dims, out, j, "x", shifted);
            if (j + 1 < NH) {
                ocp_nlp_out_get(config, dims, out, j + 1, "u", shifted);
                ocp_nlp_out_set(config, dims, out, j, "u", shifted);
            }
        }
        ocp_nlp_constraints_model_set(config, dims, in, 0, "lbx", (void *) (X_HAT + k * NX));
        ocp_nlp_constraints_model_set(config, dims, in, 0, "ubx", (void *) (X_HAT + k * NX));
        for (i = 0; i < NX; ++i) yref[i] = X_S[k * NX + i];
        for (i = 0; i < NU; ++i) yref[NX + i] = U_S[k * NU + i];
        for (j = 0; j < NH; ++j) {
            %(model)s_acados_update_params(capsule, j, (double *) (D_HAT + k * NU), NU);
            ocp_nlp_cost_model_set(config, dims, in, j, "yref", yref);
        }
        %(model)s_acados_update_params(capsule, NH, (double *) (D_HAT + k * NU), NU);
        ocp_nlp_cost_model_set(config, dims, in, NH, "yref", yref);
        code = %(model)s_acados_solve(capsule);
        ocp_nlp_out_get(config, dims, out, 0, "u", u0);
        clock_gettime(CLOCK_MONOTONIC, &ended);
        clock_gettime(CLOCK_THREAD_CPUTIME_ID, &cpu_ended);
        if (k < WARM) {
            for (i = 0; i < 50; ++i) code = %(model)s_acados_solve(capsule);
            ocp_nlp_out_get(config, dims, out, 0, "u", u0);
        }
        printf("%%d %%lld %%lld", code,
               (long long) ((ended.tv_sec - began.tv_sec) * 1000000000LL + (ended.tv_nsec - began.tv_nsec)),
               (long long) ((cpu_ended.tv_sec - cpu_began.tv_sec) * 1000000000LL
                            + (cpu_ended.tv_nsec - cpu_began.tv_nsec)));
        for (i = 0; i < NU; ++i) printf(" %%.17g", u0[i]);
        printf("\n");
    }
    %(model)s_acados_free(capsule);
    %(model)s_acados_free_capsule(capsule);
    return 0;
}
"""


def c_array(name: str, values) -> str:
    items = ", ".join(repr(float(v)) for v in np.asarray(values, dtype=float).ravel()) or "0.0"
    return f"static const double {name}[] = {{{items}}};\n"


def main(problem_path: str, result_path: str) -> None:
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    from acados_pendulum import acados_root, build_ocp

    problem = json.loads(open(problem_path).read())
    work = tempfile.mkdtemp(prefix="acados-c-")
    try:
        root = os.environ["ACADOS_SOURCE_DIR"] = acados_root(work)
        import acados

        sys.path.insert(0, os.path.dirname(acados.__file__))
        from acados_template import AcadosOcpSolver

        ocp = build_ocp(problem, work)
        json_file = os.path.join(work, "acados_ocp.json")
        os.chdir(work)
        AcadosOcpSolver.generate(ocp, json_file=json_file)
        AcadosOcpSolver.build(ocp.code_export_directory, with_cython=False)
        model, code_dir = ocp.model.name, ocp.code_export_directory
        steps = problem["steps"]
        nx, nu, N = problem["nx"], problem["nu"], problem["horizon"]
        data = "".join(
            c_array(name, [s[key] for s in steps])
            for name, key in (("X_HAT", "x_hat"), ("D_HAT", "d_hat"), ("X_S", "x_s"), ("U_S", "u_s"))
        )
        warm = problem.get("warm_up", 1)
        driver = DRIVER % dict(model=model, steps=len(steps), nx=nx, nu=nu, N=N, warm=warm, data=data)
        with open(os.path.join(work, "driver.c"), "w") as handle:
            handle.write(driver)
        include = os.path.join(root, "include")
        flags = ["-O3", "-march=native", "-std=c99"]
        flags += [f"-I{code_dir}", f"-I{include}", f"-I{os.path.join(include, 'acados')}"]
        flags += [f"-I{os.path.join(include, 'blasfeo', 'include')}", f"-I{os.path.join(include, 'hpipm', 'include')}"]
        libraries = [f"-L{code_dir}", f"-lacados_ocp_solver_{model}", f"-L{os.path.join(root, 'lib')}"]
        libraries += ["-lacados", "-lhpipm", "-lblasfeo", "-lm"]
        subprocess.run(
            ["cc", *flags, "-o", "driver", "driver.c", *libraries], check=True, capture_output=True, text=True
        )
        environment = dict(os.environ, LD_LIBRARY_PATH=f"{code_dir}:{os.path.join(root, 'lib')}")
        printed = subprocess.run(
            [os.path.join(work, "driver")], check=True, capture_output=True, text=True, env=environment
        ).stdout
        rows = np.array([[float(v) for v in line.split()] for line in printed.splitlines()])
        result = {
            "available": True,
            "step_ms": (rows[warm:, 1] * 1e-6).tolist(),
            "cpu_ms": (rows[warm:, 2] * 1e-6).tolist(),
            "status": rows[:, 0].astype(int).tolist(),
            "first_moves": rows[:, 3:].tolist(),
        }
    except Exception as err:
        detail = getattr(err, "stderr", "") or ""
        result = {
            "available": False,
            "reason": f"{type(err).__name__}: {err} {detail[-800:]} {traceback.format_exc()[-400:]}"[:2000],
        }
    finally:
        shutil.rmtree(work, ignore_errors=True)
    with open(result_path, "w") as handle:
        json.dump(result, handle)


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
