"""Linear loop analysis of any controller block: loop gains, margins, closed-loop poles.

A `models.Block` is a CasADi expression, so its exact Jacobians about an
operating point give its discrete-time linearization

    x_c,k+1 = A_c x_c,k + B_y y_k + B_r r_k,    u_k = C_c x_c,k + D_y y_k + D_r r_k.

With the plant linearized about the same point and discretized with a zero-order
hold at the controller's sample period (exact), the loop broken at the plant
input (or, for a `models.Cascade`, at the inner loop's reference) is a discrete
state-space system L(z) with the convention that the closed loop is
1 + L(z) = 0 (negative feedback), as `designs.analysis.margins` and `control.stability_margins` assume.

This is for plots and margins only: the study tables come from the nonlinear
simulation. The operating point is where the closed loop comes to rest under
a constant command at the equilibrium value (found by simulating it).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import casadi as ca
import numpy as np

import models
from designs import analysis as an
from models import Block, Cascade, deferred, interrupts

if TYPE_CHECKING:
    import control
else:
    control = deferred.module("control")

LOOPS = ("input", "inner", "outer")


@dataclass(frozen=True)
class BlockLinearization:
    """Discrete linearization of a block about (x_c, y, r); matrices as in the module docstring."""

    Ac: np.ndarray
    By: np.ndarray
    Br: np.ndarray
    Cc: np.ndarray
    Dy: np.ndarray
    Dr: np.ndarray
    u: np.ndarray


def linearize_block(block: Block, xc, y, r) -> BlockLinearization:
    """Exact Jacobians of the block's step at (x_c, y, r) with its current gains."""
    xs = ca.SX.sym("xc", block.n_state)
    ys = ca.SX.sym("y", block.n_measured)
    rs = ca.SX.sym("r", block.n_reference)
    xn, u = block.casadi_step(xs, ys, rs, block.gain_vector())
    jac = ca.Function(
        "block_jacobians",
        [xs, ys, rs],
        [
            ca.jacobian(xn, xs),
            ca.jacobian(xn, ys),
            ca.jacobian(xn, rs),
            ca.jacobian(u, xs),
            ca.jacobian(u, ys),
            ca.jacobian(u, rs),
            u,
        ],
    )
    values = [np.asarray(v, dtype=float) for v in jac(np.asarray(xc, dtype=float).reshape(-1), y, r)]
    shapes = [
        (block.n_state, block.n_state),
        (block.n_state, block.n_measured),
        (block.n_state, block.n_reference),
        (block.n_input, block.n_state),
        (block.n_input, block.n_measured),
        (block.n_input, block.n_reference),
        (block.n_input,),
    ]
    values = [v.reshape(s) for v, s in zip(values, shapes)]
    return BlockLinearization(*values)


@dataclass(frozen=True)
class OperatingPoint:
    """Where the closed loop rests: plant state x (nx,), input u (nu,), controller state xc, reference r."""

    x: np.ndarray
    u: np.ndarray
    xc: np.ndarray
    r: np.ndarray
    residual: float


def rest_point(plant: models.Plant, block: Block, reference_value: float, duration: float) -> OperatingPoint:
    """Simulate the loop from the equilibrium under a constant command and return its final rest point.

    `residual` is max |f(x, u)| there: near zero when the loop came to rest.
    """
    run = models.simulate_closed_loop(plant, block, reference_value, duration, allow_divergence=True)
    return final_point(plant, block, run)


def final_point(plant: models.Plant, block: Block, run) -> OperatingPoint:
    """The last sample of a closed-loop run (a `models.ClosedLoopResult`) as an operating point."""
    if run.diverged_at is not None:
        raise models.SimulationError(
            f"{block.name} does not hold {plant.name} at rest: the loop diverged at t = {run.diverged_at:.3g} s"
        )
    x = run.x[-1]
    u = np.clip(run.u[-1], -plant.input_limit, plant.input_limit)
    residual = float(np.max(np.abs(plant.f(x, u))))
    return OperatingPoint(x, u, run.xc[-1], run.r[-1], residual)


