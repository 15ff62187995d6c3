"""Build an optimal control problem's NLP once, solve it many times with IPOPT.

    solver = ocp.solver(Collocation(intervals=60))      # transcribes and builds IPOPT once
    first = solver.solve()                              # linear-interpolation guess
    again = solver.solve(x0=x_now, params={"z_ref": 1.0}, warm_start=first)

A solve takes new parameter values (`x0` with `start_from`, `params` of
`parameter`, `plant_params` for the fixed plant parameters) without
rebuilding anything. Starting points:

- default: states linearly interpolated between their fixed start and end
  values (a state fixed at one end only is held constant, a free one starts
  at zero moved into its bounds); inputs zero moved into their bounds;
- ``guess=``: a trajectory with attributes ``t``, ``x``, ``u``
  (a `models.Trajectory`, states interpolated, inputs held) or an
  `OCPSolution` (its interpolants, chosen parameters and final time);
- ``guess_input=``: an input (N, nu) array or a function of t, simulated on
  the plant from the fixed initial state (RK4, `models.simulate`);
- ``warm_start=``: an `OCPSolution` of this solver (or a `WarmStart`): its
  decisions and multipliers, for IPOPT's warm-start mode (the MPC path).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np

from .ocp_solution import OCPSolution, resimulate
from .transcription import Transcription

HESSIANS = ("exact", "limited-memory")

_STATUS = {
    "Solve_Succeeded": ("solved", True),
    "Solved_To_Acceptable_Level": ("solved to acceptable level", True),
    "Infeasible_Problem_Detected": ("infeasible", False),
    "Restoration_Failed": ("infeasible", False),
    "Maximum_Iterations_Exceeded": ("iteration limit", False),
}


@dataclass(frozen=True)
class WarmStart:
    """A primal-dual starting point in the solver's decision layout (scaled decisions): the decision
    vector and the multipliers lam_x of its bounds and lam_g of the constraints."""

    decision: np.ndarray
    lam_x: np.ndarray
    lam_g: np.ndarray


class OCPSolver:
    """The transcribed NLP of `ocp` and its IPOPT instance, built once.

    Parameters
    ----------
    ocp : OptimalControlProblem
    transcription : Collocation (default) or MultipleShooting
    hessian : "exact" (second derivatives by CasADi's AD, the default) or "limited-memory" (L-BFGS)
    tolerance : IPOPT's tol (scaled NLP error)
    max_iterations : IPOPT's max_iter
    ipopt_options : further IPOPT options, e.g. {"linear_solver": "ma57"}
    chosen_as_parameters : the chosen plant parameters are given values (nested co-design)
    print_level : IPOPT's print level (0 silent)

    Attributes
    ----------
    transcription : Transcription, the NLP's pieces
    """

    def __init__(
        self,
        ocp,
        transcription=None,
        *,
        hessian: str = "exact",
        tolerance: float = 1e-8,
        max_iterations: int = 3000,
        ipopt_options: dict | None = None,
        chosen_as_parameters: bool = False,
        print_level: int = 0,
    ):
        if hessian not in HESSIANS:
            raise ValueError(f"hessian must be one of {', '.join(HESSIANS)}, got {hessian!r}")
        if not np.isfinite(tolerance) or tolerance <= 0:
            raise ValueError(f"tolerance must be > 0, got {tolerance}")
        if int(max_iterations) != max_iterations or max_iterations < 1:
            raise ValueError(f"max_iterations must be an integer >= 1, got {max_iterations}")
        self.ocp = ocp
        self.transcription = Transcription(ocp, transcription, chosen_as_parameters=chosen_as_parameters)
        ipopt: dict[str, Any] = {
            "print_level": int(print_level),
            "sb": "yes",
            "tol": float(tolerance),
            "max_iter": int(max_iterations),
            "hessian_approximation": hessian,
        }
        ipopt |= dict(ipopt_options or {})
        self._options: dict[str, Any] = {"print_time": False, "ipopt": ipopt}
        self._solver = ca.nlpsol("ocp", "ipopt", self.transcription.nlp, self._options)
        self._warm_solver: ca.Function | None = None

    @property
    def warm_solver(self) -> ca.Function:
        """The same NLP with IPOPT's warm-start mode (multipliers used, small bound push); built on first use."""
        if self._warm_solver is None:
            options = {
                "print_time": False,
                "ipopt": self._options["ipopt"]
                | {
                    "warm_start_init_point": "yes",
                    "warm_start_bound_push": 1e-9,
                    "warm_start_mult_bound_push": 1e-9,
                    "mu_init": 1e-6,
                },
            }
            self._warm_solver = ca.nlpsol("ocp_warm", "ipopt", self.transcription.nlp, options)
        return self._warm_solver

    # ------------------------------------------------------------------ solve
    def solve(
        self,
        *,
        x0=None,
        params: dict | None = None,
        plant_params: dict | None = None,
        guess=None,
        guess_input=None,
        warm_start=None,
    ) -> OCPSolution:
        """Solve with these parameter values from the given starting point; see the module docstring.

        x0 : the initial state where the problem takes it as a parameter;  params : `parameter` values by
        name;  plant_params : plant parameter values by name (SI);  guess, guess_input : the starting
        states and inputs (see `initial_guess`);  warm_start : a `WarmStart` from an earlier solve.

        The result reports IPOPT's status; a failed or infeasible solve is returned (with
        the constraint of largest violation named), never replaced.
        """
        tr = self.transcription
        P = tr.parameter_values(x0, params, plant_params)
        lbx, ubx, lbg, ubg = (np.asarray(v, dtype=float).ravel() for v in tr.bounds(P))
        bad = np.flatnonzero(lbx > ubx + 1e-12)
        if bad.size:
            i = int(bad[0])
            raise ValueError(
                f"bounds on {tr.decision_labels[i]} are empty: [{lbx[i] * tr.scale[i]:.6g}, {ubx[i] * tr.scale[i]:.6g}]"
            )
        solver, lam = self._solver, {}
        if warm_start is not None:
            start = warm_start if isinstance(warm_start, WarmStart) else None
            if isinstance(warm_start, OCPSolution) and warm_start.transcription is tr:
                start = WarmStart(warm_start.decision, warm_start.lam_x, warm_start.lam_g)
            if start is None:
                raise ValueError(
                    "warm_start must be an OCPSolution of this solver or a WarmStart; pass a "
                    "solution of another mesh as guess="
                )
            if start.decision.size != tr.layout.size or start.lam_g.size != lbg.size:
                raise ValueError(
                    f"warm_start has {start.decision.size} decisions and {start.lam_g.size} "
                    f"multipliers, the NLP {tr.layout.size} and {lbg.size}"
                )
            w0 = np.clip(start.decision, lbx, ubx)
            lam = {"lam_x0": start.lam_x, "lam_g0": start.lam_g}
            solver = self.warm_solver
        else:
            w0 = self.initial_guess(P, lbx, ubx, guess, guess_input)
        started = time.perf_counter()
        try:
            result = solver(x0=w0, p=P, lbx=lbx, ubx=ubx, lbg=lbg, ubg=ubg, **lam)
            stats = solver.stats()
            ipopt_status = str(stats.get("return_status", "unknown"))
            iterations = int(stats.get("iter_count", 0))
            w = np.asarray(result["x"], dtype=float).ravel()
            lam_x = np.asarray(result["lam_x"], dtype=float).ravel()
            lam_g = np.asarray(result["lam_g"], dtype=float).ravel()
            lam_p = np.asarray(result["lam_p"], dtype=float).ravel()
        except RuntimeError as err:  # a NaN in a function evaluation, for example
            ipopt_status, iterations = f"error: {str(err).splitlines()[-1]}", 0
            w = np.full(tr.layout.size, np.nan)
            lam_x, lam_g, lam_p = np.zeros_like(lbx), np.zeros_like(lbg), np.zeros_like(P)
        solve_time = time.perf_counter() - started
        return self._solution(w, P, lbx, ubx, lbg, ubg, ipopt_status, iterations, solve_time, lam_x, lam_g, lam_p)

    def _solution(self, w, P, lbx, ubx, lbg, ubg, ipopt_status, iterations, solve_time, lam_x, lam_g, lam_p):
        tr = self.transcription
        plant, layout = tr.plant, tr.layout
        finite = bool(np.all(np.isfinite(w)))
        if finite:
            values = tr.values(w, P)
            f, accumulated, T, p, g = (np.asarray(v, dtype=float).ravel() for v in values[:5])
            fed = np.asarray(values[5], dtype=float).reshape(plant.nu, -1).T
        else:
            f, accumulated, T, p = (
                np.array([np.nan]),
                np.full(len(tr.ocp.accumulated), np.nan),
                np.array([np.nan]),
                np.full(plant.n_params, np.nan),
            )
            g = np.full(lbg.size, np.nan)
            fed = np.full((tr.intervals, plant.nu), np.nan)
        label, amount = self.largest_violation(w, g, lbx, ubx, lbg, ubg)
        status, success = _STATUS.get(ipopt_status, ("failed", False))
        success = success and finite
        if not success:
            status = f"{status}: IPOPT {ipopt_status}; largest violation {amount:.3g} in {label}"
        phys = w * tr.scale
        states = phys[layout.states]
        collocation = phys[layout.collocation] if tr.degree else None
        chosen = {name: float(phys[i]) for name, i in layout.chosen.items()}
        params = dict(zip([q.name for q in plant.param_info], p.tolist()))
        return OCPSolution(
            t=float(T[0]) * tr.mesh,
            states=states,
            inputs=phys[layout.inputs],
            plant_inputs=fed,
            controls=phys[layout.controls],
            params=params,
            chosen=chosen,
            final_time=float(T[0]),
            objective=float(f[0]),
            accumulated=accumulated,
            success=success,
            status=status,
            solver_status=ipopt_status,
            iterations=iterations,
            solve_time=solve_time,
            largest_violation=(label, amount),
            decision=w,
            lam_x=lam_x,
            lam_g=lam_g,
            lam_p=lam_p,
            parameter_vector=P,
            transcription=tr,
            collocation_states=collocation,
        )

    def largest_violation(self, w, g, lbx, ubx, lbg, ubg) -> tuple[str, float]:
        """(label, amount) of the constraint row or decision bound violated most at w (physical units for bounds).

        g : the constraint values at w;  lbx, ubx : the decision bounds;  lbg, ubg : the constraint bounds.
        """
        tr = self.transcription
        if not np.all(np.isfinite(w)):
            return "the decisions (not finite)", float("inf")
        over_x = np.maximum(np.maximum(lbx - w, w - ubx), 0) * tr.scale
        over_g = np.maximum(np.maximum(lbg - g, g - ubg), 0) if g.size else np.zeros(0)
        over_g = np.where(np.isfinite(over_g), over_g, np.inf)
        ix, ig = int(np.argmax(over_x)), (int(np.argmax(over_g)) if over_g.size else -1)
        if ig >= 0 and over_g[ig] >= over_x[ix]:
            return tr.constraint_labels[ig], float(over_g[ig])
        return f"bound on {tr.decision_labels[ix]}", float(over_x[ix])

    # ------------------------------------------------------------------ starting point
    def initial_guess(self, P, lbx, ubx, guess=None, guess_input=None) -> np.ndarray:
        """The scaled starting decisions; see the module docstring for the three kinds.

        P : the NLP parameters;  lbx, ubx : the decision bounds;  guess : an `OCPSolution`, a trajectory
        with t, x and u, or None;  guess_input : inputs (N, nu) or a function of t, or None.
        """
        tr = self.transcription
        layout, scale, ocp = tr.layout, tr.scale, tr.ocp
        lo, hi = lbx * scale, ubx * scale
        into = lambda values, idx: np.clip(values, lo[idx], hi[idx])
        phys = np.zeros(layout.size)
        T = ocp.fixed_final_time if ocp.free_time is None else ocp.free_time.guess
        if isinstance(guess, OCPSolution) and guess.transcription is tr:
            return np.clip(guess.decision, lbx, ubx)
        if isinstance(guess, OCPSolution):
            T = guess.final_time if ocp.free_time is not None else T
        elif guess is not None:
            if not all(hasattr(guess, a) for a in ("t", "x", "u")):
                raise ValueError(
                    "guess must be an OCPSolution or a trajectory with t, x and u "
                    f"(a models.Trajectory), got {type(guess).__name__}"
                )
            if ocp.free_time is not None:
                T = float(np.asarray(guess.t)[-1])
        node_times = self._node_times(T)  # (N, d+1) fractions -> times; mesh point N separately
        first, last = layout.states[0], layout.states[-1]
        start = np.where(lo[first] == hi[first], lo[first], np.nan)
        end = np.where(lo[last] == hi[last], lo[last], np.nan)

        if guess is not None:
            states_at, inputs_at = self._guess_functions(guess)
        elif guess_input is not None:
            if np.any(np.isnan(start)):
                raise ValueError("guess_input needs every initial state fixed (start_from or at_start(...) == value)")
            u = self._input_sequence(guess_input, T)
            sim = resimulate(tr.plant, T * tr.mesh, start, u, self._plant_params(P), method="rk4")
            mesh_t = T * tr.mesh
            states_at = lambda t: np.column_stack([np.interp(t, mesh_t, sim[:, i]) for i in range(sim.shape[1])])
            inputs_at = lambda t: u[np.clip(np.searchsorted(mesh_t, t, side="right") - 1, 0, len(u) - 1)]
        else:
            s_ = np.where(np.isnan(start), end, start)
            e_ = np.where(np.isnan(end), start, end)
            s_, e_ = np.nan_to_num(s_), np.nan_to_num(e_)
            states_at = lambda t: s_ + np.outer(np.asarray(t) / T, e_ - s_)
            inputs_at = lambda t: np.zeros((np.size(t), tr.plant.nu))

        N = tr.intervals
        mesh_t = T * tr.mesh
        phys[layout.states] = into(states_at(mesh_t), layout.states)
        if tr.degree:
            inner = node_times[:, 1:].ravel()
            values = states_at(inner).reshape(N, tr.degree, -1)
            phys[layout.collocation] = into(values, layout.collocation)
        middles = (mesh_t[:-1] + mesh_t[1:]) / 2
        phys[layout.inputs] = into(np.asarray(inputs_at(middles)).reshape(N, -1), layout.inputs)
        phys[layout.controls] = into(np.zeros(layout.controls.shape), layout.controls)
        chosen_guess = guess.chosen if isinstance(guess, OCPSolution) else {}
        for name, i in layout.chosen.items():
            phys[i] = np.clip(chosen_guess.get(name, ocp.chosen[name].guess), lo[i], hi[i])
        if layout.final_time is not None:
            phys[layout.final_time] = np.clip(T, lo[layout.final_time], hi[layout.final_time])
        return phys / scale

    def _node_times(self, T) -> np.ndarray:
        tr = self.transcription
        mesh_t = T * tr.mesh
        h = np.diff(mesh_t)
        tau = tr.coefficients.tau if tr.coefficients is not None else np.array([0.0])
        return mesh_t[:-1, None] + h[:, None] * tau[None, :]

    def _plant_params(self, P) -> np.ndarray:
        tr = self.transcription
        fixed = dict(zip(tr.fixed_param_names, P[tr.parameter_slices["plant"]]))
        return np.array(
            [
                fixed.get(q.name, tr.ocp.chosen[q.name].guess if q.name in tr.ocp.chosen else 0.0)
                for q in tr.plant.param_info
            ]
        )

    def _input_sequence(self, guess_input, T) -> np.ndarray:
        tr = self.transcription
        N, nu = tr.intervals, tr.plant.nu
        if callable(guess_input):
            middles = T * (tr.mesh[:-1] + tr.mesh[1:]) / 2
            values = np.array([np.asarray(guess_input(t), dtype=float).reshape(-1) for t in middles])
        else:
            values = np.asarray(guess_input, dtype=float)
        values = values.reshape(N, -1) if values.size == N * nu else values
        if values.shape != (N, nu) or not np.all(np.isfinite(values)):
            raise ValueError(
                f"guess_input must be ({N}, {nu}) finite values or a function of t, got shape {np.shape(values)}"
            )
        return values

    @staticmethod
    def _guess_functions(guess):
        if isinstance(guess, OCPSolution):
            end = guess.t[-1]
            return (lambda t: guess.state_at(np.clip(t, 0, end)), lambda t: guess.input_at(np.clip(t, 0, end)))
        t = np.asarray(guess.t, dtype=float).reshape(-1)
        x = np.asarray(guess.x, dtype=float).reshape(t.size, -1)
        u = np.asarray(guess.u, dtype=float)
        u = u.reshape(len(u), -1)
        states_at = lambda s: np.column_stack([np.interp(s, t, x[:, i]) for i in range(x.shape[1])])
        inputs_at = lambda s: u[np.clip(np.searchsorted(t, s, side="right") - 1, 0, len(u) - 1)]
        return states_at, inputs_at
