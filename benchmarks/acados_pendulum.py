"""The acados side of benchmarks/mpc.py: SQP-RTI on the NMPC problem given as JSON, per-step times.

Run by `benchmarks/mpc.py` in a subprocess with the python of a virtual
environment holding acados (the package registry's ``comma-deps-acados``,
which installs its own casadi 3.6, so it lives apart from the project's)::

    python -m venv benchmarks/.venv-acados
    benchmarks/.venv-acados/bin/pip install comma-deps-acados cython    # cython: the faster wrapper
    ACADOS_PYTHON=benchmarks/.venv-acados/bin/python python benchmarks/mpc.py --json out.json

Usage: <acados python> benchmarks/acados_pendulum.py PROBLEM.json RESULT.json

The problem file holds the plant's ẋ = f(x, u, p) as Python source over casadi
(written by `benchmarks/mpc.py` from our CasADi Function), its known
parameters, the weights, the horizon and the recorded per-sample parameters
(x̂, d̂, x_s, u_s) of our closed loop. acados gets the same problem: RK4
(explicit RK of order 4, one step per sample) on f(x, u + d̂, p), stage cost
‖x − x_s‖²_Q + ‖u − u_s‖²_R and terminal ‖x_N − x_s‖²_P as linear least squares
(weights doubled: acados' least squares carry a ½; stage weights divided by
Ts: this acados multiplies stage costs by the interval length), |u| <= limit,
soft bounds with the same slack weights.
Gauss-Newton Hessian, partial condensing HPIPM, SQP_RTI. Each sample: set x̂,
d̂ and the references, solve once, read u_0; timed around the set calls and
the solve (what a controller step pays), plus acados' own time_tot. Before
each sample the last solution is shifted by one interval (the last state and
input repeated), as our real-time iteration's warm start: acados' RTI would
otherwise linearize at the unshifted solution, a different iterate from ours
(first moves up to 0.09 N apart on the pendulum, where the converged
solutions of both agree to 4e-8).
"""

from __future__ import annotations

import json
import os
import shutil
import sys
import tempfile
import time
import traceback

import casadi as ca
import numpy as np


def acados_root(work: str) -> str:
    """An acados root (include, lib, bin, interfaces/acados_template) built beside the wheel's files."""
    import acados

    package = os.path.dirname(acados.__file__)
    install = os.path.join(package, "install")
    root = os.path.join(work, "acados-root")
    os.makedirs(os.path.join(root, "interfaces", "acados_template"), exist_ok=True)
    # A copy, not a link: the generated Makefile reads include/../interfaces.
    shutil.copytree(os.path.join(install, "include"), os.path.join(root, "include"), dirs_exist_ok=True)
    for name in ("lib", "bin"):
        target = os.path.join(root, name)
        if not os.path.exists(target):
            os.symlink(os.path.join(install, name), target)
    template = os.path.join(root, "interfaces", "acados_template", "acados_template")
    if not os.path.exists(template):
        os.symlink(os.path.join(package, "acados_template"), template)
    return root


#: acados' least-squares cost is ½‖y − y_ref‖²_W and its slack cost z σ + ½ Z σ²: W = 2 Q poses our
#: ‖x − x_s‖²_Q (and Z = 2 ρ our ρ σ²). Without soft bounds the factor only scales the objective; with
#: them, a factor 1 would weigh the slacks twice as much as ours.
LS_FACTOR = 2.0