@dataclass(frozen=True)
class LoopGain:
    """A loop transfer L(z) as discrete state space (closed loop: 1 + L = 0).

    Attributes
    ----------
    label : controller label;  which : "input", "inner" or "outer"
    A, B, C : state-space matrices of L (D = 0: the plant has no feedthrough)
    sample_period : s
    """

    label: str
    which: str
    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    sample_period: float

    def system(self) -> control.StateSpace:
        return control.ss(self.A, self.B, self.C, np.zeros((1, 1)), self.sample_period)

    def frequency_response(self, omega) -> np.ndarray:
        """L(e^{jωTs}) at the frequencies `omega` (rad/s), complex (len(omega),)."""
        return an.sampled_response(self.A, self.B, self.C, np.zeros((1, 1)), self.sample_period, omega)

    def margins(self) -> dict:
        """Gain margin (dB), phase margin (deg) and their crossover frequencies (rad/s).

        `designs.analysis.margins` of the discrete loop's state space (the one
        margins computation): with several crossings the smallest margin is
        reported; inf and nan when a crossover does not exist.
        """
        m = an.margins(self.system())
        return {
            "gain_margin_db": m["gm_db"],
            "phase_margin_deg": m["pm_deg"],
            "phase_crossover_rad_s": m["phase_crossover"],
            "gain_crossover_rad_s": m["gain_crossover"],
        }

    def closed_loop_poles(self, gain: float = 1.0) -> np.ndarray:
        """Eigenvalues z of the loop closed with gain k: eig(A − k B C)."""
        return np.linalg.eigvals(self.A - gain * self.B @ self.C)

    def s_plane(self, z) -> np.ndarray:
        """Continuous-time equivalents s = ln(z) / Ts of discrete poles (z = 0 dropped)."""
        z = np.asarray(z, dtype=complex)
        z = z[np.abs(z) > 1e-12]
        return np.log(z) / self.sample_period


def _measurement_matrix(plant_lin: models.LinearModel, block: Block) -> np.ndarray:
    return plant_lin.C if block.measures == "outputs" else np.eye(plant_lin.nx)


def loop(plant: models.Plant, block: Block, point: OperatingPoint, which: str = "input", label: str = "") -> LoopGain:
    """The loop gain of `block` on `plant` about `point`, broken where `which` says.

    Parameters
    ----------
    which : "input" (at the plant input, any block), "inner" (the inner block of a Cascade
        alone, the outer one frozen), "outer" (a Cascade broken at the inner loop's reference)
    """
    if which not in LOOPS:
        raise ValueError(f"which must be one of {LOOPS}, got {which!r}")
    if which != "input" and not isinstance(block, Cascade):
        raise ValueError(f"the {which} loop needs a models.Cascade; {block.name} is a {type(block).__name__}")
    lin = plant.linearize(point.x, point.u, check=False).discretize(block.sample_period)
    Ad, Bd = lin.A, lin.B
    Cm = _measurement_matrix(lin, block)
    meas = plant.output(point.x) if block.measures == "outputs" else point.x
    nx = Ad.shape[0]
    if which == "input":
        k = linearize_block(block, point.xc, meas, point.r)
        nc = k.Ac.shape[0]
        A = np.block([[Ad, np.zeros((nx, nc))], [k.By @ Cm, k.Ac]])
        B = np.vstack([Bd, np.zeros((nc, Bd.shape[1]))])
        C = -np.hstack([k.Dy @ Cm, k.Cc])
        return LoopGain(label or block.name, which, A, B, C, block.sample_period)
    assert isinstance(block, Cascade)  # checked above for the loops other than "input"
    no = block.outer.n_state
    xo, xi = point.xc[:no], point.xc[no:]
    outer = linearize_block(block.outer, xo, meas, point.r)
    inner_reference = np.asarray(block.outer.step(xo, meas, point.r)[1])
    inner = linearize_block(block.inner, xi, meas, inner_reference)
    if which == "inner":
        ni = inner.Ac.shape[0]
        A = np.block([[Ad, np.zeros((nx, ni))], [inner.By @ Cm, inner.Ac]])
        B = np.vstack([Bd, np.zeros((ni, Bd.shape[1]))])
        C = -np.hstack([inner.Dy @ Cm, inner.Cc])
        return LoopGain(label or block.name, which, A, B, C, block.sample_period)
    ni, n_o = inner.Ac.shape[0], outer.Ac.shape[0]
    A = np.block(
        [
            [Ad + Bd @ inner.Dy @ Cm, Bd @ inner.Cc, np.zeros((nx, n_o))],
            [inner.By @ Cm, inner.Ac, np.zeros((ni, n_o))],
            [outer.By @ Cm, np.zeros((n_o, ni)), outer.Ac],
        ]
    )
    B = np.vstack([Bd @ inner.Dr, inner.Br, np.zeros((n_o, inner.Dr.shape[1]))])
    C = -np.hstack([outer.Dy @ Cm, np.zeros((outer.Dy.shape[0], ni)), outer.Cc])
    if B.shape[1] != 1 or C.shape[0] != 1:
        raise ValueError(f"{block.name}: the outer loop of a cascade with {B.shape[1]} inner references is not SISO")
    return LoopGain(label or block.name, which, A, B, C, block.sample_period)


