"""Input validation shared by every package: one place that says what was wrong."""

from __future__ import annotations

import numpy as np


def as_vector(value, size: int, what: str) -> np.ndarray:
    """Return `value` as a finite float vector of length `size`.

    Raises
    ------
    ValueError
        Naming `what` when the length is wrong or an entry is NaN or infinite.
    """
    arr = np.asarray(value, dtype=float)
    if arr.ndim == 0 and size == 1:
        arr = arr.reshape(1)
    arr = arr.reshape(-1) if arr.ndim == 2 and 1 in arr.shape else arr
    if arr.ndim != 1 or arr.size != size:
        raise ValueError(f"{what} must have {size} entries, got shape {np.shape(value)}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{what} has non-finite entries: {arr}")
    return arr


def as_matrix(value, columns: int, what: str, rows: int | None = None) -> np.ndarray:
    """Return `value` as a finite float array of shape (rows, columns).

    A 1-D array is read as one column when `columns` is 1.
    """
    arr = np.asarray(value, dtype=float)
    if arr.ndim == 1 and columns == 1:
        arr = arr[:, None]
    if arr.ndim != 2 or arr.shape[1] != columns or (rows is not None and arr.shape[0] != rows):
        want = f"({rows if rows is not None else 'N'}, {columns})"
        raise ValueError(f"{what} must have shape {want}, got {np.shape(value)}")
    if not np.all(np.isfinite(arr)):
        bad = np.argwhere(~np.isfinite(arr))[0]
        raise ValueError(f"{what} has a non-finite entry at row {bad[0]}, column {bad[1]}")
    return arr


def positive(value: float, what: str) -> float:
    """Return `value` as a float, or raise naming `what` unless it is finite and > 0."""
    value = float(value)
    if not np.isfinite(value) or value <= 0:
        raise ValueError(f"{what} must be a finite number > 0, got {value}")
    return value


class SimulationError(RuntimeError):
    """A simulation that diverged or whose solver failed; the message says when."""


def first_divergence(x: np.ndarray, bound: float) -> int | None:
    """Index of the first row of `x` that is non-finite or exceeds `bound` in magnitude."""
    bad = ~np.all(np.isfinite(x), axis=1) | np.any(np.abs(np.nan_to_num(x, nan=np.inf)) > bound, axis=1)
    idx = np.flatnonzero(bad)
    return int(idx[0]) if idx.size else None
