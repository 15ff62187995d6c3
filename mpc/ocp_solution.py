"""The answer of an optimal control problem: trajectories, interpolants, status, and its check.

`OCPSolution.verify` re-simulates the optimal input (held on each interval)
on the nonlinear plant with the adaptive integrator (`models.simulate`,
CVODES) and reports how far the simulated states land from the optimized
ones: once over the whole horizon from x(0), and once restarted from the
optimized state on every interval (the transcription's own error, free of
the open-loop drift an unstable plant adds).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

import models
from models import Plant
from models.simulate import lagrange_basis

from .transcription import Transcription


def resimulate(
    plant: Plant, t, x0, u, params=None, *, method: str = "adaptive", rtol: float = 1e-10, atol: float = 1e-10
) -> np.ndarray:
    """States at the times `t` (M+1,) from `x0` under `u` (M, nu) held on [t_k, t_{k+1}).

    Uses `models.simulate` on `plant` with `params` (default: its own) once for a uniform grid, once
    per run of equal steps otherwise, with its `method` (``"adaptive"``: CVODES to tolerances rtol
    and atol). Returns (M+1, nx).
    """
    t = np.asarray(t, dtype=float).reshape(-1)
    u = np.asarray(u, dtype=float).reshape(t.size - 1, plant.nu)
    steps = np.diff(t)
    out = np.empty((t.size, plant.nx))
    out[0] = x0
    k = 0
    while k < steps.size:
        run = k + 1
        while run < steps.size and abs(steps[run] - steps[k]) <= 1e-12 * max(steps[k], 1.0):
            run += 1
        sim = models.simulate(plant, out[k], u[k:run], steps[k], method=method, params=params, rtol=rtol, atol=atol)
        out[k + 1 : run + 1] = sim.x[1:]
        k = run
    return out


@dataclass(frozen=True)
class Verification:
    """How well the optimal input reproduces the optimized states on the nonlinear plant.

    Attributes
    ----------
    max_defect : largest ``|x_sim(t_k) - x_k|`` over mesh points and states (SI units of that state),
        simulating the whole horizon from x(0); `state` and `time` say where.
    max_interval_defect : the same with the simulation restarted from x_k on every interval;
        `interval_state` and `interval_time` say where.
    per_state : state name -> largest whole-horizon defect
    simulated : (N+1, nx) the whole-horizon simulation at the mesh points
    """

    max_defect: float
    state: str
    time: float
    max_interval_defect: float
    interval_state: str
    interval_time: float
    per_state: dict
    simulated: np.ndarray


@dataclass
class OCPSolution:
    """One solve of an optimal control problem.

    Attributes
    ----------
    t : (N+1,) mesh times, s;  states : (N+1, nx) at the mesh points
    inputs : (N, nu) held on [t_k, t_{k+1});  controls : (N, nc) the extra controls
    plant_inputs : (N, nu) what the plant received (the inputs unless `plant_input` was set)
    params : dict, every plant parameter's value (chosen ones included), SI
    chosen : dict, the chosen parameters' values
    final_time : T, s;  objective : the minimized value
    accumulated : (n,) the values of the problem's integrals and sums, in the order created
    success : bool;  status : "solved", "solved to acceptable level", "infeasible",
        "iteration limit" or "failed", with the largest violation when not solved
    solver_status : IPOPT's return status;  iterations : IPOPT iterations;  solve_time : s
    largest_violation : (label, amount) of the worst constraint or bound at the returned point
    decision, lam_x, lam_g, lam_p : the raw NLP vectors (scaled decisions), for warm starts
    parameter_vector : the NLP parameters P it was solved with
    refinement : list of (intervals, largest collocation defect) per mesh-refinement round, if any
    transcription : the transcription it was solved with
    collocation_states : the states at the collocation points, or None (multiple shooting)
    """

    t: np.ndarray
    states: np.ndarray
    inputs: np.ndarray
    plant_inputs: np.ndarray
    controls: np.ndarray
    params: dict
    chosen: dict
    final_time: float
    objective: float
    accumulated: np.ndarray
    success: bool
    status: str
    solver_status: str
    iterations: int
    solve_time: float
    largest_violation: tuple
    decision: np.ndarray
    lam_x: np.ndarray
    lam_g: np.ndarray
    lam_p: np.ndarray
    parameter_vector: np.ndarray
    transcription: Transcription = field(repr=False)
    collocation_states: np.ndarray | None = field(default=None, repr=False)
    refinement: list = field(default_factory=list)

    @property
    def plant(self) -> Plant:
        """The plant of the transcription that was solved."""
        return self.transcription.plant

    @property
    def state_names(self) -> tuple:
        """The plant's state names, in the order of `states`' columns."""
        return self.plant.state_names

    @property
    def input_names(self) -> tuple:
        """The plant's input names, in the order of `inputs`' columns."""
        return self.plant.input_names

    def state(self, name: str) -> np.ndarray:
        """The state called `name` at the mesh points, (N+1,)."""
        return self.states[:, _index(self.plant.state_names, name, "state", self.plant.name)]

    def input(self, name: str) -> np.ndarray:
        """The input called `name` on each interval, (N,)."""
        return self.inputs[:, _index(self.plant.input_names, name, "input", self.plant.name)]

    def param_values(self) -> np.ndarray:
        """Every plant parameter as the vector p of the plant's Functions, (np,)."""
        return np.array([self.params[p.name] for p in self.plant.param_info])

    # ------------------------------------------------------------------ interpolants
    def _interval(self, times) -> tuple[np.ndarray, np.ndarray]:
        times = np.atleast_1d(np.asarray(times, dtype=float))
        if np.any(times < self.t[0] - 1e-12) or np.any(times > self.t[-1] + 1e-12):
            raise ValueError(f"times must lie in [0, {self.t[-1]:.6g}] s, got [{times.min()}, {times.max()}]")
        k = np.clip(np.searchsorted(self.t, times, side="right") - 1, 0, len(self.t) - 2)
        return times, k

    def input_at(self, times) -> np.ndarray:
        """The piecewise-constant input at `times` (s), (len(times), nu)."""
        times, k = self._interval(times)
        return self.inputs[k]

    def state_at(self, times) -> np.ndarray:
        """The state at `times` (s), (len(times), nx): the collocation polynomial of each interval,
        or with multiple shooting the cubic Hermite interpolant through x_k, x_{k+1} and f there."""
        times, k = self._interval(times)
        h = np.diff(self.t)[k]
        s = (times - self.t[k]) / h
        out = np.empty((times.size, self.plant.nx))
        if self.collocation_states is not None:
            assert self.transcription.coefficients is not None
            tau = self.transcription.coefficients.tau
            values, _ = lagrange_basis(tau, s)  # every time at once: the basis is the costly part
            nodes = np.concatenate([self.states[k][:, None, :], self.collocation_states[k]], axis=1)
            return np.einsum("ij,ijn->in", values, nodes)
        p = self.param_values()
        f = self.plant.casadi_f
        for i in range(times.size):
            x0, x1, u = self.states[k[i]], self.states[k[i] + 1], self.plant_inputs[k[i]]
            d0 = np.asarray(f(x0, u, p)).ravel() * h[i]
            d1 = np.asarray(f(x1, u, p)).ravel() * h[i]
            si = s[i]
            out[i] = (
                (2 * si**3 - 3 * si**2 + 1) * x0
                + (si**3 - 2 * si**2 + si) * d0
                + (-2 * si**3 + 3 * si**2) * x1
                + (si**3 - si**2) * d1
            )
        return out

    # ------------------------------------------------------------------ check
    def verify(self, rtol: float = 1e-10, atol: float = 1e-10) -> Verification:
        """Re-simulate the optimal input (as the plant received it) on the nonlinear plant (CVODES,
        tolerances rtol and atol) and report the state defects."""
        return verify_trajectory(
            self.plant, self.t, self.states, self.plant_inputs, self.param_values(), rtol=rtol, atol=atol
        )


