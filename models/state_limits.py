"""Physical limits on a plant's states, and whether a run leaves them.

A case declares its limits (cart travel, beam length, swing angle, panel
deflection) as :class:`StateLimit` records with their source; :func:`check_state_limits`
reads one run (sample times and state trajectory) and reports, per limit, whether
it was left, by how much and when first. A limit bounds one state, or the
difference of two (a panel's deflection φ − θ from the body it hangs on), and
its upper bound may be a plant parameter (a beam's length), read from the
parameters of the plant the run simulated (:meth:`StateLimit.at`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np


@dataclass(frozen=True)
class StateLimit:
    """A physical bound ``lower <= x[state] - x[relative_to] <= upper`` (``x[state]`` alone without `relative_to`).

    Parameters
    ----------
    name : str
        What the limit is ("cart travel"); the verdict says "leaves cart travel by 0.03 m".
    state : str
        The plant's state name the bound applies to.
    lower, upper : float
        Bounds in the state's units (``-inf``/``inf`` for one-sided limits).
    source : str
        Where the number comes from (the text's section or the case's reasoning).
    unit : str
        The state's unit, written beside the excess ("m", "rad").
    relative_to : str or None
        A second state: the bound is on ``x[state] - x[relative_to]`` (a deflection).
    upper_parameter : str or None
        A plant parameter whose value is the upper bound on the plant simulated (the beam's
        length ``ell``); `upper` is its nominal value.
    """

    name: str
    state: str
    lower: float
    upper: float
    source: str
    unit: str = ""
    relative_to: str | None = None
    upper_parameter: str | None = None

    def __post_init__(self) -> None:
        if not self.lower < self.upper:
            raise ValueError(f"state limit {self.name!r}: lower {self.lower} must be below upper {self.upper}")
        if math.isnan(self.lower) or math.isnan(self.upper):
            raise ValueError(f"state limit {self.name!r}: bounds must be numbers, got ({self.lower}, {self.upper})")
        if not self.source:
            raise ValueError(f"state limit {self.name!r}: give its source")

    @property
    def states(self) -> tuple[str, ...]:
        """The states the limit reads: (state,) or (state, relative_to)."""
        return (self.state,) if self.relative_to is None else (self.state, self.relative_to)

    def at(self, params: Mapping[str, float] | None) -> StateLimit:
        """This limit on the plant with `params` (name -> value): the upper bound read from
        `upper_parameter` when it has one (ValueError when `params` lacks it), else itself."""
        if self.upper_parameter is None or params is None:
            return self
        if self.upper_parameter not in params:
            raise ValueError(
                f"state limit {self.name!r}: its upper bound is the parameter {self.upper_parameter!r}, "
                f"which is not one of {sorted(params)}"
            )
        return replace(self, upper=float(params[self.upper_parameter]), upper_parameter=None)

    def values(self, x: np.ndarray, state_names: Sequence[str]) -> np.ndarray:
        """The limited quantity over a run: x[:, state] (− x[:, relative_to]), shape (N,)."""
        names = list(state_names)
        for name in self.states:
            if name not in names:
                raise ValueError(f"state limit {self.name!r}: no state {name!r} among {names}")
        column = x[:, names.index(self.state)]
        return column if self.relative_to is None else column - x[:, names.index(self.relative_to)]

    def describe(self) -> str:
        """One line: "cart travel: -2.5 ≤ z ≤ 2.5 m"."""
        what = self.state if self.relative_to is None else f"{self.state} − {self.relative_to}"
        unit = f" {self.unit}" if self.unit else ""
        if math.isinf(self.lower):
            return f"{self.name}: {what} ≤ {self.upper:g}{unit}"
        if math.isinf(self.upper):
            return f"{self.name}: {what} ≥ {self.lower:g}{unit}"
        return f"{self.name}: {self.lower:g} ≤ {what} ≤ {self.upper:g}{unit}"


@dataclass(frozen=True)
class LimitViolation:
    """One limit's outcome on one run.

    ``excess`` is the largest distance (state units) outside ``[lower, upper]``,
    0.0 when the run stays inside; ``first_time`` is the first sample time (s)
    outside, ``None`` when never.
    """

    limit: StateLimit
    violated: bool
    excess: float
    first_time: float | None


def check_state_limits(
    t: np.ndarray, x: np.ndarray, state_names: Sequence[str], limits: Sequence[StateLimit], tol: float = 0.0
) -> list[LimitViolation]:
    """Whether a run leaves each limit, and by how much.

    Parameters
    ----------
    t : ndarray, shape (N,)
        Sample times (s).
    x : ndarray, shape (N, n)
        States at those times, columns in the order of ``state_names``.
    state_names : sequence of str, length n
        The plant's state names.
    limits : sequence of StateLimit
        The limits to check; each names a state in ``state_names``.
    tol : float
        An excess at or below ``tol`` (state units) does not count as leaving.

    Returns
    -------
    list of LimitViolation, one per limit, in the order given.
    """
    t = np.asarray(t, dtype=float)
    x = np.asarray(x, dtype=float)
    if x.ndim != 2 or x.shape[0] != t.shape[0] or x.shape[1] != len(state_names):
        raise ValueError(f"states of shape {x.shape} do not match {t.shape[0]} times and {len(state_names)} states")
    out = []
    for lim in limits:
        col = lim.values(x, state_names)
        over = np.maximum(col - lim.upper, lim.lower - col)
        excess = float(max(np.max(over, initial=-np.inf), 0.0))
        outside = np.flatnonzero(over > tol)
        violated = outside.size > 0
        out.append(LimitViolation(lim, violated, excess, float(t[outside[0]]) if violated else None))
    return out


def summarize_limit_violations(runs: Sequence[Sequence[LimitViolation]]) -> dict[str, dict[str, float]]:
    """Per limit over many runs (a Monte Carlo): how many left it and the largest excess.

    Parameters
    ----------
    runs : sequence of the lists :func:`check_state_limits` returned, one per run,
        all for the same limits in the same order.

    Returns
    -------
    dict limit name -> {"count": runs that left it, "largest": largest excess (state units)}.
    """
    out: dict[str, dict[str, float]] = {}
    for run in runs:
        for v in run:
            entry = out.setdefault(v.limit.name, {"count": 0, "largest": 0.0})
            entry["count"] += int(v.violated)
            entry["largest"] = max(entry["largest"], v.excess)
    return out