def analyse(
    plant: models.Plant,
    case,
    controllers: dict,
    reference_value: float,
    runs: dict | None = None,
    truths: dict | None = None,
) -> tuple[dict, list]:
    """Every loop of every block controller about the point where it holds the plant at rest.

    The point is the end of the controller's run in `runs` ((label, scenario)
    -> ClosedLoopResult) when one without input disturbance ends at
    `reference_value` (the series of steps returns there), else the end of a
    run under that constant command from the equilibrium. `truths` gives a
    controller its own plant (label -> Plant), as the runner did.

    Returns
    -------
    loops : label -> {"input": LoopGain, and for a Cascade also "inner" and "outer"}
    notes : controllers left out and why
    """
    out, notes, unrested = {}, [], {}
    for label, controller in controllers.items():
        if not isinstance(controller, Block):
            notes.append(f"{label}: not a Block (it optimizes each step), no linear loop analysis")
            continue
        plant_of = (truths or {}).get(label, plant)
        try:
            finished = [
                run
                for (owner, _), run in (runs or {}).items()
                if owner == label
                and run.diverged_at is None
                and not np.any(run.d)
                and abs(run.r[-1, 0] - reference_value) < 1e-12
            ]
            point = (
                final_point(plant_of, controller, finished[0])
                if finished
                else rest_point(plant_of, controller, reference_value, 2 * case.duration)
            )
            found = {"input": loop(plant_of, controller, point, "input", label)}
            if isinstance(controller, Cascade):
                found["inner"] = loop(plant_of, controller, point, "inner", label)
                found["outer"] = loop(plant_of, controller, point, "outer", label)
        except Exception as err:  # the linear analysis is a plot; the table still has the controller
            if interrupts.is_interrupt(err):
                raise KeyboardInterrupt from err
            notes.append(f"{label}: no loop analysis ({type(err).__name__}: {err})")
            continue
        if point.residual > 1e-6:
            unrested[label] = point.residual
        out[label] = found
    if unrested:
        notes.append(
            f"linearized about the final state of their run, where the loop is not exactly at rest under "
            f"the constant command (|f| up to {max(unrested.values()):.2g}): {', '.join(unrested)}"
        )
    return out, notes


def spec_check(design: LoopGain, spec, baseline: LoopGain | None = None, points: int = 400) -> dict:
    """Whether `design` meets the loopshaping `spec` (a `studies.case.LoopSpec`).

    Relative specs are checked on a log grid: below `spec.low_frequency`
    |L| >= factor |L_baseline|; above `spec.high_frequency` (up to the Nyquist
    frequency) |L| <= |L_baseline| / factor. The crossover is met within a
    factor of 1.5 (about 3.5 dB), the phase margin when at least the value asked.

    Returns
    -------
    dict name -> bool or None (None: the spec cannot be checked, e.g. no baseline)
    """
    nyquist = np.pi / design.sample_period
    result: dict[str, bool | None] = {}
    if spec.low_frequency is not None:
        if baseline is None:
            result["low_frequency"] = None
        else:
            omega = np.logspace(np.log10(spec.low_frequency) - 3, np.log10(spec.low_frequency), points)
            result["low_frequency"] = bool(
                np.all(
                    np.abs(design.frequency_response(omega)) >= spec.factor * np.abs(baseline.frequency_response(omega))
                )
            )
    if spec.high_frequency is not None:
        if baseline is None or spec.high_frequency >= nyquist:
            result["high_frequency"] = None
        else:
            omega = np.logspace(np.log10(spec.high_frequency), np.log10(0.999 * nyquist), points)
            result["high_frequency"] = bool(
                np.all(
                    np.abs(design.frequency_response(omega)) <= np.abs(baseline.frequency_response(omega)) / spec.factor
                )
            )
    margins = design.margins() if (spec.crossover or spec.phase_margin) else {}
    if spec.crossover is not None:
        wc = margins["gain_crossover_rad_s"]
        result["crossover"] = bool(np.isfinite(wc) and spec.crossover / 1.5 <= wc <= spec.crossover * 1.5)
    if spec.phase_margin is not None:
        result["phase_margin"] = bool(margins["phase_margin_deg"] >= spec.phase_margin)
    return result
