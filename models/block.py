"""The controller-block interface: one discrete-time step for every controller.

A controller has a state x_c and a step ``(x_c, y, r) -> (x_c_next, u)`` run
every `sample_period` seconds. `Block` writes that step as CasADi
expressions of symbolic gains, so a closed loop compiles into one Function
and is differentiable with respect to the gains. Controllers that solve an
optimization each step (MPC) implement the same `step` in Python; the
closed-loop simulator runs both.
"""

from __future__ import annotations

import abc
import copy
from collections.abc import Mapping
from functools import cached_property
from typing import Protocol, Self, runtime_checkable

import casadi as ca
import numpy as np

from .checks import as_vector, integer, positive, real_array

MEASURES = ("outputs", "state")


@runtime_checkable
class Controller(Protocol):
    """What the closed-loop simulator needs from any controller.

    Attributes
    ----------
    sample_period : float, s
    measures : "outputs" (the plant's outputs y) or "state" (the full state x)
    n_reference : int, size of r
    """

    sample_period: float
    measures: str
    n_reference: int

    def initial_state(self, y0: np.ndarray, r0: np.ndarray) -> np.ndarray:
        """x_c at the first sample from the first measurement y0 and reference r0."""
        ...

    def step(self, xc: np.ndarray, y: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """One sample: (x_c_next, u (nu,)) from the state xc, the measurement y and the reference r."""
        ...


def saturate(u, limit):
    """Clip u to [-limit, limit] elementwise (CasADi or numpy); NaN stays NaN.

    Written with comparisons rather than fmin/fmax, which return the other
    argument for NaN: a NaN command would silently become -limit, a finite
    force, and a fault upstream would look like a saturated actuator. For
    every other u the value equals fmin(fmax(u, -limit), limit) bit for bit,
    and so does the derivative except exactly at u = ±limit.
    """
    if isinstance(u, (ca.SX, ca.MX, ca.DM)):
        return ca.if_else(u > limit, limit, ca.if_else(u < -limit, -limit, u))
    return np.clip(u, -np.asarray(limit), limit)


class Block(abc.ABC):
    """A controller whose step is a CasADi expression of its gains.

    Subclasses set the sizes in `__init__` and write `expr`.

    Parameters
    ----------
    sample_period : float, s
    n_state, n_measured, n_reference, n_input : int
        Sizes of x_c, y (what the block reads), r and u.
    gains : mapping name -> float or array
        Tunable values; `expr` receives them as symbols of the same shapes.
    measures : "outputs" or "state"
    name : str
    """

    def __init__(
        self,
        *,
        sample_period: float,
        n_state: int,
        n_measured: int,
        n_reference: int,
        n_input: int,
        gains: Mapping[str, float | np.ndarray],
        measures: str = "outputs",
        name: str = "",
    ):
        self.name = name or type(self).__name__
        if not isinstance(self.name, str):
            raise TypeError(f"a block's name must be a string, got {name!r}")
        self.sample_period = positive(sample_period, f"{self.name}: sample_period (s)")
        if measures not in MEASURES:
            raise ValueError(f"{self.name}: measures must be one of {MEASURES}, got {measures!r}")
        self.n_state = integer(n_state, f"{self.name}: n_state", minimum=0)
        self.n_measured = integer(n_measured, f"{self.name}: n_measured", minimum=0)
        self.n_reference = integer(n_reference, f"{self.name}: n_reference", minimum=0)
        self.n_input = integer(n_input, f"{self.name}: n_input", minimum=1)
        self.measures = measures
        if not isinstance(gains, Mapping):
            raise TypeError(f"{self.name}: gains must be a mapping name -> value, got {gains!r}")
        self.gains = {k: self._checked_gain(k, v) for k, v in gains.items()}

    # ------------------------------------------------------------- to write
    @abc.abstractmethod
    def expr(self, xc, y, r, gains: dict) -> tuple:
        """Symbolic step: (x_c_next, u) from SX xc (n_state,), y (n_measured,), r (n_reference,) and `gains`,
        a dict name -> SX symbol shaped like the gain."""

    def initial_state(self, y0, r0) -> np.ndarray:
        """x_c at the first sample from the first measurement y0 and reference r0 (zeros by default)."""
        return np.zeros(self.n_state)

    # ------------------------------------------------------------- provided
    def _checked_gain(self, name, value) -> np.ndarray:
        """A gain as a finite float array of at most two dimensions (ValueError naming the gain)."""
        arr = np.array(real_array(value, f"{self.name}: gain {name}"))
        if arr.ndim > 2:
            raise ValueError(f"{self.name}: gain {name} must be a number, vector or matrix, got shape {arr.shape}")
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"{self.name}: gain {name} is not finite: {value}")
        return arr

    @property
    def gain_names(self) -> tuple:
        """The gains' names, in `gain_vector` order."""
        return tuple(self.gains)

    def gain_vector(self) -> np.ndarray:
        """All gains flattened (column-major per gain) in `gain_names` order."""
        if not self.gains:
            return np.zeros(0)
        return np.concatenate([g.ravel(order="F") for g in self.gains.values()])

    def gains_from_vector(self, vector) -> dict:
        """Inverse of `gain_vector`: the flat `vector` as a dict name -> array with each gain's shape."""
        vector = as_vector(vector, self.gain_vector().size, f"{self.name} gain vector")
        out, i = {}, 0
        for k, g in self.gains.items():
            out[k] = vector[i : i + g.size].reshape(g.shape, order="F")
            i += g.size
        return out

    def with_gains(self, **gains) -> Self:
        """A copy with some gains replaced (same shapes); shares the compiled step."""
        unknown = set(gains) - set(self.gains)
        if unknown:
            raise ValueError(f"{self.name} has no gain {sorted(unknown)}; gains are {', '.join(self.gains)}")
        new = copy.copy(self)
        new.gains = dict(self.gains)
        for k, v in gains.items():
            arr = self._checked_gain(k, v)
            if arr.shape != self.gains[k].shape:
                raise ValueError(f"{self.name}: gain {k} must have shape {self.gains[k].shape}, got {arr.shape}")
            new.gains[k] = arr
        return new

    def symbolic_gains(self, vector: ca.SX) -> dict:
        """Split a symbolic gain vector into a dict of symbols shaped like the gains."""
        out, i = {}, 0
        for k, g in self.gains.items():
            piece = vector[i : i + g.size]
            out[k] = ca.reshape(piece, g.shape[0], g.shape[1]) if g.ndim == 2 else piece
            i += g.size
        return out

    @cached_property
    def casadi_step(self) -> ca.Function:
        """Function (xc, y, r, gains) -> (xc_next, u), gains as in `gain_vector`."""
        xc = ca.SX.sym("xc", self.n_state)
        y = ca.SX.sym("y", self.n_measured)
        r = ca.SX.sym("r", self.n_reference)
        g = ca.SX.sym("gains", self.gain_vector().size)
        xc_next, u = self.expr(xc, y, r, self.symbolic_gains(g))
        xc_next = ca.vertcat(xc_next) if self.n_state else ca.SX(0, 1)
        return ca.Function("step", [xc, y, r, g], [xc_next, ca.vertcat(u)], ["xc", "y", "r", "gains"], ["xc_next", "u"])

    def step(self, xc, y, r) -> tuple[np.ndarray, np.ndarray]:
        """One numeric step with the current gains from the state xc (n_state,), the measurement y
        (n_measured,) and the reference r (n_reference,): (x_c_next (n_state,), u (n_input,))."""
        xc = as_vector(xc, self.n_state, f"{self.name} state") if self.n_state else np.zeros(0)
        y = as_vector(y, self.n_measured, f"{self.name} measurement")
        r = as_vector(r, self.n_reference, f"{self.name} reference")
        xn, u = self.casadi_step(xc, y, r, self.gain_vector())
        return np.asarray(xn).ravel(), np.asarray(u).ravel()