def build_ocp(problem: dict, work: str):
    from acados_template import AcadosModel, AcadosOcp  # on sys.path from main()

    nx, nu, N, Ts = problem["nx"], problem["nu"], problem["horizon"], problem["sample_period"]
    namespace: dict = {}
    exec(problem["model_code"], namespace)  # defines f(x, u, p, ca) -> list of ẋ entries
    x, u, d = ca.SX.sym("x", nx), ca.SX.sym("u", nu), ca.SX.sym("d_hat", nu)
    params = ca.DM(problem["params"])
    model = AcadosModel()
    model.name = "pendulum_nmpc"
    model.x, model.u, model.p = x, u, d
    model.xdot = ca.SX.sym("xdot", nx)
    model.f_expl_expr = ca.vertcat(*namespace["f"](x, u + d, params, ca))
    model.f_impl_expr = model.xdot - model.f_expl_expr
    ocp = AcadosOcp()
    ocp.model = model
    ocp.dims.N = N
    ocp.solver_options.tf = N * Ts
    Q, R, P = (np.array(problem[k]) for k in ("Q", "R", "P"))
    ny = nx + nu
    ocp.cost.cost_type = "LINEAR_LS"
    ocp.cost.cost_type_e = "LINEAR_LS"
    ocp.cost.W = LS_FACTOR * np.block([[Q, np.zeros((nx, nu))], [np.zeros((nu, nx)), R]]) / Ts
    ocp.cost.W_e = LS_FACTOR * P
    ocp.cost.Vx = np.vstack([np.eye(nx), np.zeros((nu, nx))])
    ocp.cost.Vu = np.vstack([np.zeros((nx, nu)), np.eye(nu)])
    ocp.cost.Vx_e = np.eye(nx)
    ocp.cost.yref = np.zeros(ny)
    ocp.cost.yref_e = np.zeros(nx)
    limit = np.array(problem["input_limit"])
    ocp.constraints.lbu, ocp.constraints.ubu, ocp.constraints.idxbu = -limit, limit, np.arange(nu)
    ocp.constraints.x0 = np.zeros(nx)
    soft = problem.get("soft", [])
    if soft:
        # lower <= G x <= upper on x_1..x_N, softened with the same slack on both sides; acados
        # multiplies the slack penalties by Ts too, so they are divided by it.
        G = np.array([b["row"] for b in soft])
        lower = np.array([b["lower"] for b in soft])
        upper = np.array([b["upper"] for b in soft])
        w = np.array([b["linear_weight"] for b in soft]) / Ts
        rho = 2 * np.array([b["quadratic_weight"] for b in soft]) / Ts
        ns = len(soft)
        ocp.constraints.C, ocp.constraints.D = G, np.zeros((ns, nu))
        ocp.constraints.lg, ocp.constraints.ug = lower, upper
        ocp.constraints.idxsg = np.arange(ns)
        ocp.constraints.C_e, ocp.constraints.lg_e, ocp.constraints.ug_e = G, lower, upper
        ocp.constraints.idxsg_e = np.arange(ns)
        ocp.cost.zl = ocp.cost.zu = w
        ocp.cost.Zl = ocp.cost.Zu = rho
        ocp.cost.zl_e = ocp.cost.zu_e = w * Ts
        ocp.cost.Zl_e = ocp.cost.Zu_e = rho * Ts
    ocp.parameter_values = np.zeros(nu)
    ocp.solver_options.qp_solver = "PARTIAL_CONDENSING_HPIPM"
    ocp.solver_options.hessian_approx = "GAUSS_NEWTON"
    ocp.solver_options.integrator_type = "ERK"
    ocp.solver_options.sim_method_num_stages = 4
    ocp.solver_options.sim_method_num_steps = problem.get("substeps", 1)
    ocp.solver_options.nlp_solver_type = "SQP_RTI"
    ocp.solver_options.print_level = 0
    ocp.code_export_directory = os.path.join(work, "c_generated_code")
    return ocp


def converged_first_moves(solver, problem: dict) -> list:
    """First moves on every problem["converged_check"]["every"]-th sample, each from a cold start (the
    states at x̂, the inputs zero) iterated by the same solver until no input moves by more than the
    check's tolerance (None where that takes more than its max_iterations): with our SQP's on the same
    samples, the check that both pose the same problem, apart from the real-time iterates."""
    check = problem.get("converged_check")
    if not check:
        return []
    N, moves = problem["horizon"], []
    for step in problem["steps"][:: check["every"]]:
        x_hat, d_hat = np.array(step["x_hat"]), np.array(step["d_hat"])
        solver.reset()
        for k in range(N + 1):
            solver.set(k, "x", x_hat)
            solver.set(k, "p", d_hat)
            solver.set(k, "yref", np.concatenate([step["x_s"], step["u_s"]]) if k < N else np.array(step["x_s"]))
        solver.set(0, "lbx", x_hat)
        solver.set(0, "ubx", x_hat)
        before, answer = None, None
        for _ in range(check["max_iterations"]):
            solver.solve()
            inputs = np.array([solver.get(k, "u") for k in range(N)])
            if before is not None and np.max(np.abs(inputs - before)) <= check["tolerance"]:
                answer = inputs[0].tolist()
                break
            before = inputs
        moves.append(answer)
    return moves


