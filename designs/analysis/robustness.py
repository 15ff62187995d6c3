"""Frequency-domain measures of a loop gain: gain and phase margins, disk margin, closed-loop bandwidth.

`frequency_measures` is the one function that measures what the frequency fields of
`models.specs.Specs` ask of a loop: the study tables judge a row's linearized loop
with it (`studies.judging`), and a tuner can constrain the same numbers. For a
SISO loop gain L (continuous or sampled; the closed loop is 1 + L = 0, negative
feedback):

- gain and phase margins: `designs.analysis.margins`, the one margins computation;
- disk margin α (balanced, skew 0): 1 / max_ω |S(jω) − ½| with S = 1/(1 + L), so
  that L survives any simultaneous gain and phase change f in the disk
  |(f − 1)/(f + 1)| < α/2; its gain margin ±20 log10((1 + α/2)/(1 − α/2)) dB and
  phase margin 2 atan(α/2) deg (Seiler, Packard and Gahinet, "An introduction to
  disk margins", IEEE Control Systems 2020); 0 when the closed loop is unstable;
- bandwidth: the first frequency at which |T| = |L/(1 + L)| falls `dbdrop` dB
  (default 3) below its DC value, as python-control's `bandwidth` defines it.

The peak of |S − ½| is found on a grid that resolves every pole and zero of L and
of the closed loop (`discrete_grid` for a sampled loop, its continuous analogue
otherwise), refined by a bounded scalar search; the bandwidth's crossing by
`scipy.optimize.brentq` on the exact response. Frequencies in rad/s.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING

import numpy as np

from models import deferred

from .stability_margins import discrete_grid, margins, sampled_response

if TYPE_CHECKING:
    import control
else:
    control = deferred.module("control")
scipy = deferred.module("scipy")

__all__ = ["FrequencyMeasures", "frequency_measures", "disk_margin_from_alpha"]


@dataclass(frozen=True)
class FrequencyMeasures:
    """What `frequency_measures` finds of one loop.

    Attributes
    ----------
    gain_margin_db : dB (inf when the phase never crosses −180°)
    phase_margin_deg : deg (inf when |L| never crosses 1)
    disk_margin : α, dimensionless (0 when the closed loop is unstable)
    disk_gain_margin_db : dB, the gain change (either way) the disk margin tolerates
    disk_phase_margin_deg : deg, the phase change (either way) the disk margin tolerates
    bandwidth_rad_s : rad/s, the closed loop's −`dbdrop` dB frequency (inf when |T| never drops that far;
        nan when T's DC gain is infinite)
    stable : whether the closed loop 1 + L = 0 is stable
    """

    gain_margin_db: float
    phase_margin_deg: float
    disk_margin: float
    disk_gain_margin_db: float
    disk_phase_margin_deg: float
    bandwidth_rad_s: float
    stable: bool

    def as_dict(self) -> dict:
        """The measures by name (the names the frequency fields of `models.specs.Specs` judge)."""
        return asdict(self)


def disk_margin_from_alpha(alpha: float) -> tuple[float, float]:
    """(gain margin dB, phase margin deg) a balanced disk margin α tolerates: ±20 log10((1 + α/2)/(1 − α/2))
    and 2 atan(α/2) in degrees (inf gain margin and 90° from α ≥ 2 on)."""
    if alpha >= 2:
        return math.inf, 90.0 if alpha == 2 else math.degrees(2 * math.atan(alpha / 2))
    gain = 20 * math.log10((1 + alpha / 2) / (1 - alpha / 2))
    return gain, math.degrees(2 * math.atan(alpha / 2))


def _sensitivity(L) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, float | None]:
    """(A, B, C, D, dt) of S = 1/(1 + L) for a SISO loop L (dt None when continuous)."""
    sys = control.ss(L)
    if sys.ninputs != 1 or sys.noutputs != 1:
        raise ValueError(f"frequency measures need a SISO loop gain, got {sys.noutputs}x{sys.ninputs}")
    A, B, C, D = (np.asarray(m, dtype=float) for m in (sys.A, sys.B, sys.C, sys.D))
    d = 1.0 + float(D[0, 0])
    if d == 0:
        raise ValueError("the loop gain's feedthrough is −1: 1 + L is not proper")
    dt = float(sys.dt) if sys.isdtime(strict=True) else None
    return A - B @ C / d, B / d, -C / d, 1.0 / d, dt


def _response(A, B, C, D: float, dt: float | None):
    """omega (F,) rad/s -> C (sI − A)⁻¹ B + D at s = jω (continuous) or z = e^{jωdt} (sampled), complex (F,)."""
    Dm = np.array([[D]])
    if dt is not None:
        return lambda w: sampled_response(A, B, C, Dm, dt, np.atleast_1d(w))
    if A.shape[0] == 0:
        return lambda w: np.full(np.atleast_1d(w).shape, D, dtype=complex)
    eye = np.eye(A.shape[0])

    def response(w):
        s = 1j * np.atleast_1d(np.asarray(w, dtype=float))
        rhs = np.broadcast_to(B.astype(complex), (len(s), *B.shape))
        return (C @ np.linalg.solve(s[:, None, None] * eye - A, rhs))[:, 0, 0] + D

    return response


def _continuous_grid(features: np.ndarray, points_per_decade: int = 200) -> np.ndarray:
    """0, a logarithmic grid two decades beyond the slowest and the fastest feature (|s| and |Im s| of
    poles and zeros), and offsets from 1e-6 to 0.5 of each feature on either side, log-spaced."""
    features = features[np.isfinite(features) & (features > 0)]
    lo = features.min() / 100 if features.size else 1e-3
    hi = features.max() * 100 if features.size else 1e3
    grid = np.logspace(np.log10(lo), np.log10(hi), int(np.ceil(np.log10(hi / lo) * points_per_decade)) + 1)
    offsets = np.geomspace(1e-6, 0.5, 60)
    local = (features[:, None] * (1 + np.concatenate([-offsets, [0.0], offsets]))[None]).ravel()
    return np.concatenate([[0.0], np.unique(np.concatenate([grid, local[local > 0]]))])


def _grid(L, A_closed: np.ndarray, dt: float | None) -> np.ndarray:
    """A frequency grid resolving the poles and zeros of L and the closed loop's poles."""
    sys = control.ss(L)
    points = np.concatenate([np.linalg.eigvals(A_closed), np.atleast_1d(sys.poles()), np.atleast_1d(sys.zeros())])
    if dt is not None:
        return discrete_grid(points, dt)
    return _continuous_grid(np.concatenate([np.abs(points), np.abs(points.imag)]))