class Cascade(Block):
    """Successive loop closure: the outer block's output is the inner block's reference.

    Both blocks read the same measurement vector. Gains are prefixed
    ``outer.`` and ``inner.``; the state is (x_outer, x_inner). `name` labels the pair in
    messages and tables.
    """

    def __init__(self, outer: Block, inner: Block, name: str = "cascade"):
        for role, block in (("outer", outer), ("inner", inner)):
            if not isinstance(block, Block):
                raise TypeError(f"{name}: the {role} controller must be a models.Block, got {type(block).__name__}")
        if outer.sample_period != inner.sample_period:
            raise ValueError(
                f"outer and inner blocks need the same sample period, got "
                f"{outer.sample_period} and {inner.sample_period} s"
            )
        if outer.n_input != inner.n_reference:
            raise ValueError(
                f"the outer block's output ({outer.n_input}) must match the inner "
                f"block's reference ({inner.n_reference})"
            )
        if (outer.n_measured, outer.measures) != (inner.n_measured, inner.measures):
            raise ValueError("outer and inner blocks must read the same measurement vector")
        self.outer, self.inner = outer, inner
        gains = {f"outer.{k}": v for k, v in outer.gains.items()}
        gains |= {f"inner.{k}": v for k, v in inner.gains.items()}
        super().__init__(
            sample_period=inner.sample_period,
            n_state=outer.n_state + inner.n_state,
            n_measured=inner.n_measured,
            n_reference=outer.n_reference,
            n_input=inner.n_input,
            gains=gains,
            measures=inner.measures,
            name=name,
        )

    def expr(self, xc, y, r, gains):
        """The outer step gives the inner block's reference; the state xc is (x_outer, x_inner).

        y, r and gains as in `Block.expr` (the gains' names prefixed ``outer.`` and ``inner.``).
        """
        no = self.outer.n_state
        go = {k[6:]: v for k, v in gains.items() if k.startswith("outer.")}
        gi = {k[6:]: v for k, v in gains.items() if k.startswith("inner.")}
        xo_next, r_inner = self.outer.expr(xc[:no], y, r, go)
        xi_next, u = self.inner.expr(xc[no:], y, r_inner, gi)
        return ca.vertcat(xo_next, xi_next), u

    def initial_state(self, y0, r0) -> np.ndarray:
        """(x_outer, x_inner) at the first sample from the measurement y0 and reference r0; the inner block
        starts at the outer step's first reference."""
        xo = self.outer.initial_state(y0, r0)
        _, r_inner = self.outer.step(xo, y0, r0)
        return np.concatenate([xo, self.inner.initial_state(y0, r_inner)])

    def with_gains(self, **gains) -> Cascade:
        """A copy with some prefixed gains (``outer.kp``, ``inner.kd``) replaced, in the blocks too."""
        new = super().with_gains(**gains)
        assert isinstance(new, Cascade)  # Block.with_gains copies the instance
        new.outer = self.outer.with_gains(**{k[6:]: v for k, v in new.gains.items() if k.startswith("outer.")})
        new.inner = self.inner.with_gains(**{k[6:]: v for k, v in new.gains.items() if k.startswith("inner.")})
        return new
