"""Input validation shared by every package: one place that says what was wrong.

Type faults (a string, a bool or a list where a number belongs) raise
TypeError; value faults (NaN, a negative period, a wrong length) raise
ValueError; a request whose memory estimate exceeds `MEMORY_LIMIT_BYTES`
raises `ResourceLimitError` before any work is done. Every message names the
argument, the value given and what is allowed.
"""

from __future__ import annotations

import numbers
from collections.abc import Mapping

import numpy as np

#: Largest memory, in bytes, one call may allocate for its results and working
#: arrays (estimated up front). Override by assigning a new value, e.g.
#: ``models.checks.MEMORY_LIMIT_BYTES = 8 * 2**30``; it is read at every call.
MEMORY_LIMIT_BYTES = 2**30


class ResourceLimitError(ValueError):
    """A request refused up front because it would need more memory than `MEMORY_LIMIT_BYTES`."""


class SimulationError(RuntimeError):
    """A simulation that diverged or whose solver failed; the message says when."""


def _is_real_scalar(value) -> bool:
    """Whether `value` is one real number (a Python or numpy number, or a 0-d numeric array; not a bool)."""
    if isinstance(value, (bool, np.bool_)):
        return False
    if isinstance(value, numbers.Real):
        return True
    return isinstance(value, np.ndarray) and value.ndim == 0 and value.dtype.kind in "iuf"


def real(value, what: str, *, finite: bool = True) -> float:
    """Return one real number as a float.

    Raises
    ------
    TypeError
        Naming `what` when `value` is not a real number (a bool, a string, a
        sequence or an array of several entries are refused, not converted).
    ValueError
        When `finite` and the value is NaN or infinite.
    """
    if not _is_real_scalar(value):
        raise TypeError(f"{what} must be a real number, got {type(value).__name__} {value!r}")
    number = float(value)
    if finite and not np.isfinite(number):
        raise ValueError(f"{what} must be finite, got {number}")
    return number


def positive(value, what: str) -> float:
    """Return `value` as a float, or raise naming `what` unless it is a finite real number > 0."""
    number = real(value, what, finite=False)
    if not np.isfinite(number) or number <= 0:
        raise ValueError(f"{what} must be a finite number > 0, got {number}")
    return number


def integer(value, what: str, minimum: int | None = None) -> int:
    """Return `value` as an int, refusing fractions (2.7), bools and strings.

    A float with an integral value (3.0) is accepted.

    Raises
    ------
    TypeError
        When `value` is not a real number.
    ValueError
        When it is not integral, or below `minimum`.
    """
    if not _is_real_scalar(value):
        raise TypeError(f"{what} must be an integer, got {type(value).__name__} {value!r}")
    if not isinstance(value, numbers.Integral) and not float(value).is_integer():
        raise ValueError(f"{what} must be an integer, got {value!r}")
    number = int(value)
    if minimum is not None and number < minimum:
        raise ValueError(f"{what} must be an integer >= {minimum}, got {number}")
    return number


def boolean(value, what: str) -> bool:
    """Return `value` as a bool, refusing anything but True and False (a string "no" is truthy)."""
    if not isinstance(value, (bool, np.bool_)):
        raise TypeError(f"{what} must be True or False, got {type(value).__name__} {value!r}")
    return bool(value)


def real_array(value, what: str) -> np.ndarray:
    """`value` as a float array, refusing strings, bools and other non-numbers (TypeError naming `what`)."""
    arr = np.asarray(value)
    if arr.dtype.kind == "O":
        if any(isinstance(v, (str, bytes, bool, np.bool_)) or v is None for v in arr.flat):
            raise TypeError(f"{what} must hold real numbers, got {value!r}")
        try:
            arr = arr.astype(float)
        except (TypeError, ValueError):
            raise TypeError(f"{what} must hold real numbers, got {value!r}") from None
    elif arr.dtype.kind not in "iuf":
        raise TypeError(f"{what} must hold real numbers, got {value!r}")
    return np.asarray(arr, dtype=float)


def as_vector(value, size: int, what: str) -> np.ndarray:
    """Return `value` as a finite float vector of length `size`.

    Raises
    ------
    TypeError
        Naming `what` when an entry is not a real number (a string, a bool).
    ValueError
        Naming `what` when the length is wrong or an entry is NaN or infinite.
    """
    arr = real_array(value, what)
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
    arr = real_array(value, what)
    if arr.ndim == 1 and columns == 1:
        arr = arr[:, None]
    if arr.ndim != 2 or arr.shape[1] != columns or (rows is not None and arr.shape[0] != rows):
        want = f"({rows if rows is not None else 'N'}, {columns})"
        raise ValueError(f"{what} must have shape {want}, got {np.shape(value)}")
    if not np.all(np.isfinite(arr)):
        bad = np.argwhere(~np.isfinite(arr))[0]
        raise ValueError(f"{what} has a non-finite entry at row {bad[0]}, column {bad[1]}")
    return arr