def main(problem_path: str, result_path: str) -> None:
    problem = json.loads(open(problem_path).read())
    work = tempfile.mkdtemp(prefix="acados-bench-")
    result: dict = {}
    try:
        os.environ["ACADOS_SOURCE_DIR"] = acados_root(work)
        import acados

        sys.path.insert(0, os.path.dirname(acados.__file__))  # the wheel ships acados_template inside it
        from acados_template import AcadosOcpSolver

        ocp = build_ocp(problem, work)
        json_file = os.path.join(work, "acados_ocp.json")
        started = time.perf_counter()
        os.chdir(work)  # acados writes its build products beside the json file and into the working directory
        sys.path.insert(0, work)  # the Cython wrapper is imported as the module c_generated_code.acados_ocp_solver_pyx
        wrapper = "cython"
        try:
            AcadosOcpSolver.generate(ocp, json_file=json_file)
            AcadosOcpSolver.build(ocp.code_export_directory, with_cython=True)
            solver = AcadosOcpSolver.create_cython_solver(json_file)
        except Exception as err:  # the Cython wrapper needs Cython and a compiler for Python extensions
            wrapper = f"ctypes (Cython failed: {type(err).__name__}: {str(err).splitlines()[0][:120]})"
            solver = AcadosOcpSolver(ocp, json_file=json_file, verbose=False)
        build_s = time.perf_counter() - started
        N, nx, nu = problem["horizon"], problem["nx"], problem["nu"]
        times, internal, first, status = [], [], [], []
        warm = problem.get("warm_up", 1)
        for index, step in enumerate(problem["steps"]):
            x_hat, d_hat = np.array(step["x_hat"]), np.array(step["d_hat"])
            yref = np.concatenate([step["x_s"], step["u_s"]])
            yref_e = np.array(step["x_s"])
            begin = time.perf_counter()
            if index:  # the last solution one interval later, the last state and input repeated (as ours)
                for k in range(N):
                    solver.set(k, "x", solver.get(k + 1, "x"))
                    if k + 1 < N:
                        solver.set(k, "u", solver.get(k + 1, "u"))
            solver.set(0, "lbx", x_hat)
            solver.set(0, "ubx", x_hat)
            for k in range(N):
                solver.set(k, "p", d_hat)
                solver.set(k, "yref", yref)
            solver.set(N, "p", d_hat)
            solver.set(N, "yref", yref_e)
            code = solver.solve()
            u0 = np.array(solver.get(0, "u")).ravel()
            elapsed = time.perf_counter() - begin
            if index < warm:  # the first sample starts cold: iterate it to convergence, untimed
                for _ in range(50):
                    code = solver.solve()
                u0 = np.array(solver.get(0, "u")).ravel()
            else:
                times.append(elapsed)
                internal.append(float(np.ravel(solver.get_stats("time_tot"))[0]))
            first.append(u0.tolist())
            status.append(int(code))
        converged = converged_first_moves(solver, problem)
        result = {
            "available": True,
            "converged_first_moves": converged,
            "wrapper": wrapper,
            "build_s": build_s,
            "step_ms": [1e3 * t for t in times],
            "time_tot_ms": [1e3 * t for t in internal],
            "first_moves": first,
            "status": status,
            "casadi_version": ca.__version__,
            "nx": nx,
            "nu": nu,
        }
    except Exception as err:
        where = traceback.extract_tb(err.__traceback__)[-1]
        result = {
            "available": False,
            "reason": f"{type(err).__name__}: {err} (at {os.path.basename(where.filename)}:{where.lineno})"[:2000],
        }
    finally:
        shutil.rmtree(work, ignore_errors=True)
    with open(result_path, "w") as handle:
        json.dump(result, handle)


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
