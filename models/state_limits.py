"""Physical limits on a plant's states, and whether a run leaves them.

A case declares its limits (cart travel, beam length, swing angle, panel
deflection) as :class:`StateLimit` records with their source; :func:`check_state_limits`
reads one run (sample times and state trajectory) and reports, per limit, whether
it was left, by how much and when first.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class StateLimit:
    """A physical bound ``lower <= x[state] <= upper`` on one state.

    Parameters
    ----------
    name : str
        What the limit is ("cart travel").
    state : str
        The plant's state name the bound applies to.
    lower, upper : float
        Bounds in the state's units (``-inf``/``inf`` for one-sided limits).
    source : str
        Where the number comes from (the text's section or the case's reasoning).
    """

    name: str
    state: str
    lower: float
    upper: float
    source: str

    def __post_init__(self) -> None:
        if not self.lower < self.upper:
            raise ValueError(f"state limit {self.name!r}: lower {self.lower} must be below upper {self.upper}")
        if not self.source:
            raise ValueError(f"state limit {self.name!r}: give its source")


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
        if lim.state not in state_names:
            raise ValueError(f"state limit {lim.name!r}: no state {lim.state!r} among {list(state_names)}")
        col = x[:, list(state_names).index(lim.state)]
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
