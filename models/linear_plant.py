"""A user's linear model as a plant: a python-control system with actuator limits.

`LinearPlant(sys, limit)` wraps a `control.StateSpace` or `control.TransferFunction`
(converted with `control.ss`) so that the linear designs (PID/PD, loop shaping,
pole placement, LQR, linear MPC) take it where they take a declared `models.Plant`:
it answers the same questions (`linearize`, `equilibrium`, `input_limit`, the
signal names, the configuration read from the outputs, the input that holds a
configuration at rest). No design branches on which kind of plant it got.

The states follow the declared plants' layout: the first ``nq`` states are the
configuration coordinates q, the next ``nq`` their rates, the rest first-order
states. The model is in deviations about the operating point (xe, ue):
x' = A (x − xe) + B (u − ue), y = ye + C (x − xe) + D (u − ue), ye = C xe + D ue.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import casadi as ca
import numpy as np

from . import deferred
from .checks import as_vector
from .linear import LinearModel

if TYPE_CHECKING:
    import control
else:
    control = deferred.module("control")

__all__ = ["LinearPlant"]


class LinearPlant:
    """A python-control linear system with symmetric actuator limits, usable as a design's known plant.

    Parameters
    ----------
    sys : control.StateSpace or control.TransferFunction (continuous time)
    limit : float or (nu,) symmetric actuator limit |u_i| <= limit_i on the total input
    coordinates : number of configuration coordinates nq (the first nq states, their rates the
        next nq); default nx // 2
    xe, ue : the operating point the model is a deviation about, (nx,), (nu,); default zeros
    name : str; default the system's name

    Attributes
    ----------
    name, nx, nu, ny, nq, n_first_order, input_limit (nu,),
    coordinate_names, state_names, input_names, output_names : as `models.Plant`
    """

    def __init__(self, sys, limit, *, coordinates: int | None = None, xe=None, ue=None, name: str | None = None):
        if not isinstance(sys, (control.StateSpace, control.TransferFunction)):
            raise TypeError(f"LinearPlant needs a control.StateSpace or TransferFunction, got {type(sys).__name__}")
        sys = control.ss(sys)
        if sys.dt not in (0, None):
            raise ValueError(f"LinearPlant needs a continuous-time system, got dt = {sys.dt}")
        self.name = str(name or sys.name)
        self.A, self.B, self.C, self.D = (np.asarray(m, dtype=float) for m in (sys.A, sys.B, sys.C, sys.D))
        nx, nu = self.A.shape[0], self.B.shape[1]
        self.nq = nx // 2 if coordinates is None else int(coordinates)
        if not 0 < self.nq <= nx // 2:
            raise ValueError(f"{self.name}: coordinates must be between 1 and nx // 2 = {nx // 2}, got {coordinates}")
        self.n_first_order = nx - 2 * self.nq
        self.state_names = tuple(sys.state_labels)
        self.input_names = tuple(sys.input_labels)
        self.output_names = tuple(sys.output_labels)
        self.coordinate_names = self.state_names[: self.nq]
        limit = np.broadcast_to(np.asarray(limit, dtype=float), (nu,)).copy()
        if not np.all(np.isfinite(limit)) or np.any(limit <= 0):
            raise ValueError(f"{self.name}: input_limit must be finite and > 0, got {limit}")
        self.input_limit = limit
        self._xe = np.zeros(nx) if xe is None else as_vector(xe, nx, f"{self.name} xe")
        self._ue = np.zeros(nu) if ue is None else as_vector(ue, nu, f"{self.name} ue")
        self._configuration, self._static_input = self._functions()

    @property
    def nx(self) -> int:
        """Number of states."""
        return self.A.shape[0]

    @property
    def nu(self) -> int:
        """Number of inputs."""
        return self.B.shape[1]

    @property
    def ny(self) -> int:
        """Number of outputs."""
        return self.C.shape[0]

    def __repr__(self) -> str:
        sizes = f"nx={self.nx}, nu={self.nu}, ny={self.ny}"
        return f"LinearPlant({self.name!r}, {sizes}, input_limit={self.input_limit.tolist()})"

    def param_vector(self, params=None) -> np.ndarray:
        """No parameters: an empty vector (the declared plants' parameter slot)."""
        return np.zeros(0)

    def equilibrium(self, params=None, **fixed) -> tuple[np.ndarray, np.ndarray]:
        """The operating point (xe (nx,), ue (nu,)); fixing coordinates is not supported."""
        if fixed:
            raise ValueError(f"{self.name}: a LinearPlant has one operating point; cannot fix {sorted(fixed)}")
        return self._xe.copy(), self._ue.copy()

    def linearize(self, xe=None, ue=None, params=None, check: bool = True) -> LinearModel:
        """The model itself about its operating point (a linear model's linearization anywhere)."""
        xe = self._xe if xe is None else as_vector(xe, self.nx, f"{self.name} state")
        ue = self._ue if ue is None else as_vector(ue, self.nu, f"{self.name} input")
        if check and np.max(np.abs(self.f(xe, ue)), initial=0.0) > 1e-8:
            raise ValueError(f"{self.name}: (xe, ue) is not an equilibrium; pass check=False to linearize anyway")
        return LinearModel(
            A=self.A,
            B=self.B,
            C=self.C,
            D=self.D,
            xe=xe,
            ue=ue,
            ye=self.output(xe) + self.D @ (ue - self._ue),
            state_names=self.state_names,
            input_names=self.input_names,
            output_names=self.output_names,
            name=self.name,
        )

    def f(self, x, u, params=None) -> np.ndarray:
        """x' = A (x − xe) + B (u − ue), (nx,)."""
        return self.A @ (np.asarray(x, float) - self._xe) + self.B @ (np.asarray(u, float) - self._ue)

    def output(self, x, params=None) -> np.ndarray:
        """y = ye + C (x − xe) at u = ue, (ny,)."""
        return self.C @ np.asarray(x, float) + self.D @ self._ue

    def _static_gain(self) -> np.ndarray:
        """G (nu, nq): the input change holding a configuration change at rest, −B_v⁺ A_vq."""
        nq = self.nq
        rates = slice(nq, 2 * nq)
        return -np.linalg.pinv(self.B[rates]) @ self.A[rates, :nq]

    def _functions(self) -> tuple[ca.Function, ca.Function]:
        """CasADi (y, p) -> q read from the outputs at rest, and (q, p) -> u holding q at rest."""
        nq = self.nq
        y, q, p = ca.SX.sym("y", self.ny), ca.SX.sym("q", nq), ca.SX.sym("p", 0)
        ye = self.output(self._xe)
        read = np.linalg.pinv(self.C[:, :nq])
        configuration = ca.Function(
            "configuration", [y, p], [ca.DM(self._xe[:nq]) + ca.mtimes(ca.DM(read), y - ca.DM(ye))]
        )
        G = self._static_gain()
        static = ca.Function("static_input", [q, p], [ca.DM(self._ue) + ca.mtimes(ca.DM(G), q - ca.DM(self._xe[:nq]))])
        return configuration, static

    @property
    def casadi_configuration(self) -> ca.Function:
        """CasADi Function (y, p) -> q: the configuration from the outputs, least squares at rest."""
        return self._configuration

    @property
    def casadi_equilibrium_input(self) -> ca.Function:
        """CasADi Function (q, p) -> u: the input holding q at rest (affine in q)."""
        return self._static_input

    def equilibrium_input(self, q, params=None) -> np.ndarray:
        """The input holding the configuration q (nq,) at rest, (nu,)."""
        q = as_vector(q, self.nq, f"{self.name} configuration {self.coordinate_names}")
        return self._ue + self._static_gain() @ (q - self._xe[: self.nq])

    def equilibrium_input_jacobian(self, q=None, params=None) -> np.ndarray:
        """∂u_e/∂q, (nu, nq): constant for a linear plant."""
        return self._static_gain()