def weight_matrix(value, size: int, what: str, *, names=None, definite: bool = False) -> np.ndarray:
    """A quadratic weight as a (size, size) matrix, checked finite, symmetric and positive (semi)definite.

    The one normalizer of every weight Q, R, P of the LQR, MPC and tuning layers.

    Parameters
    ----------
    value : a scalar (times the identity), a diagonal (size,), a matrix (size, size), or, with `names`,
        a dict {name: diagonal weight} (the names not given weigh 0)
    size : the matrix's order
    what : the argument's name, for messages
    names : (size,) the signal names a dict may use
    definite : require positive definite (an input weight R) instead of semidefinite

    Returns
    -------
    ndarray (size, size), as given when it is a matrix (a computed weight such as a noise covariance
    G Σ Gᵀ, symmetric only to rounding, is not symmetrized: its solvers' answers stay as they were)

    Raises
    ------
    TypeError
        When an entry is not a real number.
    ValueError
        Naming `what`: a wrong shape, an unknown name, a non-finite entry, an asymmetric or an
        indefinite matrix.
    """
    arr: np.ndarray
    if isinstance(value, Mapping):
        if names is None:
            raise TypeError(f"{what} must be a scalar, a diagonal or a matrix, got a dict {value!r}")
        unknown = [k for k in value if k not in names]
        if unknown:
            raise ValueError(f"{what}: no signal named {unknown}; the names are {', '.join(names)}")
        arr = np.diag([real(value.get(k, 0.0), f"{what}[{k!r}]") for k in names])
    else:
        arr = real_array(value, what)
        if arr.ndim == 0:
            arr = arr * np.eye(size)
        elif arr.ndim == 1 and arr.size == size:
            arr = np.diag(arr)
    if arr.shape != (size, size):
        raise ValueError(
            f"{what} must be {'a dict, ' if names is not None else ''}a scalar, {size} diagonal entries or a "
            f"({size}, {size}) matrix, got shape {np.shape(value)}"
        )
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{what} has non-finite entries: {arr.tolist()}")
    scale = max(1.0, float(np.max(np.abs(arr), initial=0.0)))
    if not np.allclose(arr, arr.T, rtol=0.0, atol=1e-12 * scale):
        raise ValueError(f"{what} must be symmetric, got {arr.tolist()}")
    lowest = float(np.min(np.linalg.eigvalsh(arr))) if size else 1.0
    if (definite and lowest <= 0) or lowest < -1e-12 * scale:
        kind = "definite" if definite else "semidefinite"
        raise ValueError(f"{what} must be positive {kind} (lowest eigenvalue {lowest:.3g})")
    return arr


def format_bytes(nbytes: float) -> str:
    """'1.5 GiB' for 1.5 * 2**30."""
    for unit, size in (("TiB", 2**40), ("GiB", 2**30), ("MiB", 2**20), ("KiB", 2**10)):
        if nbytes >= size:
            return f"{nbytes / size:.3g} {unit}"
    return f"{nbytes:.0f} B"


def check_memory(nbytes: float, what: str, hint: str = "") -> None:
    """Refuse a request whose estimated memory `nbytes` exceeds `MEMORY_LIMIT_BYTES`.

    Parameters
    ----------
    nbytes : estimated bytes the request would allocate
    what : the request, e.g. "simulate_closed_loop of 1e9 steps"
    hint : how to stay within the limit (appended to the message)

    Raises
    ------
    ResourceLimitError
        Naming the request, its size and the limit.
    """
    if nbytes > MEMORY_LIMIT_BYTES:
        raise ResourceLimitError(
            f"{what} needs about {format_bytes(nbytes)}, above the limit of {format_bytes(MEMORY_LIMIT_BYTES)} "
            f"(models.checks.MEMORY_LIMIT_BYTES){'; ' + hint if hint else ''}"
        )


def first_divergence(x: np.ndarray, bound: float) -> int | None:
    """Index of the first row of `x` that is non-finite or exceeds `bound` in magnitude."""
    bad = ~np.all(np.isfinite(x), axis=1) | np.any(np.abs(np.nan_to_num(x, nan=np.inf)) > bound, axis=1)
    idx = np.flatnonzero(bad)
    return int(idx[0]) if idx.size else None
