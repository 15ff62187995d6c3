"""The walk a case study's notebook takes: the plant linearized, a PD by pole placement, the LQR, the quick
study's table on the text's step, the linear MPC's prediction model and the tuned gains.

Each step is one function of the case (and of the homework's numbers a notebook gives it) that returns a
record of its numbers beside an independent derivation of them, and raises AssertionError naming the
numbers when the two disagree: the notebooks (``notebooks/<case>.py``) show the records and so check,
on a fresh kernel, the same numbers the tests check. Every record's `report()` is the text a notebook
prints.

>>> import numpy as np
>>> import studies
>>> from studies import course
>>> case = studies.get("arm")
>>> plant = course.linearization(case)
>>> pd = course.pd_by_poles(course.loop_model(case), wn=10.0, zeta=0.707)
>>> K = course.lqr_gain(plant.A, plant.B, np.eye(2), np.eye(1))
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

import models
from designs.loops import cascade_plants
from designs.pid import PDDesign, pd_design
from models import deferred
from models.lqr import lqr

from . import providers, tuner
from .case import CaseStudy
from .runner import Options, StudyResult, run_study

if TYPE_CHECKING:
    import control
    from scipy import linalg
else:
    control = deferred.module("control")
    linalg = deferred.module("scipy.linalg")

__all__ = [
    "TABLE_COLUMNS",
    "Linearization",
    "PolePlacement",
    "PredictionModel",
    "linearization",
    "loop_model",
    "lqr_gain",
    "pd_by_poles",
    "prediction_model",
    "quick_table",
    "rounded",
    "tuned_gains",
    "tuning_report",
]

#: The columns of table.md a notebook shows.
TABLE_COLUMNS = ["controller", "verdict", "rise_time_s", "settling_time_s", "overshoot_pct", "peak_u", "u_limit"]
#: The controller kinds of the quick table: the case's own designs and its stored tuned gains.
KINDS = (providers.classical, providers.statespace, providers.mpc, providers.tuned)


def _check(ok, detail) -> None:
    """Raise AssertionError(`detail`) unless `ok` (a check that ``python -O`` keeps, unlike ``assert``)."""
    if not ok:
        raise AssertionError(detail)


def rounded(values: dict, digits: int = 4) -> dict:
    """`values` with every float rounded to `digits` decimals (for printing); the others as they are."""
    return {k: round(float(v), digits) if isinstance(v, (float, np.floating)) else v for k, v in values.items()}


@dataclass(frozen=True)
class Linearization:
    """The known plant linearized about its operating point.

    Attributes
    ----------
    case : the case study;  known : the plant the controllers know;  linear : its `models.LinearModel`
    A, B : (nx, nx), (nx, nu) the continuous-time deviation model
    input_name, limit : the input's name and its actuator limit, in the case's input unit
    eigenvalues : (nx,) of A, rad/s
    tracked : control.TransferFunction from the input to the tracked coordinate (python-control's `ss2tf`
        of (A, B) with C picking that coordinate's state)
    poles : its poles, rad/s, each an eigenvalue of A
    """

    case: CaseStudy
    known: models.Plant
    linear: Any
    A: np.ndarray
    B: np.ndarray
    input_name: str
    limit: float
    eigenvalues: np.ndarray
    tracked: Any
    poles: np.ndarray

    def report(self) -> str:
        """The plant, its tracked coordinate and input, and the eigenvalues and poles (4 decimals)."""
        case = self.case
        return (
            f"{case.plant} tracked: {case.tracked} input: {self.input_name} limit: {self.limit:g} {case.input_unit}\n"
            f"eigenvalues of A: {np.round(self.eigenvalues, 4)}\npoles of G(s): {np.round(self.poles, 4)}"
        )


def linearization(case: CaseStudy) -> Linearization:
    """The case's known plant linearized (`Plant.linearize`), and the transfer function to its tracked
    coordinate; checks that every pole of that transfer function is an eigenvalue of A (to 1e-6 relative).

    Parameters
    ----------
    case : the case study (`studies.get(name)`)

    Returns
    -------
    Linearization

    Raises
    ------
    AssertionError
        Naming the poles and eigenvalues when a pole is not an eigenvalue.
    """
    known = case.known_plant()
    linear = known.linearize()
    (input_name,) = linear.input_names
    A, B = np.asarray(linear.A, dtype=float), np.asarray(linear.B, dtype=float)
    eigenvalues = np.linalg.eigvals(A)
    C = np.eye(A.shape[0])[[linear.state_names.index(case.tracked)]]
    G = control.ss2tf(A, B, C, np.zeros((1, 1)))
    poles = np.roots(np.ravel(G.den[0][0]))
    _check(all(np.min(np.abs(eigenvalues - p)) <= 1e-6 * max(1.0, abs(p)) for p in poles), (poles, eigenvalues))
    limit = float(known.input_limit[0])
    return Linearization(case, known, linear, A, B, input_name, limit, eigenvalues, G, poles)


def loop_model(case: CaseStudy, model: models.Plant | None = None):
    """The second-order model b / (s² + a₁ s + a₀) a PD is placed on: the inner loop of the case's cascade
    (`designs.loops.cascade_plants`) when it has one, else the input to the tracked coordinate.

    Parameters
    ----------
    case : the case study
    model : the plant to read it from (default the case's known plant), e.g. a simpler design model

    Returns
    -------
    control.TransferFunction
    """
    model = model or case.known_plant()
    if case.cascade:
        return cascade_plants(model, case.cascade[0], case.cascade[1]).inner
    linear = model.linearize()
    return linear.tf(case.tracked, linear.input_names[0])


@dataclass(frozen=True)
class PolePlacement:
    """A PD u = kp e − kd ẏ on b / (s² + a₁ s + a₀): the closed loop s² + (a₁ + b kd) s + (a₀ + b kp).

    Attributes
    ----------
    design : `designs.pid.PDDesign`;  kp, kd : its gains (input unit per rad, per rad/s)
    b, a1, a0 : the loop model's coefficients (denominator monic)
    wn, zeta : the poles asked for (rad/s, damping ratio);  closed_poles : the closed loop's, rad/s
    """

    design: PDDesign
    b: float
    a1: float
    a0: float
    wn: float
    zeta: float
    closed_poles: np.ndarray

    @property
    def kp(self) -> float:
        """The proportional gain (input unit per rad of error)."""
        return float(self.design.kp)

    @property
    def kd(self) -> float:
        """The derivative gain (input unit per rad/s)."""
        return float(self.design.kd)

    def pid_poles(self, kp: float, ki: float, kd: float) -> np.ndarray:
        """Roots of a PID's closed loop on the same model, s³ + (a₁ + b kd) s² + (a₀ + b kp) s + b ki, rad/s."""
        return np.roots([1.0, self.a1 + self.b * kd, self.a0 + self.b * kp, self.b * ki])

    def report(self, unit: str) -> str:
        """The gains, with the input's `unit` per rad."""
        return f"kp = {self.kp:.6g} {unit}/rad, kd = {self.kd:.6g} (the same per rad/s)"


def pd_by_poles(loop, wn: float, zeta: float) -> PolePlacement:
    """`designs.pid.pd_design` placing the closed loop's poles at ωn, ζ, against the closed form
    kp = (ωn² − a₀) / b, kd = (2 ζ ωn − a₁) / b and the roots of the closed loop's denominator.

    Parameters
    ----------
    loop : control.TransferFunction b / (s² + a₁ s + a₀) (`loop_model`)
    wn : natural frequency, rad/s;  zeta : damping ratio

    Returns
    -------
    PolePlacement

    Raises
    ------
    AssertionError
        When the gains differ from the closed form, or the closed loop's poles from ωn, ζ (1e-9 relative).
    """
    num, den = np.ravel(loop.num[0][0]), np.ravel(loop.den[0][0])
    b, a1, a0 = num[-1] / den[0], den[1] / den[0], den[2] / den[0]
    pd = pd_design(loop, zeta=zeta, wn=wn)
    _check(np.isclose(pd.kp, (wn**2 - a0) / b, rtol=1e-9), (pd.kp, (wn**2 - a0) / b))
    _check(np.isclose(pd.kd, (2 * zeta * wn - a1) / b, rtol=1e-9), (pd.kd, (2 * zeta * wn - a1) / b))
    closed = np.roots([1.0, a1 + b * pd.kd, a0 + b * pd.kp])
    _check(np.allclose(np.abs(closed), wn, rtol=1e-9), closed)
    _check(np.allclose(-closed.real / np.abs(closed), zeta, rtol=1e-9), closed)
    return PolePlacement(pd, float(b), float(a1), float(a0), wn, zeta, closed)


def lqr_gain(A, B, Q, R) -> np.ndarray:
    """The continuous LQR gain K (nu, nx) of `models.lqr.lqr`, checked against K = R⁻¹ Bᵀ P with P from
    SciPy's `solve_continuous_are` and against python-control's `lqr` (1e-8 relative); A − B K is stable.

    Parameters
    ----------
    A, B : (nx, nx), (nx, nu);  Q : (nx, nx) state weight;  R : (nu, nu) input weight

    Raises
    ------
    AssertionError
        Naming the gains that differ, or when A − B K has an eigenvalue with real part >= 0.
    """
    P = linalg.solve_continuous_are(A, B, Q, R)
    K = np.linalg.solve(R, B.T @ P)
    K_project = np.atleast_2d(lqr(A, B, Q, R)[0])
    K_control, _, _ = control.lqr(A, B, Q, R)
    _check(np.allclose(K_project, K, rtol=1e-8), (K_project, K))
    _check(np.allclose(K_control, K, rtol=1e-8), (K_control, K))
    _check(np.all(np.linalg.eigvals(A - B @ K).real < 0), np.linalg.eigvals(A - B @ K))
    return K_project


def quick_table(case: CaseStudy, expected: Sequence[str] = ()) -> StudyResult:
    """Every controller the case designs (classical, state space, linear and nonlinear MPC) and its stored
    tuned gains on the true plant, on the step scenario only and without the Monte Carlo (quick settings).

    Parameters
    ----------
    case : the case study
    expected : controller labels the table must hold

    Returns
    -------
    studies.StudyResult (its `table` and `controllers`)

    Raises
    ------
    AssertionError
        When a row's peak input exceeds its limit, or an expected controller has no row.
    """
    result = run_study(case, Options(scenarios=("step",), mc=0, quick=True), providers=list(KINDS))
    table = result.table
    _check((table["peak_u"] <= table["u_limit"] + 1e-9).all(), table[["controller", "peak_u", "u_limit"]])
    missing = set(expected) - set(table["controller"])
    _check(not missing, missing)
    return result


@dataclass(frozen=True)
class PredictionModel:
    """The linear MPC's discrete prediction model and its Van Loan derivation.

    Attributes
    ----------
    sample_period : Ts, s;  A, B : (nx, nx), (nx, nu) the controller's A_d, B_d
    """

    sample_period: float
    A: np.ndarray
    B: np.ndarray

    def report(self) -> str:
        """Ts and the largest |eigenvalue| of A_d."""
        largest = np.max(np.abs(np.linalg.eigvals(self.A)))
        return f"Ts = {self.sample_period} s; the largest |eigenvalue| of A_d: {largest:.6f}"


def prediction_model(controller, A, B) -> PredictionModel:
    """The linear MPC `controller`'s model against the zero-order hold of (A, B): A_d = e^{A Ts},
    B_d = ∫₀^Ts e^{A τ} dτ B, read off one matrix exponential of [[A, B], [0, 0]] Ts (Van Loan).

    Parameters
    ----------
    controller : an `mpc.LinearMPC` (its `sample_period` and `model`)
    A, B : (nx, nx), (nx, nu) the continuous-time linearization it was built from

    Raises
    ------
    AssertionError
        When A_d or B_d differ from the matrix exponential's (1e-8 relative, 1e-10 absolute).
    """
    Ts = float(controller.sample_period)
    n, m = B.shape
    block = linalg.expm(np.block([[A, B], [np.zeros((m, n + m))]]) * Ts)
    Ad, Bd = np.asarray(controller.model.A, dtype=float), np.asarray(controller.model.B, dtype=float)
    _check(np.allclose(Ad, block[:n, :n], rtol=1e-8, atol=1e-10), (Ad, block[:n, :n]))
    _check(np.allclose(Bd, block[:n, n:], rtol=1e-8, atol=1e-10), (Bd, block[:n, n:]))
    return PredictionModel(Ts, Ad, Bd)


def tuned_gains(case: CaseStudy) -> dict:
    """The case's stored tuning record (`studies.tuner.stored`): the hand design's gains it started from
    ("start_gains") and the tuned ones ("gains").

    Raises
    ------
    AssertionError
        When the case has no stored gains, or the two records name different gains.
    """
    record = tuner.stored(case)
    if record is None:
        raise AssertionError(f"{case.plant} has no stored tuned gains (python -m studies.tuner {case.plant})")
    _check(set(record["gains"]) == set(record["start_gains"]), (record["gains"], record["start_gains"]))
    return record


def tuning_report(case: CaseStudy, table) -> str:
    """The hand design's and the tuned gains (`tuned_gains`, 4 decimals) and the tuned row's verdict in
    `table` (`quick_table`'s)."""
    record = tuned_gains(case)
    row = table.loc[table["controller"] == "tuned", ["verdict", "verdict_detail"]]
    return "\n".join(
        [
            f"hand design: {rounded(record['start_gains'])}",
            f"tuned:       {rounded(record['gains'])}",
            row.to_string(index=False),
        ]
    )