def _peak(f, grid: np.ndarray) -> float:
    """The largest f on `grid`, refined between the neighbours of the grid's largest."""
    values = f(grid)
    i = int(np.argmax(values))
    best = float(values[i])
    if 0 < i < grid.size - 1:
        found = scipy.optimize.minimize_scalar(
            lambda w: -float(f(np.array([w]))[0]),
            bounds=(grid[i - 1], grid[i + 1]),
            method="bounded",
            options={"xatol": 1e-12 * max(grid[i], 1.0)},
        )
        best = max(best, -float(found.fun))
    return best


def frequency_measures(L, dbdrop: float = -3.0) -> FrequencyMeasures:
    """Margins, disk margin and closed-loop bandwidth of the SISO loop gain `L` (see the module docstring).

    Parameters
    ----------
    L : a continuous or sampled SISO `control.TransferFunction` or `control.StateSpace`, or an object with
        `system()` returning one (`studies.loops.LoopGain`); the closed loop is 1 + L = 0
    dbdrop : dB < 0, the drop of |T| that defines the bandwidth

    Returns
    -------
    FrequencyMeasures
    """
    if hasattr(L, "system"):
        L = L.system()
    if isinstance(dbdrop, bool) or not isinstance(dbdrop, (int, float, np.floating)) or not dbdrop < 0:
        raise ValueError(f"dbdrop must be a negative number of dB, got {dbdrop!r}")
    dbdrop = float(dbdrop)
    A, B, C, D, dt = _sensitivity(L)
    poles = np.linalg.eigvals(A)
    stable = bool(np.all(np.abs(poles) < 1)) if dt is not None else bool(np.all(poles.real < 0))
    sensitivity = _response(A, B, C, D, dt)
    grid = _grid(L, A, dt)
    alpha = 1.0 / _peak(lambda w: np.abs(sensitivity(w) - 0.5), grid) if stable else 0.0
    disk_gain, disk_phase = disk_margin_from_alpha(alpha)
    found = margins(L)
    return FrequencyMeasures(
        gain_margin_db=float(found["gm_db"]),
        phase_margin_deg=float(found["pm_deg"]),
        disk_margin=float(alpha),
        disk_gain_margin_db=float(disk_gain),
        disk_phase_margin_deg=float(disk_phase),
        bandwidth_rad_s=_bandwidth(sensitivity, grid, dbdrop) if stable else math.nan,
        stable=stable,
    )


def _bandwidth(sensitivity, grid: np.ndarray, dbdrop: float) -> float:
    """The first ω at which |T| = |1 − S| falls below its DC value times 10^(dbdrop/20)."""
    complementary = lambda w: np.abs(1.0 - sensitivity(w))  # noqa: E731
    dc = float(complementary(np.array([0.0]))[0])
    if not np.isfinite(dc):
        return math.nan
    level = dc * 10 ** (dbdrop / 20)
    below = np.flatnonzero(complementary(grid) < level)
    if below.size == 0:
        return math.inf
    i = int(below[0])
    return float(
        scipy.optimize.brentq(lambda w: complementary(np.array([w]))[0] - level, grid[i - 1], grid[i], xtol=1e-14)
    )
