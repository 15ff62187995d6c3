"""The spec judged at the answer only: the closed loop's slowest mode at the end of each run."""

from __future__ import annotations

import casadi as ca
import numpy as np

import models
from models import Block, Plant

from .problem import TuningProblem


def closed_loop_spectral_abscissa(plant: Plant, block: Block, x, xc, r, params=None, substeps: int = 10) -> float:
    """Slowest mode of the sampled closed loop linearized at (x, xc, r), in 1/s.

    log(spectral radius of ∂(x⁺, x_c⁺)/∂(x, x_c)) / Ts: negative when the loop is
    locally stable; a saturated input makes the loop open there.

    x : (nx,) plant state;  xc : (n_state,) block state;  r : the block's reference (n_reference,)
    """
    s = ca.SX.sym("s", plant.nx + block.n_state)
    p = plant.param_vector(params)
    xs, xcs = s[: plant.nx], s[plant.nx :]
    y = plant.casadi_h(xs, p) if block.measures == "outputs" else xs
    xc_next, u = block.casadi_step(xcs, y, np.atleast_1d(r), block.gain_vector())
    u = ca.fmin(ca.fmax(u, -plant.input_limit), plant.input_limit)
    x_next = plant.step_function(block.sample_period, substeps)(xs, u, p)
    jac = ca.Function("closed_loop_jacobian", [s], [ca.jacobian(ca.vertcat(x_next, xc_next), s)])
    eig = np.linalg.eigvals(np.asarray(jac(np.concatenate([x, xc]))))
    return float(np.log(np.max(np.abs(eig))) / block.sample_period)


def spectral_violations(problem: TuningProblem, decision) -> list[str]:
    """The `Specs.max_spectral_abscissa` bounds missed at `decision`, one message per run, each judged at
    the end of a fresh simulation on the problem's first parameter sample."""
    found = []
    block = None
    for run in problem.runs:
        bound = run.specs.max_spectral_abscissa
        if bound is None:
            continue
        block = block or problem.block_at(decision)
        sc = run.scenario
        where = f" ({run.label})" if run.label else ""
        res = models.simulate_closed_loop(
            problem.plant,
            block,
            run.r,
            sc.duration,
            x0=run.x0,
            params=problem.samples[0],
            input_disturbance=run.d,
            substeps=problem.substeps,
            allow_divergence=True,
        )
        if res.diverged_at is not None:
            found.append(
                f"spectral abscissa <= {bound:g} 1/s{where} (the closed loop diverged at t = {res.diverged_at:.3g} s)"
            )
            continue
        assert res.xc is not None, "a Block controller's states are recorded"
        alpha = closed_loop_spectral_abscissa(
            problem.plant, block, res.x[-1], res.xc[-1], res.r[-1], problem.samples[0], problem.substeps
        )
        if alpha > bound:
            found.append(f"spectral abscissa <= {bound:g} 1/s{where} (got {alpha:.3g} 1/s)")
    return found


def missed_specs(problem: TuningProblem, decision) -> list[str]:
    """The specs `decision` misses on the exact loop (the actuator limit and the spectral bound included)."""
    return problem.values(decision)[2] + spectral_violations(problem, decision)
