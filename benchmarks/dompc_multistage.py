"""do-mpc's multi-stage (scenario-tree) MPC on a problem exported by benchmarks/robust_mpc.py.

    benchmarks/.venv-dompc/bin/python benchmarks/dompc_multistage.py PROBLEM.json

Run by benchmarks/robust_mpc.py in do-mpc's own virtual environment (do-mpc is never a dependency
of the project). PROBLEM.json gives the discrete model (a CasADi Function file x, u, p -> x_next,
the project's RK4 step), the uncertain parameters' values (do-mpc's scenarios are their
combinations: the box's corners), the fixed ones, the weights Q, R, P, the horizon, the input limit,
the start state and the number of closed-loop steps. It prints one JSON line: the first move of a
converged solve from the start, and the per-step times of a closed loop on the nominal parameters.
"""

from __future__ import annotations

import json
import sys
import time

import casadi as ca
import do_mpc
import numpy as np


def controller(spec: dict, step: ca.Function):
    """do-mpc's MPC with n_robust = 1 on the discrete model `step`, the problem of `spec`."""
    model = do_mpc.model.Model("discrete")
    nx, nu = len(spec["x0"]), 1
    x = model.set_variable("_x", "x", shape=(nx, 1))
    u = model.set_variable("_u", "u", shape=(nu, 1))
    values = []
    for name, value in zip(spec["parameter_names"], spec["parameter_values"]):
        values.append(model.set_variable("_p", name) if name in spec["uncertain"] else value)
    x_next = step(x, u, ca.vertcat(*values))
    model.set_rhs("x", x_next)
    Q, R, P = (np.array(spec[k]) for k in ("Q", "R", "P"))
    model.setup()
    mpc = do_mpc.controller.MPC(model)
    mpc.settings.n_horizon = spec["horizon"]
    mpc.settings.t_step = spec["sample_period"]
    mpc.settings.n_robust = 1
    mpc.settings.store_full_solution = False
    mpc.settings.nlpsol_opts = {
        "ipopt.print_level": 0,
        "ipopt.sb": "yes",
        "print_time": 0,
        "ipopt.tol": spec["tolerance"],
        "ipopt.acceptable_tol": spec["tolerance"],
    }
    mpc.set_objective(lterm=ca.bilin(Q, x, x) + ca.bilin(R, u, u), mterm=ca.bilin(P, x, x))
    mpc.bounds["lower", "_u", "u"] = -spec["input_limit"]
    mpc.bounds["upper", "_u", "u"] = spec["input_limit"]
    mpc.set_uncertainty_values(**{name: np.array(v) for name, v in spec["uncertain"].items()})
    mpc.setup()
    return mpc


def main() -> None:
    with open(sys.argv[1]) as handle:
        spec = json.load(handle)
    step = ca.Function.load(spec["model"])
    mpc = controller(spec, step)
    x0 = np.array(spec["x0"]).reshape(-1, 1)
    mpc.x0 = x0
    mpc.set_initial_guess()
    first = np.array(mpc.make_step(x0)).ravel()
    stats = mpc.solver_stats
    times, x = [], x0
    nominal = np.array(spec["nominal_parameters"])
    for _ in range(spec["steps"]):
        begin = time.perf_counter()
        u = mpc.make_step(x)
        times.append(time.perf_counter() - begin)
        x = np.array(step(x, u, nominal)).reshape(-1, 1)
    print(
        json.dumps(
            {
                "first_move": first.tolist(),
                "first_solve_status": stats.get("return_status"),
                "first_solve_iterations": stats.get("iter_count"),
                "step_s": times,
                "do_mpc_version": do_mpc.__version__,
                "scenarios": int(mpc.n_combinations),
            }
        )
    )


if __name__ == "__main__":
    main()