def verify_trajectory(
    plant: Plant, t, states, inputs, params=None, *, rtol: float = 1e-10, atol: float = 1e-10
) -> Verification:
    """The `Verification` of states (N+1, nx) at times t (N+1,) under inputs (N, nu) held in between,
    re-simulated on `plant` with `params` (default: its own) to tolerances rtol and atol.

    For a trajectory from any source (another optimizer, a hand-written transcription).
    """
    t = np.asarray(t, dtype=float).reshape(-1)
    states = np.asarray(states, dtype=float).reshape(t.size, plant.nx)
    inputs = np.asarray(inputs, dtype=float).reshape(t.size - 1, plant.nu)
    p = plant.param_vector(params)
    simulated = resimulate(plant, t, states[0], inputs, p, rtol=rtol, atol=atol)
    errors = np.abs(simulated - states)
    k, i = np.unravel_index(int(np.argmax(errors)), errors.shape)
    restarted = np.empty_like(states)
    restarted[0] = states[0]
    for j in range(t.size - 1):
        run = models.simulate(
            plant, states[j], inputs[j : j + 1], t[j + 1] - t[j], method="adaptive", params=p, rtol=rtol, atol=atol
        )
        restarted[j + 1] = run.x[-1]
    local = np.abs(restarted - states)
    kl, il = np.unravel_index(int(np.argmax(local)), local.shape)
    return Verification(
        float(errors[k, i]),
        plant.state_names[i],
        float(t[k]),
        float(local[kl, il]),
        plant.state_names[il],
        float(t[kl]),
        dict(zip(plant.state_names, errors.max(axis=0).tolist())),
        simulated,
    )


def _index(names, name, kind, owner) -> int:
    if name not in names:
        raise ValueError(f"{owner} has no {kind} {name!r}; its {kind}s are {', '.join(names)}")
    return names.index(name)
