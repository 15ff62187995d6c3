"""Linear models: the exact linearization of a plant about an equilibrium."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from . import deferred
from .checks import positive, real_array

if TYPE_CHECKING:
    import control
else:
    control = deferred.module("control")
scipy = deferred.module("scipy")


@dataclass(frozen=True)
class LinearModel:
    """x̃' = A x̃ + B ũ, ỹ = C x̃ + D ũ with x̃ = x − xe, ũ = u − ue, ỹ = y − ye.

    Attributes
    ----------
    A, B, C, D : ndarray, shapes (nx, nx), (nx, nu), (ny, nx), (ny, nu)
    xe, ue, ye : ndarray, the operating point, (nx,), (nu,), (ny,)
    state_names, input_names, output_names : tuple of str
    sample_period : float or None
        None for continuous time; Ts in s after `discretize`.
    name : str
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    xe: np.ndarray
    ue: np.ndarray
    ye: np.ndarray
    state_names: tuple
    input_names: tuple
    output_names: tuple
    sample_period: float | None = None
    name: str = ""

    def __post_init__(self):
        """Check every matrix and vector for shape and finiteness, naming the first that is wrong."""
        who = self.name or "LinearModel"
        A, B, C = (real_array(getattr(self, key), f"{who}: {key}") for key in "ABC")
        nx = A.shape[0] if A.ndim == 2 else -1
        nu = B.shape[1] if B.ndim == 2 else -1
        ny = C.shape[0] if C.ndim == 2 else -1
        want = {"A": (nx, nx), "B": (nx, nu), "C": (ny, nx), "D": (ny, nu), "xe": (nx,), "ue": (nu,), "ye": (ny,)}
        for key, shape in want.items():
            value = real_array(getattr(self, key), f"{who}: {key}")
            if value.shape != shape or min(shape) < 0:
                raise ValueError(
                    f"{who}: {key} must have shape {shape} (nx = {nx}, nu = {nu}, ny = {ny} from "
                    f"A, B, C), got {value.shape}"
                )
            if not np.all(np.isfinite(value)):
                raise ValueError(f"{who}: {key} has non-finite entries")
        for key, size in (("state_names", nx), ("input_names", nu), ("output_names", ny)):
            if len(getattr(self, key)) != size:
                raise ValueError(f"{who}: {key} must name {size} signals, got {getattr(self, key)}")
        if self.sample_period is not None:
            positive(self.sample_period, f"{who}: sample_period (s)")

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

    def output_index(self, name: str) -> int:
        """Index of the output called `name` (ValueError listing the outputs otherwise)."""
        if name not in self.output_names:
            raise ValueError(f"{self.name} has no output {name!r}; outputs are {', '.join(self.output_names)}")
        return self.output_names.index(name)

    def select_outputs(self, *names: str) -> LinearModel:
        """The same model keeping only the named outputs, in the given order."""
        rows = [self.output_index(n) for n in names]
        return replace(self, C=self.C[rows], D=self.D[rows], ye=self.ye[rows], output_names=tuple(names))

    def ss(self) -> control.StateSpace:
        """python-control state space with named signals (discrete when sampled)."""
        dt = 0 if self.sample_period is None else self.sample_period
        return control.ss(
            self.A,
            self.B,
            self.C,
            self.D,
            dt,
            name=self.name or None,
            states=list(self.state_names),
            inputs=list(self.input_names),
            outputs=list(self.output_names),
        )

    def tf(self, output: str | None = None, input: str | None = None) -> control.TransferFunction:
        """Transfer function(s); with `output`/`input` names, the single SISO entry.

        Coefficients below 1e-9 of the largest in their polynomial (ss2tf roundoff) are set to zero so that
        exact zeros of the model, such as a missing static term, stay exact.
        """
        model = self.select_outputs(output) if output is not None else self
        sys = control.ss2tf(model.ss())
        if input is not None:
            if input not in self.input_names:
                raise ValueError(f"{self.name} has no input {input!r}; inputs are {', '.join(self.input_names)}")
            j = self.input_names.index(input)
            sys = sys[:, j]
        return clean_tf(sys)

    def discretize(self, sample_period: float) -> LinearModel:
        """Exact zero-order-hold discretization at `sample_period` s (matrix exponential)."""
        if self.sample_period is not None:
            raise ValueError(f"{self.name} is already discrete (Ts = {self.sample_period} s)")
        sample_period = positive(sample_period, "sample_period (s)")
        nx, nu = self.nx, self.nu
        block = np.zeros((nx + nu, nx + nu))
        block[:nx, :nx] = self.A
        block[:nx, nx:] = self.B
        phi = scipy.linalg.expm(block * sample_period)
        return replace(self, A=phi[:nx, :nx], B=phi[:nx, nx:], sample_period=float(sample_period))


def clean_tf(sys: control.TransferFunction) -> control.TransferFunction:
    """`sys` with every polynomial `chop`ped (roundoff below 1e-9 of the largest coefficient set to zero)."""
    num = [[chop(np.atleast_1d(n)) for n in row] for row in sys.num]
    den = [[chop(np.atleast_1d(d)) for d in row] for row in sys.den]
    if sys.ninputs == 1 and sys.noutputs == 1:
        return control.tf(num[0][0], den[0][0], sys.dt)
    return control.tf(num, den, sys.dt)


def chop(coeffs: np.ndarray, rel: float = 1e-9) -> np.ndarray:
    """Descending coefficients with those below `rel` of the largest set to zero, leading zeros removed."""
    coeffs = np.atleast_1d(np.asarray(coeffs, dtype=float))
    scale = np.max(np.abs(coeffs)) if coeffs.size else 0.0
    out = np.where(np.abs(coeffs) <= rel * scale, 0.0, coeffs)
    nonzero = np.flatnonzero(out)
    return out[nonzero[0] :] if nonzero.size else np.zeros(1)


def polynomial_string(coeffs, var: str = "s", digits: int = 4) -> str:
    """'66.67 s^2 + 0.6667 s' from descending coefficients; zeros are skipped."""
    coeffs = np.atleast_1d(np.asarray(coeffs, dtype=float))
    order = coeffs.size - 1
    terms = []
    for i, c in enumerate(coeffs):
        if c == 0:
            continue
        power = order - i
        mag = abs(c)
        num = "" if (mag == 1 and power > 0) else f"{mag:.{digits}g}"
        sym = "" if power == 0 else (var if power == 1 else f"{var}^{power}")
        term = " ".join(t for t in (num, sym) if t)
        terms.append(("- " if c < 0 else "+ ") + term)
    if not terms:
        return "0"
    text = " ".join(terms)
    return text[2:] if text.startswith("+ ") else "-" + text[2:]


def tf_string(G: control.TransferFunction, digits: int = 4) -> str:
    """One-line '(num) / (den)' of a SISO transfer function."""
    num = polynomial_string(np.ravel(G.num[0][0]), digits=digits)
    den = polynomial_string(np.ravel(G.den[0][0]), digits=digits)
    return f"({num}) / ({den})"
