"""How far a constraint lies outside its bounds, relative to their size: the one measure the specs are
judged by (`TuningProblem.excess`), the phase one minimizes and the aggregated specs bound."""

from __future__ import annotations

import casadi as ca
import numpy as np


def bound_scale(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """What a constraint's violation is measured relative to: 1 + max(|lo|, |hi|) when both bounds are
    finite, else 1 (elementwise, shape of the bounds)."""
    scale = 1 + np.maximum(np.abs(lo), np.abs(hi))
    return np.where(np.isfinite(scale), scale, 1.0)


def relative_excess(g: ca.MX, lbg: np.ndarray, ubg: np.ndarray) -> ca.MX:
    """Each finite bound's excess relative to its scale (as `TuningProblem.excess`), <= 0 where it holds:
    one row per finite upper bound, then one per finite lower bound."""
    scale = bound_scale(lbg, ubg)
    up, low = np.flatnonzero(np.isfinite(ubg)), np.flatnonzero(np.isfinite(lbg))
    parts = [(g[up.tolist()] - ca.DM(ubg[up])) / ca.DM(scale[up])] if up.size else []
    if low.size:
        parts.append((ca.DM(lbg[low]) - g[low.tolist()]) / ca.DM(scale[low]))
    return ca.vertcat(*parts) if parts else ca.MX(0, 1)


def soft_max_excess(expr: ca.MX, lo, hi, width: ca.MX) -> ca.MX:
    """One smooth inequality (<= 0) for ``lo <= expr <= hi`` elementwise: the soft maximum of the
    relative excesses v (as in `TuningProblem.excess`), m + τ log(mean exp((v - m)/τ)), m = max v,
    τ = width / max(log n, 1): between max v - width and max v, exact as the width goes to 0."""
    n = expr.numel()
    lo, hi = np.broadcast_to(lo, (n,)).astype(float), np.broadcast_to(hi, (n,)).astype(float)
    scale = bound_scale(lo, hi)
    sides = []
    upper, lower = np.flatnonzero(np.isfinite(hi)), np.flatnonzero(np.isfinite(lo))
    if upper.size:
        sides.append((expr[upper.tolist()] - hi[upper]) / scale[upper])
    if lower.size:
        sides.append((lo[lower] - expr[lower.tolist()]) / scale[lower])
    if not sides:
        return ca.MX(-1.0)  # no finite bound: always holds
    v = ca.vertcat(*sides)
    tau = width / max(np.log(v.numel()), 1.0)
    m = ca.mmax(v)  # shift for the exponentials; its derivative cancels exactly
    return m + tau * ca.log(ca.sum1(ca.exp((v - m) / tau)) / v.numel())


class Constraints:
    """The spec constraints of one problem as they are added: expressions, bounds and named row ranges.

    aggregated_width : None for one inequality per element of each added expression; else the smoothed
        problem's width symbol, and each added spec becomes one `soft_max_excess` row <= 0.
    """

    def __init__(self, aggregated_width: ca.MX | None = None):
        self.aggregated_width = aggregated_width
        self.rows: list[ca.MX] = []
        self.lower: list[np.ndarray] = []
        self.upper: list[np.ndarray] = []
        self.names: list[tuple[str, slice]] = []
        self.size = 0

    def add(self, name: str, expr: ca.MX, lo, hi) -> None:
        """Constrain lo <= expr <= hi (bounds scalars or shaped like vec(expr)) under `name`."""
        expr = ca.vec(expr)
        if self.aggregated_width is not None:
            expr, lo, hi = soft_max_excess(expr, lo, hi, self.aggregated_width), -np.inf, 0.0
        self.rows.append(expr)
        self.lower.append(np.broadcast_to(lo, (expr.numel(),)))
        self.upper.append(np.broadcast_to(hi, (expr.numel(),)))
        self.names.append((name, slice(self.size, self.size + expr.numel())))
        self.size += expr.numel()

    def stacked(self) -> tuple[ca.MX, np.ndarray, np.ndarray, list[tuple[str, slice]]]:
        """(g, lbg, ubg, names): every row stacked, an empty column and empty bounds when none."""
        g = ca.vertcat(*self.rows) if self.rows else ca.MX(0, 1)
        lbg = np.concatenate(self.lower) if self.lower else np.zeros(0)
        ubg = np.concatenate(self.upper) if self.upper else np.zeros(0)
        return g, lbg, ubg, self.names
